"""Issue 6 item 5: the acceptance targets on the virtual printer's scenarios.

Where the tap classifier is not what a test is about (glitches, drift, slow ADC, the
watchdog), the probe runs with `tap_classifier: empty`: shape and break-contact validation
still run, the quality score does not. The clean-accuracy test runs the default classifier.
Peak force is the true force on the cell (simulator truth), so corrupted frames do not count.
"""

from __future__ import annotations

import re

import pytest

from probe_vprinter import make_printer, true_contact_z, true_peak_force_g
from tapcell.host.gcode import GCodeError

NO_SCORE = "tap_classifier: empty"


def accuracy(printer, speed_mm_s: float, samples: int = 20, extra: str = "") -> tuple[float, float]:
    """(σ, average − truth) in µm of PROBE_ACCURACY from 0.4 mm clearance. The homing tap runs at
    most at 5 mm/s: until a tap has measured the bed, the force guard allows no more."""
    printer.gcode.run_script(f"PROBE HOME=Z PROBE_SPEED={min(speed_mm_s, 5.0)} {extra}\nG1 Z0.4")
    printer.gcode.run_script(f"PROBE_ACCURACY SAMPLES={samples} PROBE_SPEED={speed_mm_s} "
                             f"SAMPLE_RETRACT_DIST=0.4 {extra}")
    stats = printer.lookup_object("probe").last_accuracy
    return stats.standard_deviation_mm * 1000.0, (stats.average_mm - true_contact_z(printer)) * 1000.0


@pytest.mark.parametrize("speed_mm_s", [2.0, 5.0, 10.0])
def test_clean_accuracy_does_not_depend_on_speed(tmp_path, speed_mm_s):
    printer, _ = make_printer(tmp_path)
    sigma_um, bias_um = accuracy(printer, speed_mm_s)
    # Measured (the toe model): sigma 0.39 / 0.44 / 0.44 um, bias +0.45 / +0.39 / -0.06 um at 2 / 5 / 10
    # mm/s; per tap over 20 seeds +0.55 ± 0.42 / +0.12 ± 0.31 / +0.17 ± 0.31 um (test_sim_taps). CONTACT_MODEL=sharp: sigma
    # 0.12 / 0.12 / 0.20 um, bias -1.32 / -1.38 / -1.78 um (the sim's 2 um onset read half low).
    assert sigma_um <= 0.8
    assert abs(bias_um) <= 0.8
    assert true_peak_force_g(printer) < 2000.0


def test_clean_taps_are_valid_and_fast(tmp_path):
    printer, _ = make_printer(tmp_path, probe_options=NO_SCORE)
    printer.gcode.run_script("PROBE HOME=Z\nG1 Z0.4")
    device = printer.lookup_object("load_cell_probe")
    device.last_taps.clear()
    t0_s = printer.backend.now_s
    printer.gcode.run_script("PROBE_ACCURACY SAMPLES=10 SAMPLE_RETRACT_DIST=0.4")
    assert all(t.valid for t in device.last_taps) and len(device.last_taps) == 10
    # The goal: <= 0.8 s per tap at 5 mm/s from 0.4 mm. Physics: approach 0.1 s, dwell
    # 10 samples (31 ms), pullback 0.15 mm at 0.32 mm/s (0.47 s), lift 0.07 s; nothing else.
    assert (printer.backend.now_s - t0_s) / 10 == pytest.approx(0.680, abs=0.005)
    for recorded in device.last_taps:
        events = recorded.tap.events
        assert events["pullback_start_time"] - events["home_end_time"] == pytest.approx(10 / 320, abs=1e-6)
        assert events["pullback_end_time"] - events["pullback_start_time"] == pytest.approx(0.15 / 0.32, abs=0.002)
        # Break contact inside the middle two thirds of the pullback (the guide's rule).
        share = ((recorded.analysis.break_contact_time_s - events["pullback_start_time"])
                 / (events["pullback_end_time"] - events["pullback_start_time"]))
        assert 1 / 6 < share < 5 / 6
    assert true_peak_force_g(printer) < 2000.0


def test_slow_adc_probes_at_2mm_s(tmp_path):
    printer, _ = make_printer(tmp_path, scenario="slow-adc", probe_options=NO_SCORE)
    sigma_um, bias_um = accuracy(printer, 2.0, samples=5)
    assert sigma_um <= 0.3 and abs(bias_um) <= 2.0  # measured 0.14 and -1.66 um
    assert true_peak_force_g(printer) < 2000.0


