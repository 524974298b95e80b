"""A printer owner's first session on the shipped example is guided: every "not calibrated" and
"not homed" answer names the command that fixes it, STATUS says what is still to do, and the
examples home Z in the middle of the bed."""

from __future__ import annotations

import pytest

from tapcell.host.config import ConfigFile
from tapcell.host.gcode import GCodeError
from tapcell.host.printer import Printer
from tapcell.package_files import example_config, example_names

CALIBRATE = "LOAD_CELL_CALIBRATE\nTARE\nSIM_PLACE_WEIGHT GRAMS=1000\nCALIBRATE GRAMS=1000\nACCEPT\nSIM_REMOVE_WEIGHT"


@pytest.fixture
def printer(tmp_path):
    config = tmp_path / "printer.cfg"
    config.write_text(example_config().read_text())
    responses: list[str] = []
    return Printer.from_config(str(config), responses=responses), responses


def status_line(printer, responses) -> str:
    responses.clear()
    printer.gcode.run_script("STATUS")
    return responses[0]


def error_of(printer, line: str) -> str:
    with pytest.raises(GCodeError) as error:
        printer.gcode.run_script(line)
    return str(error.value)


def test_each_refusal_names_its_fix_and_status_says_what_is_left(printer):
    printer, responses = printer
    assert status_line(printer, responses) == (
        "// Printer is ready; before probing: load_cell_probe is not calibrated: run LOAD_CELL_CALIBRATE "
        "(then SAVE_CONFIG); not homed: run G28")
    assert error_of(printer, "G28") == ("Load Cell Probe Error: Load Cell not calibrated: run LOAD_CELL_CALIBRATE "
                                        "(then SAVE_CONFIG to keep it)")
    printer.gcode.run_script(CALIBRATE)
    # The refused G28 homed X and Y ([safe_z_home] homes them first), not Z.
    assert status_line(printer, responses) == "// Printer is ready; before probing: not homed (homed: xy): run G28"
    assert error_of(printer, "PROBE") == "Must home before probe (run G28)"
    assert error_of(printer, "G1 Z1") == "Must home axis first: Z (run G28)"
    printer.gcode.run_script("G28")
    assert status_line(printer, responses) == "// Printer is ready"


@pytest.mark.parametrize("name", example_names())
def test_the_examples_home_z_in_the_middle_of_the_bed(name):
    config = ConfigFile.read(str(example_config(name)))
    home_xy = [float(v) for v in config.getsection("safe_z_home").get("home_xy_position").split(",")]
    for axis, value in zip("xy", home_xy):
        stepper = config.getsection(f"stepper_{axis}")
        low, high = float(stepper.get("position_min", "0")), float(stepper.get("position_max"))
        assert value == pytest.approx((low + high) / 2, abs=0.5)


def test_g28_probes_z_at_the_home_xy_position(printer):
    printer, responses = printer
    printer.gcode.run_script(CALIBRATE + "\nG28\nPROBE")
    assert "// probe at 117.500,117.500 is z=" in "\n".join(responses)



def test_a_fresh_printer_is_not_homed(printer):
    printer, responses = printer
    printer.gcode.run_script(CALIBRATE)
    assert status_line(printer, responses) == "// Printer is ready; before probing: not homed: run G28"
    assert error_of(printer, "G1 Z1") == "Must home axis first: Z (run G28)"
