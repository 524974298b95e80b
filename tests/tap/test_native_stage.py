"""The two-stage fit's compiled kernel (tapcell.tap._c_stage) against its numpy twin (tapcell.tap.stage).

Inputs are the two-stage fits the analysis runs on taplab's taps (the two-stage mount, the soft
sheet, mild ooze: the taps whose toe is wide enough to be checked). Both
sides repeat the same arithmetic per grid point; only the sums of the weights over the grid run in
another order.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from tapcell.tap import analysis, stage
from native_kernel_inputs import OPTIONS, generated_taps, recorded_calls

pytestmark = pytest.mark.skipif(stage._C is None, reason="the stage kernel is not built (TAPCELL_NATIVE=0)")

# The fit runs under a wide toe only: on most soft sheets, on the two-stage taps the ramp check above
# the contact did not already reject, and on some ooze.
SCENARIO_NAMES = ("two_stage", "soft_sheet", "mild_ooze")
# 20 each: 21 fits, 2 of them showing the two stages (16 each gave 2 of 17 fits while the toe fit's walk was the
# approach's and departure's pooled, 1 of 16 since the walk is told apart from a pull curved in height).
TAPS_EACH = 20


@pytest.fixture(scope="module")
def fits():
    """The arguments of every two_stage_fit the analysis of the taps runs."""
    calls = recorded_calls(stage, "two_stage_fit", [OPTIONS["default"]],
                           generated_taps(TAPS_EACH, 7, SCENARIO_NAMES))
    assert len(calls) >= 15
    # The fits on the free air's drift (sxx infinite: the drift's column out of every projection), 15
    # of the 32 here: the kernels must agree with their twins on those too.
    held = [call for call in calls if call[5:] == (True,)]
    assert len(held) >= 10, len(held)
    return calls


def test_the_soft_stage_ramp_equals_the_numpy_twin_bit_for_bit(monkeypatch):
    # The kernel sums the force's mean pairwise as numpy does: on taplab, the reference taps and
    # sessions (2,023 ramps) kernel and twin agree to the last bit.
    taps = generated_taps(3, 7, (*SCENARIO_NAMES, "clean_hx717", "cable_drift", "mains_hum"))
    calls = recorded_calls(analysis, "departure_soft_stage", [OPTIONS["default"]], taps)
    found = [stage.departure_soft_stage(*call) for call in calls]
    monkeypatch.setattr(stage, "_C", None)
    twins = [stage.departure_soft_stage(*call) for call in calls]
    assert [None if fit is None else dataclasses.astuple(fit) for fit in found] == [
        None if fit is None else dataclasses.astuple(fit) for fit in twins]
    assert sum(fit is not None for fit in twins) >= 10
    assert any(stage.shows_soft_stage(fit, 1.0, 0.0) for fit in twins if fit)  # a ramp clearly there, too


def test_the_soft_stage_ramp_is_the_same_whatever_the_tops_order():
    # Along rising tops the kernel counts the samples below each on from the last; any other order
    # takes binary searches: the same best ramp (a soft stage 12 um long, 0.4 g/um, under 0.5 g noise).
    x, f = _departure()
    x_lo, x_hi = x - 0.25, x + 0.25

    def ramp(tops):
        return stage._C.soft_stage(x_lo, x_hi, f, 0.0, 10.0, 0.25, 0.0, np.ascontiguousarray(tops),
                                   stage.STAGE_FROM_UM, stage.STAGE_REACH_UM, stage.STAGE_MIN_SAMPLES)

    rising = ramp(stage.STAGE_TOPS_UM)
    assert rising[1] == pytest.approx(22.0, abs=1.5) and rising[0] > stage.STAGE_MIN_CHI2
    for tops in (stage.STAGE_TOPS_UM[::-1], np.random.default_rng(6).permutation(stage.STAGE_TOPS_UM)):
        assert repr(ramp(tops)) == repr(rising)


def _grid_inputs(x_um, force_g, contact_um, noise_var_g2, window_um, drift_held=False):
    """two_stage_fit's arguments as its grid takes them (the same steps as two_stage_fit)."""
    near = (x_um > contact_um - stage.TWO_STAGE_BELOW_UM) & (x_um < contact_um + stage.TWO_STAGE_ABOVE_UM)
    x, _, f, sxx, ff = stage._sorted_detrended(x_um[near], force_g[near], drift_held)
    spacing_um = float(np.median(np.diff(x)))
    shortest_um = max(stage.TWO_STAGE_MIN_SPAN_UM, stage.TWO_STAGE_MIN_SPAN_WINDOWS * max(window_um, spacing_um))
    return x, f, contact_um, sxx, ff, noise_var_g2, shortest_um


