"""The robust-statistics kernel (tapcell.tap._c_analysis) against its numpy twins, to the last bit."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from tapcell.tap import analysis, contact, native, robust
from tapcell.tap.motion import Motion, tap_motion
from tapcell.tap.readers import tap_from_object
from tapcell.taplab.generate import SCENARIOS, make_tap
from native_kernel_inputs import OPTIONS, generated_taps, recorded_calls

KERNEL = native.load("analysis")
pytestmark = pytest.mark.skipif(KERNEL is None, reason="the analysis kernel is not built")

finite = st.floats(-1e6, 1e6, allow_nan=False, allow_subnormal=False)


def _twins(compute):
    """compute() with the kernel, then with the numpy twins."""
    fast = compute()
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(analysis, "_C", None)
        patch.setattr(robust, "_C", None)
        return fast, compute()


@settings(max_examples=100, deadline=None)
@given(arrays(np.float64, st.integers(1, 60), elements=st.one_of(finite, st.sampled_from([0.0, 1.0, -1.0]))))
def test_median_is_numpys(values):
    # Repeated values (the sampled constants) exercise the selection's equal-to-pivot runs.
    assert KERNEL.median(values) == np.median(values)


def test_median_of_long_samples_is_numpys():
    # Tap-sized arrays (hundreds to thousands of samples), where the selection partitions through
    # its scratch runs: noise, quantised noise (an ADC's counts: long runs of equal values), a
    # constant, sorted and reversed ramps, a tap-like step; odd and even counts; either side of 256
    # values, where the selection's scratch leaves the stack for the heap and the sampled pivots begin.
    rng = np.random.default_rng(21)
    for n in (12, 13, 101, 255, 256, 257, 700, 1449, 4769):
        noise = rng.normal(0.0, 1.0, n)
        for values in (noise, np.round(noise * 2.0) / 2.0, np.full(n, 3.25), np.arange(n, dtype=float),
                       np.arange(n, 0, -1, dtype=float), np.where(np.arange(n) < n // 3, 0.0, 75.0) + noise):
            assert KERNEL.median(values) == np.median(values), (n, values[:5])
            assert KERNEL.median(values[1:]) == np.median(values[1:])
    # Every tenth value far above the rest: an evenly spaced sample of 64 (from 256 values on) takes
    # only those, and its pivots miss the median (the selection over every value finds it).
    for n in (640, 641, 1280):
        values = np.where(np.arange(n) % (n // 64) == 0, 1000.0, rng.normal(0.0, 1.0, n))
        assert KERNEL.median(values) == np.median(values)
    # A NaN among them, where the sample takes it (index 0) and where it does not: NaN, as numpy's.
    for at in (0, 5, 699):
        values = rng.normal(0.0, 1.0, 700)
        values[at] = np.nan
        assert math.isnan(KERNEL.median(values))


def test_median_of_nan_is_nan_and_of_nothing_an_error():
    assert math.isnan(KERNEL.median(np.array([1.0, np.nan, 3.0])))
    with pytest.raises(ValueError, match="no values"):
        KERNEL.median(np.array([]))


def test_a_wrong_array_type_is_an_error_not_garbage():
    with pytest.raises(TypeError, match="float64"):
        KERNEL.median(np.arange(5))  # int64: the same bytes per item, other numbers
    with pytest.raises(ValueError, match="contiguous"):
        KERNEL.median(np.arange(10.0)[::2])


def test_robust_median_takes_other_arrays_through_numpy():
    assert robust.median(np.arange(10.0)[::2]) == 4.0
    assert robust.median(np.array([3, 1, 2])) == 2.0


@settings(max_examples=100, deadline=None)
@given(arrays(np.float64, st.integers(0, 80), elements=finite), st.floats(2.0, 8.0))
def test_noise_and_spikes_are_the_twins_on_any_series(force_g, threshold_sigma):
    def compute():
        repaired, count = analysis.repair_spikes(force_g, threshold_sigma)
        return analysis.noise_sigma_g(force_g), repaired.tolist(), count
    fast, reference = _twins(compute)
    assert fast == reference


def test_noise_and_spikes_are_the_twins_on_independent_taps():
    rng = np.random.default_rng(3)
    forces = [tap_from_object(make_tap(SCENARIOS[name].draw(rng), rng)[0]).force_g
              for name in ("corrupt_frames", "clean_hx717", "mains_hum", "cable_drift") for _ in range(3)]

    def compute():
        return [(analysis.noise_sigma_g(f), analysis.repair_spikes(f, 5.0)[0].tolist(), robust.median(f))
                for f in forces]
    fast, reference = _twins(compute)
    assert fast == reference
    assert sum(analysis.repair_spikes(f, 5.0)[1] for f in forces[:3]) >= 3  # corrupt frames were repaired


def _polarity_and_repaired(time_s, force_raw, motion, outlier_sigma):
    """analysis.polarity_and_repaired as (polarity, force as a list, repaired), or the TapInvalid's code."""
    try:
        polarity, force, outliers, _ = analysis.polarity_and_repaired(time_s, force_raw, motion, outlier_sigma)
    except analysis.TapInvalid as invalid:
        return invalid.code, invalid.message
    return polarity, force.tolist(), outliers


