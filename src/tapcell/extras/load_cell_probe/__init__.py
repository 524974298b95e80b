"""`[load_cell_probe]`: the nozzle taps the bed through a load cell.

`device` (the tapping device, one tap step by step), `commands` (its G-code commands),
`options` (the option table and the pure rules of one tap), `calibration` (the pure math of
LOAD_CELL_PROBE_CALIBRATE). This module assembles them for the config section.
"""

from __future__ import annotations

from tapcell.extras.load_cell import register_load_cell_commands
from tapcell.extras.load_cell_probe.commands import LoadCellProbeCommands
from tapcell.extras.load_cell_probe.device import LoadCellProbe
from tapcell.extras.load_cell_probe.overrides import disabled_protections
from tapcell.extras.load_cell_probe.watch import NozzleWatch, read_watch_options
from tapcell.extras.probe.calibrate import register_probe_calibrate
from tapcell.extras.probe.options import PROBE_TEMPLATE_OPTIONS, read_probe_options
from tapcell.extras.probe.session import Probe
from tapcell.host.templates import GCodeTemplate, StatusView, compile_template


def _template_runner(printer):
    """Run a probe G-code template (activate/deactivate/scrubber) with `printer` and `params`."""

    def run(option: str, template: GCodeTemplate, params: dict) -> None:
        script = template.render({"printer": StatusView(printer), "params": params})
        printer.gcode.run_script(script, caller=template.label)  # named in a recursion error

    return run


def load_config(section, printer) -> LoadCellProbe:
    """Build `[load_cell_probe]`: the device, the generic probe (object `probe`), the commands."""
    device = LoadCellProbe(section, printer)
    templates = {name: compile_template(section, name, f"[{section.get_name()}] {name}")
                 for name in PROBE_TEMPLATE_OPTIONS if section.has_option(name)}
    probe = Probe("load_cell_probe", read_probe_options(section, templates), device, device.motion,
                  printer.gcode, _template_runner(printer))
    device.probe = probe
    printer.warnings.extend(disabled_protections(device.options))
    device.nozzle_watch = device.motion.nozzle_watch = NozzleWatch(device, read_watch_options(section))
    device.refuse_a_hiding_drift_filter(section, probe.options)
    probe.register_commands()
    register_probe_calibrate(printer, probe)
    register_load_cell_commands(printer.gcode, device.load_cell, device.name)
    commands = LoadCellProbeCommands(device, probe)
    commands.register(printer.gcode)
    printer.add_object("probe", probe)
    printer.add_object("query_endstops", commands)
    if not printer.config.has_section("load_cell"):
        # As in Klipper: macros read the probe's cell as printer.load_cell (force_g, tare_counts, ...).
        printer.add_object("load_cell", device.load_cell)
    return device