def _kernel_grid(x, f, contact_um, sxx, ff, noise_var_g2, shortest_um):
    return stage._C.two_stage_grid(x, f, stage.TWO_STAGE_HINGES_UM, stage.TWO_STAGE_SPANS_UM, contact_um, sxx, ff,
                                   float(x.mean()), noise_var_g2, shortest_um, stage.TWO_STAGE_MIN_SOFT_SHARE,
                                   stage.TWO_STAGE_MAX_SOFT_SHARE)


def test_the_grid_equals_the_numpy_twin(fits):
    # Measured on these taps and on taplab's, the reference taps' and sessions' 486 fits: the least
    # residual, noise, best span, its share and the hinge's gain bit for bit; the top's mean and sd
    # (weighted sums over 1,520 grid points in another order) to 1.5e-15 relative.
    answered = 0
    for call in fits:
        inputs = _grid_inputs(*call)
        if len(inputs[0]) < 2 * stage.STAGE_MIN_SAMPLES:
            continue
        twin, kernel = stage._two_stage_grid(*inputs), _kernel_grid(*inputs)
        assert (twin is None) == (kernel is None)
        if twin is None:
            continue
        answered += 1
        least, noise, top_mean, top_sd, span, share, hinge_gain = twin
        assert (kernel[0], kernel[1], kernel[4], kernel[5], kernel[6]) == (least, noise, span, share, hinge_gain)
        assert kernel[2] == pytest.approx(top_mean, rel=1e-13)
        assert kernel[3] == pytest.approx(top_sd, rel=1e-11, abs=1e-12)
    assert answered >= 15


def test_the_fit_answers_the_same_with_and_without_the_kernel(fits, monkeypatch):
    shown = 0
    fast = [stage.two_stage_fit(*call) for call in fits]
    monkeypatch.setattr(stage, "_C", None)
    for call, kernel in zip(fits, fast):
        twin = stage.two_stage_fit(*call)
        assert (twin is None) == (kernel is None)
        if twin is None:
            continue
        # The evidence is a difference of two residuals of the force's size over the noise: 4.4e-12
        # noise variances apart on these taps (the one-stage grid sums in another order).
        assert kernel.evidence_chi2 == pytest.approx(twin.evidence_chi2, abs=1e-9)
        assert dataclasses.astuple(kernel)[1:] == pytest.approx(dataclasses.astuple(twin)[1:], rel=1e-12, abs=1e-12)
        shown += stage.shows_two_stage(twin, call[2])
    assert shown >= 2  # the one-stage toe's grid ran too: the evidence passed the hinge's bound