def test_slow_adc_explains_what_goes_wrong_too_fast(tmp_path):
    # force_safety_limit 4000 in the config: a sensor stuck at contact would press 2.9 kg at 8 mm/s on this
    # sensor (an override may not raise the limit past the config).
    printer, _ = make_printer(tmp_path, scenario="slow-adc", probe_options=NO_SCORE + "\nforce_safety_limit: 4000")
    # A good tap at 2 mm/s first: from it the probe knows the bed (3.26 g/um).
    printer.gcode.run_script("PROBE HOME=Z PROBE_SPEED=2\nG1 Z0.4")
    # At 8 mm/s the HX711 sees the nozzle every 100 um, while the force reaches the 75 g trigger
    # 23 um after contact: the compression falls between two samples (the tap cannot be
    # analysed) and the halt comes ~170 um past contact, beyond 3/4 of the 0.15 mm pullback.
    with pytest.raises(GCodeError) as error:
        printer.gcode.run_script("PROBE PROBE_SPEED=8 BAD_PROBE_STRATEGY=fail")
    message = str(error.value)
    # The lines through samples either side of a compression no sample saw are out of order or
    # misshapen: the analysis names the cause, the approach too fast for the sensor (issue 21).
    assert re.match(r"^Probe failed because it was deemed bad quality: TAP_DATA_INSUFFICIENT - the compression holds "
                    r"0\.\d\d samples: .* at 8\.00 mm/s\), too few to place the touch and the halt: probe slower", message)
    why = re.search(r"\(probing too fast for this sensor: .*\)$", message)[0]
    assert re.fullmatch(
        r"\(probing too fast for this sensor: at 8 mm/s and 80 samples/s the nozzle moves 100\.0 um per sample, "
        r"but on this bed \(about 3\.[23] g/um\) the force reaches the 75g trigger 2[34] um after first contact: it "
        r"jumped from -?\d+g to (\d+)g within one sample, so no sample shows the compression and the tap cannot be "
        r"analysed; the nozzle stopped about \d+ um past first contact, pressing (\d+)g(, more than 3/4 of the "
        r"0\.15 mm pullback, so it leaves the bed late in the pullback or not at all)?; probe at 1\.[89] mm/s or "
        r"slower \(or use a faster sensor\)\)", why)
    peak_g = float(re.search(r"pressing (\d+)g", why)[1])
    assert peak_g == pytest.approx(true_peak_force_g(printer), rel=0.1)
    # Below force_safety_limit on this bed; the default limit (2000 g, an override may tighten to it)
    # makes the probe refuse before moving:
    # the guard's worst case (the measured 3.2 g/um with a 25 % margin) is a sensor that sticks as
    # the nozzle meets the bed, stopped only after 7 samples (87.5 ms), far above this tap's peak.
    assert true_peak_force_g(printer) < 2000.0
    printer.gcode.run_script("G1 Z0.4")
    z_before = printer.backend.position[2]
    with pytest.raises(GCodeError) as refusal:
        printer.gcode.run_script("PROBE PROBE_SPEED=8 FORCE_SAFETY_LIMIT=2000")
    match = re.fullmatch(r"Load Cell Probe Error: probing at 8 mm/s refused: it could press the bed with up to "
                         r"(\d+)g, more than force_safety_limit \(2000g\): at 80 samples/s the nozzle moves 100\.0 um "
                         r"per sample into a bed of up to 4\.0 g/um \(measured by the taps, with a margin\), and 1 ms "
                         r"more before the steppers stop \(should the sensor stick as the nozzle meets the bed, the "
                         r"firmware stops the move after 7 identical samples, 87\.5 ms: stuck_sensor_samples\); probe "
                         r"at 5 mm/s or slower", str(refusal.value))
    # 7 samples + read delay + stop latency of travel at 8 mm/s into 4.0 g/um: 2.9 kg
    assert match and 2800 < float(match[1]) < 3000
    assert printer.backend.position[2] == z_before  # refused before moving


