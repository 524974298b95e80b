"""`tapcell demo` runs the scale job end to end on the virtual printer."""

from __future__ import annotations

import io
import re

import pytest

from tapcell.tools import cli, demo
from tapcell.tap import read_tap_file

SCALE_CONFIG = """\
[virtual_printer]
scenario: clean
[load_cell]
sensor_type: hx717
sclk_pin: PA5
dout_pin: PA4
"""


def test_demo_calibrates_and_weighs(tmp_path, capsys):
    config = tmp_path / "scale.cfg"
    config.write_text(SCALE_CONFIG)
    assert demo.main(["--config", str(config), "--out", str(tmp_path / "out")]) == 0
    out = capsys.readouterr().out
    assert config.read_text() == SCALE_CONFIG  # the demo works on a copy
    assert "counts_per_gram" in (tmp_path / "out" / "printer.cfg").read_text()  # the calibration, saved there
    for command in ("> LOAD_CELL_DIAGNOSTIC", "> CALIBRATE GRAMS=1000", "> ACCEPT", "> SAVE_CONFIG",
                    "> LOAD_CELL_READ"):
        assert command in out
    counts_per_gram = float(re.search(r"Counts/gram: (\d+\.\d+)", out)[1])
    assert counts_per_gram == pytest.approx(110.0, rel=0.005)  # the clean scenario's cell
    grams = float(re.search(r"// (\d+\.\d)g \(", out)[1])
    assert grams == pytest.approx(demo.TEST_WEIGHT_G, rel=0.01)
    assert "Sample range in grams" in out
    assert "!!" not in out
    # Not a terminal (captured): a response line longer than 80 columns is printed whole, never
    # wrapped (a wrapped line breaks numbers and its continuation loses the `// ` prefix).
    calibration = re.search(r"^    // Calibration value: .*$", out, flags=re.M)[0]
    assert len(calibration) > 80
    assert re.fullmatch(r"    // Calibration value: -?\d+\.\d+% \(-?\d+\), Counts/gram: \d+\.\d+, "
                        r"Total capacity: \+/- \d+\.\d+Kg", calibration)


def test_demo_reports_a_broken_config_without_a_traceback(tmp_path, capsys):
    config = tmp_path / "broken.cfg"
    config.write_text(SCALE_CONFIG + "counts_per_gram: 0.1\n")
    assert demo.main(["--config", str(config), "--out", str(tmp_path / "out")]) == 1
    assert "The printer did not start:" in capsys.readouterr().out


def test_make_demo_default_runs(tmp_path, capsys, monkeypatch):
    assert demo.main(["--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "!!" not in out and "> LOAD_CELL_READ" in out
    # Probing: PROBE_ACCURACY on the warped bed's centre, then the last tap's plot and tap file.
    assert f"> PROBE_ACCURACY SAMPLES={demo.ACCURACY_SAMPLES} SAMPLE_RETRACT_DIST=0.4" in out
    sigma_mm = float(re.search(r"standard deviation (\d+\.\d+)", out)[1])
    # Measured 0.32 µm with the toe model (the sharp model's 0.075 µm left its ~1.4 µm onset bias in):
    # well below the 1 µm a load cell can do.
    assert sigma_mm <= 0.0006
    points = re.findall(r"^    P(\d)  t = +(\d+\.\d+) s  force = +(-?\d+\.\d) g$", out, flags=re.M)
    assert [p[0] for p in points] == ["0", "1", "2", "3", "4", "5"]
    assert [float(p[1]) for p in points] == sorted(float(p[1]) for p in points)  # in time order
    assert float(points[2][2]) > 75.0 and abs(float(points[4][2])) < 5.0  # pressed, then left the bed
    png = tmp_path / "last-tap.png"
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert len(read_tap_file(tmp_path / "last-taps.jsonl")) == demo.ACCURACY_SAMPLES + 1  # + PROBE HOME=Z
    assert out.index("> PROBE_ACCURACY") < out.index("> NOZZLE_CLEANUP") < out.index("> BED_MESH_CALIBRATE")
    # The explanations quote the printer's own numbers (the dwell was once said to be 4 samples).
    flat = " ".join(out.split())
    assert "until the load cell reads 75 g, stop, wait 10 samples (31 ms at 320 samples/s), pull back 0.15 mm" in flat
    assert "{" not in out
    # G28 homes Z mid-bed, a trigger's depth into it: the first PROBE reads a few hundredths above 0.
    first_probe_z = float(re.search(r"> PROBE HOME=Z\n(?:.*\n)*?    // probe at 117\.500,117\.500 is z=(-?\d+\.\d+)", out)[1])
    assert 0.02 < first_probe_z < 0.05  # measured 0.0338
    # Two clocks, each labelled: the printer's and this computer's.
    printer_s = float(re.search(r"49/49 points, printer time (\d+\.\d) s, this computer's \d+:\d\d:\d\d", flat)[1])
    done_s = float(re.search(r"Mesh 'default' done in (\d+\.\d) s", out)[1])
    assert 0.0 <= done_s - printer_s <= 0.2  # the command also counts the lift after the last point
    # The mesh against the true bed: each probed point within a few µm (measured 1.75 µm at worst).
    worst_um = float(re.search(r"at the probed points:\s+largest\s+error\s+(\d+\.\d+)\s+um", out)[1])
    assert worst_um < 2.5
    assert (tmp_path / "bed-mesh.png").read_bytes()[:4] == b"\x89PNG"
    assert (tmp_path / "bed-mesh-error.png").read_bytes()[:4] == b"\x89PNG"
    # The calibrated printer stays in the output folder, and the demo ends with the command to go on.
    saved = (tmp_path / "printer.cfg").read_text()
    assert "counts_per_gram" in saved and "[bed_mesh default]" in saved
    command = demo.console_command(tmp_path / "printer.cfg")
    assert out.rstrip().splitlines()[-1] == f"    {command}"
    assert command.endswith(f"tapcell console --config {tmp_path / 'printer.cfg'}")
    # ... and the console goes on from there: calibrated, the mesh loaded.
    monkeypatch.setattr("sys.stdin", io.StringIO("LOAD_CELL_READ\nBED_MESH_OUTPUT\n"))
    assert cli.main(["console", "--config", str(tmp_path / "printer.cfg")]) == 0
    console_out = capsys.readouterr().out
    assert "Mesh Leveling Probed Z positions:" in console_out and "!!" not in console_out
