"""The C endstop (through cffi) and its Python model agree bit for bit on random configurations
and sample streams: every event, index, error, timestamp and filter output, and the state the
next sample meets.

The streams mix what the firmware must tell apart: noise, presses past the trigger and the
force limit, single wild frames, runs of one value, late and stale timestamps, and the 2^32
tick wrap (the clock runs at 1 Hz here so a timestamp in seconds is exactly a tick count).
"""

from __future__ import annotations

import numpy as np
from hypothesis import example, given, settings, strategies as st

from tapcell.filters import FilterOptions, design_firmware_filter
from tapcell.mcu.trigger import MAX_PERIOD_TICKS, FirmwareTrigger, TriggerParams
from tapcell.mcu.trigger_model import TriggerModel

FIELDS = ("state", "error", "glitches", "filtered_q", "trigger_ticks", "release_ticks", "error_ticks",
          "last_sample_ticks", "last_counts", "repeats", "force_low", "force_span", "drift_low", "drift_span",
          "glitch_held")
FILTERS = (None, FilterOptions(660, 0.8), FilterOptions(660, 20.0, 1, 100, 2),
           FilterOptions(660, 0.8, 2, 100, 2, (50, 60), 2.0))


@st.composite
def trigger_params(draw) -> TriggerParams:
    counts_per_gram = draw(st.sampled_from((0.5, 7.3, 110.0, 245.3, 1000.0)))
    trigger_g = draw(st.floats(10.0, 250.0))
    return TriggerParams(
        counts_per_gram=counts_per_gram,
        reference_tare_counts=draw(st.integers(-2 ** 23, 2 ** 23)),
        trigger_force_g=trigger_g,
        release_force_g=draw(st.sampled_from((0.0, 0.3, 0.9))) * trigger_g,
        sample_rate_sps=1.0 / draw(st.sampled_from((1, 7, 1000, MAX_PERIOD_TICKS - 1))),
        force_safety_limit_g=draw(st.sampled_from((0.0, 100.0, 2000.0, 5000.0))),
        drift_safety_limit_g=draw(st.sampled_from((0.0, 50.0, 1000.0, 3000.0))),
        watchdog_periods=draw(st.integers(1, 4)),
        inverted=draw(st.booleans()),
        sos=None if (options := draw(st.sampled_from(FILTERS))) is None else design_firmware_filter(options),
        clock_hz=1.0,
        stuck_samples=draw(st.sampled_from((0, 2, 3, 9))),
    )


def sample_stream(params: TriggerParams, tare: int, start_tick: int, rng: np.random.Generator, n: int):
    """(t_s, counts): seconds (= ticks) and raw counts, in runs of different kinds."""
    period = round(1.0 / params.sample_rate_sps)
    cpg = params.counts_per_gram
    t, c = [], []
    tick, value = start_tick, tare
    while len(t) < n:
        kind = rng.integers(0, 8)
        run = int(rng.integers(1, 12))
        for _ in range(run):
            step = period
            if kind == 0:                                   # noise around the tare
                value = tare + int(rng.normal(0, 3 * cpg))
            elif kind == 1:                                 # a press, a few grams to kilograms per sample
                value += int(rng.exponential(40) * cpg)
            elif kind == 2:                                 # wild frames: anywhere, or kilograms away
                value = int(rng.integers(-2 ** 23, 2 ** 23)) if rng.integers(0, 2) else \
                    tare + int(rng.uniform(-3000, 3000) * cpg)
            elif kind == 3:                                 # stuck: the value repeats
                pass
            elif kind == 4:                                 # late: up to a few periods
                step = int(rng.integers(period, 5 * period + 2))
            elif kind == 5:                                 # stale: older than the one before
                step = -int(rng.integers(0, 3 * period + 1))
            elif kind == 6:                                 # a pull below the tare
                value -= int(rng.exponential(40) * cpg)
            else:                                           # within a count or two: a quiet sensor
                value += int(rng.integers(-1, 2))
            tick += step
            t.append(float(tick))
            c.append(int(np.clip(value, -2 ** 23, 2 ** 23 - 1)))
    return np.array(t[:n]), np.array(c[:n], dtype=np.int64)


def assert_same(c_trigger: FirmwareTrigger, model: TriggerModel, what: str) -> None:
    for name in FIELDS:
        assert c_trigger.field(name) == model.field(name), f"{what}: {name}"