def test_the_repair_answers_the_noise_sigma_of_the_force_it_left_as_it_was():
    # Where no frame was repaired the kernel answers noise_sigma_g of the force it returns (the split
    # takes it for a window of every sample); where one was, None: the force is no longer the one measured.
    calls = recorded_calls(analysis, "polarity_and_repaired", [OPTIONS["default"]])
    answered = repaired = 0
    for t, f, motion, _ in calls:
        for sign, sigma in ((1.0, 5.0), (-1.0, 5.0), (1.0, 3.0)):
            _, force, outliers, noise_g = analysis.polarity_and_repaired(t, sign * f, motion, sigma)
            if outliers:
                assert noise_g is None
                repaired += 1
            else:
                assert noise_g == analysis.noise_sigma_g(force) == _twins(lambda: analysis.noise_sigma_g(force))[1]
                answered += 1
    assert answered >= 20 and repaired >= 3


def test_polarity_and_repair_are_the_twins_on_generated_taps():
    # Every taplab scenario (corrupt frames among them), each as recorded and mirrored (a cell
    # mounted the other way), the default threshold and a low one that repairs noise peaks too.
    calls = recorded_calls(analysis, "polarity_and_repaired", [OPTIONS["default"]])
    cases = [(t, sign * f, motion, sigma) for t, f, motion, _ in calls for sign in (1.0, -1.0) for sigma in (5.0, 3.0)]
    fast, twin = _twins(lambda: [_polarity_and_repaired(*case) for case in cases])
    assert fast == twin
    assert {found[0] for found in fast} == {1, -1}
    assert sum(found[2] for found in fast) >= 10  # frames were repaired


