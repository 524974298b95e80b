"""`[load_cell_probe]`: the nozzle taps the bed through a load cell.

`device` (the tapping device, one tap step by step), `commands` (its G-code commands),
`options` (the option table and the pure rules of one tap), `calibration` (the pure math of
LOAD_CELL_PROBE_CALIBRATE). This module assembles them for the config section.
"""

from __future__ import annotations

import jinja2

from tapcell.extras.gcode_macro import StatusView
from tapcell.extras.load_cell import register_load_cell_commands
from tapcell.extras.load_cell_probe.commands import LoadCellProbeCommands
from tapcell.extras.load_cell_probe.device import LoadCellProbe
from tapcell.extras.probe.options import PROBE_TEMPLATE_OPTIONS, read_probe_options
from tapcell.extras.probe.session import Probe
from tapcell.host.gcode import GCodeError


def _template_runner(printer):
    """Run a probe G-code template (activate/deactivate/scrubber): Jinja2 with `printer` and `params`."""

    def run(option: str, template: str, params: dict) -> None:
        try:
            script = jinja2.Template(template).render(printer=StatusView(printer), params=params)
        except jinja2.TemplateError as exc:
            raise GCodeError(f"[load_cell_probe] {option}: template error: {exc}") from exc
        printer.gcode.run_script(script)

    return run


def load_config(section, printer) -> LoadCellProbe:
    """Build `[load_cell_probe]`: the device, the generic probe (object `probe`), the commands."""
    device = LoadCellProbe(section, printer)
    templates = {name: section.get(name) for name in PROBE_TEMPLATE_OPTIONS if section.has_option(name)}
    probe = Probe("load_cell_probe", read_probe_options(section, templates), device, device.motion,
                  printer.gcode, _template_runner(printer))
    device.probe = probe
    probe.register_commands()
    register_load_cell_commands(printer.gcode, device.load_cell, device.name)
    commands = LoadCellProbeCommands(device, probe)
    commands.register(printer.gcode)
    printer.add_object("probe", probe)
    printer.add_object("query_endstops", commands)
    return device
