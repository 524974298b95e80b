"""`tapcell demo` runs the scale job end to end on the virtual printer."""

from __future__ import annotations

import re

import pytest

from tapcell import demo

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
    assert demo.main(["--config", str(config)]) == 0
    out = capsys.readouterr().out
    assert config.read_text() == SCALE_CONFIG  # the demo works on a copy
    for command in ("> LOAD_CELL_DIAGNOSTIC", "> CALIBRATE GRAMS=1000", "> ACCEPT", "> SAVE_CONFIG",
                    "> LOAD_CELL_READ"):
        assert command in out
    counts_per_gram = float(re.search(r"Counts/gram: (\d+\.\d+)", out)[1])
    assert counts_per_gram == pytest.approx(110.0, rel=0.005)  # the clean scenario's cell
    grams = float(re.search(r"// (\d+\.\d)g \(", out)[1])
    assert grams == pytest.approx(demo.TEST_WEIGHT_G, rel=0.01)
    assert "Sample range in grams" in out
    assert "!!" not in out


def test_demo_reports_a_broken_config_without_a_traceback(tmp_path, capsys):
    config = tmp_path / "broken.cfg"
    config.write_text(SCALE_CONFIG + "counts_per_gram: 0.1\n")
    assert demo.main(["--config", str(config)]) == 1
    assert "The printer did not start:" in capsys.readouterr().out


def test_make_demo_default_runs(capsys):
    assert demo.main([]) == 0
    out = capsys.readouterr().out
    assert "!!" not in out and "> LOAD_CELL_READ" in out