@pytest.mark.filterwarnings("ignore:overflow encountered")  # the twin's median of two 1e308s
def test_polarity_and_repair_are_the_twins_at_the_edges():
    # A force that does not change between approach and dwell (TAP_SHAPE_INVALID), one whose change
    # overflows (not finite: the same), a spike in the dwell beside a frame pair on the compression,
    # and a dwell of one sample (the pullback starts before the sample after the halt).
    rng = np.random.default_rng(5)
    tap = tap_from_object(make_tap(SCENARIOS["clean_hx717"].draw(rng), rng)[0])
    motion = tap_motion(tap)
    time_s = np.ascontiguousarray(tap.time_s, dtype=float)
    force_g = np.ascontiguousarray(tap.force_g, dtype=float)
    halt = int(time_s.searchsorted(motion.home_end_s))
    spiked = force_g.copy()
    spiked[halt + 3] += 400.0
    spiked[halt - 3:halt - 1] -= 300.0
    huge = np.where(time_s < motion.home_end_s, -1.7e308, 1.7e308)
    one_sample_dwell = dataclasses.replace(motion, home_end_s=float(time_s[halt]) - 1e-9,
                                           pullback_start_s=float(time_s[halt]) + 1e-9)
    cases = [(time_s, np.full_like(force_g, 2.5), motion, 5.0), (time_s, huge, motion, 5.0),
             (time_s, spiked, motion, 5.0), (time_s, force_g, one_sample_dwell, 5.0)]
    # At 10 sps a baseline of two samples (0 and 10 g) before the one read just before the halt (10 g,
    # left out), under a 7 g dwell: +1 (a baseline holding the sample before the halt would say -1).
    slow_s = np.arange(40) * 0.1
    slow_g = np.zeros(40)
    slow_g[19:21], slow_g[21:31] = 10.0, 7.0
    slow = Motion(home_end_s=2.05, pullback_start_s=3.0, pullback_cruise_s=3.0, pullback_end_s=3.25, z_halt_mm=0.0,
                  approach_speed_mm_s=1.0, pullback_speed_mm_s=1.0)
    cases.append((slow_s, slow_g, slow, 5.0))
    fast, twin = _twins(lambda: [_polarity_and_repaired(*case) for case in cases])
    assert fast == twin
    assert fast[0] == fast[1] == (analysis.TAP_SHAPE_INVALID, analysis.NO_FORCE_CHANGE)
    assert fast[2][0] == fast[3][0] == fast[4][0] == 1 and fast[2][2] == 3


def test_window_heights_are_the_twins_to_the_last_bit(monkeypatch):
    calls = recorded_calls(analysis, "model_window", [OPTIONS["default"], OPTIONS["sharp"]])
    fast = [analysis.model_window(*args) for args in calls]
    monkeypatch.setattr(analysis, "_C", None)
    for args, window in zip(calls, fast):
        twin = analysis.model_window(*args)
        assert np.array_equal(window.x_min_um, twin.x_min_um) and np.array_equal(window.span_um, twin.span_um)
        assert (window.contact_line_um, window.break_line_um) == (twin.contact_line_um, twin.break_line_um)
        assert np.array_equal(window.force_g, twin.force_g) and np.array_equal(window.time_s, twin.time_s)
        # The pullback's first sample the kernel counted at the window's delay: what pullback_first searches.
        (rising_s, first), = window.firsts.items()
        assert rising_s == analysis.pullback_rising_s(*args[2:5])
        searched = int(window.time_s.searchsorted(rising_s, side="right"))
        assert first == searched == analysis.pullback_first(twin, *args[2:5])
    assert len(calls) >= 30


def test_window_heights_count_the_samples_read_by_a_time_as_searchsorted_does():
    # Before every sample, on each sample's time exactly (read by then: counted), between two, after the
    # last, and a NaN (numpy sorts it past every time).
    time_s = np.arange(12) * 0.01 + 1.0
    rows = [0.0, 100.0, 0.0, 0.0, 5.0, -1.0]  # one move: 100 s long, at rest at Z 5
    for rising_s in (-1.0, 0.99, *time_s, 1.005, 1.115, 2.0, math.nan, math.inf, -math.inf):
        *_, first = KERNEL.window_heights(rows, time_s, 0.0, 0.001, 5.0, 1e-6, 1.0, 1.0, rising_s, np.empty(12),
                                          np.empty(12))
        assert first == int(time_s.searchsorted(rising_s, side="right")), rising_s


