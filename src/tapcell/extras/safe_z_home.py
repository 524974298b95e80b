"""`[safe_z_home]`: G28 homes Z with the nozzle at home_xy_position (over the bed).

G28 (any axes): lift z_hop first (Z not homed: by z_hop from where it stands; the toolhead
keeps how far, so the nozzle watch knows the X/Y homing starts clear), home X/Y as asked, then
for Z move to home_xy_position and home Z (through the load cell), lift z_hop again, and with
move_to_previous go back to the X/Y the toolhead had.
"""

from __future__ import annotations

from tapcell.host.config import ConfigSection
from tapcell.host.gcode import GCodeCommand, parse_line
from tapcell.host.limits import COORDINATE_RANGE, MAX_COORDINATE_MM, SPEED_RANGE


class SafeZHome:
    def __init__(self, printer, home_xy: list[float], speed: float, z_hop: float, z_hop_speed: float,
                 move_to_previous: bool):
        self.printer = printer
        self.toolhead = printer.lookup_object("toolhead")
        self.home_xy = home_xy
        self.speed_mm_s = speed
        self.z_hop_mm = z_hop
        self.z_hop_speed_mm_s = z_hop_speed
        self.move_to_previous = move_to_previous
        self.home_original = printer.gcode.replace_command(
            "G28", self.cmd_G28, desc="Home axes: G28 [X] [Y] [Z] (Z at [safe_z_home] home_xy_position)")

    def _lift(self) -> None:
        toolhead = self.toolhead
        z_now = toolhead.get_position()[2]
        if toolhead.is_z_homed():
            if z_now < self.z_hop_mm:
                toolhead.move_to(z=self.z_hop_mm, speed_mm_s=self.z_hop_speed_mm_s)
        else:
            # Z unknown: lift by z_hop from wherever it is (the virtual machine stops at its end of travel).
            top = toolhead.backend.limits["z"][1] + toolhead.frame_offset_mm["z"]
            toolhead.move_to(z=min(z_now + self.z_hop_mm, top), speed_mm_s=self.z_hop_speed_mm_s)

    def cmd_G28(self, gcmd: GCodeCommand) -> None:
        asked = [axis for axis in "XYZ" if gcmd.has(axis)] or ["X", "Y", "Z"]
        if self.z_hop_mm:
            self._lift()
        xy = [axis for axis in asked if axis in "XY"]
        if xy:
            self.home_original(homing_command(self.printer, xy))
        if "Z" not in asked:
            return
        toolhead = self.toolhead
        if not {"x", "y"} <= toolhead.homed_axes:
            raise gcmd.error("Must home X and Y axes first (run G28, or G28 X Y)")
        previous_xy = toolhead.get_position()[:2]
        toolhead.move_to(x=self.home_xy[0], y=self.home_xy[1], speed_mm_s=self.speed_mm_s)
        self.home_original(homing_command(self.printer, ["Z"]))
        if self.z_hop_mm and toolhead.get_position()[2] < self.z_hop_mm:
            toolhead.move_to(z=self.z_hop_mm, speed_mm_s=self.z_hop_speed_mm_s)
        if self.move_to_previous:
            toolhead.move_to(x=previous_xy[0], y=previous_xy[1], speed_mm_s=self.speed_mm_s)


def homing_command(printer, axes: list[str]) -> GCodeCommand:
    """A G28 command for `axes`, to hand to the original G28 handler."""
    return GCodeCommand(printer.gcode, parse_line("G28 " + " ".join(axes)))


def load_config(section: ConfigSection, printer) -> SafeZHome:
    if section.config.has_section("homing_override"):
        raise section.error("home_xy_position", "[safe_z_home] and [homing_override] cannot be used together")
    toolhead = printer.lookup_object("toolhead")
    home_xy = section.getfloatlist("home_xy_position", count=2, **COORDINATE_RANGE)
    for axis, value in zip("xy", home_xy):
        limits = toolhead.options.axes[axis]
        if not limits.position_min_mm <= value <= limits.position_max_mm:
            raise section.error("home_xy_position", f"{axis.upper()}={value:g} is outside [stepper_{axis}] "
                                f"position_min..position_max ({limits.position_min_mm:g}..{limits.position_max_mm:g})")
    return SafeZHome(printer, home_xy,
                     speed=section.getfloat("speed", 50.0, **SPEED_RANGE),
                     z_hop=section.getfloat("z_hop", 0.0, minval=0.0, maxval=MAX_COORDINATE_MM),
                     z_hop_speed=section.getfloat("z_hop_speed", 15.0, **SPEED_RANGE),
                     move_to_previous=section.getboolean("move_to_previous", False))
