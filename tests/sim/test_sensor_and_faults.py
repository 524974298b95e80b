"""The sensor stream (rate, calibration truth, saturation, hum, latency) and every fault's symptom."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import armed_trigger
from tapcell.mcu.trigger import TriggerError
from tapcell.sim import FaultError, McuResetError, SimParamError, VirtualPrinter
from tapcell.sim.sensor import COUNTS_MAX


def _batch(vp, seconds):
    vp.dwell(seconds)
    return vp.take_samples()


def test_samples_arrive_at_the_chip_rate_with_small_read_jitter():
    vp = VirtualPrinter.from_scenario("slow-adc", seed=1)           # HX711 80 sps, oscillator +1.5 %
    batch = _batch(vp, 10.0)
    assert batch.t_s.size == pytest.approx(10.0 * 80.0 * 1.015, abs=2)
    intervals = np.diff(batch.t_s)
    assert np.median(intervals) == pytest.approx(1.0 / (80.0 * 1.015), rel=0.01)
    # data-ready polling at T/10 (uniform) plus ~15 µs of task latency
    assert intervals.max() - intervals.min() < 2 * 0.1 / (80.0 * 1.015) + 0.3e-3
    assert batch.counts.dtype == np.int32 and batch.errors == 0 and batch.overflows == 0
    assert vp.take_samples().t_s.size == 0                          # nothing new without time passing


def test_weight_on_the_cell_moves_counts_by_counts_per_gram():
    vp = VirtualPrinter.from_scenario("clean", seed=3, gain=64)
    assert vp.truth.counts_per_gram == pytest.approx(55.0)          # 110 counts/g at gain 128, halved
    empty = _batch(vp, 2.0).counts.mean()
    vp.place_weight(1000.0)
    vp.dwell(0.05)
    vp.take_samples()
    loaded = _batch(vp, 2.0).counts.mean()
    vp.remove_weight()
    vp.dwell(0.05)
    vp.take_samples()
    again = _batch(vp, 2.0).counts.mean()
    assert empty == pytest.approx(vp.truth.zero_offset_counts, abs=30)
    assert (loaded - empty) / 1000.0 == pytest.approx(55.0, rel=0.002)
    assert again == pytest.approx(empty, abs=30)


def test_overload_saturates_at_the_24_bit_limit():
    vp = VirtualPrinter.from_scenario("clean", seed=1)
    vp.place_weight(100000.0)                                        # 100 kg * 110 counts/g > 2^23
    batch = _batch(vp, 0.5)
    assert np.all(batch.counts[5:] == COUNTS_MAX)


def test_mains_hum_is_visible_at_320_sps_and_rejected_by_a_10_sps_hx711():
    quiet = _batch(VirtualPrinter.from_scenario("clean", seed=1), 5.0).counts.std()
    noisy = _batch(VirtualPrinter.from_scenario("noisy-mains", seed=1), 5.0).counts.std()
    hx711_10 = _batch(VirtualPrinter.from_scenario("noisy-mains", seed=1, chip="hx711", sample_rate_sps=10.0),
                      20.0).counts.std()
    assert noisy > 4.0 * quiet
    assert hx711_10 < 0.35 * noisy     # a 100 ms window spans whole 50 Hz cycles


def test_ads1220_pipeline_delays_a_step_by_one_more_period():
    def step_delay(scenario, rate):
        vp = VirtualPrinter.from_scenario(scenario, seed=1, white_noise_counts=0.0, pink_noise_counts=0.0)
        vp.dwell(0.5)
        t_step = vp.now_s
        vp.place_weight(1000.0)
        vp.dwell(0.1)
        b = vp.take_samples()
        half = (b.counts.min() + b.counts.max()) / 2
        return (b.t_s[np.argmax(b.counts > half)] - t_step) * rate
    hx717 = step_delay("clean", 320.0)
    ads = step_delay("fast-adc", 660.0)
    assert 0.5 <= hx717 <= 1.7 and 1.5 <= ads <= 2.7


def test_bowden_drag_follows_toolhead_position():
    vp = VirtualPrinter.from_scenario("bowden-drift", seed=1, pink_noise_counts=0.0)
    vp.move_to(x=20.0, speed_mm_s=200.0)
    left = _batch(vp, 1.0).counts[-100:].mean()
    vp.move_to(x=220.0, speed_mm_s=200.0)
    vp.take_samples()
    right = _batch(vp, 1.0).counts[-100:].mean()
    assert (right - left) / vp.truth.counts_per_gram == pytest.approx(0.6 * 200.0, rel=0.05)


def test_disconnected_sensor_delivers_nothing_and_the_watchdog_stops_a_probe():
    vp = VirtualPrinter.from_scenario("clean", seed=1)
    vp.move_to(z=1.0, speed_mm_s=10.0)
    trigger = armed_trigger(vp)
    vp.inject_fault("disconnected")
    t0 = vp.now_s
    result = vp.probing_move(-1.0, 3.0, trigger)
    assert not result.triggered and result.error == TriggerError.WATCHDOG_TIMEOUT
    # no sample for more than 2 periods: stopped on the 3rd tick after the last sample
    assert result.halt_time_s - t0 == pytest.approx(3.0 / 320.0, abs=1.2 / 320.0)
    assert result.halt_z_mm > 0.9
    assert np.all(_batch(vp, 1.0).t_s < t0 + 1.0 / 320.0)        # at most one sample already converted
    assert VirtualPrinter.from_scenario("disconnected").take_samples().t_s.size == 0


def test_stuck_sensor_repeats_one_value():
    vp = VirtualPrinter.from_scenario("clean", seed=1)
    vp.dwell(0.5)
    before = vp.take_samples().counts[-1]
    vp.inject_fault("stuck", duration_s=1.0)
    stuck = _batch(vp, 0.9).counts
    assert stuck.size > 250 and np.unique(stuck[1:]).size == 1 and abs(int(stuck[-1]) - int(before)) < 800
    after = _batch(vp, 0.5).counts
    assert np.unique(after).size > 50


def test_chip_reset_jumps_the_offset_after_a_short_gap():
    vp = VirtualPrinter.from_scenario("clean", seed=1)
    before = _batch(vp, 1.0)
    vp.inject_fault("chip_reset", offset_jump_counts=50000, gap_s=0.05)
    t_reset = vp.now_s
    after = _batch(vp, 1.0)
    assert after.t_s[0] - t_reset >= 0.05
    assert after.counts.mean() - before.counts.mean() == pytest.approx(50000, abs=60)


def test_single_corrupted_frames_stand_out_and_detected_ones_are_counted_as_errors():
    vp = VirtualPrinter.from_scenario("clean", seed=1)
    vp.dwell(0.2)
    vp.take_samples()
    vp.inject_fault("corrupt_frame", count=3, spacing_s=0.2)
    batch = _batch(vp, 1.0)
    jumps = np.abs(batch.counts - np.median(batch.counts)) > 30000      # a flipped bit 16..22
    assert np.count_nonzero(jumps) == 3 and batch.errors == 0
    vp.inject_fault("corrupt_frame", count=2, spacing_s=0.2, detected=True)
    batch = _batch(vp, 1.0)
    assert batch.errors == 2 and batch.t_s.size == pytest.approx(318, abs=3)


def test_glitchy_scenario_corrupts_about_half_a_frame_per_second():
    batch = _batch(VirtualPrinter.from_scenario("glitchy", seed=7), 60.0)
    glitches = np.count_nonzero(np.abs(batch.counts - np.median(batch.counts)) > 30000)
    assert 15 <= glitches <= 45


def test_saturation_fault_pegs_the_reading():
    vp = VirtualPrinter.from_scenario("clean", seed=1)
    vp.inject_fault("saturation", at_s=0.5, duration_s=0.5, level="min")
    b = _batch(vp, 1.5)
    inside = (b.t_s > 0.51) & (b.t_s < 0.99)
    assert np.all(b.counts[inside] == -(1 << 23)) and not np.any(b.counts[~inside & (b.t_s > 1.01)] == -(1 << 23))


def test_bowden_tug_is_a_smooth_force_pulse():
    vp = VirtualPrinter.from_scenario("clean", seed=1)
    vp.inject_fault("bowden_tug", at_s=1.0, force_g=300.0, duration_s=0.4)
    vp.dwell(2.0)
    t, force = vp.truth.force_g(0.0, 2.0)
    assert force.max() == pytest.approx(300.0, rel=0.01)
    assert t[np.argmax(force)] == pytest.approx(1.2, abs=0.01)
    assert np.all(force[t < 0.99] == 0.0) and np.all(force[t > 1.41] == 0.0)


def test_a_pending_bowden_tug_waits_for_its_probing_move_and_then_pulls():
    vp = VirtualPrinter.from_scenario("clean", seed=1)
    vp.move_to(z=1.0, speed_mm_s=10.0)
    vp.inject_fault("bowden_tug", when="probing_move", force_g=200.0, duration_s=0.3)
    vp.dwell(0.5)                                                    # pending: no force, no error
    assert vp.take_samples().t_s.size > 100
    t, force = vp.truth.force_g(0.0, vp.now_s)
    assert np.all(force == 0.0)
    trigger = armed_trigger(vp)
    t0 = vp.now_s
    result = vp.probing_move(-1.0, 1.0, trigger)                     # 1 mm above the bed: the tug triggers
    assert result.triggered and result.halt_z_mm > 0.9
    vp.dwell(0.5)
    t, force = vp.truth.force_g(t0, vp.now_s)
    assert force.max() == pytest.approx(200.0, rel=0.01) and t[np.argmax(force)] == pytest.approx(t0 + 0.15, abs=0.01)


def test_truth_reports_the_peak_nozzle_force_and_the_clearance_now():
    vp = VirtualPrinter.from_scenario("clean", seed=1)
    x, y, _ = vp.position
    contact = vp.truth.contact_z_at(x, y)
    vp.move_to(z=contact + 0.5, speed_mm_s=10.0)
    assert vp.truth.nozzle_clearance_mm == pytest.approx(0.5, abs=0.0025)     # one 2.5 um Z step
    assert vp.truth.take_peak_force_g() == 0.0
    vp.move_to(z=contact - 0.1, speed_mm_s=1.0)                      # 100 um into the bed, 3.26 g/um
    assert vp.truth.nozzle_clearance_mm == pytest.approx(-0.1, abs=0.0025)
    pressed_g = vp.truth.stiffness_g_um * (100.0 - 0.5 * 2.0)        # linear beyond the 2 um onset
    assert vp.truth.take_peak_force_g() == pytest.approx(pressed_g, rel=0.03)
    vp.move_to(z=contact + 1.0, speed_mm_s=10.0)
    vp.dwell(0.1)
    assert vp.truth.take_peak_force_g() == pytest.approx(pressed_g, rel=0.03)   # the lift started pressed
    assert vp.truth.take_peak_force_g() == 0.0                       # read and started again


def test_mcu_reset_stops_the_steppers_drops_samples_and_raises_when_the_link_is_back():
    vp = VirtualPrinter.from_scenario("clean", seed=1)
    vp.move_to(z=5.0, speed_mm_s=10.0)
    vp.dwell(0.1)
    vp.take_samples()
    t0 = vp.now_s
    vp.inject_fault("mcu_reset", at_s=t0 + 0.2, duration_s=0.4)
    with pytest.raises(McuResetError, match=r"reset at .* the host link was lost until") as info:
        vp.move_to(z=15.0, speed_mm_s=10.0)                          # would take 1 s (and accelerate)
    assert info.value.reset_s == pytest.approx(t0 + 0.2) and info.value.restored_s == pytest.approx(t0 + 0.6)
    assert vp.now_s == pytest.approx(t0 + 0.6)
    stopped_z = vp.position[2]
    assert 5.5 < stopped_z < 7.0                                      # stopped 0.2 s into the move
    vp.dwell(0.5)
    assert vp.position[2] == stopped_z                                # nothing resumes the move
    batch = vp.take_samples()
    assert not np.any((batch.t_s > t0 + 0.2 + 1.0 / 320.0) & (batch.t_s < t0 + 0.6))
    assert np.count_nonzero(batch.t_s > t0 + 0.6) > 150               # samples again after the link is back
    vp.dwell(1.0)                                                     # a reset happens once


def test_mcu_reset_on_contact_stops_a_probing_move_at_the_bed():
    vp = VirtualPrinter.from_scenario("clean", seed=1)
    contact = vp.truth.contact_z_at(*vp.position[:2])
    vp.move_to(z=contact + 0.3, speed_mm_s=10.0)
    trigger = armed_trigger(vp)
    vp.inject_fault("mcu_reset", when="contact")
    with pytest.raises(McuResetError):
        vp.probing_move(contact - 1.0, 3.0, trigger)
    assert vp.position[2] == pytest.approx(contact, abs=0.003)
    assert vp.truth.take_peak_force_g() < 10.0


def test_fault_on_contact_starts_when_the_nozzle_reaches_the_bed():
    vp = VirtualPrinter.from_scenario("clean", seed=1)
    contact = vp.truth.contact_z_at(*vp.position[:2])
    vp.move_to(z=contact + 0.3, speed_mm_s=10.0)
    trigger = armed_trigger(vp)
    t0 = vp.now_s
    vp.inject_fault("disconnected", when="contact")
    result = vp.probing_move(contact - 0.5, 3.0, trigger)
    assert result.error == TriggerError.WATCHDOG_TIMEOUT and not result.triggered
    contact_time = vp._faults[-1].start_s
    assert contact_time - t0 == pytest.approx(0.3 / 3.0 + 3.0 / 200.0 / 2, abs=0.003)


def test_faults_at_the_phases_of_a_tap_wait_for_their_nth_occurrence():
    """halt (the dwell), lift (pullback, between taps) and travel (mesh travel, wipes), each on
    the occurrence asked for: the bench's faults at every phase start where they say."""
    vp = VirtualPrinter.from_scenario("clean", seed=1)
    contact = vp.truth.contact_z_at(*vp.position[:2])
    vp.move_to(z=contact + 0.3, speed_mm_s=10.0)
    vp.inject_fault("stuck", when="halt")
    vp.inject_fault("stuck", when="lift", nth=2)
    vp.inject_fault("stuck", when="travel")
    halt, lift, travel = vp._faults[-3:]
    result = vp.probing_move(contact - 0.5, 3.0, armed_trigger(vp))
    assert halt.start_s == result.halt_time_s and lift.start_s is None and travel.start_s is None
    vp.move_to(z=contact + 0.3, speed_mm_s=10.0)   # the first lift: not yet
    assert lift.start_s is None and lift.waits_for == 1
    second_lift_s = vp.now_s
    vp.move_to(z=contact + 1.0, speed_mm_s=10.0)
    assert lift.start_s == second_lift_s and travel.start_s is None
    travel_s = vp.now_s
    vp.move_to(x=vp.position[0] + 5.0, speed_mm_s=50.0)
    assert travel.start_s == travel_s
    with pytest.raises(FaultError, match="nth must be a whole number from 1, and only with a condition"):
        vp.inject_fault("stuck", nth=2)


