"""The compiled contact kernel (tapcell.tap._c_contact) against its numpy twins in contact.py and
analysis.py (the pullback's and the compression's whole fits, at the end).

The kernel evaluates the twin's formulas in the twin's order; only its sums over samples run in
another order (numpy sums pairwise, BLAS dots its own way), so the two agree to rounding. The
tolerances are 10x the largest differences measured on 4 seeds of generated taps (about 1150
fits: contact 8.5e-11 µm, stiffness and sigma 1.9e-12 relative, baseline 5e-11 g, residual sigma
and rss 1.1e-13 relative, residuals 3.6e-10 g; whole analyses: z 7e-11 µm, z sigma 3.8e-11 relative).
"""

from __future__ import annotations

import numpy as np
import pytest

from native_kernel_inputs import OPTIONS, generated_taps, kernel_functions_used, recorded_calls
from tapcell.tap import analysis, analyze_tap, contact

# Without a C compiler the kernel is not built and the twin is all there is (`make test` requires it).
pytestmark = pytest.mark.skipif(contact._C is None, reason="tapcell.tap._c_contact is not built")

ABSOLUTE = {"contact_um": 1e-9, "baseline_g": 1e-9}
RELATIVE = {"stiffness_g_um": 2e-11, "contact_sigma_um": 2e-11, "residual_sigma_g": 1e-12, "rss_g2": 1e-12}
RESIDUAL_G = 5e-9


def twin_fit(monkeypatch, *args):
    with monkeypatch.context() as patch:
        patch.setattr(contact, "_C", None)
        return contact.fit_fixed_onset(*args)


def assert_fits_agree(ours, theirs):
    assert (ours is None) == (theirs is None)
    if ours is None:
        return
    (fit, residual), (twin, twin_residual) = ours, theirs
    assert fit.onset_um == twin.onset_um
    for name, tolerance in ABSOLUTE.items():
        assert getattr(fit, name) == pytest.approx(getattr(twin, name), rel=0, abs=tolerance), name
    for name, tolerance in RELATIVE.items():
        assert getattr(fit, name) == pytest.approx(getattr(twin, name), rel=tolerance, abs=0), name
    np.testing.assert_allclose(residual, twin_residual, rtol=0, atol=RESIDUAL_G)


def test_the_kernels_are_used():
    # A fixed onset: the pullback's and the compression's whole fits; a fitted onset: the grid's searches.
    assert kernel_functions_used(contact, OPTIONS["sharp"]) == ["fit_pullback", "fit_compression"]
    used = kernel_functions_used(contact, OPTIONS["fitted_onset"])
    assert set(used) == {"fit_fixed_onset", "fit_compression"} and used.count("fit_fixed_onset") > 1


@pytest.mark.parametrize("name", list(OPTIONS))
def test_fits_agree_with_the_twin_on_generated_taps(monkeypatch, name):
    # Every onset path: none (default, sharp), fitted per tap (a grid of onsets), calibrated. The
    # searches the twins make (with a fixed onset the kernels fit_pullback and fit_compression make them).
    with monkeypatch.context() as patch:
        patch.setattr(contact, "_C", None)
        calls = recorded_calls(analysis, "fit_fixed_onset", [OPTIONS[name]])
    assert len(calls) >= len(generated_taps())  # pullback and compression of most taps, robust refits
    onsets = {args[-1] for args in calls}
    if name == "fitted_onset":  # the grid, and the compression at the pullback's fitted onset
        assert {0.0, *analysis.ONSET_GRID_UM} < onsets
    else:
        assert onsets == ({4.0} if name == "calibrated_onset" else {0.0})
    for args in calls:
        assert_fits_agree(contact.fit_fixed_onset(*args), twin_fit(monkeypatch, *args))


def _pullback(count: int, force_g: np.ndarray | None = None):
    """A plain pullback: windows of 1 µm from 6 µm below to `count - 6` µm above a contact at 0."""
    x_min = np.arange(count, dtype=float) - 6.0
    span = np.ones(count)
    if force_g is None:
        force_g = 3.0 * np.maximum(-x_min - 0.5, 0.0) + np.sin(np.arange(count))  # 3 g/µm, 1 g of "noise"
    return force_g, x_min, span


