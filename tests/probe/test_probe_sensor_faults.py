"""Sensor faults during probing on the virtual printer, end to end through the firmware endstop:
a stuck sensor stops the move within its run of identical samples, a corrupted frame past
force_safety_limit stops it at once and the move is tried again, and the stuck_sensor_samples
option (default from the sensor, range, message)."""

from __future__ import annotations

import numpy as np
import pytest

from probe_vprinter import make_printer, true_contact_z, true_peak_force_g
from tapcell.host.config import ConfigError
from tapcell.host.gcode import GCodeError
from tapcell.extras.load_cell_probe.options import CORRUPT_FRAME_RETRIES, lone_frame

STUCK = (r"^Load Cell Probe Error: load cell reads a constant value \({n} identical samples in a row while "
         r"probing\): sensor stuck! Check the sensor's wiring and power \(see stuck_sensor_samples\)$")


@pytest.mark.parametrize("scenario, speed_mm_s, peak_below_g", [
    ("clean", 5.0, 320.0),     # HX717 A-128 at 320 sps: 7 samples; measured 268-274 g (seeds 1-4)
    # HX711 A-128 at 80 sps: 7 samples; measured 385-459 g (where in a sample the contact falls);
    # at most 7 samples + read delay + stop latency of travel at 2 mm/s into 3.26 g/um: 578 g
    ("slow-adc", 2.0, 600.0),
])
def test_stuck_at_contact_stops_within_the_run(tmp_path, scenario, speed_mm_s, peak_below_g):
    printer, _ = make_printer(tmp_path, scenario=scenario)
    printer.gcode.run_script("G1 Z2")
    start_s = printer.backend.now_s
    with pytest.raises(GCodeError, match=STUCK.format(n=7)):
        printer.gcode.run_script(f"SIM_FAULT NAME=stuck WHEN=contact\nPROBE PROBE_SPEED={speed_mm_s}")
    # the force the cell never reported: a small part of force_safety_limit (2000 g), not kilograms
    assert 100.0 < true_peak_force_g(printer, start_s) < peak_below_g


def test_stuck_after_a_trigger_stops_the_retry_in_the_air(tmp_path):
    # The tap that triggered is bad (its samples are flat): the retry's move stops on the run.
    printer, responses = make_printer(tmp_path, probe_options="stuck_sensor_samples: 12")
    printer.gcode.run_script("G1 Z2")
    start_s = printer.backend.now_s
    with pytest.raises(GCodeError, match=STUCK.format(n=12)):
        printer.gcode.run_script("SIM_FAULT NAME=stuck WHEN=trigger\nPROBE")
    assert any("Retrying (1/6)..." in line for line in responses)
    assert true_peak_force_g(printer, start_s) < 200.0      # the first tap's own (measured 148 g)
    nozzle_z = printer.backend.position[2] + printer.lookup_object("toolhead").frame_offset_mm["z"]
    assert nozzle_z - true_contact_z(printer) > 1.5          # stopped 12 samples into the retry, in the air


def test_a_corrupted_frame_past_the_limit_stops_the_move_and_it_is_probed_again(tmp_path):
    # 500 g: every corrupted frame of the virtual sensor (one of bits 16-22 flipped) is past it
    # (2 mm/s: with a 500 g limit G28 Z's first tap goes at 0.2 mm/s, its backoffs measure the bed.)
    printer, responses = make_printer(tmp_path, probe_options="force_safety_limit: 500",
                                      replace={"\nspeed: 5\n": "\nspeed: 2\n"})
    printer.gcode.run_script("G1 Z2\nSIM_FAULT NAME=corrupt_frame WHEN=probing_move\nPROBE")
    notes = [r for r in responses if "(a corrupted frame); the move stopped at once, probing again" in r]
    assert len(notes) == 1
    assert abs(printer.lookup_object("probe").last_z_result - true_contact_z(printer)) < 0.01


def test_corrupted_frames_far_apart_never_end_a_long_move_but_a_burst_does(tmp_path):
    # A long move (G28 Z's first tap on an unmeasured bed runs at 0.8 mm/s; here 10 mm at 3 mm/s): six
    # corrupted frames 0.4 s apart are each moved on from; a fifth within 0.5 s ends the move.
    assert CORRUPT_FRAME_RETRIES == 4
    printer, responses = make_printer(tmp_path, probe_options="force_safety_limit: 500")
    printer.gcode.run_script("G1 Z10\nSIM_FAULT NAME=corrupt_frame WHEN=probing_move COUNT=6 SPACING_S=0.4\n"
                             "PROBE PROBE_SPEED=3")
    notes = [r for r in responses if "(a corrupted frame); the move stopped at once, probing again" in r]
    assert len(notes) == 6
    assert abs(printer.lookup_object("probe").last_z_result - true_contact_z(printer)) < 0.01
    responses.clear()
    with pytest.raises(GCodeError, match=r"force exceeded force_safety_limit \(500g\) while probing!"):
        printer.gcode.run_script("G1 Z10\nSIM_FAULT NAME=corrupt_frame WHEN=probing_move COUNT=5 SPACING_S=0.1\n"
                                 "PROBE PROBE_SPEED=3")
    assert sum("(a corrupted frame)" in r for r in responses) == 4


