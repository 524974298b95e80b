"""The toe fit's compiled kernel (tapcell.tap._c_toe) against its numpy twin (tapcell.tap.toe).

Inputs are the toe fits of taps from the independent generator (taplab): clean taps fit the
drift with the baseline or take it from the approach, cable-drift taps weigh the baseline's walk
(the whitened grid). Both sides solve the same least squares; only the order of the sums differs.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from tapcell.tap import analysis, analyze_tap, toe
from native_kernel_inputs import OPTIONS, generated_taps, recorded_calls

pytestmark = pytest.mark.skipif(toe._C is None, reason="the toe kernel is not built (TAPCELL_NATIVE=0)")

# Three taps of each: the walk is weighed on most cable-drift taps and on some clean 2000-sps ones.
SCENARIO_NAMES = ("clean_hx717", "clean_ads1220_2000", "cable_drift", "mild_ooze", "soft_sheet", "mains_hum",
                  "latency")
TAPS_EACH = 3


@pytest.fixture(scope="module")
def taps():
    return generated_taps(TAPS_EACH, 7, SCENARIO_NAMES)


@pytest.fixture(scope="module")
def toe_fits(taps):
    """The arguments of every fit_toe call the analysis of the taps makes."""
    return recorded_calls(analysis, "fit_toe", [OPTIONS["default"]], taps)


def _grid_inputs(x_lo_um, x_hi_um, force_g, contact0_um, spacing_um, drift_g_um, wander):
    """fit_toe's arguments as its grids take them (the same steps as fit_toe)."""
    keep = (x_lo_um < contact0_um + toe.COARSE_ABOVE_UM + toe.DEPARTURE_REACH_SAMPLES * spacing_um) & (
        x_hi_um > contact0_um - toe.PENETRATION_REACH_UM)
    walk = wander if wander is not None and wander.matters(np.count_nonzero(keep)) else None
    return (x_lo_um[keep], x_hi_um[keep], force_g[keep], drift_g_um, walk, contact0_um + toe._CONTACT_OFFSETS_UM,
            contact0_um + toe._GRID_OFFSETS_UM)


def _whitened_yy(x_lo_um, x_hi_um, force_g, drift_g_um, wander, contacts_um, _):
    """The whitened force's sum of squares (numpy twin's `_Whitened`)."""
    window_um = x_lo_um[:, None] + (x_hi_um - x_lo_um)[:, None] * toe._SUBSAMPLE_FRACTIONS
    x_mid = 0.5 * (x_lo_um + x_hi_um)
    y = force_g if drift_g_um is None else force_g - drift_g_um * x_mid
    return toe._Whitened.prepare(window_um, x_mid, y, wander, contacts_um[0], contacts_um[-1],
                                 toe.TOE_WIDTHS_UM[-1]).yy


def test_grids_and_stiffness_equal_the_numpy_twin(toe_fits):
    # Measured on these taps and seeds 8, 9: the plain grid agrees to 6e-14 of its largest finite
    # residual, its stiffness to 2e-15. The walk-weighted grid to 1.9e-11 of the whitened force's
    # sum of squares (`yy`), its stiffness to 7e-12: a walk small against the white noise makes the
    # whitening recursion's gain near 1, so the whitened toe column grows along the pressed run and
    # its sums cancel; the kernel takes the pressed and free runs from sums prepared once where
    # numpy steps through every sample, so the two round differently. Tolerances: 10-20x those.
    paths = {"plain": 0, "walk": 0}
    for args in toe_fits:
        inputs = _grid_inputs(*args)
        rss_np, unit_np, stiffness_np = toe._toe_grid(*inputs)
        rss_c, unit_c, stiffness_c = toe._toe_grid_native(*inputs)
        assert unit_c == unit_np
        walk = unit_np != 1.0
        paths["walk" if walk else "plain"] += 1
        assert rss_c.shape == rss_np.shape == (len(toe.TOE_POWERS), len(toe._GRID_OFFSETS_UM))
        assert np.array_equal(np.isinf(rss_c), np.isinf(rss_np))
        finite = np.isfinite(rss_np)
        assert finite.sum() > 100
        if walk:
            scale = _whitened_yy(*inputs)
            np.testing.assert_allclose(rss_c[finite], rss_np[finite], rtol=0, atol=2e-10 * scale)
        else:
            scale = np.abs(rss_np[finite]).max()
            np.testing.assert_allclose(rss_c[finite], rss_np[finite], rtol=0, atol=1e-12 * scale)
        contact0_um = args[3]
        for power in toe.TOE_POWERS:
            for width_um in (0.0, 4.5, 16.0):
                expected = stiffness_np(contact0_um + 0.75, width_um, power)
                got = stiffness_c(contact0_um + 0.75, width_um, power)
                assert got == pytest.approx(expected, rel=1e-10 if walk else 3e-14)
    assert paths["walk"] >= 3 and paths["plain"] >= 8  # both kernels ran


