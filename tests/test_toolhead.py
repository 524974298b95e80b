"""[printer] + [stepper_*] on the virtual printer: homing, moves, coordinates, temperature, status."""

from __future__ import annotations

import pytest

from tapcell.host.config import ConfigError
from tapcell.host.gcode import GCodeError
from tapcell.host.printer import Printer

from machines import machine_config

STEPPERS = machine_config()


def start(tmp_path, text: str = STEPPERS):
    path = tmp_path / "printer.cfg"
    path.write_text(text)
    responses: list[str] = []
    return Printer.from_config(str(path), responses=responses), responses


def error_of(printer, line: str) -> str:
    with pytest.raises(GCodeError) as info:
        printer.gcode.run_line(line)
    return str(info.value)


def test_home_xy_and_move_with_feed_rate(tmp_path):
    printer, _ = start(tmp_path)
    toolhead = printer.lookup_object("toolhead")
    assert error_of(printer, "G1 X10") == "Must home axis first: X (run G28)"
    printer.gcode.run_line("G28 X Y")
    assert printer.get_status()["toolhead"]["homed_axes"] == "xy"
    t0 = printer.backend.now_s
    printer.gcode.run_line("G1 X100 Y50 F6000")  # 100 mm/s
    assert toolhead.get_position()[:2] == pytest.approx((100.0, 50.0))
    elapsed = printer.backend.now_s - t0
    # 111.8 mm at 100 mm/s plus accelerating to speed at 3000 mm/s^2 (+1/30 s)
    assert elapsed == pytest.approx(111.803 / 100 + 100 / 3000, rel=0.02)
    assert printer.get_status()["gcode_move"]["speed"] == pytest.approx(6000.0)  # mm/min, as Klipper


def test_limits_relative_moves_g92_and_m114(tmp_path):
    printer, responses = start(tmp_path)
    printer.gcode.run_script("G28 X Y\nG1 X20 Y30 F3000")
    assert error_of(printer, "G1 X240") == "Move out of range: 240.000 30.000 10.000 (X must be within 0 to 235)"
    printer.gcode.run_script("G91\nG1 X5 Y-10\nG90")
    assert printer.lookup_object("toolhead").get_position()[:2] == pytest.approx((25.0, 20.0))
    printer.gcode.run_script("G92 X0")
    responses.clear()
    printer.gcode.run_line("M114")
    assert responses == ["X:0.000 Y:20.000 Z:10.000 E:0.000"]
    printer.gcode.run_line("G1 X10")
    status = printer.get_status()["toolhead"]
    assert status["position"][:2] == pytest.approx([35.0, 20.0])
    assert printer.get_status()["gcode_move"]["gcode_position"][:2] == pytest.approx([10.0, 20.0])
    assert status["axis_minimum"] == [0.0, 0.0, -2.0, 0.0]
    assert status["axis_maximum"] == [235.0, 235.0, 250.0, 0.0]
    assert error_of(printer, "G1 X1 E5") == ("Error on 'G1 X1 E5': Extrude below minimum temp\n"
                                             "See the 'min_extrude_temp' config option for details")
    assert error_of(printer, "G1 X1 F0") == "Error on 'G1 X1 F0': F must have minimum of 6 (allowed: 6 to 600000)"


def test_g28_z_needs_a_probe(tmp_path):
    printer, _ = start(tmp_path)
    assert error_of(printer, "G28 Z") == ("G28 Z: [stepper_z] endstop_pin is probe:z_virtual_endstop but there is "
                                          "no probe; add a [load_cell_probe] section")
    assert printer.get_status()["toolhead"]["homed_axes"] == ""


def test_nozzle_temperature(tmp_path):
    printer, responses = start(tmp_path)
    printer.gcode.run_line("M104 S200")
    assert printer.get_status()["extruder"]["target"] == 200.0
    responses.clear()
    printer.gcode.run_line("M109 S150")
    assert printer.get_status()["extruder"]["temperature"] == pytest.approx(150.0, abs=1.0)
    assert responses[0].startswith("// extruder: 1")
    assert error_of(printer, "M104 S400") == ("Error on 'M104 S400': Requested temperature (400.0) out of range "
                                              "(0.0:300.0)")


@pytest.mark.parametrize("change, message", [
    (("kinematics: cartesian", "kinematics: delta"), "[printer] kinematics = delta: must be one of: cartesian, corexy"),
    (("max_z_velocity: 15", "max_z_velocity: 400"), "[printer] max_z_velocity = 400: must be at most 300"),
    (("endstop_pin: ^PC0", "endstop_pin: probe:z_virtual_endstop"),
     "[stepper_x] endstop_pin = probe:z_virtual_endstop: probe:z_virtual_endstop can only home Z"),
    (("position_endstop: 0\nposition_max: 235\n\n[stepper_y]", "position_endstop: 300\nposition_max: 235\n\n[stepper_y]"),
     "[stepper_x] position_endstop = 300: must be at most 235"),
    (("microsteps: 16\nrotation_distance: 8", "microsteps: 12\nrotation_distance: 8"),
     "[stepper_z] microsteps = 12: must be one of: 1, 2, 4, 8, 16, 32, 64, 128, 256"),
])
def test_config_errors(tmp_path, change, message):
    old, new = change
    assert old in STEPPERS
    with pytest.raises(ConfigError) as info:
        start(tmp_path, STEPPERS.replace(old, new, 1))
    assert str(info.value).startswith(f"{tmp_path / 'printer.cfg'}: {message}"), str(info.value)
