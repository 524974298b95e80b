"""`query_endstops`: QUERY_ENDSTOPS and the `query_endstops/status` API endpoint (always loaded).

As in Klipper the endstops are named after their rail (`x`, `y`, `z`) and read "open" or
"TRIGGERED"; the status object keeps the last query (true: triggered) per name. X and Y read the virtual
printer's switches (pressed while the carriage sits at position_endstop, as right after G28).
Z homes through the load cell (`probe:z_virtual_endstop`), which reads "open" as Klipper's
load_cell_probe does: it only triggers inside a homing or probing move.
"""

from __future__ import annotations

from tapcell.host.config import ConfigSection
from tapcell.host.gcode import GCodeCommand

ENDSTOP_NAMES = ("x", "y", "z")


class QueryEndstops:
    def __init__(self, printer, toolhead):
        self.printer = printer
        self.toolhead = toolhead
        self.last_query: dict[str, bool] = {}

    def query(self) -> dict[str, bool]:
        """Each endstop's state now (True: triggered)."""
        backend = self.printer.backend
        states = {axis: bool(backend.endstop_triggered(axis)) for axis in "xy"}
        z_axis = self.toolhead.options.axes["z"]
        states["z"] = False if z_axis.homes_with_probe else bool(backend.endstop_triggered("z"))
        self.last_query = dict(states)
        return states

    def cmd_QUERY_ENDSTOPS(self, gcmd: GCodeCommand) -> None:
        gcmd.respond_info(" ".join(f"{name}:{_word(triggered)}" for name, triggered in self.query().items()))

    def endpoint_status(self, params: dict) -> dict:
        return {name: _word(triggered) for name, triggered in self.query().items()}

    def get_status(self, eventtime=None) -> dict:
        return {"last_query": dict(self.last_query)}


def _word(triggered: bool) -> str:
    return "TRIGGERED" if triggered else "open"


def load_config(section: ConfigSection, printer) -> QueryEndstops | None:
    toolhead = printer.lookup_object("toolhead", None)
    if toolhead is None or not hasattr(printer.backend, "endstop_triggered"):
        return None
    endstops = QueryEndstops(printer, toolhead)
    printer.gcode.register_command("QUERY_ENDSTOPS", endstops.cmd_QUERY_ENDSTOPS,
                                   desc="Report on the status of each endstop")
    printer.gcode.register_command("M119", endstops.cmd_QUERY_ENDSTOPS, desc="Report on the status of each endstop")
    printer.register_endpoint("query_endstops/status", endstops.endpoint_status)
    return endstops