def test_stuck_sensor_samples_option(tmp_path):
    with pytest.raises(ConfigError, match=r"\[load_cell_probe\] stuck_sensor_samples = 1: 1 is not allowed; "
                                          r"allowed: 0 \(disabled\) or 2 \.\. 65535"):
        make_printer(tmp_path, probe_options="stuck_sensor_samples: 1", calibrate=False, home=False)
    with pytest.raises(ConfigError, match=r"stuck_sensor_samples = 70000: must be at most 65535"):
        make_printer(tmp_path, probe_options="stuck_sensor_samples: 70000", calibrate=False, home=False)
    printer, _ = make_printer(tmp_path)
    assert printer.lookup_object("load_cell_probe").default_stuck_samples == 7     # hx717 A-128 at 320 sps
    with pytest.raises(GCodeError, match=r"^Error on 'PROBE STUCK_SENSOR_SAMPLES=1': STUCK_SENSOR_SAMPLES: 1 is "
                                         r"not allowed; allowed: 0 \(disabled\) or 2 \.\. 65535$"):
        printer.gcode.run_script("PROBE STUCK_SENSOR_SAMPLES=1")
    with pytest.raises(GCodeError, match=r"^Error on 'PROBE STUCK_SENSOR_SAMPLES=-2': STUCK_SENSOR_SAMPLES must "
                                         r"have minimum of 0 \(allowed: 0 to 65535\)$"):
        printer.gcode.run_script("PROBE STUCK_SENSOR_SAMPLES=-2")
    # An override may shorten the run (tighten), never lengthen it past the sensor's 7 (loosen).
    with pytest.raises(GCodeError, match=r"STUCK_SENSOR_SAMPLES=30 would loosen the stuck-sensor check"):
        printer.gcode.run_script("PROBE STUCK_SENSOR_SAMPLES=30 PROBE_SPEED=1")
    (tmp_path / "long").mkdir()
    # (probing at 1 mm/s, homing included: 30 samples of travel at 5 mm/s are refused by the force guard)
    printer, _ = make_printer(tmp_path / "long", probe_options="stuck_sensor_samples: 30",
                              replace={"\nspeed: 5\n": "\nspeed: 1\n"})
    printer.gcode.run_script("G1 Z2")
    with pytest.raises(GCodeError, match=STUCK.format(n=30)):
        # 30 samples of travel: slow enough that the force guard allows it on an unmeasured bed
        printer.gcode.run_script("SIM_FAULT NAME=stuck WHEN=contact\nPROBE PROBE_SPEED=1")


PERIOD_S = 1.0 / 320.0


def lone(force_g, armed_at=1, limit_g=2000.0, quiet_g=75.0, stop_at=None):
    """lone_frame on samples 1/320 s apart, armed at sample `armed_at`, stopped past `limit_g`."""
    force_g = np.asarray(force_g, dtype=float)
    t_s = 10.0 + PERIOD_S * np.arange(force_g.size)
    stop_s = None if stop_at is None else t_s[stop_at]
    return lone_frame(t_s, force_g, np.abs(force_g) > limit_g, t_s[armed_at], quiet_g, stop_s)


def test_only_a_lone_sample_between_quiet_neighbours_counts_as_a_corrupted_frame():
    assert lone([0.0, 3.0, -2400.0, 5.0]) == 2
    assert lone([0.0, 50.0, 2100.0, 2300.0]) is None     # a real press
    assert lone([0.0, 2100.0, 80.0]) is None             # in contact after
    assert lone([0.0, 3.0, 2100.0]) is None              # no sample after
    assert lone([2100.0, 3.0], armed_at=0) is None       # none before
    assert lone([0.0, 3.0, 5.0]) is None


def test_the_stop_judged_is_the_first_the_armed_firmware_saw():
    # A frame read before the arm (the last attempt's, moved on from; or one the tare dropped) is
    # not this stop: a real press after it stays a real press ...
    assert lone([0.0, -4766.0, 1.0, 2.0, 60.0, 2100.0, 2300.0], armed_at=3) is None
    assert lone([0.0, -4766.0, 1.0, 2100.0, 2300.0], armed_at=2) is None
    # ... and a second lone frame one quiet sample after it is judged on its own (glitchy seed 9).
    assert lone([0.0, -16062.0, 1.0, -16062.0, 0.0], armed_at=2) == 3
    # The first one the firmware saw stopped it: a lone frame after a real press is not looked at.
    assert lone([0.0, 2100.0, 2300.0, 2200.0, 1.0, -9000.0, 1.0], armed_at=1) is None


def test_a_trigger_on_a_lone_frame_is_judged_through_the_triggering_sample():
    # Trigger force 75 g: samples past it, quiet under half of it (37.5 g).
    args = {"limit_g": 74.99, "quiet_g": 37.5}
    assert lone([0.0, 1.0, 595.0, 2.0, 0.0], stop_at=2, **args) == 2           # no filter: the frame itself
    assert lone([0.0, 1.0, 595.0, 2.0, 0.0, 1.0], stop_at=3, **args) == 2      # a filter triggered a sample later
    assert lone([0.0, 1.0, 595.0, 2.0, 0.0], stop_at=4, **args) is None        # no sample after the trigger yet
    assert lone([0.0, 20.0, 80.0, 84.0], stop_at=2, **args) is None            # a contact holds after the halt
    assert lone([0.0, 20.0, 80.0, 40.0], stop_at=2, **args) is None            # even with a noisy sample after
    assert lone([0.0, 45.0, 595.0, 2.0], stop_at=2, **args) is None            # force already rising before
