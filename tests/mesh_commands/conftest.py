"""Printers built from small config files for the mesh-command tests."""

from __future__ import annotations

from pathlib import Path

import pytest

from tapcell.host.printer import Printer

from machines import machine_config

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "virtual-printer.cfg"


PROBE = """
[load_cell_probe]
sensor_type: hx717
sclk_pin: PA5
dout_pin: PA4
sample_rate: 320
counts_per_gram: {counts_per_gram}
reference_tare_counts: {reference_tare_counts}
z_offset: 0
trigger_force: 75
speed: 5
# On this stiff bed (3.26 g/um) break contact comes 30-45 um
# up, inside the first sixth of the default 0.2 mm pullback (the spec wants the middle two thirds);
# 0.15 mm puts it at 20-30 % and leaves room for an ooze strand to tear before the pullback ends.
pullback_distance: 0.15
"""


class PrinterFactory:
    def __init__(self, tmp_path: Path):
        self.tmp_path = tmp_path
        self.responses: list[str] = []

    def __call__(self, extra: str, *, scenario: str = "clean", seed: int = 1, probe: bool = False,
                 name: str = "printer.cfg") -> Printer:
        text = machine_config(scenario, seed)
        if probe:
            text += PROBE.format(counts_per_gram=110.0, reference_tare_counts=-38000)
        path = self.tmp_path / name
        path.write_text(text + extra)
        self.responses = []
        return Printer.from_config(str(path), responses=self.responses)


@pytest.fixture
def make_printer(tmp_path):
    return PrinterFactory(tmp_path)


def _home_without_probe(printer: Printer, z_mm: float = 10.0) -> None:
    """Home X/Y on their endstops and declare the current Z to be z_mm (no probe needed)."""
    printer.gcode.run_script("G28 X Y")
    printer.lookup_object("toolhead").set_z_position(z_mm)


@pytest.fixture
def home_without_probe():
    return _home_without_probe
