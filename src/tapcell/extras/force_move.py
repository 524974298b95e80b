"""`[force_move]`: SET_KINEMATIC_POSITION when `enable_force_move: True`, as in Klipper.

SET_KINEMATIC_POSITION [X=] [Y=] [Z=] [SET_HOMED=XYZ] [CLEAR_HOMED=]: the toolhead takes the
given position without moving (an axis not given keeps its position) and the axes in SET_HOMED
(all of them by default, as in Klipper) count as homed; CLEAR_HOMED (or the older CLEAR) forgets
homing of the axes it names. Macros use it to lift Z before homing. FORCE_MOVE and STEPPER_BUZZ
drive single steppers, which the virtual printer does not have: they are not registered.
"""

from __future__ import annotations

from tapcell.host.config import ConfigSection
from tapcell.host.gcode import GCodeCommand
from tapcell.host.limits import COORDINATE_RANGE

AXES = "xyz"


def _axes(gcmd: GCodeCommand, name: str, default: str) -> str:
    text = gcmd.get(name, default).strip().lower()
    if any(letter not in AXES for letter in text):
        raise gcmd.param_error(f"{name} must name axes from X, Y, Z (got '{text.upper()}')")
    return text


class ForceMove:
    def __init__(self, printer, toolhead):
        self.printer = printer
        self.toolhead = toolhead

    def cmd_SET_KINEMATIC_POSITION(self, gcmd: GCodeCommand) -> None:
        toolhead = self.toolhead
        current = toolhead.get_position()
        machine = toolhead.backend.position
        wanted = [gcmd.get_float(axis.upper(), current[i], **COORDINATE_RANGE) for i, axis in enumerate(AXES)]
        set_homed = _axes(gcmd, "SET_HOMED", AXES)
        clear_homed = _axes(gcmd, "CLEAR_HOMED", _axes(gcmd, "CLEAR", ""))
        for i, axis in enumerate(AXES):
            toolhead.frame_offset_mm[axis] = wanted[i] - float(machine[i])
        toolhead.homed_axes.update(set_homed)
        toolhead.homed_axes.difference_update(clear_homed)
        gcmd.respond_info("SET_KINEMATIC_POSITION pos: " + " ".join(f"{a}={v:.3f}" for a, v in zip(AXES, wanted)))


def load_config(section: ConfigSection, printer) -> ForceMove | None:
    if not section.getboolean("enable_force_move", False):
        return None
    toolhead = printer.lookup_object("toolhead")
    force_move = ForceMove(printer, toolhead)
    printer.gcode.register_command("SET_KINEMATIC_POSITION", force_move.cmd_SET_KINEMATIC_POSITION,
                                   desc="Set the toolhead's position without moving: [X=] [Y=] [Z=] "
                                        "[SET_HOMED=XYZ] [CLEAR_HOMED=]")
    return None