def test_window_heights_are_the_twins_at_the_moves_edges():
    # Windows read before the first move starts and after the last ends (a move's time clamped at
    # 0 and at its duration), exactly on move boundaries, a delay reading every sample before the
    # moves, an integration of zero (a window of one height: the MIN_SPAN_UM floor) and line points
    # outside the samples: the kernel's inlined maximum/minimum give the twin's np.maximum/np.minimum.
    tap = tap_from_object(make_tap(SCENARIOS["clean_hx717"].draw(np.random.default_rng(3)), np.random.default_rng(3))[0])
    motion = tap_motion(tap)
    starts = motion.move_table[0]
    ends = starts + motion.move_table[1]
    edges = np.concatenate((starts, ends))
    time_s = np.unique(np.concatenate((np.linspace(starts[0] - 0.5, ends[-1] + 0.5, 400), edges, edges + 1e-9)))
    lines = [(0.0, 0.0)] * 5
    points = [(float(starts[0]) - 1.0, 0.0)] * 2 + [(0.0, 0.0)] * 2 + [(float(ends[-1]) + 1.0, 0.0)] * 2
    dec = analysis.Decomposition(0, len(time_s), (1, 2, 3, 4), lines, points, [0.0] * 4)
    clamped = 0
    for delay_s, integration_s in ((0.0, 0.003), (0.0, 0.0), (0.02, 0.5), (ends[-1] - starts[0] + 1.0, 0.001)):
        timing = analysis.SensorTiming(delay_s, integration_s, False, False, 0.003, 0.0)
        fast, twin = _twins(lambda: analysis.model_window(time_s, time_s * 0.0, motion, timing, delay_s, dec))
        assert np.array_equal(fast.x_min_um, twin.x_min_um) and np.array_equal(fast.span_um, twin.span_um)
        assert (fast.contact_line_um, fast.break_line_um) == (twin.contact_line_um, twin.break_line_um)
        clamped += int(np.sum(twin.span_um == analysis.MIN_SPAN_UM))
    assert clamped >= 400  # the floor was met (zero integration, and windows at rest before and after the moves)


def test_the_height_at_one_time_is_the_twins_to_the_last_bit():
    # Motion.z_at_time_mm (one kernel call) against Motion.z_at (numpy): before the first move, on
    # every move's start and end and just either side, inside each, past the last, the motion's own
    # phase times (the checks read the pullback's end), infinities and NaN (NaN either way).
    for seed, scenario in ((3, "clean_hx717"), (5, "cable_drift"), (8, "clean_ads1220_2000")):
        draw = SCENARIOS[scenario].draw(np.random.default_rng(seed))
        motion = tap_motion(tap_from_object(make_tap(draw, np.random.default_rng(seed))[0]))
        starts = motion.move_table[0]
        ends = starts + motion.move_table[1]
        edges = np.concatenate((starts, ends))
        times = [*np.linspace(starts[0] - 0.5, ends[-1] + 0.5, 301), *edges, *np.nextafter(edges, -np.inf),
                 *np.nextafter(edges, np.inf), motion.home_end_s, motion.pullback_start_s, motion.pullback_cruise_s,
                 motion.pullback_end_s, math.inf, -math.inf]
        for t_s in times:
            twin = float(motion.z_at(t_s))
            assert motion.z_at_time_mm(t_s) == twin and type(motion.z_at_time_mm(t_s)) is float, (scenario, t_s)
        assert math.isnan(motion.z_at_time_mm(math.nan)) and math.isnan(float(motion.z_at(math.nan)))
    with pytest.raises(ValueError, match="not 6 rows"):
        KERNEL.z_at([0.0] * 7, 1.0)
    with pytest.raises(ValueError, match="not 6 rows"):
        KERNEL.z_at([], 1.0)
    with pytest.raises(TypeError, match="not a sequence"):
        KERNEL.z_at(None, 1.0)


def test_the_height_at_one_time_without_moves_is_the_traces():
    # A motion read from a commanded Z trace has no move table: the twin interpolates the trace.
    time_s = np.linspace(0.0, 1.0, 11)
    motion = Motion(0.4, 0.6, 0.6, 0.9, 0.0, 1.0, 1.0, trace_time_s=time_s, trace_z_mm=np.abs(time_s - 0.5))
    assert [motion.z_at_time_mm(t) for t in (0.0, 0.25, 0.5, 2.0)] == [0.5, 0.25, 0.0, 0.5]


