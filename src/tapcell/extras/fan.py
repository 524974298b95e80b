"""`[fan]`, the part-cooling fan: M106/M107, status `fan`; the speed is recorded on the virtual printer.

`Fan` and `read_fan_options` are shared with [heater_fan], [controller_fan] and [fan_generic].
"""

from __future__ import annotations

from tapcell.host.config import ConfigSection
from tapcell.host.gcode import GCodeCommand
from tapcell.host.limits import SECONDS_RANGE, SHARE_RANGE


def read_fan_options(section: ConfigSection) -> tuple[float, float]:
    """The pin options every Klipper fan has; returns (max_power, off_below)."""
    section.get("pin")
    section.get("enable_pin", None)
    section.get("tachometer_pin", None)
    section.getint("tachometer_ppr", 2, minval=1, maxval=100)
    section.getfloat("tachometer_poll_interval", 0.0015, **SECONDS_RANGE)
    section.getfloat("cycle_time", 0.010, **SECONDS_RANGE)
    section.getboolean("hardware_pwm", False)
    section.getfloat("kick_start_time", 0.1, minval=0.0, maxval=SECONDS_RANGE["maxval"])
    section.getfloat("shutdown_speed", 0.0, **SHARE_RANGE)
    max_power = section.getfloat("max_power", 1.0, above=0.0, maxval=1.0)
    off_below = section.getfloat("off_below", 0.0, **SHARE_RANGE)
    return max_power, off_below


class Fan:
    """A fan's speed, recorded on the virtual printer under the fan's name. As in Klipper the
    speed asked for is scaled by max_power, and `speed` in the status is the scaled value."""

    def __init__(self, printer, name: str, max_power: float, off_below: float):
        self.printer = printer
        self.name = name
        self.max_power = max_power
        self.off_below = off_below
        self.speed = 0.0

    def set_speed(self, speed: float) -> None:
        speed = 0.0 if speed < self.off_below else min(max(speed, 0.0), 1.0) * self.max_power
        if speed != self.speed:
            self.speed = speed
            self.printer.backend.set_output(self.name, speed)

    def get_status(self, eventtime=None) -> dict:
        return {"speed": self.speed, "rpm": None}


class PrinterFan(Fan):
    # P (a fan index: OrcaSlicer writes `M106 P2 S0` for an auxiliary fan) is read and ignored, as
    # Klipper does: M106/M107 always drive the [fan] section's part fan.
    def cmd_M106(self, gcmd: GCodeCommand) -> None:
        gcmd.get("P", None)
        self.set_speed(gcmd.get_float("S", 255.0, minval=0.0, maxval=255.0) / 255.0)

    def cmd_M107(self, gcmd: GCodeCommand) -> None:
        gcmd.get("P", None)
        self.set_speed(0.0)


def load_config(section: ConfigSection, printer) -> Fan:
    fan = PrinterFan(printer, "fan", *read_fan_options(section))
    printer.gcode.register_command("M106", fan.cmd_M106, desc="Set the part fan speed: M106 S<0-255>")
    printer.gcode.register_command("M107", fan.cmd_M107, desc="Turn the part fan off")
    printer.register_event_handler("printer:shutdown", lambda: fan.set_speed(0.0))
    return fan
