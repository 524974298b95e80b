"""Gantry levelling on a printer with one Z motor: `[z_tilt]` and `[quad_gantry_level]`.

Common PRINT_START macros run Z_TILT_ADJUST or QUAD_GANTRY_LEVEL (often guarded by
`printer.z_tilt.applied`). The virtual printer moves its bed or gantry with one Z motor, so
there is no tilt between motors to measure or correct: the command answers with one line saying
so and reports `applied: true` (the gantry is level by construction), and the macro goes on.
The section's options (points, z_positions, retries, ...) are taken as written. Bed tilt itself
is measured by the load cell's mesh (BED_MESH_CALIBRATE).
"""

from __future__ import annotations

from tapcell.host.config import ConfigSection
from tapcell.host.gcode import GCodeCommand


class GantryLevelStandIn:
    def __init__(self, section_name: str, command: str):
        self.section_name = section_name
        self.command = command
        self.applied = False

    def cmd_level(self, gcmd: GCodeCommand) -> None:
        for name in ("RETRIES", "RETRY_TOLERANCE", "HORIZONTAL_MOVE_Z", "SAMPLES", "PROBE_SPEED"):
            gcmd.get(name, None)
        self.applied = True
        gcmd.respond_info(f"{self.command}: the virtual printer moves Z with one motor, so there is no "
                          f"tilt between motors to correct; nothing adjusted")

    def get_status(self, eventtime=None) -> dict:
        return {"applied": self.applied}


def load_standin(section: ConfigSection, printer, command: str, desc: str) -> GantryLevelStandIn:
    section.config.mark_section_read(section.get_name())
    standin = GantryLevelStandIn(section.get_name(), command)
    printer.gcode.register_command(command, standin.cmd_level, desc=desc)
    printer.register_event_handler("toolhead:motors_off", lambda: setattr(standin, "applied", False))
    return standin