def test_fit_toe_dispatches_to_the_kernel(toe_fits, monkeypatch):
    def numpy_grid(*args):
        raise AssertionError("the numpy grid ran with the kernel there")

    monkeypatch.setattr(toe, "_toe_grid", numpy_grid)
    assert any(toe.fit_toe(*args) is not None for args in toe_fits)
    monkeypatch.setattr(toe, "_C", None)
    with pytest.raises(AssertionError, match="numpy grid ran"):
        toe.fit_toe(*toe_fits[0])


def test_fits_equal_the_numpy_twin(toe_fits, monkeypatch):
    fits = [toe.fit_toe(*args) for args in toe_fits]
    monkeypatch.setattr(toe, "_C", None)
    for args, fit in zip(toe_fits, fits):
        twin = toe.fit_toe(*args)
        assert (fit is None) == (twin is None)
        if fit is None:
            continue
        assert fit.contact_um == pytest.approx(twin.contact_um, abs=1e-8)
        assert fit.sigma_um == pytest.approx(twin.sigma_um, rel=1e-8)
        assert fit.residual_sigma_g == pytest.approx(twin.residual_sigma_g, rel=1e-8)


def test_marginal_contact_equals_the_numpy_twin(monkeypatch):
    rng = np.random.default_rng(3)
    contacts_um = 40.0 + toe._CONTACT_OFFSETS_UM
    count = len(contacts_um)
    bowl = (np.arange(count) - rng.uniform(3, count - 3, size=(20, 1))) ** 2 * rng.uniform(0.5, 3, size=(20, 1))
    rss = 50.0 + bowl + rng.normal(size=(20, count)) * 0.1
    rss[3, :] = np.inf  # a toe that never solves
    rss[4, 8] = np.inf  # a neighbour of the least that does not
    rss[5, :] = 60.0
    rss[5, [6, 12]] = 59.0  # exact ties: the first is the toe's minimum, as np.argmin
    rss[5, 7] = 61.0
    cases = [(rss, 0.3, toe._TOE_PRIOR), (rss, 2.0, None), (rss[:, ::-1].copy(), 0.05, toe._TOE_PRIOR),
             (np.full((20, count), np.inf), 1.0, None)]
    kernel = [toe.marginal_contact_um(contacts_um, *case) for case in cases]
    monkeypatch.setattr(toe, "_C", None)
    for case, (mean, sd) in zip(cases, kernel):
        twin_mean, twin_sd = toe.marginal_contact_um(contacts_um, *case)
        if twin_mean is None:
            assert mean is None and sd == twin_sd == toe.COARSE_STEP_UM
            continue
        assert mean == pytest.approx(twin_mean, abs=1e-12) and sd == pytest.approx(twin_sd, rel=1e-12)


def test_shape_spread_equals_the_numpy_twin(monkeypatch):
    # shape_spread_um's one kernel call (each toe's minimum found once for both shapes) against its
    # two marginal calls, on residual grids with ties, unsolvable toes and a shape with no curved minimum.
    rng = np.random.default_rng(4)
    contacts_um = 40.0 + toe._CONTACT_OFFSETS_UM
    toes, count = len(toe._TOE_PRIOR), len(contacts_um)
    bowl = (np.arange(count) - rng.uniform(3, count - 3, size=(toes, 1))) ** 2 * rng.uniform(0.5, 3, size=(toes, 1))
    rss = 50.0 + bowl + rng.normal(size=(toes, count)) * 0.1
    rss[3, :] = np.inf
    rss[5, [6, 12]] = 40.0  # exact ties
    one_shape = rss.copy()
    one_shape[len(toe.TOE_WIDTHS_UM):] = 70.0  # the second shape flat: only the first has a minimum
    cases = [(rss, 0.3), (rss, 5.0), (rss[:, ::-1].copy(), 0.05), (one_shape, 0.3), (np.full((toes, count), np.inf), 1.0)]
    kernel = [toe.shape_spread_um(contacts_um, *case) for case in cases]
    compiled = toe._C
    monkeypatch.setattr(toe, "_C", None)
    twins = [toe.shape_spread_um(contacts_um, *case) for case in cases]
    assert kernel[3:] == twins[3:] == [0.0, 0.0]  # one shape known, or none: no spread
    assert kernel[:3] == pytest.approx(twins[:3], rel=1e-12, abs=1e-12)
    assert min(kernel[:3]) > 0.0
    mean, sd, spread = compiled.marginal_contact_and_spread(contacts_um, rss, 0.3, toe._TOE_PRIOR, 2)
    assert (mean, sd) == pytest.approx(toe.marginal_contact_um(contacts_um, rss, 0.3, toe._TOE_PRIOR), rel=1e-12)
    assert spread == kernel[0]
    with pytest.raises(ValueError, match="shapes: 3 does not divide"):
        compiled.marginal_contact_and_spread(contacts_um, rss, 1.0, toe._TOE_PRIOR, 3)