@pytest.mark.parametrize(("case", "answers"), [
    (_pullback(4), False),  # fewer than 5 samples: no fit
    (_pullback(30, np.full(30, 2.0)), False),  # no force: no positive stiffness anywhere
    (_pullback(30), True),
])
@pytest.mark.parametrize("onset_um", [0.0, 3.0])
def test_fits_agree_where_there_is_none(monkeypatch, case, answers, onset_um):
    args = (*case, 1.0, 1.0, onset_um)
    ours = contact.fit_fixed_onset(*args)
    assert (ours is not None) == answers
    assert_fits_agree(ours, twin_fit(monkeypatch, *args))


def test_bad_arrays_are_an_error():
    force_g, x_min, span = _pullback(30)
    with pytest.raises(TypeError, match="expected a float64 array"):
        contact._C.fit_fixed_onset(force_g, x_min, span.astype(np.int64), 0.0, 1.0, 0.0, 4, np.empty(30))
    with pytest.raises(ValueError, match="x_min_um: 29 values, 30 expected"):
        contact._C.fit_fixed_onset(force_g, x_min[1:], span, 0.0, 1.0, 0.0, 4, np.empty(30))
    with pytest.raises(ValueError, match="residual_g: 3 values, 30 expected"):
        contact._C.fit_fixed_onset(force_g, x_min, span, 0.0, 1.0, 0.0, 4, np.empty(3))


def test_whole_analyses_agree_with_the_twin(monkeypatch):
    for name in ("default", "sharp"):
        ours = [analyze_tap(tap, OPTIONS[name]) for tap in generated_taps()]
        monkeypatch.setattr(contact, "_C", None)
        theirs = [analyze_tap(tap, OPTIONS[name]) for tap in generated_taps()]
        monkeypatch.undo()
        assert [(a.valid, a.error, a.z_method) for a in ours] == [(b.valid, b.error, b.z_method) for b in theirs]
        assert sum(a.valid for a in ours) >= len(ours) // 2
        for a, b in zip(ours, theirs):
            assert (a.z_mm is None) == (b.z_mm is None)
            if a.z_mm is not None:
                assert a.z_mm == pytest.approx(b.z_mm, rel=0, abs=1e-12)  # 1e-9 µm
                assert a.z_sigma_um == pytest.approx(b.z_sigma_um, rel=1e-9)


# The pullback's and the compression's whole fits (_c_contact.fit_pullback, fit_compression) repeat their
# twins' arithmetic in their twins' order, the searches through the fit_fixed_onset kernel: the same to
# the last bit as the twins with that kernel; against the numpy twins, to the rounding of the searches.
NEAR_SIGMA_RELATIVE = 1e-11


def numpy_twin(monkeypatch, function, *args):
    """`function(*args)` with every kernel it may call off (contact's and analysis's)."""
    with monkeypatch.context() as patch:
        patch.setattr(contact, "_C", None)
        patch.setattr(analysis, "_C", None)
        return function(*args)


def assert_pullbacks_agree(ours, theirs):
    assert (ours is None) == (theirs is None)
    if ours is not None:
        assert_fits_agree((ours[0], np.zeros(1)), (theirs[0], np.zeros(1)))
        assert ours[1] == pytest.approx(theirs[1], rel=NEAR_SIGMA_RELATIVE, abs=0)