def test_the_grid_is_the_same_whatever_the_hinges_order():
    # Along rising hinges the kernel counts the samples below each hinge and each row's first top on
    # from the last row's; hinges in any other order take binary searches. The same cells, so the
    # same least residual, noise, best span, share and hinge gain; the top's weighed mean and sd,
    # summed over the cells in another order, to rounding.
    x, f, contact_um, sxx, ff, noise, shortest = _grid_inputs(*_departure(), 10.0, 0.25, 1.0)

    def grid(hinges):
        return stage._C.two_stage_grid(x, f, np.ascontiguousarray(hinges), stage.TWO_STAGE_SPANS_UM, contact_um, sxx,
                                       ff, float(x.mean()), noise, shortest, stage.TWO_STAGE_MIN_SOFT_SHARE,
                                       stage.TWO_STAGE_MAX_SOFT_SHARE)

    rising = grid(stage.TWO_STAGE_HINGES_UM)
    for hinges in (stage.TWO_STAGE_HINGES_UM[::-1], np.random.default_rng(4).permutation(stage.TWO_STAGE_HINGES_UM)):
        other = grid(hinges)
        assert (other[0], other[1], other[5], other[6]) == (rising[0], rising[1], rising[5], rising[6])
        assert other[4] == rising[4]  # the span index: the best cell's, wherever its row lies
        assert other[2] == pytest.approx(rising[2], rel=1e-13) and other[3] == pytest.approx(rising[3], rel=1e-11)


def test_the_kernel_refuses_wrong_arrays():
    x = np.arange(30.0)
    with pytest.raises(ValueError):
        stage._C.two_stage_grid(x, x[:-1], stage.TWO_STAGE_HINGES_UM, stage.TWO_STAGE_SPANS_UM,
                                10.0, 1.0, 1.0, 15.0, 1.0, 5.0, 0.08, 0.5)
    with pytest.raises(TypeError):
        stage._C.two_stage_grid(x.astype(np.float32), x, stage.TWO_STAGE_HINGES_UM, stage.TWO_STAGE_SPANS_UM,
                                10.0, 1.0, 1.0, 15.0, 1.0, 5.0, 0.08, 0.5)
    # The grid takes its spans from the first long enough on: spans out of order would let it fit a
    # shorter one (reversed, shortest 15 um: a 9 um span chosen, where the twin leaves it out).
    for spans in (stage.TWO_STAGE_SPANS_UM[::-1], np.array([2.0, 5.0, 5.0, 9.0])):
        with pytest.raises(ValueError, match="spans_um: the spans must rise"):
            stage._C.two_stage_grid(x, x, stage.TWO_STAGE_HINGES_UM, np.ascontiguousarray(spans),
                                    10.0, 1.0, 1.0, 15.0, 1.0, 15.0, 0.08, 0.5)


def _one_stage_calls(fits) -> list[tuple]:
    """`_one_stage_rss`'s arguments on each departure the fits weigh, as two_stage_fit prepares them."""
    calls = []
    for x_um, force_g, contact_um, *rest in fits:
        near = (x_um > contact_um - stage.TWO_STAGE_BELOW_UM) & (x_um < contact_um + stage.TWO_STAGE_ABOVE_UM)
        if np.count_nonzero(near) >= 2 * stage.STAGE_MIN_SAMPLES:
            x, _, f, sxx, ff = stage._sorted_detrended(x_um[near], force_g[near], *rest[2:])
            calls.append((x, f, float(x.mean()), sxx, ff, contact_um))
    return calls


def test_the_one_stage_toe_grid_equals_the_numpy_twin(fits, monkeypatch):
    # The kernel takes the samples on the toe's linear part from prefix sums, the twin sums every
    # shape: on taplab's, the reference taps' and sessions' 34 grids 2.4e-15 of the force's sum of squares.
    calls = _one_stage_calls(fits)
    kernel = [stage._one_stage_rss(*call) for call in calls]
    monkeypatch.setattr(stage, "_C", None)
    twins = [stage._one_stage_rss(*call) for call in calls]
    for call, fast, twin in zip(calls, kernel, twins):
        ff = call[4]
        assert abs(fast - twin) <= 1e-12 * ff
        assert twin < ff  # a toe explains part of every departure here: the grid is not empty
    assert len(calls) >= 15


