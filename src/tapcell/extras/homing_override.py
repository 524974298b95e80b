"""`[homing_override]`: G28 runs the user's G-code instead (a G28 inside it is the original homing).

Options as in Klipper: gcode (a template with `params` and `printer`), axes (default xyz:
a G28 for none of them homes normally), set_position_x/y/z (mark the axis homed at that
position before the G-code runs, so it can move it).
"""

from __future__ import annotations

from tapcell.host.config import ConfigSection
from tapcell.host.gcode import GCodeCommand, parse_line
from tapcell.host.limits import COORDINATE_RANGE
from tapcell.host.templates import StatusView, compile_template


class HomingOverride:
    def __init__(self, printer, template, axes: str, set_position: dict[str, float]):
        self.printer = printer
        self.template = template
        self.axes = axes
        self.set_position = set_position
        self.home_original = printer.gcode.replace_command("G28", self.cmd_G28,
                                                           desc="Home axes ([homing_override] G-code)")

    def cmd_G28(self, gcmd: GCodeCommand) -> None:
        asked = [axis for axis in "XYZ" if gcmd.has(axis)]
        if asked and not any(axis.lower() in self.axes for axis in asked):
            self.home_original(gcmd)
            return
        toolhead = self.printer.lookup_object("toolhead")
        for axis, position_mm in self.set_position.items():
            index = "xyz".index(axis)
            toolhead.frame_offset_mm[axis] = position_mm - float(toolhead.backend.position[index])
            toolhead.homed_axes.add(axis)
        script = self.template.render({"printer": StatusView(self.printer), "params": gcmd.get_command_parameters(),
                                       "rawparams": gcmd.rawparams})
        self._run_script(script)

    def _run_script(self, script: str) -> None:
        """The override's G-code, line by line; a G28 in it is the original homing (not this override)."""
        gcode = self.printer.gcode
        for line in script.split("\n"):
            parsed = parse_line(line)
            if parsed is not None and parsed.command == "G28":
                self.home_original(GCodeCommand(gcode, parsed))
            else:
                gcode.run_line(line)


def load_config(section: ConfigSection, printer) -> HomingOverride:
    template = compile_template(section, "gcode", "[homing_override] gcode")
    axes = section.get("axes", "xyz").strip().lower()
    if not axes or any(axis not in "xyz" for axis in axes):
        raise section.error("axes", "must be letters from xyz")
    set_position = {axis: value for axis in "xyz"
                    if (value := section.getfloat(f"set_position_{axis}", None, **COORDINATE_RANGE)) is not None}
    return HomingOverride(printer, template, axes, set_position)
