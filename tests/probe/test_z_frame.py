"""One Z frame: the console's `probe at X,Y is z=`, the tap file, `tapcell analyze` and the tap
plot give the same Z for the same tap (they differed by the homing offset: 0.000010 vs 0.0145)."""

from __future__ import annotations

import json
import re

import matplotlib
import pytest

from tapcell.tap import read_tap_file
from tapcell.tap.plot import draw_tap
from tapcell.tools import cli

from probe_vprinter import make_printer


def test_console_tap_file_analyze_and_plot_agree(tmp_path, capsys):
    # The machine's bed is 0.3 mm below the machine's Z 0; homing makes the bed Z 0.
    printer, responses = make_printer(tmp_path, virtual_printer="bed_z_offset_mm: -0.3")
    printer.gcode.run_script("PROBE HOME=Z\nG1 Z0.4\nPROBE")
    machine_offset_mm = printer.lookup_object("toolhead").frame_offset_mm["z"]
    assert machine_offset_mm == pytest.approx(0.3, abs=0.005)
    console_z = float(re.fullmatch(r"// probe at [\d.]+,[\d.]+ is z=(-?\d+\.\d+)",
                                   [r for r in responses if r.startswith("// probe at")][-1])[1])
    assert abs(console_z) < 0.002  # the bed is Z 0 after PROBE HOME=Z
    device = printer.lookup_object("load_cell_probe")
    path = tmp_path / "taps.jsonl"
    device.write_last_taps(path)
    tap = read_tap_file(path)[-1]
    assert tap.meta["frame"] == "toolhead"
    assert tap.meta["machine_offset_mm"][2] == pytest.approx(machine_offset_mm)
    assert tap.probe["x"] == pytest.approx(printer.lookup_object("toolhead").get_position()[0])
    # tapcell analyze on the file, as a user runs it.
    capsys.readouterr()
    assert cli.main(["analyze", "--json", str(path)]) == 0
    analyzed_z = json.loads(capsys.readouterr().out)[-1]["z"]
    assert analyzed_z == pytest.approx(console_z, abs=1e-6)  # the console prints 6 decimals
    # The plot's Z label.
    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    axes = Figure().add_subplot()
    draw_tap(axes, device.last_taps[-1].tap, device.last_taps[-1].analysis)
    z_labels = [t.get_text() for t in axes.texts if t.get_text().startswith("Z = ")]
    assert z_labels and z_labels[0].startswith(f"Z = {console_z:.4f} mm")
