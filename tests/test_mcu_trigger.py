"""The firmware load-cell trigger through tapcell.mcu.trigger (one C call per batch)."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from scipy import signal

from tapcell.filters import FilterOptions, design_firmware_filter, design_sos
from tapcell.mcu.trigger import (
    FirmwareTrigger, TriggerConfigError, TriggerError, TriggerParams, quantize_scale, reference_counts_to_q1615,
)

SPS = 660.0
PERIOD_S = 1 / SPS
FIRMWARE = Path(__file__).resolve().parents[1] / "firmware"


def params(**overrides) -> TriggerParams:
    values = dict(counts_per_gram=245.3, reference_tare_counts=12000, trigger_force_g=75.0, sample_rate_sps=SPS)
    values.update(overrides)
    return TriggerParams(**values)


def sample_times(n: int, start_s: float = 1.0) -> np.ndarray:
    return start_s + (np.arange(n) + 1) * PERIOD_S


def test_error_codes_match_the_firmware_header():
    header = (FIRMWARE / "include" / "tc_errors.h").read_text()
    codes = {name: int(value) for name, value in re.findall(r"TC_ERR_(\w+) = (\d+)", header)}
    assert codes == {e.name: e.value for e in TriggerError if e not in (TriggerError.NONE, TriggerError.SENSOR)}


def test_no_filter_fires_on_exactly_the_first_sample_at_trigger_force():
    rng = np.random.default_rng(7)
    tare = 15000
    grams = np.concatenate([rng.uniform(-70, 70, 3000), [74.99, -74.995, -75.0, 80.0, 10.0]])
    counts = np.round(tare + grams * 245.3).astype(np.int64)
    trigger = FirmwareTrigger(params(reference_tare_counts=tare))
    assert trigger.arm(tare, 1.0) == TriggerError.NONE
    t = sample_times(counts.size)
    result = trigger.feed(t, counts, want_filtered=True)
    float_g = (counts - tare) / 245.3
    first = int(np.argmax(np.abs(float_g) >= 75.0))
    assert result.trigger_index == first == 3002        # -75.0 g (rounded counts are exactly -75.0 g)
    assert result.trigger_time_s == t[first]
    assert result.consumed == first + 1 and result.error == TriggerError.NONE
    assert trigger.state == "triggered"
    scale, frac_bits = quantize_scale(245.3, inverted=False)
    exact_q = reference_counts_to_q1615(counts[:first + 1], tare, scale, frac_bits)
    assert np.array_equal(np.round(result.filtered_g * 32768).astype(np.int64), exact_q)
    assert np.max(np.abs(result.filtered_g - float_g[:first + 1])) < 1 / 32768


def test_drift_filter_ignores_a_slow_200_g_ramp_but_not_contact():
    sos = design_firmware_filter(FilterOptions(SPS, drift_filter_cutoff_frequency=0.8))
    trigger = FirmwareTrigger(params(sos=sos, reference_tare_counts=0))
    t = sample_times(int(10 * SPS))
    slow_counts = np.round(200.0 * (t - t[0]) / 10.0 * 245.3).astype(np.int64)   # 200 g over 10 s
    assert trigger.arm(0, 1.0) == TriggerError.NONE
    slow = trigger.feed(t, slow_counts, want_filtered=True)
    assert slow.trigger_index is None and slow.error == TriggerError.NONE and slow.consumed == t.size
    # the order-2 high-pass removes a ramp entirely once settled; its start transient peaks near 1.8 g
    float_g = signal.sosfilt(design_sos(FilterOptions(SPS, drift_filter_cutoff_frequency=0.8)), slow_counts / 245.3)
    assert np.max(np.abs(slow.filtered_g - float_g)) < 0.01
    assert 1.7 < np.max(np.abs(slow.filtered_g)) < 1.9
    # contact: the same ramp, then the nozzle hits the bed and force rises at 3 kg/s
    contact_s = t[0] + 5.0
    contact_g = 200.0 * (t - t[0]) / 10.0 + np.where(t > contact_s, 3000.0 * (t - contact_s), 0.0)
    assert trigger.arm(0, 1.0) == TriggerError.NONE
    hit = trigger.feed(t, np.round(contact_g * 245.3).astype(np.int64))
    assert hit.trigger_index is not None
    assert contact_s < hit.trigger_time_s < contact_s + 0.05  # 75 g at 3 kg/s is 25 ms after contact


def test_force_safety_at_arm():
    trigger = FirmwareTrigger(params(force_safety_limit_g=2000.0))
    limit_counts = round(2000.0 * 245.3)
    assert trigger.arm(12000 + limit_counts, 0.0) == TriggerError.NONE
    assert trigger.arm(12000 - limit_counts - 1, 0.0) == TriggerError.FORCE_SAFETY
    assert trigger.state == "error"
    assert trigger.feed(sample_times(3), np.full(3, 12000)).error == TriggerError.FORCE_SAFETY
    assert FirmwareTrigger(params(force_safety_limit_g=0)).arm(8_000_000, 0.0) == TriggerError.NONE


def test_drift_safety_and_glitch_quarantine():
    trigger = FirmwareTrigger(params(drift_safety_limit_g=1000.0, reference_tare_counts=0))
    trigger.arm(0, 1.0)
    wild = round(1900 * 245.3)                         # past the drift limit, inside the force limit
    counts = np.array([0, 50, wild, 60, -wild, 70, 80], dtype=np.int64)   # two isolated bad frames
    result = trigger.feed(sample_times(counts.size), counts, want_filtered=True)
    assert result.error == TriggerError.NONE and result.trigger_index is None
    assert result.glitches == 2
    assert result.filtered_g[2] == result.filtered_g[1]                             # held, not filtered
    trigger.arm(0, 1.0)
    over = round(1001 * 245.3)
    result = trigger.feed(sample_times(5), np.array([0, over, over, 0, 0]))
    assert result.error == TriggerError.DRIFT_SAFETY and result.error_index == 2 and result.consumed == 3
    assert trigger.state == "error"


def test_force_limit_stops_on_the_first_sample_past_it_with_or_without_quarantine():
    # 2000 g at 245.3 counts/g is 490600 counts from the reference (12000) and from the tare.
    for drift_g in (0.0, 1000.0):
        trigger = FirmwareTrigger(params(drift_safety_limit_g=drift_g))
        trigger.arm(12000, 1.0)
        counts = np.array([12000, 12000 + 50 * 245, 12000 + 490601, 12000])   # 50 g, then just past 2000 g
        result = trigger.feed(sample_times(counts.size), counts)
        assert result.error == TriggerError.FORCE_SAFETY and result.error_index == 2, drift_g
        # exactly at the limit it is a sample like any other: it triggers, or waits in quarantine
        trigger.arm(12000, 1.0)
        at_limit = trigger.feed(sample_times(2), np.array([12000, 12000 + 490600]))
        assert at_limit.error == TriggerError.NONE
        assert at_limit.trigger_index == (1 if drift_g == 0 else None)
    # a tare 1500 g above the reference leaves 500 g to push (the reference window)
    trigger = FirmwareTrigger(params(trigger_force_g=250.0, drift_safety_limit_g=0.0))
    tare = 12000 + round(1500 * 245.3)
    assert trigger.arm(tare, 1.0) == TriggerError.NONE
    result = trigger.feed(sample_times(2), np.array([tare + round(200 * 245.3), 12000 + 490601]))  # +200 g, +500 g
    assert result.error == TriggerError.FORCE_SAFETY and result.error_index == 1
    # a single corrupted frame past the limit stops the move too (it cannot wait for the next sample)
    trigger.arm(12000, 1.0)
    assert trigger.feed(sample_times(3), np.array([12000, 0x7FFFFF, 12000])).error_index == 1


def test_stuck_sensor_stops_after_the_default_run_at_660_sps():
    trigger = FirmwareTrigger(params())                 # stuck_samples None: 9 at 660 sps (16 counts of noise)
    assert trigger.params.effective_stuck_samples == 9
    rng = np.random.default_rng(3)
    live = 12000 + np.round(rng.normal(0, 16, 2000)).astype(np.int64)
    trigger.arm(12000, 1.0)
    alive = trigger.feed(sample_times(live.size), live)
    assert alive.error == TriggerError.NONE and alive.consumed == live.size
    stuck = np.concatenate([live[:100], np.full(20, live[99])])
    trigger.arm(12000, 1.0)
    result = trigger.feed(sample_times(stuck.size), stuck)
    assert result.error == TriggerError.STUCK_SENSOR and result.error_index == 99 + 8
    assert FirmwareTrigger(params(stuck_samples=0)).params.effective_stuck_samples == 0


def test_watchdog_after_exactly_n_sample_periods():
    trigger = FirmwareTrigger(params(watchdog_periods=2, clock_hz=1e6, sample_rate_sps=500.0))
    trigger.arm(12000, 10.0)
    trigger.feed(np.array([10.001]), np.array([12000]))
    assert trigger.check_watchdog(10.001 + 0.004) == TriggerError.NONE       # exactly 2 periods
    assert trigger.check_watchdog(10.001 + 0.004 + 1e-6) == TriggerError.WATCHDOG_TIMEOUT
    assert trigger.state == "error"
    trigger.disarm()
    assert trigger.state == "idle" and trigger.check_watchdog(99.0) == TriggerError.NONE


def test_samples_before_arm_are_ignored_and_ticks_wrap():
    trigger = FirmwareTrigger(params(reference_tare_counts=0, clock_hz=1e6))
    wrap_s = 2 ** 32 / 1e6                                  # 4294.967296 s
    trigger.arm(0, wrap_s - 0.002)
    t = np.array([wrap_s - 0.003, wrap_s - 0.0015, wrap_s + 0.0, wrap_s + 0.0015])
    counts = np.round(np.array([500.0, 10.0, 20.0, 80.0]) * 245.3)
    result = trigger.feed(t, counts)
    assert result.trigger_index == 3 and result.trigger_time_s == t[3]     # not the early 500 g sample


def test_hysteresis_reports_trigger_then_release():
    trigger = FirmwareTrigger(params(trigger_force_g=125.0, release_force_g=45.0, reference_tare_counts=0))
    trigger.arm(0, 0.0)
    grams = np.array([0, 100, 130, 200, 60, 40, 30, 126])
    t = sample_times(grams.size, 0.0)
    counts = np.round(grams * 245.3)
    first = trigger.feed(t, counts)
    assert first.trigger_index == 2 and trigger.state == "triggered"
    second = trigger.feed(t[3:], counts[3:])
    assert second.release_index == 2 and second.release_time_s == t[5] and trigger.state == "armed"
    third = trigger.feed(t[6:], counts[6:])
    assert third.trigger_index == 1 and third.trigger_time_s == t[7]


def test_inverted_orientation_and_sensor_abort():
    trigger = FirmwareTrigger(params(inverted=True, reference_tare_counts=0))
    trigger.arm(0, 0.0)
    result = trigger.feed(sample_times(1, 0.0), np.array([round(10 * 245.3)]), want_filtered=True)
    assert result.filtered_g[0] == pytest.approx(-10.0, abs=1e-4)
    trigger.abort(107, 0.01)                                  # e.g. the HX71x desync code
    result = trigger.feed(sample_times(2, 0.01), np.array([0, 0]))
    assert result.error == TriggerError.SENSOR and result.sensor_error_code == 107 and result.error_index is None


def test_one_call_for_a_10000_sample_tap():
    sos = design_firmware_filter(FilterOptions(SPS, 0.8, 2, 100, 2, (50, 60), 2.0))
    trigger = FirmwareTrigger(params(sos=sos, reference_tare_counts=0))
    t = sample_times(10_000)
    grams = np.where(np.arange(10_000) >= 9000, (np.arange(10_000) - 9000) * 5.0, 0.0)
    grams += np.random.default_rng(1).normal(0, 0.1, grams.size)    # a live sensor is never flat
    trigger.arm(0, 1.0)
    result = trigger.feed(t, np.round(grams * 245.3))
    assert result.trigger_index is not None and 9014 <= result.trigger_index <= 9030


@pytest.mark.parametrize("overrides, message", [
    (dict(counts_per_gram=0.0), "counts_per_gram: 0.0 is not allowed; allowed: a positive number of counts per "
                                "gram (1e-4 .. 1e9)"),
    (dict(trigger_force_g=-5.0), "trigger_force_g: -5.0 is not allowed; allowed: above 0 and below 65536 g"),
    (dict(release_force_g=80.0), "release_force_g: 80.0 is not allowed; allowed: 0 (latched trigger) or above 0 "
                                 "and below trigger_force_g (75 g)"),
    (dict(watchdog_periods=0), "watchdog_periods: 0 is not allowed; allowed: an integer 1 .. 15"),
    (dict(drift_safety_limit_g=-1.0), "drift_safety_limit_g: -1.0 is not allowed; allowed: 0 (disabled) or a "
                                      "positive force in grams"),
    (dict(sample_rate_sps=0.001), "sample_rate_sps: 0.001 is not allowed; allowed: a sample period of "
                                  "1 .. 134217727 ticks at clock_hz 1e+06"),
    (dict(stuck_samples=1), "stuck_samples: 1 is not allowed; allowed: 0 (disabled) or an integer 2 .. 65535"),
    (dict(stuck_samples=70000), "stuck_samples: 70000 is not allowed; allowed: 0 (disabled) or an integer 2 .. 65535"),
    (dict(reference_tare_counts=2 ** 31 - 1000), "force_safety_limit_g: 2000.0 is not allowed; allowed: a window "
                                                 "reference_tare_counts +- limit within int32"),
])
def test_bad_parameters_are_named(overrides, message):
    with pytest.raises(TriggerConfigError) as info:
        FirmwareTrigger(params(**overrides))
    assert str(info.value) == message


def test_feed_rejects_mismatched_arrays():
    trigger = FirmwareTrigger(params())
    with pytest.raises(ValueError, match="one length"):
        trigger.feed(np.zeros(3), np.zeros(2))
    with pytest.raises(ValueError, match="counts must fit int32"):
        trigger.feed(np.zeros(1), np.array([2 ** 40]))


def test_library_rebuild_watches_every_file_the_host_build_compiles():
    from tapcell.mcu import _lib

    watched = set(_lib._sources())
    compiled = {*_lib.FIRMWARE_DIR.glob("src/*.c"), *_lib.FIRMWARE_DIR.glob("host/*.c"),
                *_lib.FIRMWARE_DIR.glob("include/*.h")}
    assert _lib.FIRMWARE_DIR / "host" / "batch.c" in compiled
    assert compiled <= watched