@pytest.mark.parametrize("name", ["default", "sharp", "calibrated_onset"])
def test_whole_fits_are_their_twins_on_generated_taps(monkeypatch, name):
    pullbacks = recorded_calls(analysis, "pullback_fit", [OPTIONS[name]])
    compressions = recorded_calls(analysis, "compression_fit", [OPTIONS[name]])
    assert len(pullbacks) == len(compressions) >= len(generated_taps()) * 3 // 4
    assert sum(analysis.pullback_fit(*args) is not None for args in pullbacks) >= len(pullbacks) * 3 // 4
    assert sum(analysis.compression_fit(*args) is not None for args in compressions) >= len(compressions) * 3 // 4
    assert any(args[-1] != 0.0 for args in compressions)  # a free-air drift taken out
    for args in pullbacks:
        ours = analysis.pullback_fit(*args)
        assert ours == analysis.pullback_fit_twin(*args)
        assert_pullbacks_agree(ours, numpy_twin(monkeypatch, analysis.pullback_fit_twin, *args))
    for args in compressions:
        ours = analysis.compression_fit(*args)
        assert ours == analysis.compression_fit_twin(*args)
        twin = numpy_twin(monkeypatch, analysis.compression_fit_twin, *args)
        assert_fits_agree(ours and (ours, np.zeros(1)), twin and (twin, np.zeros(1)))


def _robust_pass_case(count: int, spikes: dict[int, float]):
    """A pullback of `count` samples (`_pullback`) with forces added at some samples."""
    force_g, x_min, span = _pullback(count)
    for index, added_g in spikes.items():
        force_g[index] += added_g
    return force_g, x_min, span


def _dropped(force_g, x_min, span, options):
    """How many samples the twin's robust pass drops (0: its first fit explains them all)."""
    onset_um = options.contact_onset_um or 0.0
    fit, residual = contact.fit_fixed_onset(force_g, x_min, span, 0.5 + 0.5 * onset_um, 1.0, onset_um)
    keep = analysis._outliers_kept(residual, options.outlier_sigma, fit.residual_sigma_g)
    return 0 if keep is None else int(np.count_nonzero(~keep))


@pytest.mark.parametrize(("case", "dropped", "answers"), [
    (_pullback(4), None, False),  # fewer than 5 samples: no fit
    (_pullback(30, np.full(30, 2.0)), None, False),  # no force: no positive stiffness
    (_robust_pass_case(150, {}), 0, True),  # every residual within the limit: no median, no refit
    # A blob beyond 8 x the residual sigma, which it inflates itself (so only a long pullback shows it):
    (_robust_pass_case(150, {20: 60.0}), 1, True),  # dropped, fitted again
    (_robust_pass_case(150, {2: -100.0, 25: 100.0}), 2, True),  # one in contact, one in the departure
    (_robust_pass_case(30, {20: 60.0}), 0, True),  # within 8 x the sigma it inflates: kept
])
@pytest.mark.parametrize("options", [OPTIONS["sharp"], OPTIONS["calibrated_onset"]])
def test_the_pullback_kernel_is_its_twin_on_edge_cases(monkeypatch, case, dropped, answers, options):
    args = (*case, 0.5, 1.0, options)
    ours = analysis.pullback_fit(*args)
    assert (ours is not None) == answers
    assert ours == analysis.pullback_fit_twin(*args)
    assert_pullbacks_agree(ours, numpy_twin(monkeypatch, analysis.pullback_fit_twin, *args))
    if dropped is not None:
        assert _dropped(*case, options) == dropped
    if dropped:  # the refit moved the contact from the first fit's
        first = contact.fit_fixed_onset(*case, 0.5 + 0.5 * (options.contact_onset_um or 0.0), 1.0,
                                        options.contact_onset_um or 0.0)[0]
        assert ours[0].contact_um != first.contact_um


def test_the_near_sigma_falls_back_to_the_residual_sigma_below_four_samples(monkeypatch):
    # Windows 1 µm apart from 2.5 µm into contact; a 0.03 µm search spacing reaches 0.3 µm past the
    # contact: 3 samples start below that.
    x_min = np.arange(20.0) - 2.5
    force_g = 3.0 * np.maximum(-x_min - 0.5, 0.0) + 0.3 * np.sin(np.arange(20))
    args = (force_g, x_min, np.ones(20), 0.0, 0.03, OPTIONS["sharp"])
    fit, near_sigma_g = analysis.pullback_fit(*args)
    assert np.count_nonzero(x_min < fit.contact_um + analysis.MISFIT_REACH_SAMPLES * 0.03) == 3
    assert near_sigma_g == fit.residual_sigma_g
    assert (fit, near_sigma_g) == analysis.pullback_fit_twin(*args)
    assert_pullbacks_agree((fit, near_sigma_g), numpy_twin(monkeypatch, analysis.pullback_fit_twin, *args))


