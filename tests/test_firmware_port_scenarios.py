"""The emulator images' scenario tables (firmware/port/scenarios.py), checked on the host.

`make firmware-emu` boots them; here only what the generator promises: the frames the
software HX71x shifts out decode to the counts through the firmware's own decoder, a desync
frame is one the decoder refuses, and every scenario ends as it was built to (the generator
raises when the C library, the Python trigger model and the construction disagree).
"""

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

from tapcell.mcu.sensors import SensorFrameError, decode_hx71x_frames

PORT = Path(__file__).resolve().parents[1] / "firmware" / "port"


@pytest.fixture(scope="module")
def scenarios():
    spec = importlib.util.spec_from_file_location("port_scenarios", PORT / "scenarios.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module              # its dataclasses look their module up
    spec.loader.exec_module(module)
    return module


def test_frames_decode_to_their_counts(scenarios):
    counts = np.array([0, 1, -1, 8_388_607, -8_388_608, 150_400])
    frames = scenarios.frame_of(counts)
    assert frames[2] == 0x1FFFFFF                       # -1: 24 ones, then the trailing 1
    assert np.array_equal(decode_hx71x_frames(frames, scenarios.PULSES), counts)
    with pytest.raises(SensorFrameError):
        decode_hx71x_frames(scenarios.frame_of(counts, trailing=0), scenarios.PULSES)


@pytest.mark.parametrize("ticks_per_s", [1_000_000, 16_000_000])
def test_scenarios_end_as_built(scenarios, ticks_per_s):
    ends = {row[0]: row[1:] for row in scenarios.describe(ticks_per_s)}
    assert ends["watchdog"] == (40, scenarios.END_WATCHDOG, 3)
    assert ends["hx71x_desync"] == (30, scenarios.END_ABORT, 107)
    assert ends["stuck_sensor"][1:] == (scenarios.END_SAMPLE, 7)
    assert ends["force_window_slow_ramp"][1:] == (scenarios.END_SAMPLE, 1)
    assert 60 < ends["tap"][0] < 120 and ends["tap"][1:] == (scenarios.END_SAMPLE, 0)


def test_c_table_holds_every_scenario(scenarios, tmp_path):
    out = tmp_path / "scenarios.c"
    scenarios.write_c(1_000_000, out)
    text = out.read_text()
    for name, *_ in scenarios.describe(1_000_000):
        assert f'.name = "{name}"' in text
    assert "const struct cost_case cost_case" in text