def _one_stage_call(x, f, contact_um, contacts_um=stage.ONE_STAGE_CONTACTS_UM):
    """one_stage_rss's kernel on a departure prepared as two_stage_fit prepares it."""
    x, _, f, sxx, ff = stage._sorted_detrended(x, f, False)
    return stage._C.one_stage_rss(x, f, np.ascontiguousarray(contacts_um), stage._ONE_STAGE_WIDTHS,
                                  stage._ONE_STAGE_POWERS, contact_um, sxx, ff, float(x.mean()))


def test_the_one_stage_toe_grid_is_the_same_whatever_the_contacts_order():
    # Along rising contacts the kernel counts the samples below each contact and its toe on from the
    # last contact's; any other order takes binary searches. The least residual is the same bits.
    x, f = _departure()
    rising = _one_stage_call(x, f, 10.0)
    for contacts in (stage.ONE_STAGE_CONTACTS_UM[::-1], np.random.default_rng(2).permutation(stage.ONE_STAGE_CONTACTS_UM)):
        assert repr(_one_stage_call(x, f, 10.0, contacts)) == repr(rising)


def test_the_two_shapes_summed_side_by_side_give_the_general_loops_bits(fits):
    # The grid's own shapes (0.5, 1.0) run in one pass over the toe's samples; in the other order the
    # kernel takes its general loop, one shape at a time. Each sum is added in the same order, so the
    # least residual is the same bits, the best toe a Hertzian one on some departures, a parabolic on others.
    calls = _one_stage_calls(fits)
    assert len(calls) >= 15
    for call in calls:
        assert repr(least_of(call, [0.5, 1.0])) == repr(least_of(call, [1.0, 0.5]))
    best_shape = {min((least_of(call, [0.5]), 0.5), (least_of(call, [1.0]), 1.0))[1] for call in calls}
    assert best_shape == {0.5, 1.0}


def least_of(call: tuple, powers: list[float]) -> float:
    """The one-stage toe grid's least residual with these shapes alone."""
    x, f, x_mean, sxx, ff, contact_um = call
    return stage._C.one_stage_rss(x, f, stage.ONE_STAGE_CONTACTS_UM, stage._ONE_STAGE_WIDTHS, np.array(powers),
                                  contact_um, sxx, ff, x_mean)


def test_the_one_stage_toe_grid_with_samples_on_its_own_heights(monkeypatch):
    # Samples at every half µm: on each contact and on the edge of each (whole or half µm) width's toe, where
    # a count below it and the "pressed a width deep" test are decided by equality.
    x = np.arange(-15.0, 60.0, 0.5)
    rng = np.random.default_rng(5)
    f = 2.0 * np.clip(10.0 - x, 0.0, None) ** 1.5 / 3.0 + rng.normal(0.0, 0.3, len(x))
    xs, _, fs, sxx, ff = stage._sorted_detrended(x, f, False)
    kernel = stage._one_stage_rss(xs, fs, float(xs.mean()), sxx, ff, 10.0)
    monkeypatch.setattr(stage, "_C", None)
    twin = stage._one_stage_rss(xs, fs, float(xs.mean()), sxx, ff, 10.0)
    assert abs(kernel - twin) <= 1e-12 * ff
    assert twin < 0.05 * ff  # the toe explains the departure: the grid's best is a real fit


def _kernel_fit_and_samples(x_um, force_g, contact_um, noise_var_g2, window_um, drift_held=False):
    """The kernel's whole answer, and the samples it wrote out (by height, level and drift taken out)."""
    x_out, f_out = np.full(len(x_um), np.nan), np.full(len(x_um), np.nan)
    found = stage._C.two_stage_fit(x_um, force_g, contact_um, stage.TWO_STAGE_BELOW_UM, stage.TWO_STAGE_ABOVE_UM,
                                   stage.STAGE_MIN_SAMPLES, noise_var_g2, window_um, stage.TWO_STAGE_MIN_SPAN_UM,
                                   stage.TWO_STAGE_MIN_SPAN_WINDOWS, stage.TWO_STAGE_HINGES_UM,
                                   stage.TWO_STAGE_SPANS_UM, stage.TWO_STAGE_MIN_SOFT_SHARE,
                                   stage.TWO_STAGE_MAX_SOFT_SHARE, drift_held, x_out, f_out)
    return found, x_out, f_out