def test_the_move_table_is_six_contiguous_rows_of_the_moves():
    # What window_heights and Motion.z_at read: one column per move, rows in this order.
    tap = tap_from_object(make_tap(SCENARIOS["clean_hx717"].draw(np.random.default_rng(3)), np.random.default_rng(3))[0])
    motion = tap_motion(tap)
    table = motion.move_table
    fields = [[move.print_time, move.move_t, move.start_v, move.accel, move.start_z, move.z_r] for move in tap.moves]
    assert table.flags.c_contiguous and table.dtype == float and table.shape == (6, len(tap.moves)) and len(fields) >= 5
    assert table.tolist() == np.transpose(fields).tolist()
    # The list window_heights reads: the same rows one after the other.
    assert motion.move_rows == np.transpose(fields).ravel().tolist()


def test_window_heights_refuse_a_table_that_is_not_six_rows():
    with pytest.raises(ValueError, match="not 6 rows"):
        KERNEL.window_heights(np.zeros(7), np.zeros(3), 0.0, 0.001, 0.0, 1e-6, 0.0, 0.0, 0.0, np.empty(3), np.empty(3))
    with pytest.raises(ValueError, match="not 6 rows"):
        KERNEL.window_heights([], np.zeros(3), 0.0, 0.001, 0.0, 1e-6, 0.0, 0.0, 0.0, np.empty(3), np.empty(3))
    with pytest.raises(TypeError):
        KERNEL.window_heights([0.0] * 5 + ["1"], np.zeros(3), 0.0, 0.001, 0.0, 1e-6, 0.0, 0.0, 0.0, np.empty(3),
                              np.empty(3))
    with pytest.raises(TypeError, match="not a sequence"):
        KERNEL.window_heights(None, np.zeros(3), 0.0, 0.001, 0.0, 1e-6, 0.0, 0.0, 0.0, np.empty(3), np.empty(3))


@pytest.mark.parametrize("change, problem", [
    (lambda t, f: None, 0),
    (lambda t, f: f.__setitem__(7, np.nan), 1),
    (lambda t, f: t.__setitem__(3, np.inf), 1),
    (lambda t, f: t.__setitem__(5, t[4]), 2),
    (lambda t, f: t.__setitem__(slice(None), t[::-1].copy()), 2),
    # The kernel reads every sample without an early exit, several at a time: a NaN after an earlier
    # step back is still the problem named, the last samples (past the last full block of four)
    # are read too, and the largest finite double is finite.
    (lambda t, f: (t.__setitem__(2, t[1]), f.__setitem__(21, np.nan)), 1),
    (lambda t, f: f.__setitem__(22, -np.inf), 1),
    (lambda t, f: t.__setitem__(22, np.nan), 1),
    (lambda t, f: t.__setitem__(22, t[21]), 2),
    (lambda t, f: f.__setitem__(0, np.finfo(float).max), 0),
    # Fine, but a reading equals the one before it (4: `stale_readings` looks), the last pair too.
    (lambda t, f: f.__setitem__(6, f[5]), 4),
    (lambda t, f: f.__setitem__(22, f[21]), 4),
    # A saturated sensor (3): 8 samples in a row at the extreme away from the first sample; 7 are
    # not enough, nor a run at the first sample's side, nor one held to the last sample (a stuck
    # sensor); one ending at the second last sample and a negative polarity count; NaN and times
    # out of order are named first.
    (lambda t, f: f.__setitem__(slice(12, 20), 10.0), 3),
    (lambda t, f: f.__setitem__(slice(12, 19), 10.0), 4),
    (lambda t, f: f.__setitem__(slice(14, 22), 10.0), 3),
    (lambda t, f: f.__setitem__(slice(15, 23), 10.0), 4),
    (lambda t, f: f.__setitem__(slice(0, 8), 5.0), 4),
    (lambda t, f: f.__setitem__(slice(None), np.r_[-f[:10], np.full(12, -10.0), -9.0]), 3),
    (lambda t, f: (f.__setitem__(slice(12, 20), 10.0), f.__setitem__(3, np.nan)), 1),
    (lambda t, f: (f.__setitem__(slice(12, 20), 10.0), t.__setitem__(3, t[2])), 2),
    # The other samples repeat a value in at most one step in four: 12 samples before a run of 10
    # and one after hold 12 steps, 3 repeats are still a saturated sensor, 4 a coarse one.
    (lambda t, f: f.__setitem__(slice(None), np.r_[0, 1, 1, 2, 3, 3, 4, 5, 5, 6, 7, 8, [10.0] * 10, 9]), 3),
    (lambda t, f: f.__setitem__(slice(None), np.r_[0, 1, 1, 2, 3, 3, 4, 5, 5, 6, 6, 8, [10.0] * 10, 9]), 4),
])
def test_sample_checks_name_the_twins_problem(change, problem):
    time_s, force_g = np.linspace(0.0, 1.0, 23), np.linspace(5.0, 9.0, 23)
    change(time_s, force_g)
    assert KERNEL.sample_problem(time_s, force_g) == problem
    tap = type("Tap", (), {"time_s": time_s, "force_g": force_g})()
    messages = []
    for kernel in (KERNEL, None):
        with pytest.MonkeyPatch.context() as patch:
            patch.setattr(analysis, "_C", kernel)
            try:
                analysis._check_samples(tap)
                messages.append(None)
            except analysis.TapInvalid as invalid:
                messages.append(invalid.message)
    assert messages[0] == messages[1] and (messages[0] is None) == (problem in (0, 4))