def test_kernel_rejects_wrong_arrays():
    x_lo_um = np.arange(20.0)
    samples = (x_lo_um, x_lo_um + 1.0, x_lo_um, math.nan, 2)
    contacts_um, widths_um = np.arange(5.0), np.zeros(5)
    with pytest.raises(ValueError, match="rss_out: 9 values, 10 expected"):
        toe._C.rss_grid(*samples, contacts_um, widths_um, np.empty(9))
    with pytest.raises(ValueError, match="force_g: 19 values, 20 expected"):
        toe._C.rss_grid(x_lo_um, x_lo_um + 1.0, x_lo_um[:-1], 0.0, 2, contacts_um, widths_um, np.empty(10))
    with pytest.raises(ValueError, match="power: 2"):
        toe._C.stiffness_at(*samples, 3.0, 1.0, 2.0)


def test_analysis_equals_the_numpy_twin(taps, monkeypatch):
    results = [analyze_tap(tap) for tap in taps]
    monkeypatch.setattr(toe, "_C", None)
    toe_used = 0
    for tap, result in zip(taps, results):
        twin = analyze_tap(tap)
        assert (result.valid, result.error) == (twin.valid, twin.error)
        if twin.z_mm is None:
            assert result.z_mm is None
            continue
        assert abs(result.z_mm - twin.z_mm) * 1000.0 < 1e-6
        if twin.z_sigma_um is not None:
            assert math.isclose(result.z_sigma_um, twin.z_sigma_um, rel_tol=1e-6)
        toe_used += twin.contact_onset_um is not None
    assert toe_used >= 15


def test_free_air_variogram_equals_the_numpy_twin(taps, monkeypatch):
    # Measured on these taps and seed 8: 1e-15 relative (the kernel takes the line out of each
    # difference, numpy out of each sample first).
    segments = [force_g for (force_g,) in recorded_calls(analysis, "free_air_variogram", [OPTIONS["default"]],
                                                          taps[:6])]
    kernel = [toe.free_air_variogram(force_g) for force_g in segments]
    monkeypatch.setattr(toe, "_C", None)
    measured = 0
    for force_g, (expected, values) in zip(segments, kernel):
        twin_expected, twin_values = toe.free_air_variogram(force_g)
        assert expected == twin_expected
        np.testing.assert_allclose(values, twin_values, rtol=1e-13, atol=0)
        measured += len(values) > 0
    assert measured >= 8


def test_adhesion_measures_equal_the_numpy_twin(monkeypatch):
    # The dip's run means are summed in another order than np.convolve's: ~1e-15 relative of forces
    # of tens of grams; medians select, they do not sum.
    calls = recorded_calls(analysis, "adhesion_measures", [OPTIONS["default"]])
    kernel = [toe.adhesion_measures(*args) for args in calls]
    monkeypatch.setattr(toe, "_C", None)
    twins = [toe.adhesion_measures(*args) for args in calls]
    for measured, twin in zip(kernel, twins):
        for value, twin_value in zip(measured, twin):
            assert (value is None) == (twin_value is None)
            if twin_value is not None:
                assert value == pytest.approx(twin_value, abs=1e-9)
    assert sum(dip is not None for dip, _ in twins) >= 10 and sum(pull is not None for _, pull in twins) >= 10
    assert max(dip for dip, _ in twins if dip is not None) > 3.0  # ooze taps: real dips, not only noise (4.9 g)


def test_thread_pulls_equal_the_numpy_twin_bit_for_bit(monkeypatch):
    # Both take the same mid-heights and differences and select their medians: no sum in another order.
    calls = recorded_calls(analysis, "thread_pulls_g", [OPTIONS["default"]])
    kernel = [toe.thread_pulls_g(*args) for args in calls]
    monkeypatch.setattr(toe, "_C", None)
    twins = [toe.thread_pulls_g(*args) for args in calls]
    assert kernel == twins
    assert sum(near is not None for near, _ in twins) >= 10 and sum(far is not None for _, far in twins) >= 5
    assert any(far is None and near is not None for near, far in twins)  # a pullback too short to reach far
