"""`tapcell run` of whole slicer files (PrusaSlicer, OrcaSlicer, Cura start G-code, hundreds of
extrusion moves, end G-code) on the Voron-style printer.cfg, as a print would run."""

from __future__ import annotations

import math

import pytest

from machines_klipper import calibrated_voron, start
from slicer_files import CUBE_NAME, LAYER_MM, cube_layer_paths, slicer_file
from tapcell.tools import cli

LAYERS = 8
# To keep the tests short: the example's 5x5 mesh in PRINT_START made 3x3, and its ADS1220 read at
# 330 samples/s (a print's minutes of heating are samples the virtual printer computes). At 330 sps on
# the toolboard the force guard lets an unmeasured bed be met at 3 mm/s at most (docs/safety.md).
SHORTER = {"probe_count: 5, 5": "probe_count: 3, 3", "sample_rate: 2000": "sample_rate: 330",
           "\nspeed: 5\nsamples: 1": "\nspeed: 3\nsamples: 1"}
# Klipper answers these in a print with "Unknown command" and goes on (it has no M201/M203/M205).
UNKNOWN_TO_KLIPPER = {"prusaslicer": ['// Unknown command:"M201"', '// Unknown command:"M203"',
                                      '// Unknown command:"M205"'],
                      "orcaslicer": [], "cura": []}


def path_mm() -> float:
    """Length of every extruding path of the cube (its perimeters and infill)."""
    return sum(math.dist(a, b) for layer in range(LAYERS) for path in cube_layer_paths(layer)
               for a, b in zip(path, path[1:]))


@pytest.mark.parametrize("slicer", ["prusaslicer", "orcaslicer", "cura"])
def test_slicer_file_prints_to_the_end(tmp_path, capsys, slicer):
    config = calibrated_voron(tmp_path, SHORTER)
    text, extrusions = slicer_file(slicer, layers=LAYERS)
    assert extrusions >= 300
    gcode = tmp_path / f"{slicer}.gcode"
    gcode.write_text(text)
    capsys.readouterr()
    status = cli.main(["run", "--progress", "always", "--config", str(config), str(gcode)])
    out, err = capsys.readouterr()
    assert status == 0, out[-2000:]
    lines = out.splitlines()
    assert [line for line in lines if line.startswith("!!") or "unknown parameter" in line] == []
    assert [line for line in lines if "Unknown command" in line] == UNKNOWN_TO_KLIPPER[slicer]
    # The progress bar on stderr reached the end; the summary gives the printer time it took.
    total_lines = len(text.splitlines())
    assert f"] 100% line {total_lines}/{total_lines}" in err
    summary = err.replace("\x1b[K", "").strip().splitlines()[-1].split("\r")[-1]
    assert summary.startswith(f"tapcell run: {total_lines} lines, ")
    hours, minutes, seconds = map(int, summary.split(", ")[1].split()[0].split(":"))
    printer_s = 3600 * hours + 60 * minutes + seconds
    # At least the heat-up (bed to 60 C: minutes) and the extrusion at F1800 (30 mm/s).
    assert printer_s > 120.0 + path_mm() / 30.0


def test_a_print_leaves_the_printer_as_its_end_gcode_says(tmp_path):
    config = calibrated_voron(tmp_path, SHORTER)
    printer, responses = start(tmp_path, config.read_text(), "again.cfg")
    text, extrusions = slicer_file("prusaslicer", layers=2)
    body = text[:text.index("; Filament-specific end gcode")]
    printer.gcode.run_script("\n".join(line for line in body.splitlines() if not line.startswith(("M201", "M203", "M205"))))
    status = printer.get_status()
    assert status["exclude_object"]["objects"][0]["name"] == CUBE_NAME.upper()
    assert status["display_status"]["message"] == "Printing cube"
    assert status["display_status"]["progress"] == 1.0
    assert status["fan"]["speed"] == 1.0
    # Relative E (M83): the purge line plus every extrusion of the two layers, nothing lost.
    extruded = sum(math.dist(a, b) for layer in range(2) for path in cube_layer_paths(layer) for a, b in zip(path, path[1:]))
    assert status["toolhead"]["position"][3] == pytest.approx(12.0 - 0.0 + extruded * 0.0333, abs=0.01)
    assert status["gcode_move"]["gcode_position"][2] == pytest.approx(2 * LAYER_MM)
    printer.gcode.run_script(text[text.index("; Filament-specific end gcode"):])
    status = printer.get_status()
    assert (status["extruder"]["target"], status["heater_bed"]["target"], status["fan"]["speed"]) == (0.0, 0.0, 0.0)
    assert status["toolhead"]["homed_axes"] == ""