def _fault_session(vp):
    """Faults one after another (one begun in the past, one waiting for a condition) and the
    samples they give."""
    vp.inject_fault("stuck", when="trigger")
    vp.dwell(0.3)
    vp.inject_fault("weight", at_s=vp.now_s - 0.01, grams=200.0, duration_s=0.05)
    vp.inject_fault("corrupt_frame", count=3, spacing_s=0.05)
    vp.inject_fault("bowden_tug", at_s=vp.now_s + 0.5)
    vp.dwell(0.2)
    faults_then = [f.name for f in vp._faults]
    vp.inject_fault("saturation", duration_s=0.05)
    vp.inject_fault("chip_reset", duration_s=0.05)
    for _ in range(8):
        vp.dwell(0.1)
    return faults_then, vp.take_samples()


def test_finished_faults_are_forgotten_and_forgetting_changes_no_sample(monkeypatch):
    vp = VirtualPrinter.from_scenario("clean", seed=2)
    faults_then, pruned = _fault_session(vp)
    assert faults_then == ["stuck", "bowden_tug"]       # the weight and the 3 frames are over, the tug to come
    # the tug and the saturation are over too; the offset jump lasts; the stuck one still waits
    assert [f.name for f in vp._faults] == ["stuck", "chip_reset"]
    monkeypatch.setattr("tapcell.sim.faults.still_acting", lambda faults, *_: faults)
    _, kept_all = _fault_session(VirtualPrinter.from_scenario("clean", seed=2))
    np.testing.assert_array_equal(pruned.t_s, kept_all.t_s)
    np.testing.assert_array_equal(pruned.counts, kept_all.counts)