@settings(max_examples=200, deadline=None)
@given(arrays(np.float64, st.integers(1, 40), elements=st.one_of(st.integers(-3, 3).map(float), st.floats(-9.0, 9.0))),
       st.integers(0, 40), st.integers(0, 12), st.floats(-10.0, 10.0))
def test_a_saturated_run_is_found_as_the_twin_finds_it(force_g, at, held, level_g):
    """A run of `held` samples at `level_g` put into samples with few levels or many (runs and repeats
    anywhere, the run at the extreme or not, either side): the kernel answers 3 exactly where the twin
    finds a saturated run."""
    at = min(at, len(force_g))
    force_g = np.r_[force_g[:at], np.full(held, level_g), force_g[at:]]
    time_s = np.arange(len(force_g), dtype=float)
    assert (KERNEL.sample_problem(time_s, force_g) == 3) == (analysis.saturated_run(force_g)[1] > 0)


@settings(max_examples=100, deadline=None)
@given(arrays(np.float64, st.integers(1, 60), elements=finite), st.floats(2.0, 6.0), st.floats(0.0, 1e3))
def test_the_robust_pass_keeps_what_the_twin_keeps(residual_g, outlier_sigma, floor_g):
    fast, reference = _twins(lambda: analysis._outliers_kept(residual_g, outlier_sigma, floor_g))
    assert (fast is None) == (reference is None)
    if reference is not None:
        assert fast.tolist() == reference.tolist()


def test_near_sigma_and_compression_samples_are_the_twins(monkeypatch):
    with monkeypatch.context() as patch:  # with a fixed onset the contact kernel's fit_pullback holds the near sigma
        patch.setattr(contact, "_C", None)
        near_calls = recorded_calls(analysis, "near_contact_sigma_g", [OPTIONS["default"]])
    count_calls = recorded_calls(analysis, "compression_sample_count", [OPTIONS["default"]])
    fast = ([analysis.near_contact_sigma_g(*args) for args in near_calls],
            [analysis.compression_sample_count(*args) for args in count_calls])
    monkeypatch.setattr(analysis, "_C", None)
    twin = ([analysis.near_contact_sigma_g(*args) for args in near_calls],
            [analysis.compression_sample_count(*args) for args in count_calls])
    assert fast[0] == pytest.approx(twin[0], rel=1e-12)  # a sum in another order than numpy's dot
    assert fast[1] == twin[1] and max(twin[1]) >= 2
    assert len(near_calls) >= 15


