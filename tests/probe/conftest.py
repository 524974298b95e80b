"""Helpers shared by the probe tests."""

from __future__ import annotations

import pytest

from tapcell.host.config import ConfigFile
from tapcell.host.gcode import GCodeCommand, GCodeDispatch, parse_line


@pytest.fixture
def make_section(tmp_path):
    """Build a ConfigSection from the text of one section."""

    def make(text: str, name: str = "load_cell_probe"):
        path = tmp_path / "printer.cfg"
        path.write_text(f"[{name}]\n{text}\n")
        return ConfigFile.read(path).getsection(name)

    return make


@pytest.fixture
def make_gcmd():
    """Build a GCodeCommand from a G-code line (responses collected in .responses)."""

    def make(line: str) -> GCodeCommand:
        responses: list[str] = []
        dispatch = GCodeDispatch(responses)
        gcmd = GCodeCommand(dispatch, parse_line(line))
        gcmd.responses = responses
        return gcmd

    return make
