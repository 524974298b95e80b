"""The first layer right: after G28 and a mesh by each method, `G1 Z0.2` leaves 0.2 mm between
nozzle and bed everywhere on a tilted bed, as the simulator's truth (SIM_TRUTH) measures it.

The trigger-only methods (two_pass, prusa) halt a threshold's depth into the bed: 42-58 um low on
this bed (their own output says by how much), which one analysed tap at the middle point takes
out. Measured (seed 1, 0.4 mm tilt across X, -0.3 mm across Y, 7 x 7 bicubic): clearance
0.1931-0.2022 mm at the five places below for tap and prusa (two_pass: see the xfail below); without the tap's correction two_pass
and prusa put the nozzle up to 49 and 62 um low.
"""

from __future__ import annotations

import re

import pytest

from tapcell.host.printer import Printer
from tapcell.package_files import example_config

CALIBRATE = "LOAD_CELL_CALIBRATE\nTARE\nSIM_PLACE_WEIGHT GRAMS=1000\nCALIBRATE GRAMS=1000\nACCEPT\nSIM_REMOVE_WEIGHT"
PLACES_XY_MM = ((30, 30), (200, 40), (117.5, 117.5), (50, 200), (210, 210))
FIRST_LAYER_MM = 0.2
TOLERANCE_MM = 0.010  # measured worst 6.9 um (interpolation and each method's spread)


def tilted_printer(tmp_path) -> tuple[Printer, list[str]]:
    text = example_config().read_text().replace(
        "scenario: clean\nseed: 1\n", "scenario: clean\nseed: 1\nbed_shape: tilted\nbed_tilt_x_mm: 0.4\n"
                                      "bed_tilt_y_mm: -0.3\n")
    assert "bed_shape: tilted" in text
    path = tmp_path / "printer.cfg"
    path.write_text(text + "\n[prusa_probe]\n")
    responses: list[str] = []
    return Printer.from_config(str(path), responses=responses), responses


def clearance_mm(printer: Printer, responses: list[str], x_mm: float, y_mm: float) -> float:
    responses.clear()
    printer.gcode.run_script(f"G1 X{x_mm} Y{y_mm} Z{FIRST_LAYER_MM} F6000\nSIM_TRUTH")
    (value,) = [float(m.group(1)) for line in responses if (m := re.fullmatch(r"// nozzle_clearance_mm: (\S+)", line))]
    return value


# two_pass: since G28 Z's first tap runs at 0.8 mm/s the first layer is up to 14.4 um low away from
# the middle point whose tap sets the offset (6.9 um when G28 Z's first tap ran at 5 mm/s; 3 um with
# both passes at 0.8 mm/s). Not a bias of the slow homing: a second G28 before the mesh gives
# 0.192-0.200 mm again. Each trigger-only point lands on the sample grid (25 um of travel per sample
# in the fast pass), so two runs that differ only in what came before the mesh read single points up
# to 27 um apart (point 1's slow pass: -0.080 and -0.053 mm), and the clearance at a place depends on
# that phase. Sub-sample trigger timing in two_pass would take it out; not built yet.
TWO_PASS_AFTER_SLOW_G28 = pytest.mark.xfail(strict=True, reason="two_pass's first layer up to 14.4 um low since "
                                                                "G28 Z's first tap is slow (issue 19 follow-up)")


@pytest.mark.parametrize("method", ["tap", pytest.param("two_pass", marks=TWO_PASS_AFTER_SLOW_G28), "prusa"])
def test_z_0_2_is_0_2_above_a_tilted_bed(method, tmp_path):
    printer, responses = tilted_printer(tmp_path)
    printer.gcode.run_script(f"{CALIBRATE}\nG28\nBED_MESH_CALIBRATE METHOD={method}")
    offset_lines = [line for line in responses if line.startswith(f"// METHOD={method} offset:")]
    if method == "tap":
        assert offset_lines == []
    else:
        (line,) = offset_lines
        raised_um = float(re.search(r"every point raised by \+(\d+\.\d) um", line).group(1))
        assert 35.0 < raised_um < 70.0  # measured 42.0 (two_pass), 55.9 (prusa)
    clearances = [clearance_mm(printer, responses, x, y) for x, y in PLACES_XY_MM]
    assert max(abs(c - FIRST_LAYER_MM) for c in clearances) <= TOLERANCE_MM, clearances