def test_slow_adc_first_tap_too_fast_estimates_the_bed_from_the_jump(tmp_path):
    # No valid tap yet: the stiffness comes from the one-sample force jump (a low estimate). At 80 sps
    # G28 Z's backoffs are too fast to read the bed, so the guard assumes max_bed_stiffness: by default
    # (100 g/um) it lowers 8 mm/s to 1 mm/s even with this limit; a declared soft bed and a high limit
    # let 8 mm/s through.
    printer, responses = make_printer(tmp_path, scenario="slow-adc",
                                      probe_options=NO_SCORE + "\nforce_safety_limit: 10000")
    printer.gcode.run_script("PROBE PROBE_SPEED=8 BAD_PROBE_STRATEGY=fail")
    assert "// Probing at 1 mm/s, not 8 mm/s, until a tap measures the bed: up to 100 g/um is assumed before that " \
           "(max_bed_stiffness)" in responses
    (tmp_path / "declared").mkdir()
    printer, _ = make_printer(tmp_path / "declared", scenario="slow-adc",
                              probe_options=NO_SCORE + "\nforce_safety_limit: 10000\nmax_bed_stiffness: 5")
    with pytest.raises(GCodeError) as error:
        printer.gcode.run_script("PROBE PROBE_SPEED=8 BAD_PROBE_STRATEGY=fail")
    why = re.search(r"\(probing too fast for this sensor: .*\)$", str(error.value))[0]
    stiffness = float(re.search(r"about (\d+\.\d) g/um", why)[1])
    # A low estimate (true 3.26 g/um): the triggering sample was only partly in contact, by how
    # much depends on where in the sample the nozzle met the bed. Measured 2.4-2.5 on seeds 1-10.
    assert 2.2 <= stiffness <= 2.8
    assert "at 8 mm/s and 80 samples/s the nozzle moves 100.0 um per sample" in why
    assert true_peak_force_g(printer) < 2000.0


def test_glitchy_frames_never_abort(tmp_path):
    # A corrupted frame in the air is moved on from; one inside a tap's samples makes that tap bad
    # (TAP_CHRONOLOGY on seed 1 since G28 Z's first tap is slow, COASTING_MOVE_ACCELERATION on seed 3
    # before), so the bad tap is retried. Seeds 2 and 6 still abort on force_safety_limit (seed 6: a
    # third past-limit frame within 0.5 s in G28 Z; seed 2 in PROBE_ACCURACY, not traced yet).
    printer, _ = make_printer(tmp_path, scenario="glitchy", probe_options=NO_SCORE)
    sigma_um, bias_um = accuracy(printer, 5.0, extra="BAD_PROBE_STRATEGY=retry")  # ~10 s: ~5 corrupted frames
    assert sigma_um <= 0.8 and abs(bias_um) <= 0.8  # measured 0.35 and -0.06 um (0.44, +0.37 before)
    assert true_peak_force_g(printer) < 2000.0


def test_bowden_drift_needs_the_drift_filter(tmp_path):
    printer, _ = make_printer(tmp_path, scenario="bowden-drift", probe_options=NO_SCORE)
    printer.gcode.run_script("PROBE HOME=Z DRIFT_FILTER_CUTOFF_FREQUENCY=0.8")
    # From 10 mm the tube pulls 8 g/mm harder as Z falls: 80 g before the nozzle gets there.
    printer.gcode.run_script("G1 Z10\nPROBE BAD_PROBE_STRATEGY=ignore")
    early_mm = printer.lookup_object("probe").last_z_result - true_contact_z(printer)
    # Triggered on the drift alone, ~0.4 mm above the bed (ten times any tap's over-travel).
    assert early_mm > 0.3
    printer.gcode.run_script("G1 Z10")
    with pytest.raises(GCodeError, match=r"^Load Cell Probe Error: force exceeded drift_safety_limit before "
                                         r"triggering!$"):
        printer.gcode.run_script("PROBE DRIFT_SAFETY_LIMIT=40")
    printer.gcode.run_script("G1 Z10\nPROBE DRIFT_FILTER_CUTOFF_FREQUENCY=0.8")
    assert abs(printer.lookup_object("probe").last_z_result - true_contact_z(printer)) < 0.002
    assert true_peak_force_g(printer) < 2000.0


