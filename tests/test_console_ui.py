"""The console on a terminal (tapcell.tools.console_ui): TAB completion, the check of a line
before it runs, colours, and the progress line with points done and time left."""

from __future__ import annotations

import io
import re

import pytest

from tapcell.host.printer import Printer
from tapcell.package_files import example_config
from tapcell.tools import cli, console_ui

CALIBRATE = "LOAD_CELL_CALIBRATE\nTARE\nSIM_PLACE_WEIGHT GRAMS=1000\nCALIBRATE GRAMS=1000\nACCEPT\nSIM_REMOVE_WEIGHT"


@pytest.fixture
def printer(tmp_path):
    config = tmp_path / "printer.cfg"
    config.write_text(example_config().read_text().replace("probe_count: 7, 7", "probe_count: 3, 3")
                      .replace("algorithm: bicubic", "algorithm: lagrange"))
    return Printer.from_config(str(config), responses=[])


def test_completions_of_commands_parameters_and_values(printer):
    gcode = printer.gcode
    assert console_ui.completions(gcode, "bed_mesh_cal") == [("BED_MESH_CALIBRATE", -12)]
    assert console_ui.completions(gcode, "BED_MESH_CALIBRATE ME") == [("METHOD=", -2)]
    assert console_ui.completions(gcode, "BED_MESH_CALIBRATE METHOD=t") == [("tap", -1), ("two_pass", -1)]
    assert console_ui.completions(gcode, "LOAD_CELL_PROBE_CALIBRATE CALIBRATION=") == [
        ("CONTACT_ONSET", 0), ("PULLBACK_DISTANCE", 0), ("DECOMPRESSION_ANGLE", 0)]
    # A parameter already on the line is not offered again.
    assert ("PROFILE=", -1) not in console_ui.completions(gcode, "BED_MESH_CALIBRATE PROFILE=a P")
    # Parameters the command read in this session count too (PROBE_ACCURACY's help lists none).
    assert console_ui.completions(gcode, "PROBE_ACCURACY SA") == []
    printer.gcode.run_script(CALIBRATE + "\nG28\nPROBE_ACCURACY SAMPLES=2")
    assert ("SAMPLES=", -2) in console_ui.completions(gcode, "PROBE_ACCURACY SA")


def test_the_prompt_toolkit_completer_offers_them(printer):
    from prompt_toolkit.completion import CompleteEvent
    from prompt_toolkit.document import Document

    completer = console_ui.make_completer(printer.gcode)
    found = completer.get_completions(Document("bed_mesh_calibrate METHOD=tw"), CompleteEvent(completion_requested=True))
    assert [(c.text, c.start_position) for c in found] == [("two_pass", -2)]


def test_a_misspelt_parameter_holds_the_line_back_until_sent_again(tmp_path, monkeypatch, capsys):
    config = tmp_path / "printer.cfg"
    config.write_text(example_config().read_text())
    monkeypatch.setattr("sys.stdin", io.StringIO("BED_MESH_CALIBRATE METOD=tap\nBED_MESH_CALIBRATE METOD=tap\n"))
    assert cli.main(["console", "--config", str(config)]) == 0
    out = capsys.readouterr().out.splitlines()
    refused = [line for line in out if "METOD" in line]
    assert refused[0] == ("tapcell> !! BED_MESH_CALIBRATE: unknown parameter METOD (did you mean METHOD?): not run; "
                          "send the line again to run it as it is")
    # Sent again it runs (and is refused for its own reason: nothing is homed yet).
    assert "!! BED_MESH_CALIBRATE: home all axes first (G28)" in "\n".join(out)
    assert console_ui.misspelt_parameter(Printer.from_config(str(config), responses=[]).gcode,
                                         "BED_MESH_CALIBRATE BAD_PROBE_STRATEGY=CIRCLE") is None


def test_colours_only_errors_and_warnings(printer, monkeypatch):
    out = io.StringIO()
    console_ui.TerminalConsole(printer, out=out, progress_stream=io.StringIO(), colours=True)
    printer.gcode.run_script_reporting_errors("G1 Z1")
    printer.gcode.run_script_reporting_errors("STATUS OBJECT=probe")
    lines = out.getvalue().splitlines()
    assert lines[0] == "\033[31m!! Must home axis first: Z (run G28)\033[0m"
    assert lines[1] == '// name: "load_cell_probe"'  # JSON-like, no colour
    assert console_ui.coloured("// WARNING: x") == "\033[33m// WARNING: x\033[0m"
    monkeypatch.setenv("NO_COLOR", "1")
    assert console_ui.shows_colours(io.StringIO()) is False


class FakeClock:
    """One second per reading: deterministic times left."""

    def __init__(self):
        self.now_s = 0.0

    def __call__(self) -> float:
        self.now_s += 1.0
        return self.now_s


def test_progress_line_counts_points_and_time_left(printer):
    progress = io.StringIO()
    out = io.StringIO()
    console_ui.TerminalConsole(printer, out=out, progress_stream=progress, colours=False, clock=FakeClock())
    printer.gcode.run_script(CALIBRATE + "\nG28\nBED_MESH_CALIBRATE\nPROBE_ACCURACY SAMPLES=3")
    drawn = [part for part in progress.getvalue().split("\r\033[K") if part]
    mesh = [part for part in drawn if "mesh" in part]
    assert mesh[0] == "  mesh 0/9 points"
    counts = [re.match(r"  mesh (\d)/9 points", part).group(1) for part in mesh]
    assert [n for i, n in enumerate(counts) if i == 0 or counts[i - 1] != n] == [str(n) for n in range(9)]
    assert all(re.fullmatch(r"  mesh \d/9 points, about \d+ s left", part) for part in mesh[1:])
    accuracy = [part for part in drawn if "PROBE_ACCURACY" in part]
    assert accuracy[0] == "  PROBE_ACCURACY 0/3 points"
    counts = [part.split(",")[0] for part in accuracy]
    assert [n for i, n in enumerate(counts) if i == 0 or counts[i - 1] != n] == [
        "  PROBE_ACCURACY 0/3 points", "  PROBE_ACCURACY 1/3 points", "  PROBE_ACCURACY 2/3 points"]
    # The line is wiped before each response line: the responses stay clean.
    assert progress.getvalue().endswith("\r\033[K") and "\033" not in out.getvalue()
    assert console_ui.progress_text("mesh", 12, 49, 24.0) == "mesh 12/49 points, about 74 s left"
