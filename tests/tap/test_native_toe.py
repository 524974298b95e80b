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
from native_kernel_inputs import OPTIONS, generated_taps, recorded_calls, scalar_build

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


def test_fit_kernel_grid_and_stiffness_equal_the_numpy_twin(toe_fits):
    # The kernel's whole fit (c/toe.c `fit`) against the twin's grid, step by step. Measured on
    # these taps and seeds 8, 9: the plain grid agrees to 6e-14 of its largest finite residual, its
    # stiffness to 2e-15. The walk-weighted grid to 1.9e-11 of the whitened force's sum of squares
    # (`yy`), its stiffness to 7e-12: a walk small against the white noise makes the whitening
    # recursion's gain near 1, so the whitened toe column grows along the pressed run and its sums
    # cancel; the kernel takes the pressed and free runs from sums prepared once where numpy steps
    # through every sample, so the two round differently. Tolerances: 10-20x those.
    paths = {"plain": 0, "walk": 0}
    for args in toe_fits:
        inputs = _grid_inputs(*args)
        rss_np, unit_np, stiffness_np = toe._toe_grid(*inputs)
        fit = toe.fit_toe(*args)
        assert fit is not None
        walk = unit_np != 1.0
        paths["walk" if walk else "plain"] += 1
        # The candidates' heights are the twin's sums, bit for bit; the grid has the twin's layout.
        assert np.array_equal(fit.grid.contacts_um, inputs[5])
        assert fit.grid.prior is toe._TOE_PRIOR
        rss_c = fit.grid.rss.reshape(rss_np.shape)
        assert np.array_equal(np.isinf(rss_c), np.isinf(rss_np))
        finite = np.isfinite(rss_np)
        assert finite.sum() > 100
        tolerance = 2e-10 * _whitened_yy(*inputs) if walk else 1e-12 * np.abs(rss_np[finite]).max()
        np.testing.assert_allclose(rss_c[finite], rss_np[finite], rtol=0, atol=tolerance)
        # The least residual's toe, its variance per degree of freedom and the stiffness at the
        # marginal contact, as the twin takes them from its grid.
        best = int(rss_np.argmin())
        power_index, width_index = divmod(best // len(toe._CONTACT_OFFSETS_UM), len(toe.TOE_WIDTHS_UM))
        assert (fit.power, fit.width_um) == (toe.TOE_POWERS[power_index], toe.TOE_WIDTHS_UM[width_index])
        samples = len(inputs[2])
        dof = samples - 4 - (2 if inputs[3] is None else 1)
        assert fit.grid.noise_var == pytest.approx(max(rss_np.flat[best] / dof, 1e-12), rel=0, abs=tolerance / dof)
        assert fit.residual_sigma_g == pytest.approx(math.sqrt(fit.grid.noise_var * unit_np), rel=1e-15)
        expected = stiffness_np(fit.contact_um, fit.width_um, fit.power)
        assert fit.stiffness_g_um == pytest.approx(expected, rel=1e-10 if walk else 3e-14)
    assert paths["walk"] >= 3 and paths["plain"] >= 8  # both grids ran


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
        assert (fit.width_um, fit.power) == (twin.width_um, twin.power)
        assert fit.stiffness_g_um == pytest.approx(twin.stiffness_g_um, rel=1e-8)
        assert fit.grid.rss.shape == twin.grid.rss.shape and np.array_equal(fit.grid.contacts_um, twin.grid.contacts_um)


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


def test_the_fit_keeps_the_shape_spread_its_grid_gives(toe_fits, monkeypatch):
    # The kernel's fit finds z_sigma_um's shape part from the minima its marginal found: the same bits as
    # shape_spread_um's own kernel call on the grid it returned (what the Z uncertainty called before).
    from tapcell.tap import uncertainty

    fits = [fit for fit in (toe.fit_toe(*args) for args in toe_fits) if fit is not None]
    assert len(fits) >= 20
    kept = [fit.grid.shape_um for fit in fits]
    assert kept == [toe.shape_spread_um(fit.grid.contacts_um, fit.grid.rss, fit.grid.noise_var) for fit in fits]
    assert sum(spread > 0.0 for spread in kept) >= 10  # spreads, not only the zeros of one shape
    # The twin leaves it to be computed from the grid when asked.
    monkeypatch.setattr(toe, "_C", None)
    twin = toe.fit_toe(*toe_fits[0])
    assert twin.grid.shape_um is None and uncertainty.toe_shape_um(twin.grid) == toe.shape_spread_um(
        twin.grid.contacts_um, twin.grid.rss, twin.grid.noise_var)


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


def _fit_args(x_lo_um, force_g, contact0_um=10.0, drift_g_um=math.nan, walk=(math.nan, math.nan), span_um=1.0):
    return (x_lo_um, x_lo_um + span_um, force_g, contact0_um, 1.0, drift_g_um, *walk, toe._FIT_GRID)


def _fit_outputs():
    return np.empty(len(toe._CONTACT_OFFSETS_UM)), np.empty((len(toe._TOE_PRIOR), len(toe._CONTACT_OFFSETS_UM)))


def test_kernel_rejects_wrong_arrays():
    x_lo_um = np.arange(20.0)
    contacts, rss = _fit_outputs()
    with pytest.raises(ValueError, match="rss_out: 539 values, 540 expected"):
        toe._C.fit(*_fit_args(x_lo_um, x_lo_um), contacts, np.empty(539))
    with pytest.raises(ValueError, match="force_g: 19 values, 20 expected"):
        toe._C.fit(*_fit_args(x_lo_um, x_lo_um[:-1]), contacts, rss)
    with pytest.raises(ValueError, match="contacts_out: 26 values, 27 expected"):
        toe._C.fit(*_fit_args(x_lo_um, x_lo_um), np.empty(26), rss)
    with pytest.raises(TypeError, match="float64"):
        toe._C.fit(*_fit_args(x_lo_um, np.arange(20)), contacts, rss)
    bad_grid = (*toe._FIT_GRID[:4], 0, *toe._FIT_GRID[5:])  # no subsample per window
    with pytest.raises(ValueError, match="0 subsamples"):
        toe._C.fit(*_fit_args(x_lo_um, x_lo_um)[:-1], bad_grid, contacts, rss)
    model = toe._free_air_model(60)
    with pytest.raises(ValueError, match="not rows of 4"):
        toe._C.free_air_walks(np.zeros(60), np.zeros(60), model.ravel()[:-1], model, 10.0, 1.0)
    with pytest.raises(ValueError, match="row 0's lag is not a whole number of 1..59"):
        toe._C.free_air_walks(np.zeros(60), np.zeros(60), model, model + [0.5, 0, 0, 0], 10.0, 1.0)
    with pytest.raises(ValueError, match="of 1..19"):  # a model for more samples than the segment has
        toe._C.free_air_walks(np.zeros(20), np.zeros(60), model, model, 10.0, 1.0)


def test_fit_kernel_on_degenerate_pullbacks(monkeypatch):
    # Each case as the twin answers it: too few samples near the start, every window of zero span,
    # a force that never leaves the baseline (no toe presses: no finite residual), a walk that
    # matters but samples that are no plain rise (the plain grid runs), and a clean hinge.
    x_lo_um = np.arange(-40.0, 80.0, 0.5)
    hinge_g = 30.0 * np.maximum(9.6 - (x_lo_um + 0.5), 0.0)
    noise_g = np.random.default_rng(5).normal(0.0, 0.3, len(x_lo_um))
    cases = {
        "few samples": (x_lo_um[::40], hinge_g[::40] + noise_g[::40], 10.0, 0.0, None, 1.0),
        "zero span": (x_lo_um, hinge_g + noise_g, 10.0, None, None, 0.0),
        "flat": (x_lo_um, np.zeros_like(x_lo_um), 10.0, None, None, 1.0),
        "walk, not a rise": (x_lo_um[::-1].copy(), (hinge_g + noise_g)[::-1].copy(), 10.0, 0.0,
                             toe.Wander(0.09, 0.5), 1.0),
        "walk": (x_lo_um, hinge_g + noise_g, 10.0, 0.0, toe.Wander(0.09, 0.5), 1.0),
        "hinge": (x_lo_um, hinge_g + noise_g, 10.0, None, None, 1.0),
    }

    def fit(x_lo, force, contact0, drift, wander, span):
        return toe.fit_toe(x_lo, x_lo + span, force, contact0, 0.5, drift, wander)

    kernel = {name: fit(*case) for name, case in cases.items()}
    monkeypatch.setattr(toe, "_C", None)
    twins = {name: fit(*case) for name, case in cases.items()}
    assert kernel["few samples"] is None and twins["few samples"] is None
    assert kernel["flat"] is None and twins["flat"] is None
    for name in ("zero span", "walk, not a rise", "walk", "hinge"):
        got, twin = kernel[name], twins[name]
        assert got is not None and twin is not None, name
        # As test_fits_equal_the_numpy_twin (the sd comes from second differences of the residual:
        # the grid's rounding, 1e-12 of its largest value, shows there at ~1e-9).
        assert got.contact_um == pytest.approx(twin.contact_um, abs=1e-8), name
        assert got.sigma_um == pytest.approx(twin.sigma_um, rel=1e-8), name
        assert got.width_um == twin.width_um, name
        if got.width_um > 0.0:  # a hinge has no shape: both tie but for rounding, and either may win
            assert got.power == twin.power, name
        assert got.stiffness_g_um == pytest.approx(twin.stiffness_g_um, rel=1e-8), name
        assert got.residual_sigma_g == pytest.approx(twin.residual_sigma_g, rel=1e-8), name
    assert kernel["hinge"].contact_um == pytest.approx(9.6, abs=0.3)  # the hinge's break contact
    assert kernel["walk"].residual_sigma_g != kernel["hinge"].residual_sigma_g  # the walk-weighted grid ran


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


def test_free_air_walks_equal_the_numpy_twin(taps, monkeypatch):
    # The kernel's variograms, sums and both least squares against the twin's free_air_variogram,
    # walk_beside_height_pull and wander_from_variograms. Measured on these taps: 3e-15 relative
    # (the kernel takes the line out of each difference, numpy out of each sample first; the rest
    # repeats the twin's operations), so 1e-12.
    calls = recorded_calls(analysis, "free_air_walks", [OPTIONS["default"]], taps)
    # Short segments too: no rows from the departure, or from either.
    approach_g, departure_g, steps_um = calls[0]
    calls += [(approach_g, departure_g[:20], steps_um), (approach_g[:30], departure_g[:5], steps_um),
              (approach_g, np.zeros(0), steps_um)]
    kernel = [toe.free_air_walks(*args) for args in calls]
    variograms = [toe.free_air_variogram(force_g) for args in calls for force_g in args[:2]]
    monkeypatch.setattr(toe, "_C", None)
    found = {"beside": 0, "approach": 0}
    for args, walks in zip(calls, kernel):
        for name, walk, twin in zip(found, walks, toe.free_air_walks(*args)):
            assert (walk is None) == (twin is None)
            if twin is not None:
                found[name] += 1
                assert walk.white_var_g2 == pytest.approx(twin.white_var_g2, rel=1e-12)
                assert walk.walk_var_g2 == pytest.approx(twin.walk_var_g2, rel=1e-12, abs=1e-15 * twin.white_var_g2)
    assert kernel[-2] == (None, None)  # both too short for a variogram
    assert kernel[-1][1] == kernel[-3][1] == kernel[0][1]  # the approach's own walk: whatever the departure
    assert found["beside"] >= 15 and found["approach"] >= 15
    assert sum(beside is not None and beside.walk_var_g2 > 0.0 for beside, _ in kernel) >= 3  # walks, not only white
    # free_air_variogram's own kernel (lag_mean_squares) on the same segments.
    segments = [force_g for args in calls for force_g in args[:2]]
    for force_g, (expected, values) in zip(segments, variograms):
        twin_expected, twin_values = toe.free_air_variogram(force_g)
        assert expected == twin_expected
        np.testing.assert_allclose(values, twin_values, rtol=1e-13, atol=0)


def test_adhesion_measures_equal_the_numpy_twin(monkeypatch):
    # The dip's run means are summed in another order than np.convolve's: ~1e-15 relative of forces
    # of tens of grams; medians select, they do not sum.
    calls = recorded_calls(analysis, "adhesion_measures", [OPTIONS["default"]])
    kernel_module = toe._C
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
    # Over a ringing's half period (`analysis.adhesion_run_samples`): the same calls with runs of 9 and 25.
    for run_samples in (9, 25):
        monkeypatch.setattr(toe, "_C", kernel_module)
        longer = [toe.adhesion_measures(*args[:6], run_samples) for args in calls]
        monkeypatch.setattr(toe, "_C", None)
        longer_twins = [toe.adhesion_measures(*args[:6], run_samples) for args in calls]
        for (dip, pull), (twin_dip, twin_pull), (short_dip, _) in zip(longer, longer_twins, kernel):
            assert (dip is None) == (twin_dip is None) and pull == twin_pull
            if twin_dip is not None:
                assert dip == pytest.approx(twin_dip, abs=1e-9)
                if run_samples % toe.ADHESION_RUN_SAMPLES == 0:  # a mean of whole 5-runs: no lower than their lowest
                    assert dip <= short_dip + 1e-9


def test_thread_pulls_equal_the_numpy_twin_bit_for_bit(monkeypatch):
    # Both take the same mid-heights and differences and select their medians: no sum in another order.
    calls = recorded_calls(analysis, "thread_pulls_g", [OPTIONS["default"]])
    kernel = [toe.thread_pulls_g(*args) for args in calls]
    monkeypatch.setattr(toe, "_C", None)
    twins = [toe.thread_pulls_g(*args) for args in calls]
    assert kernel == twins
    assert sum(near is not None for near, _ in twins) >= 10 and sum(far is not None for _, far in twins) >= 5
    assert any(far is None and near is not None for near, far in twins)  # a pullback too short to reach far


def test_thread_pulls_fill_overlapping_reaches_each_with_its_own_samples():
    # One pass fills both reaches' pulls: reaches that overlap (here by 20 µm) must each keep every
    # sample of theirs, in sample order, as the twin selects them one reach at a time.
    rng = np.random.default_rng(7)
    x_lo = np.sort(rng.uniform(-20.0, 180.0, 150))
    x_hi = x_lo + 1.25
    force = rng.normal(0.0, 0.4, 150) - 0.01 * x_lo
    near_reach, far_reach = (10.0, 80.0), (60.0, 150.0)
    near, far, highest = toe._C.thread_pulls(x_lo, x_hi, force, 0.002, 1.5, 12.0, near_reach, far_reach,
                                             toe.THREAD_MIN_SAMPLES)
    x_um = 0.5 * (x_lo + x_hi)
    assert near == toe.thread_pull_g(x_um, force, 0.002, 1.5, 12.0, near_reach)
    assert far == toe.thread_pull_g(x_um, force, 0.002, 1.5, 12.0, far_reach)
    assert highest == x_um.max()
    # too few samples in a reach: None there, the other reach still read
    near, far, _ = toe._C.thread_pulls(x_lo[:40], x_hi[:40], force[:40], 0.002, 1.5, 12.0, near_reach, far_reach,
                                       toe.THREAD_MIN_SAMPLES)
    assert far is None and near == toe.thread_pull_g(x_um[:40], force[:40], 0.002, 1.5, 12.0, near_reach)
    # no samples: neither pull, the highest -inf; a NaN height is the highest, as numpy's max has it
    assert toe._C.thread_pulls(x_lo[:0], x_hi[:0], force[:0], 0.002, 1.5, 12.0, near_reach, far_reach, 5) == (
        None, None, -math.inf)
    x_nan = x_lo.copy()
    x_nan[3] = math.nan
    assert math.isnan(toe._C.thread_pulls(x_nan, x_hi, force, 0.002, 1.5, 12.0, near_reach, far_reach, 5)[2])


@pytest.fixture(scope="module")
def scalar_kernel(tmp_path_factory):
    """c/toe.c built with -DTAPCELL_SCALAR (the plain loops an ARM board runs instead of SSE2),
    loaded beside the installed kernel."""
    return scalar_build("toe", tmp_path_factory.mktemp("scalar"))


def test_the_scalar_build_gives_the_kernels_bits(toe_fits, scalar_kernel, monkeypatch):
    # The SSE2 toe grid (a window's two heights side by side, both shapes in one vector) repeats the
    # plain loops' operations lane by lane: every fit, the grid's residuals included, bit for bit.
    vector = [toe.fit_toe(*args) for args in toe_fits]
    monkeypatch.setattr(toe, "_C", scalar_kernel)
    walks = 0
    for args, fit in zip(toe_fits, vector):
        plain = toe.fit_toe(*args)
        assert (fit.contact_um, fit.sigma_um, fit.width_um, fit.power, fit.stiffness_g_um, fit.residual_sigma_g) == (
            plain.contact_um, plain.sigma_um, plain.width_um, plain.power, plain.stiffness_g_um, plain.residual_sigma_g)
        assert fit.grid.rss.tobytes() == plain.grid.rss.tobytes() and fit.grid.noise_var == plain.grid.noise_var
        walks += fit.residual_sigma_g != math.sqrt(fit.grid.noise_var)
    assert walks >= 3  # the walk-weighted grid's vector recursion ran too


def test_the_detrended_variogram_kernel_gives_the_twins_bits(monkeypatch):
    # Its cumulative sums in numpy's order, its two dot products exact: every segment length the walk
    # estimate meets (12 to ~2,900 samples, odd and even: t on whole or half numbers) bit for bit;
    # longer ones, where BLAS's order could round t·f, go to the twin (None).
    twin = toe._detrended_variogram.__wrapped__
    lengths = [n for n in (*range(12, 400), *range(400, 3000, 7)) if toe._variogram_lags(n)]
    kernel = [toe._C.detrended_variogram(n, toe._variogram_lags(n)) for n in lengths]
    monkeypatch.setattr(toe, "_C", None)
    twins = [twin(n, toe._variogram_lags(n)) for n in lengths]
    exact = [(n, k, t) for n, k, t in zip(lengths, kernel, twins) if k is not None]
    assert all(k == t for _, k, t in exact)
    assert max(n for n, _, _ in exact) > 2800 and all(k is None for n, k in zip(lengths, kernel) if n > 2950)
    assert all(isinstance(white, float) and isinstance(walk, float) for _, k, _ in exact for white, walk in k)


def test_the_detrended_variogram_kernel_refuses_bad_lags():
    with pytest.raises(ValueError, match="lags"):
        toe._C.detrended_variogram(20, (4, 20))
    with pytest.raises(ValueError, match="lags"):
        toe._C.detrended_variogram(20, (0, 4))
    with pytest.raises(ValueError, match="samples"):
        toe._C.detrended_variogram(1, (1,))
    with pytest.raises(TypeError):
        toe._C.detrended_variogram(20, [4, 8])
    assert toe._C.detrended_variogram(10**7, (4, 8, 12)) is None  # far too long to be exact: the twin's


def test_the_free_air_model_kernel_fills_the_twins_rows_bit_for_bit(monkeypatch):
    # `_free_air_model`'s rows (lag, white, walk, height pull per step^4) in one kernel call: the same
    # bits as the columns built from the twin's parts at every length a segment has, past the
    # variogram kernel's exact sums too (~2,930 samples: the kernel declines, the twin's rows).
    lengths = [n for n in (*range(0, 400), *range(400, 3300, 7)) if toe._variogram_lags(n)]
    kernel = [toe._free_air_model.__wrapped__(n) for n in lengths]
    monkeypatch.setattr(toe, "_C", None)
    twins = [toe._free_air_model.__wrapped__(n) for n in lengths]
    assert all(k.shape == t.shape == (len(toe._variogram_lags(n)), 4) for n, k, t in zip(lengths, kernel, twins))
    assert all(np.array_equal(k.view(np.int64), t.view(np.int64)) for k, t in zip(kernel, twins))
    assert kernel[lengths.index(300)][2].tolist() == [12.0, *twins[lengths.index(300)][2, 1:3], 144 * (288**2 - 1) / 12.0]


def test_the_free_air_model_kernel_refuses_what_it_cannot_fill():
    model = np.empty((3, 4))
    assert toe._C.free_air_model(10**7, (4, 8, 12), model) is False  # too long to be exact: the twin fills it
    with pytest.raises(ValueError, match="model"):
        toe._C.free_air_model(40, (4, 8, 12), np.empty((2, 4)))
    with pytest.raises(ValueError, match="lags"):
        toe._C.free_air_model(20, (4, 20, 8), model)
    with pytest.raises(TypeError):
        toe._C.free_air_model(40, (4, 8, 12), np.empty((3, 4), dtype=np.float32))
    frozen = np.empty((3, 4))
    frozen.flags.writeable = False
    with pytest.raises((ValueError, BufferError)):
        toe._C.free_air_model(40, (4, 8, 12), frozen)


def test_the_lags_four_at_a_time_give_each_lags_own_bits():
    # The variogram's lags go through the segment four at a time, each lag's sum still in sample order:
    # every lag's mean square is what it is measured alone (a tuple of one lag runs the single loop).
    rng = np.random.default_rng(11)
    for n in (12, 13, 40, 121, 400):
        force_g = 80.0 + np.cumsum(rng.normal(0.0, 0.3, n)) + rng.normal(0.0, 1.0, n)
        lags = tuple(lag for lag in (4, 8, 1, 12, 3, 16, 20, 2, 24, 28, 5) if lag < n)
        together = toe._C.lag_mean_squares(force_g, lags)
        assert together == [toe._C.lag_mean_squares(force_g, (lag,))[0] for lag in lags]
    with pytest.raises(ValueError, match="lags"):
        toe._C.lag_mean_squares(force_g, (4, 8, 12, 400))
