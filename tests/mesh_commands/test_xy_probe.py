"""XY probing: touching the virtual printer's calibration pin (known position) from the side."""

from __future__ import annotations

import pytest

from machines import gcode_error

PIN = """
[xy_probe]
pin_x: 225
pin_y: 225
pin_diameter: 6
# The virtual toolhead gives 4 g/um sideways: a guard for up to 10 lets 2 mm/s through.
max_side_stiffness: 10
"""


@pytest.fixture
def pin_printer(make_printer):
    # The pin really is at (225.3, 224.8): 0.3 / -0.2 mm from where the config says.
    printer = make_printer(PIN, probe=True)
    text = (make_printer.tmp_path / "printer.cfg").read_text().replace(
        "seed: 1\n", "seed: 1\npin_diameter_mm: 6\npin_x_mm: 225.3\npin_y_mm: 224.8\n", 1)
    (make_printer.tmp_path / "printer.cfg").write_text(text)
    printer.gcode.run_script("RESTART\nG28")
    return printer


def test_pin_centre_found_from_four_sides(pin_printer, make_printer):
    pin_printer.gcode.run_script("XY_PROBE_PIN")
    result = pin_printer.get_status()["xy_probe"]["last_result"]
    assert result["center_x"] == pytest.approx(225.3, abs=0.005)
    assert result["center_y"] == pytest.approx(224.8, abs=0.005)
    assert result["offset_x"] == pytest.approx(0.3, abs=0.005)
    # Pin 6 mm + tip 1 mm, less the give before 40 g on each side (2 g/um seen by the cell: ~20 um).
    assert 6.90 < result["width_x"] < 7.0 and 6.90 < result["width_y"] < 7.0
    assert make_printer.responses[-2].startswith("// XY_PROBE_PIN: pin centre at X=225.3")


def test_single_touch_reports_the_contact_position(pin_printer, make_printer):
    gcode = pin_printer.gcode
    gcode.run_script("G1 X215 Y224.8 F3000\nG1 Z2\nXY_PROBE DIRECTION=+X")
    contact_x = pin_printer.get_status()["xy_probe"]["last_result"]["contact_x"]
    surface_x = 225.3 - 3.0 - 0.5  # pin radius + nozzle tip radius
    assert 0.015 < contact_x - surface_x < 0.035  # measured: 24.6 um
    assert make_printer.responses[-1].startswith(f"// XY_PROBE: contact at X={contact_x:.4f} Y=224.8")
    assert make_printer.responses[-1].endswith("(moving +X, 40 g)")
    # A higher threshold presses further in before it triggers.
    gcode.run_script("XY_PROBE DIRECTION=+X FORCE=120")
    harder_x = pin_printer.get_status()["xy_probe"]["last_result"]["contact_x"]
    assert harder_x - contact_x == pytest.approx(0.080 / 2.0, abs=0.005)  # 80 g more at 2 g/um seen


def test_missing_the_pin_is_an_error(pin_printer):
    pin_printer.gcode.run_script("G1 X100 Y100 Z2 F3000")
    assert gcode_error(pin_printer, "XY_PROBE DIRECTION=-Y DISTANCE=5") == "XY probe: no contact within 5 mm from X=100.000 Y=100.000"
    assert "DIRECTION must be one of +X, -X, +Y, -Y" in gcode_error(pin_printer, "XY_PROBE DIRECTION=up")


def test_an_error_during_an_xy_probing_move_backs_the_nozzle_off(pin_printer, make_printer):
    # The sensor freezes as the move starts: the firmware's stuck-sensor check stops it. Wherever
    # an XY probing move stops on an error (pressed against the pin, as a frozen sensor near it
    # would leave it), the nozzle goes back to where the move started before the error is reported.
    gcode = pin_printer.gcode
    gcode.run_script("G1 X215 Y224.8 F3000\nG1 Z2\nSIM_FAULT NAME=stuck WHEN=probing_move")
    message = gcode_error(pin_printer, "XY_PROBE DIRECTION=+X")
    assert "stuck" in message.lower()
    assert pin_printer.backend.position[:2] == pytest.approx((215.0, 224.8), abs=1e-9)
    backed = [line for line in make_printer.responses if line.startswith("// Backed the nozzle off")]
    # 7 identical samples at 320 sps (about 22 ms) at 2 mm/s: some 0.04-0.05 mm into the move.
    assert len(backed) == 1 and 0.02 < float(backed[0].split()[5]) < 0.08