def _kernel_fit(*call):
    """The kernel's answer up to ff (the twin's tuple), or None."""
    found = _kernel_fit_and_samples(*call)[0]
    return None if found is None else found[:8]


def _twin_fit(x_um, force_g, contact_um, noise_var_g2, window_um, drift_held=False):
    """The twin's steps of two_stage_fit up to and with its grid, and ff (None where it stops)."""
    near = (x_um > contact_um - stage.TWO_STAGE_BELOW_UM) & (x_um < contact_um + stage.TWO_STAGE_ABOVE_UM)
    if int(near.sum()) < 2 * stage.STAGE_MIN_SAMPLES or noise_var_g2 <= 0:
        return None
    x, _, f, sxx, ff = stage._sorted_detrended(x_um[near], force_g[near], drift_held)
    if not sxx > 0:
        return None
    shortest_um = max(stage.TWO_STAGE_MIN_SPAN_UM,
                      stage.TWO_STAGE_MIN_SPAN_WINDOWS * max(window_um, stage.median(np.diff(x))))
    grid = stage._two_stage_grid(x, f, contact_um, sxx, ff, noise_var_g2, shortest_um)
    return None if grid is None else (*grid, ff)


def assert_fit_agrees(kernel, twin):
    """The selection, sort, level and drift as the twin takes them (pairwise sums): the least residual,
    noise, best span, share, hinge gain and ff bit for bit; the top's mean and sd (the weights summed in
    another order) to rounding."""
    assert (kernel is None) == (twin is None)
    if twin is not None:
        exact = [0, 1, 4, 5, 6, 7]
        assert [repr(kernel[i]) for i in exact] == [repr(twin[i]) for i in exact]  # a NaN equals a NaN
        assert kernel[2] == pytest.approx(twin[2], rel=1e-13)
        assert kernel[3] == pytest.approx(twin[3], rel=1e-11, abs=1e-12)


def test_the_whole_fit_up_to_the_one_stage_toe_equals_the_twin(fits):
    # On the reference taps' 361 fits (drift held and fitted) the same: least, noise, span, share,
    # hinge gain and ff bit for bit, the top within 1.7e-13 µm, its sd within 7e-15.
    for call in fits:
        assert_fit_agrees(_kernel_fit(*call), _twin_fit(*call))
    assert sum(_twin_fit(*call) is not None for call in fits) >= 15


def test_the_fit_writes_out_the_samples_it_fitted_as_the_twin_takes_them(fits):
    # The one-stage toe reads them next (no second selection and sort): the twin's _sorted_detrended
    # samples, their count, the centred heights' sum of squares and the heights' mean, bit for bit.
    answered = 0
    for call in fits:
        found, x_out, f_out = _kernel_fit_and_samples(*call)
        if found is None:
            continue
        answered += 1
        x_um, force_g, contact_um = call[:3]
        drift_held = call[5] if len(call) > 5 else False
        near = (x_um > contact_um - stage.TWO_STAGE_BELOW_UM) & (x_um < contact_um + stage.TWO_STAGE_ABOVE_UM)
        x, _, f, sxx, _ = stage._sorted_detrended(x_um[near], force_g[near], drift_held)
        count = found[8]
        assert count == len(x)
        assert x_out[:count].tobytes() == x.tobytes() and f_out[:count].tobytes() == f.tobytes()
        assert np.isnan(x_out[count:]).all()  # nothing written past them
        assert repr(found[9]) == repr(sxx) and repr(found[10]) == repr(float(x.mean()))
    assert answered >= 15


