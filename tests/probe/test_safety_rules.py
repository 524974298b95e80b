"""The force guard's prediction and the trigger-only rules, against the physics they stand for."""

from __future__ import annotations

import numpy as np
import pytest

from tapcell.extras.load_cell_probe import safety
from tapcell.filters import FilterOptions, design_firmware_filter
from tapcell.host.config import pin_mcu
from tapcell.mcu.trigger import TriggerError, TriggerParams
from tapcell.scale import SENSOR_24BIT


def params(rate_sps: float, **changes) -> TriggerParams:
    return TriggerParams(counts_per_gram=110.0, reference_tare_counts=-38000, trigger_force_g=75.0,
                         sample_rate_sps=rate_sps, **changes)


@pytest.mark.parametrize("chip, rate_sps, sensor_mcu", [("hx711", 80, "mcu"), ("hx717", 320, "mcu"),
                                                          ("ads1220", 660, "toolboard")])
@pytest.mark.parametrize("speed_mm_s", [1.0, 5.0, 20.0])
def test_without_filters_the_peak_is_the_trigger_plus_the_travel_until_the_stop(chip, rate_sps, sensor_mcu,
                                                                                speed_mm_s):
    # The brief's bound: trigger + (pipeline + sample period + stop latency) x speed x stiffness, with
    # the read delay and the half window that the window average lags a ramp by; at least the travel
    # after the triggering sample was read. 3.26 g/um, the drift window off (a raw window would stop
    # a fast ramp first).
    timing = safety.stop_timing(chip, rate_sps, sensor_mcu, "mcu")
    stiffness = 3.26
    prediction = safety.predict_stop(params(rate_sps, drift_safety_limit_g=0.0), timing, speed_mm_s, stiffness)
    ramp_g_per_s = stiffness * speed_mm_s * 1000.0
    after_read_s = timing.pipeline_s + timing.read_delay_s + timing.stop_latency_s
    assert prediction.stopped_by == TriggerError.NONE
    assert 75.0 + ramp_g_per_s * after_read_s < prediction.peak_force_g
    assert prediction.peak_force_g <= 75.0 + ramp_g_per_s * (after_read_s + 1.5 * timing.period_s)


def test_a_drift_filter_hides_a_slow_tap_and_a_raw_window_stops_it():
    sos = design_firmware_filter(FilterOptions(sample_rate_sps=320, drift_filter_cutoff_frequency=20.0))
    timing = safety.stop_timing("hx717", 320, "mcu", "mcu")
    hidden = safety.predict_stop(params(320, sos=sos), timing, 1.0, safety.SOFTEST_STIFFNESS_G_UM)
    assert hidden.hidden and hidden.stopped_by == TriggerError.DRIFT_SAFETY
    assert 1000.0 < hidden.peak_force_g < 1100.0           # the drift window (1000 g) plus ~one sample
    assert not safety.unprotected_hiding_speeds(params(320, sos=sos), timing, [1.0, 5.0])
    unprotected = params(320, sos=sos, drift_safety_limit_g=0.0)
    assert safety.unprotected_hiding_speeds(unprotected, timing, [1.0, 5.0]) == [1.0, 5.0]
    seen = safety.predict_stop(params(320, sos=sos), timing, 20.0, 10.0)
    assert not seen.hidden                                   # a fast tap on a stiff bed comes through


def test_the_stop_latency_follows_the_pins():
    assert pin_mcu("PA4") == pin_mcu("^!PA4") == "mcu"
    assert pin_mcu("toolboard:PA4") == pin_mcu("^toolboard: PA4") == "toolboard"
    assert safety.stop_timing("hx717", 320, "toolboard", "mcu").stop_latency_s == 0.025
    assert safety.stop_timing("hx717", 320, "mcu", "mcu").stop_latency_s == 0.001


def test_sensor_faults_from_raw_samples():
    live = np.array([-38000, -37990, -38012, -38004, -37998, -38007, -38001, -37995, -38003])
    assert safety.sensor_fault(live, SENSOR_24BIT, 8) is None
    assert safety.sensor_fault(np.r_[live, [-38124] * 8], SENSOR_24BIT, 8) == "stuck"
    assert safety.sensor_fault(np.r_[live, [-38124] * 7], SENSOR_24BIT, 8) is None
    assert safety.sensor_fault(np.r_[live, [(1 << 23) - 1]], SENSOR_24BIT, 8) == "saturated"


def test_a_contact_holds_a_glitch_or_a_swing_does_not():
    assert safety.contact_holds(np.array([140.0, 138.0, 137.0, 137.0]), 75.0)
    assert safety.contact_holds(np.array([140.0, 138.0, 137.0]), 75.0)          # one sample missing
    assert not safety.contact_holds(np.array([2.0, -1.0, 3.0, 0.0]), 75.0)       # a corrupted frame in the air
    assert not safety.contact_holds(np.array([60.0, 10.0, -40.0, -90.0]), 75.0)  # a transient the tare took in
    assert not safety.contact_holds(np.array([140.0, 138.0]), 75.0)
