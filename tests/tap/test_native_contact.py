"""The compiled contact kernel (tapcell.tap._c_contact) against its numpy twin in contact.py.

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


def test_the_kernel_is_used(monkeypatch):
    used = kernel_functions_used(contact, OPTIONS["sharp"])
    assert used and set(used) == {"fit_fixed_onset"}


@pytest.mark.parametrize("name", list(OPTIONS))
def test_fits_agree_with_the_twin_on_generated_taps(monkeypatch, name):
    # Every onset path: none (default, sharp), fitted per tap (a grid of onsets), calibrated.
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