def _approach_window(count: int, contact_line_um: float = 0.5) -> analysis.ModelWindow:
    """An approach down to 8 µm below a contact at 0 (windows 1 µm wide, 3 g/µm), a 0.02 g/µm drift."""
    x_min = np.linspace(count - 9.0, -8.0, count)
    force_g = 3.0 * np.maximum(-x_min - 0.5, 0.0) + 0.02 * x_min + 0.3 * np.sin(np.arange(count))
    return analysis.ModelWindow(np.arange(count) * 0.01, force_g, x_min, np.ones(count), contact_line_um, 0.0)


@pytest.mark.parametrize(("window", "read_until_s", "answers"), [
    (_approach_window(40), 0.395, True),  # every sample read
    (_approach_window(40), 0.3651, True),  # the last three are read after: left out
    (_approach_window(40), 0.045, False),  # 5 samples read: too few
    (_approach_window(40), -1.0, False),  # none read
    (_approach_window(40, float("nan")), 0.395, False),  # no line estimate to search around
])
@pytest.mark.parametrize("drift_g_um", [0.0, 0.02])
@pytest.mark.parametrize("onset_um", [0.0, 3.0])
def test_the_compression_kernel_is_its_twin_on_edge_cases(monkeypatch, window, read_until_s, answers, drift_g_um,
                                                          onset_um):
    args = (window, read_until_s, 1.0, onset_um, drift_g_um)
    ours = analysis.compression_fit(*args)
    assert (ours is not None) == answers
    assert ours == analysis.compression_fit_twin(*args)
    twin = numpy_twin(monkeypatch, analysis.compression_fit_twin, *args)
    assert_fits_agree(ours and (ours, np.zeros(1)), twin and (twin, np.zeros(1)))
    if ours is not None and onset_um == 0.0:  # the sharp contact the window holds, within its noise
        assert abs(ours.contact_um) < 0.5


def test_the_compression_reads_only_the_samples_before_the_halt():
    window = _approach_window(40)
    early = analysis.compression_fit(window, 0.3651, 1.0, 0.0, 0.0)
    cut = analysis.ModelWindow(window.time_s[:37], window.force_g[:37], window.x_min_um[:37], window.span_um[:37],
                               window.contact_line_um, 0.0)
    assert early == analysis.compression_fit(cut, 10.0, 1.0, 0.0, 0.0)
    assert early == analysis.compression_fit(window, 36 * 0.01, 1.0, 0.0, 0.0)  # one read at the halt: in
    assert early == analysis.compression_fit_twin(window, 36 * 0.01, 1.0, 0.0, 0.0)
    assert early != analysis.compression_fit(window, 0.395, 1.0, 0.0, 0.0)


def test_bad_arrays_are_an_error_in_the_whole_fits():
    force_g, x_min, span = _pullback(30)
    with pytest.raises(ValueError, match="span_um: 29 values, 30 expected"):
        contact._C.fit_pullback(force_g, x_min, span[1:], 0.0, 1.0, 0.0, 4, 8.0, 10.0)
    with pytest.raises(ValueError, match="must be positive"):
        contact._C.fit_pullback(force_g, x_min, span, 0.0, 0.0, 0.0, 4, 8.0, 10.0)
    with pytest.raises(ValueError, match="time_s: 29 values, 30 expected"):
        contact._C.fit_compression(np.arange(29.0), force_g, x_min, span, 1.0, 0.0, 1.0, 0.0, 0.0, 4)
    with pytest.raises(TypeError, match="expected a float64 array"):
        contact._C.fit_compression(np.arange(30), force_g, x_min, span, 1.0, 0.0, 1.0, 0.0, 0.0, 4)
