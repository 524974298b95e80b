"""Printers built from small config files for the mesh-command tests."""

from __future__ import annotations

from pathlib import Path

import pytest

from tapcell.host.printer import Printer

from machines import PROBE_SECTION as PROBE, machine_config

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "virtual-printer.cfg"


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