def test_the_fit_refuses_output_arrays_it_cannot_fill():
    x, f = _departure()
    args = (x, f, 10.0, stage.TWO_STAGE_BELOW_UM, stage.TWO_STAGE_ABOVE_UM, stage.STAGE_MIN_SAMPLES, 0.25, 1.0,
            stage.TWO_STAGE_MIN_SPAN_UM, stage.TWO_STAGE_MIN_SPAN_WINDOWS, stage.TWO_STAGE_HINGES_UM,
            stage.TWO_STAGE_SPANS_UM, stage.TWO_STAGE_MIN_SOFT_SHARE, stage.TWO_STAGE_MAX_SOFT_SHARE, False)
    with pytest.raises(ValueError, match="x_out"):
        stage._C.two_stage_fit(*args, np.empty(len(x) - 1), np.empty(len(x)))
    with pytest.raises(ValueError, match="force_out"):
        stage._C.two_stage_fit(*args, np.empty(len(x)), np.empty(len(x) - 1))
    readonly = np.empty(len(x))
    readonly.flags.writeable = False
    with pytest.raises((ValueError, BufferError)):
        stage._C.two_stage_fit(*args, np.empty(len(x)), readonly)


def _departure(n=90, seed=3):
    """A departure with a soft stage: 2.5 g/µm stiff up to 10 µm, 0.4 g/µm soft to 22 µm, noise 0.5 g."""
    rng = np.random.default_rng(seed)
    x = np.linspace(-20.0, 70.0, n)
    force = 2.5 * np.clip(10.0 - x, 0.0, None) + 0.4 * np.clip(22.0 - x, 0.0, None) + rng.normal(0.0, 0.5, n)
    return x, force


EDGE_CASES = {
    "a soft stage": lambda x, f: (x, f, 10.0, 0.25, 1.0),
    "the drift held": lambda x, f: (x, f, 10.0, 0.25, 1.0, True),
    "samples out of order, ties among them": lambda x, f: (np.round(x[::-1] / 3.0) * 3.0, f[::-1].copy(), 10.0,
                                                           0.25, 1.0),
    "shuffled": lambda x, f: (x[np.random.default_rng(1).permutation(len(x))],
                              f[np.random.default_rng(1).permutation(len(x))], 10.0, 0.25, 1.0),
    "19 samples near the contact (too few)": lambda x, f: (x[:19] * 0.1 + 10.0, f[:19].copy(), 10.0, 0.25, 1.0),
    "20 samples near the contact": lambda x, f: (x[:20] * 0.1 + 10.0, f[:20].copy(), 10.0, 0.25, 1.0),
    "no noise": lambda x, f: (x, f, 10.0, 0.0, 1.0),
    "every sample at one height": lambda x, f: (np.full(len(x), 12.0), f, 10.0, 0.25, 1.0),
    "NaN heights and forces away from the contact": lambda x, f: (np.where(x > 60.0, np.nan, x),
                                                                  np.where(x > 60.0, np.nan, f), 10.0, 0.25, 1.0),
    "no sample near": lambda x, f: (x + 500.0, f, 10.0, 0.25, 1.0),
    "a flat force (every stiffness 0: a share of 0 / 0)": lambda x, f: (x, np.zeros(len(x)), 10.0, 0.25, 1.0),
    "a force rising with height (no grid point allowed)": lambda x, f: (x, -f, 10.0, 0.25, 1.0),
    "a window wider than every span": lambda x, f: (x, f, 10.0, 0.25, 50.0),
}


@pytest.mark.filterwarnings("ignore:invalid value encountered:RuntimeWarning")  # the twin's 0 / 0
@pytest.mark.parametrize("make", EDGE_CASES.values(), ids=EDGE_CASES.keys())
def test_the_whole_fit_equals_the_twin_on_edge_cases(make):
    call = make(*_departure())
    assert_fit_agrees(_kernel_fit(*call), _twin_fit(*call))