def test_watchdog_stops_the_move_when_the_sensor_goes_silent(tmp_path):
    printer, _ = make_printer(tmp_path, probe_options=NO_SCORE)
    printer.gcode.run_script("PROBE HOME=Z\nG1 Z1\nSIM_FAULT NAME=disconnected WHEN=probing_move")
    vp = printer.backend
    with pytest.raises(GCodeError, match=r"^Load Cell Probe Error: timed out waiting for sensor data$"):
        printer.gcode.run_script("PROBE")
    last_sample_s = printer.lookup_object("load_cell_probe").history.newest_s
    # The halt is the zero-length marker that ends the probing move (the lift after the error follows).
    halt_s = [m for m in vp.recorded_moves(0.0, vp.now_s) if m["move_t"] == 0.0][-1]["print_time"]
    # watchdog_periods (2) silent periods past the next expected sample, up to one more period
    # until the timer's check runs, then the stop latency: at most 4 periods at 320 sps.
    assert halt_s - last_sample_s <= 4.0 / 320 + 0.0005
    assert vp.position[2] > true_contact_z(printer) - printer.lookup_object("toolhead").frame_offset_mm["z"] + 0.5


def test_a_disconnected_sensor_refuses_to_probe(tmp_path):
    printer, _ = make_printer(tmp_path, scenario="disconnected", calibrate=False, home=False,
                              probe_options="counts_per_gram: 110\nreference_tare_counts: -38000")
    with pytest.raises(GCodeError, match=r"^Load Cell Probe Error: timed out waiting for sensor data$"):
        printer.gcode.run_script("G28")


def test_oozy_fouled_tap_is_rejected(tmp_path):
    # The scenario's nozzle starts at 210 C under a thick PETG film: the first tap touches the
    # film, not the bed, and the shape/chronology checks alone reject it (no quality score).
    # G28 Z's two taps (the second confirms the first) each tear the strand and leave 40 % of the
    # film behind: 100 um at the start keeps ~36 um for the PROBE (with 60 or 80 um the thinner film
    # left taps validly, within 5 um of the bed).
    printer, _ = make_printer(tmp_path, scenario="oozy", probe_options=NO_SCORE, virtual_printer="ooze_film_um: 100")
    assert printer.backend.truth.film_um > 10.0
    with pytest.raises(GCodeError, match=r"^Probe failed because it was deemed bad quality: TAP_"):
        printer.gcode.run_script("G1 Z0.4\nPROBE BAD_PROBE_STRATEGY=fail")
    assert printer.lookup_object("load_cell_probe").last_taps[-1].valid is False
    assert true_peak_force_g(printer) < 2000.0


def cool_oozy_nozzle(printer) -> None:
    """The guide's advice: probe below the ooze point. The film (~40 um) stays until tapped off."""
    printer.gcode.run_script("M109 S150\nG1 Z0.4")
    assert printer.backend.truth.film_um > 10.0


# The default classifier is the acceptance target; "empty" shows the same logic without the score.
CLASSIFIERS = pytest.mark.parametrize("classifier", ["tap_quality", "empty"])


@CLASSIFIERS
def test_oozy_circle_moves_to_clean_spots(tmp_path, classifier):
    printer, responses = make_printer(tmp_path, scenario="oozy", probe_options=f"tap_classifier: {classifier}")
    cool_oozy_nozzle(printer)
    responses.clear()
    printer.gcode.run_script("PROBE BAD_PROBE_STRATEGY=circle")
    result = printer.lookup_object("probe").last_result
    assert result.valid and result.attempts >= 2
    assert any(line.startswith("// Bad probe detected: TAP_") for line in responses)
    assert (result.tapped_x_mm, result.tapped_y_mm) != (110.0, 110.0)
    # The accepted tap still had a few µm of film on the nozzle (1.1 µm left after it): the toe model
    # reads the film's soft first touch as part of the contact, +3.8 µm (CONTACT_MODEL=sharp: -0.24 µm;
    # +3.0 µm before the toe model's walk weighting).
    assert abs(result.z_mm - true_contact_z(printer)) < 0.005
    assert true_peak_force_g(printer) < 2000.0


@CLASSIFIERS
def test_nozzle_cleanup_clears_a_fouled_nozzle(tmp_path, classifier):
    printer, responses = make_printer(tmp_path, scenario="oozy", probe_options=f"tap_classifier: {classifier}")
    cool_oozy_nozzle(printer)
    printer.gcode.run_script("NOZZLE_CLEANUP")
    assert re.match(r"// NOZZLE_CLEANUP succeeded: 3 good taps in a row after [4-9] taps$", responses[-1])
    assert any(line.startswith("// NOZZLE_CLEANUP: bad tap at ") for line in responses)
    assert printer.backend.truth.film_um < 1.0
    assert true_peak_force_g(printer) < 2000.0
