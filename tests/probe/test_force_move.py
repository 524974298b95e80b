"""FORCE_MOVE and STEPPER_BUZZ ([force_move]): Klipper's single-stepper moves, with the load
cell's nozzle watch guarding the ones that can reach the bed (a FORCE_MOVE down is a macro move
the guard must not assume away)."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

from probe_vprinter import make_printer, run_measured

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tests/machines.py
from machines import gcode_error  # noqa: E402

ENABLED = "\n[force_move]\nenable_force_move: True\n"
FORCE_SAFETY_LIMIT_G = 2000.0
COLLISION = "Load Cell Probe Error: nozzle collision at "


def printer_with(tmp_path, name: str, sections: str = ENABLED, **options):
    folder = tmp_path / name
    folder.mkdir()
    printer, responses = make_printer(folder, sections=sections, **options)
    return printer, responses


def test_force_move_needs_enable_force_move_but_stepper_buzz_does_not(tmp_path):
    printer, responses = printer_with(tmp_path, "plain", sections="")
    assert gcode_error(printer, "FORCE_MOVE STEPPER=stepper_z DISTANCE=1 VELOCITY=5") == 'Unknown command:"FORCE_MOVE"'
    toolhead = printer.lookup_object("toolhead")
    before = toolhead.get_position()
    t0_s = printer.backend.now_s
    printer.gcode.run_script("STEPPER_BUZZ STEPPER=stepper_x")
    assert "// Stepper buzz stepper_x" in responses
    # Ten times 1 mm out and back at 4 mm/s with 0.05 s and 0.45 s pauses: at least 10 s.
    assert printer.backend.now_s - t0_s >= 10.0
    peak_x = max(printer.backend.position_at(t0_s + 0.01 * i)[0] for i in range(int((printer.backend.now_s - t0_s) * 100)))
    assert peak_x == pytest.approx(printer.backend.position[0] + 1.0, abs=1e-3)
    assert toolhead.get_position() == pytest.approx(before, abs=1e-9)
    assert toolhead.homed_axes == {"x", "y", "z"}  # back where it was: still homed


def test_force_move_keeps_the_commanded_position_and_forgets_homing(tmp_path):
    printer, responses = printer_with(tmp_path, "lift")
    toolhead = printer.lookup_object("toolhead")
    before = toolhead.get_position()
    machine_z = float(printer.backend.position[2])
    printer.gcode.run_script("FORCE_MOVE STEPPER=stepper_z DISTANCE=5 VELOCITY=10")
    assert float(printer.backend.position[2]) == pytest.approx(machine_z + 5.0, abs=1e-6)
    assert toolhead.get_position() == pytest.approx(before, abs=1e-9)  # Klipper's toolhead is not told
    assert toolhead.homed_axes == {"x", "y"}
    assert responses[-1].startswith("// FORCE_MOVE stepper_z: Z no longer homed")
    assert gcode_error(printer, "G1 Z1 F600") == "Must home axis first: Z (run G28)"
    # With Z not homed, a FORCE_MOVE up is the lift before homing X/Y ([safe_z_home]'s z_hop).
    printer.gcode.run_script("FORCE_MOVE STEPPER=stepper_z DISTANCE=3 VELOCITY=10")
    assert toolhead.z_lift_while_unhomed_mm == pytest.approx(3.0)


def test_force_move_names_the_steppers_it_can_drive(tmp_path):
    printer, _ = printer_with(tmp_path, "names", calibrate=False, home=False)
    assert gcode_error(printer, "FORCE_MOVE STEPPER=stepper_q DISTANCE=1 VELOCITY=5") == (
        "Unknown stepper stepper_q: STEPPER= one of stepper_x, stepper_y, stepper_z")
    assert "VELOCITY" in gcode_error(printer, "FORCE_MOVE STEPPER=stepper_x DISTANCE=1 VELOCITY=0")
    assert "ACCEL" in gcode_error(printer, "FORCE_MOVE STEPPER=stepper_x DISTANCE=1 VELOCITY=5 ACCEL=-1")


def test_corexy_steppers_move_both_axes_by_half(tmp_path):
    printer, _ = printer_with(tmp_path, "corexy", calibrate=False, home=False,
                              replace={"kinematics: cartesian": "kinematics: corexy"})
    x0, y0, _ = (float(v) for v in printer.backend.position)
    printer.gcode.run_script("FORCE_MOVE STEPPER=stepper_y DISTANCE=10 VELOCITY=20")
    x1, y1, _ = (float(v) for v in printer.backend.position)
    assert (x1 - x0, y1 - y0) == pytest.approx((5.0, -5.0), abs=1e-6)


def test_a_stepper_moved_into_the_bed_is_stopped_by_the_watch(tmp_path):
    """Without the watch FORCE_MOVE 2.5 mm down from 1 mm presses kilograms into the bed and stays
    there; with it the move stops below force_safety_limit and the nozzle is lifted."""
    script = "G1 Z1 F600\nFORCE_MOVE STEPPER=stepper_z DISTANCE=-2.5 VELOCITY=5"
    off, _ = printer_with(tmp_path, "off", probe_options="nozzle_watch_height: 0")
    error, peak_g, clearance_mm = run_measured(off, script)
    assert error is None and peak_g > FORCE_SAFETY_LIMIT_G and clearance_mm < -1.0
    on, _ = printer_with(tmp_path, "on")
    error, peak_g, clearance_mm = run_measured(on, script)
    assert error is not None and error.startswith(COLLISION), error
    assert "during 'FORCE_MOVE STEPPER=stepper_z DISTANCE=-2.5 VELOCITY=5'" in error
    assert peak_g < FORCE_SAFETY_LIMIT_G and clearance_mm > 0.0
    assert "z" not in on.lookup_object("toolhead").homed_axes  # the stepper moved: home again


def test_a_buzz_near_the_bed_runs_watched(tmp_path):
    """STEPPER_BUZZ on Z at 0.5 mm: every move back down runs with the watch armed (the way up
    only rises); nothing touches, so it ends where it began, still homed."""
    printer, _ = printer_with(tmp_path, "buzz", sections="")
    printer.gcode.run_script("G1 Z0.5 F600")
    watch = printer.lookup_object("toolhead").nozzle_watch
    watched_before = watch.watched_moves
    error, peak_g, clearance_mm = run_measured(printer, "STEPPER_BUZZ STEPPER=stepper_z")
    assert error is None and watch.watched_moves - watched_before == 10
    assert clearance_mm == pytest.approx(0.5, abs=0.05) and peak_g < 50.0
    assert "z" in printer.lookup_object("toolhead").homed_axes