def stiff_pin_printer(make_printer, side_stiffness_g_um: float, xy_probe_lines: str = "", probe_lines: str = ""):
    """The pin on a toolhead this stiff sideways; [xy_probe] with the default guard unless told."""
    printer = make_printer(PIN.replace("max_side_stiffness: 10\n", xy_probe_lines), probe=True)
    path = make_printer.tmp_path / "printer.cfg"
    text = path.read_text().replace("seed: 1\n", "seed: 1\npin_diameter_mm: 6\npin_x_mm: 225.3\npin_y_mm: 224.8\n"
                                    f"pin_side_stiffness_g_um: {side_stiffness_g_um:g}\n", 1)
    if probe_lines:
        text = text.replace("[load_cell_probe]\n", f"[load_cell_probe]\n{probe_lines}", 1)
    path.write_text(text)
    printer.gcode.run_script("RESTART\nG28\nG1 X215 Y224.8 F3000\nG1 Z2\nSIM_TRUTH")
    return printer


def truth(printer, make_printer) -> dict[str, float]:
    printer.gcode.run_script("SIM_TRUTH")
    lines = [line[3:].split(": ") for line in make_printer.responses if line.startswith("// peak_")][-3:]
    return {name: float(value) for name, value in lines}


def test_sim_truth_counts_the_pins_sideways_force(make_printer):
    # Issue 19: XY_PROBE at 20 mm/s on a stiff toolhead pressed kg sideways, and SIM_TRUTH's
    # peak_force_g left the pin out. With the force guards off (force_safety_limit: 0) it shows now.
    printer = stiff_pin_printer(make_printer, 100.0, probe_lines="force_safety_limit: 0\ndrift_safety_limit: 0\n")
    truth(printer, make_printer)
    printer.gcode.run_script("XY_PROBE DIRECTION=+X SPEED=20")
    peaks = truth(printer, make_printer)
    # 20 mm/s for ~6 ms after the trigger plus a 12.5 um step at 100 g/um: 5000 g measured.
    assert peaks["peak_pin_force_g"] > 2.0 * 2000.0
    assert peaks["peak_force_g"] == peaks["peak_pin_force_g"] and peaks["peak_bed_force_g"] == 0.0


def test_xy_probe_too_fast_for_the_stiffest_toolhead_is_refused_before_it_moves(make_printer):
    printer = stiff_pin_printer(make_printer, 100.0)
    truth(printer, make_printer)
    x_before = printer.backend.position[0]
    message = gcode_error(printer, "XY_PROBE DIRECTION=+X SPEED=20")
    assert message == ("XY probing at 20 mm/s refused: on a toolhead of up to 100 g/um sideways ([xy_probe] "
                       "max_side_stiffness) it could press the pin with up to 13410g, more than force_safety_limit "
                       "(2000g); probe at 0.98 mm/s or slower")
    assert printer.backend.position[0] == x_before and truth(printer, make_printer)["peak_pin_force_g"] == 0.0


def test_xy_probing_at_the_configured_speed_is_slowed_to_the_guards(make_printer):
    # The default guard (100 g/um) on a toolhead that stiff: [xy_probe] speed 2 becomes 0.98 mm/s
    # and the pin is pressed with 1,250 g at most (one 12.5 um step), under the 2,000 g limit.
    printer = stiff_pin_printer(make_printer, 100.0)
    truth(printer, make_printer)
    printer.gcode.run_script("XY_PROBE DIRECTION=+X")
    assert any(line.startswith("// XY probing at 0.98 mm/s, not 2: on a toolhead of up to 100 g/um")
               for line in make_printer.responses)
    assert make_printer.responses[-1].startswith("// XY_PROBE: contact at X=221.8")
    assert truth(printer, make_printer)["peak_pin_force_g"] <= 2000.0
    printer.gcode.run_script("XY_PROBE_PIN")
    assert truth(printer, make_printer)["peak_pin_force_g"] <= 2000.0
    assert printer.get_status()["xy_probe"]["last_result"]["center_x"] == pytest.approx(225.3, abs=0.01)


def test_a_toolhead_stiffer_than_any_safe_speed_is_refused(make_printer):
    printer = stiff_pin_printer(make_printer, 150.0, xy_probe_lines="max_side_stiffness: 150\n")
    message = gcode_error(printer, "XY_PROBE_PIN")
    assert message.startswith("XY probing refused: even at 0.5 mm/s on a toolhead of up to 150 g/um sideways")