@settings(max_examples=100, deadline=None)
@given(arrays(np.float64, st.integers(1, 40), elements=finite, unique=True),
       st.lists(st.floats(-2e6, 2e6, allow_nan=False), min_size=0, max_size=5))
def test_sample_indices_are_the_twins(values, times):
    time_s = np.sort(values)
    fast, reference = _twins(lambda: analysis._indices(time_s, *times))
    assert fast == reference


def test_a_strided_tap_is_analysed_like_a_plain_one():
    from tapcell.tap.synth import synth_tap
    tap = synth_tap(seed=3)
    doubled_time, doubled_force = np.repeat(tap.time_s, 2), np.repeat(tap.force_g, 2)
    strided = type(tap)(**{**tap.__dict__, "time_s": doubled_time[::2], "force_g": doubled_force[::2]})
    assert not strided.time_s.flags.c_contiguous
    assert analysis.analyze_tap(strided).z_mm == analysis.analyze_tap(tap).z_mm


def test_the_window_noise_is_measured_again_where_the_hum_was_removed():
    # The spike repair's noise sigma stands for the window's only where the force is the one it measured:
    # a tap whose hum was fitted and removed (mains_hz=auto) measures its cleaned force again, as the twins do.
    options = analysis.AnalysisOptions(mains_hz="auto")
    fitted = 0
    for tap in generated_taps(per_scenario=4, scenarios=("mains_hum",)):
        fast, twin = _twins(lambda: analysis.analyze_tap(tap, options))
        assert fast.noise_sigma_g == twin.noise_sigma_g
        fitted += fast.hum is not None
    assert fitted >= 3


def test_the_window_noise_is_the_twins_where_the_window_is_cut_short():
    # The spike repair measured every sample; it stands for the window's noise only where the window
    # is every sample. Where the window starts after the first sample or ends before the last (6 of
    # the 30 generated taps), the window is measured again, as the twins measure it.
    options = analysis.AnalysisOptions()
    cut = 0
    for tap in generated_taps():
        fast, twin = _twins(lambda: analysis.analyze_tap(tap))
        assert fast.noise_sigma_g == twin.noise_sigma_g
        try:
            split = analysis.split_tap(tap, options)[0]
        except analysis.TapInvalid:
            continue
        cut += not (split.dec.start == 0 and split.dec.stop == len(split.force_g))
    assert cut >= 3


def test_the_force_at_a_time_is_the_twins_median_of_the_samples_up_to_it():
    # The first sample at or after the time and the END_SAMPLES before it: before the first sample (one
    # value), on a sample's time, between two (an even count: the middle two's mean), past the end (the
    # last four), on a record shorter than the reach, and on the recorded checks' calls.
    rng = np.random.default_rng(4)
    for n in (1, 2, 3, 4, 5, 9):
        time_s = np.sort(rng.uniform(0.0, 1.0, n))
        force_g = rng.standard_normal(n) * 10.0
        for t_s in (-1.0, *time_s, *(time_s + 1e-9), 0.5, 2.0):
            fast, twin = _twins(lambda: analysis.force_at_g(time_s, force_g, float(t_s)))
            assert fast == twin, (n, t_s)
    calls = recorded_calls(analysis, "force_at_g", [OPTIONS["default"]])
    fast, twin = _twins(lambda: [analysis.force_at_g(*args) for args in calls])
    assert fast == twin and len(calls) >= 20
    with pytest.raises(ValueError, match="not negative"):
        KERNEL.median_up_to(np.zeros(3), np.zeros(3), 0.0, -1)