def test_finished_hand_taps_are_forgotten_and_a_delayed_one_still_presses():
    vp = VirtualPrinter.from_scenario("clean", seed=2)
    vp.tap_nozzle(300.0, duration_s=0.1)
    vp.tap_nozzle(300.0, duration_s=0.1, delay_s=1.0)
    vp.dwell(0.5)
    assert len(vp._hand_taps) == 1                      # the first is over, the delayed one to come
    vp.take_samples()
    vp.dwell(0.65)
    counts = vp.take_samples().counts
    assert np.ptp(counts) > 100.0 * abs(vp.truth.counts_per_gram)  # the delayed tap still pressed (300 g)
    assert vp._hand_taps == []


def test_hand_tap_triggers_the_firmware_with_no_motion():
    vp = VirtualPrinter.from_scenario("clean", seed=1)
    trigger = armed_trigger(vp, trigger_force_g=75.0)
    t_tap = vp.now_s
    vp.tap_nozzle(400.0, 0.2)
    result = vp.wait_for_trigger(trigger, timeout_s=2.0)
    assert result.triggered and result.error == TriggerError.NONE
    # a half-sine of 400 g reaches 75 g after asin(75/400)/pi of its duration
    reaches_75_g = t_tap + 0.2 * np.arcsin(75.0 / 400.0) / np.pi
    assert reaches_75_g < result.trigger_time_s < reaches_75_g + 2.0 / 320.0 + 1e-3
    assert result.moves == [] and result.halt_z_mm == vp.position[2]
    quiet = VirtualPrinter.from_scenario("clean", seed=1)
    missed = quiet.wait_for_trigger(armed_trigger(quiet), timeout_s=0.5)
    assert not missed.triggered and missed.error == TriggerError.NONE and missed.halt_time_s == quiet.now_s


def test_fault_and_parameter_errors_name_what_is_allowed():
    vp = VirtualPrinter.from_scenario("clean")
    with pytest.raises(FaultError, match="unknown fault 'melted'; allowed: disconnected, stuck, chip_reset"):
        vp.inject_fault("melted")
    with pytest.raises(FaultError, match="fault 'weight' has no parameter 'kg'; allowed: grams, duration_s"):
        vp.inject_fault("weight", kg=1)
    with pytest.raises(FaultError, match="unknown fault condition 'later'; allowed: probing_move, contact, trigger, halt, lift, travel"):
        vp.inject_fault("stuck", when="later")
    with pytest.raises(SimParamError, match="'sample_rate_sps' = 640 is not a hx717 rate; allowed: 10, 20, 80, 320"):
        VirtualPrinter.from_scenario("clean", sample_rate_sps=640)
    with pytest.raises(SimParamError, match="unknown virtual printer parameter 'speed'"):
        VirtualPrinter.from_scenario("clean", speed=3)
    with pytest.raises(SimParamError, match="unknown scenario 'dirty'; allowed: clean, fast-adc"):
        VirtualPrinter.from_scenario("dirty")