def assert_same_result(a, b, what: str) -> None:
    for name in ("trigger_index", "trigger_time_s", "release_index", "release_time_s", "error", "error_index",
                 "glitches", "consumed", "sensor_error_code"):
        assert getattr(a, name) == getattr(b, name), f"{what}: {name}"
    assert np.array_equal(a.filtered_g, b.filtered_g), f"{what}: filtered_g"


def outcome(result) -> str:
    if result.error_index is not None:
        return result.error.name
    if result.trigger_index is not None:
        return "trigger"
    return "release" if result.release_index is not None else "none"


def run_moves(params: TriggerParams, seed: int, tare: int, start_tick: int, c_trigger: FirmwareTrigger | None) -> set:
    """Three moves of random samples fed in random batches through the model (and the C trigger
    when given, comparing everything after every call); returns the outcomes met."""
    rng = np.random.default_rng(seed)
    model = TriggerModel(params)
    seen = set()
    for move in range(3):
        arm_tick = start_tick + move * 10 ** 9
        error = model.arm(tare, float(arm_tick))
        seen.add(f"arm {error.name}")
        if c_trigger is not None:
            assert c_trigger.arm(tare, float(arm_tick)) == error
            assert_same(c_trigger, model, f"arm {move}")
        t_s, counts = sample_stream(params, tare, arm_tick, rng, 120)
        bounds = sorted(set(rng.integers(0, t_s.size, 5).tolist()) | {0, t_s.size})
        for lo, hi in zip(bounds, bounds[1:]):
            while lo < hi:                     # after an event the caller goes on with the next sample
                what = f"move {move} samples {lo}:{hi}"
                result = model.feed(t_s[lo:hi], counts[lo:hi], want_filtered=True)
                seen |= {outcome(result), "glitch" if result.glitches else "no glitch"}
                if c_trigger is not None:
                    assert_same_result(c_trigger.feed(t_s[lo:hi], counts[lo:hi], want_filtered=True), result, what)
                    assert_same(c_trigger, model, what)
                lo += result.consumed
            now = t_s[hi - 1] + float(rng.integers(0, 4)) / params.sample_rate_sps
            if c_trigger is not None:
                assert c_trigger.check_watchdog(now) == model.check_watchdog(now), f"move {move} at {hi}"
                assert_same(c_trigger, model, f"move {move} watchdog at {hi}")
            else:
                model.check_watchdog(now)
        if rng.integers(0, 2):
            model.abort(107, t_s[-1])
            if c_trigger is not None:
                c_trigger.abort(107, t_s[-1])
                assert_same(c_trigger, model, f"move {move} abort")
    model.disarm()
    if c_trigger is not None:
        c_trigger.disarm()
        assert_same(c_trigger, model, "disarm")
    return seen


@settings(max_examples=60, deadline=None)
@given(params=trigger_params(), seed=st.integers(0, 2 ** 32 - 1),
       tare_offset_g=st.sampled_from((0.0, 40.0, -1500.0, 2500.0)),
       start_tick=st.sampled_from((0, 2 ** 31 - 5, 2 ** 32 - 3, 123456789)))
@example(params=TriggerParams(100.0, 0, 75.0, 1.0 / (MAX_PERIOD_TICKS - 1), clock_hz=1.0, stuck_samples=0),
         seed=1, tare_offset_g=0.0, start_tick=2 ** 32 - 3)
def test_c_trigger_equals_model(params, seed, tare_offset_g, start_tick):
    tare = params.reference_tare_counts + round(tare_offset_g * params.counts_per_gram)
    run_moves(params, seed, tare, start_tick, FirmwareTrigger(params))


def test_the_streams_meet_every_kind_of_stop():
    """The random streams above reach every outcome (else the comparison proves little)."""
    seen = set()
    for seed in range(30):
        params = TriggerParams(110.0, 0, (75.0, 250.0)[seed % 2], 1.0 / 7, clock_hz=1.0,
                               release_force_g=(0.0, 60.0)[seed % 4 < 2], drift_safety_limit_g=(0.0, 100.0, 1000.0)[seed % 3],
                               stuck_samples=(3, 9, 0)[seed % 3])
        seen |= run_moves(params, seed, round(110 * (0, 1500, 2500)[seed % 5 // 2]), 2 ** 32 - 100, None)
    assert seen == {"FORCE_SAFETY", "DRIFT_SAFETY", "STUCK_SENSOR", "WATCHDOG_TIMEOUT", "trigger", "release", "none",
                    "glitch", "no glitch", "arm NONE", "arm FORCE_SAFETY"}