def test_a_strided_array_is_fitted_as_the_twin_fits_it(monkeypatch):
    x, f = _departure(180)
    fast = stage.two_stage_fit(x[::2], f[::2], 10.0, 0.25, 1.0)  # not C-contiguous: copied for the kernel
    monkeypatch.setattr(stage, "_C", None)
    twin = stage.two_stage_fit(x[::2], f[::2], 10.0, 0.25, 1.0)
    assert fast is not None and dataclasses.astuple(fast) == pytest.approx(dataclasses.astuple(twin), rel=1e-12)


def test_the_kernel_finds_the_soft_stage():
    least, noise, top_mean, top_sd, span, share, hinge_gain, ff = _kernel_fit(*_departure(), 10.0, 0.25, 1.0)
    assert top_mean == pytest.approx(22.0, abs=1.5)  # the first touch, 12 µm above the stiff stage's
    assert share == pytest.approx(0.4 / 2.5, abs=0.05)
    assert least / (90 - 6) == pytest.approx(0.25, rel=0.3)  # the fit leaves the noise


@pytest.fixture(scope="module")
def departures():
    """The arguments of every `_departure_fit` the analysis of the taps runs (wide toes and ramps)."""
    calls = recorded_calls(stage, "_departure_fit", [OPTIONS["default"]], generated_taps(TAPS_EACH, 7, SCENARIO_NAMES))
    assert len(calls) >= 15
    return calls


def test_the_departures_selection_equals_the_twin_bit_for_bit(departures, monkeypatch):
    # _departure_fit's selection in one kernel call (departure_near): the same samples, the same
    # mid-heights, drift-free force and window median to the bit, so the same fits follow; on the
    # analysis's calls and on ones that select nothing, a few samples, or every sample.
    calls = list(departures)
    x_lo, x_hi, force, drift, contact, *rest = calls[0]
    top = float(np.max(0.5 * (x_lo + x_hi)))
    calls += [(x_lo, x_hi, force, drift, contact + 1e4, *rest),  # nothing selected: no fit
              (x_lo, x_hi, force, drift, top + stage.TWO_STAGE_BELOW_UM - 0.5, *rest),  # the topmost few
              (x_lo, x_hi, force, 0.0, float(np.median(x_lo)), *rest)]
    fitted = []
    monkeypatch.setattr(stage, "two_stage_fit", lambda *args: fitted.append(args))
    for call in calls:
        stage._departure_fit(*call)
    kernel, fitted[:] = list(fitted), []
    monkeypatch.setattr(stage, "_C", None)
    for call in calls:
        stage._departure_fit(*call)
    assert len(kernel) == len(fitted) >= len(calls) - 1  # (the one that selects nothing fits nothing)
    for ours, twins in zip(kernel, fitted):
        assert ours[0].tobytes() == twins[0].tobytes() and ours[1].tobytes() == twins[1].tobytes()
        assert ours[2:] == twins[2:]  # the window median among them
    assert min(len(args[0]) for args in kernel) < 20 < max(len(args[0]) for args in kernel)  # the topmost few too


def test_the_departures_selection_refuses_wrong_arrays():
    values = np.arange(10.0)
    with pytest.raises(ValueError, match="force_g"):
        stage._C.departure_near(values, values, values[1:], 0.0, 0.0, 5.0, np.empty(10), np.empty(10))
    with pytest.raises(ValueError, match="x_out"):
        stage._C.departure_near(values, values, values, 0.0, 0.0, 5.0, np.empty(9), np.empty(10))
    readonly = np.empty(10)
    readonly.flags.writeable = False
    with pytest.raises((ValueError, BufferError)):
        stage._C.departure_near(values, values, values, 0.0, 0.0, 5.0, np.empty(10), readonly)
    assert stage._C.departure_near(values, values + 1.0, values, 0.5, 2.0, 6.0, np.empty(10), np.empty(10))[0] == 4
