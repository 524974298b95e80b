"""`[controller_fan NAME]`: on while the steppers are enabled (axes homed) or one of its heaters is on."""

from __future__ import annotations

from tapcell.extras.fan import read_fan_options
from tapcell.extras.heater_fan import HeaterFan, read_heater_names
from tapcell.host.config import ConfigSection


class ControllerFan(HeaterFan):
    def is_on(self) -> bool:
        motors_on = bool(self.printer.lookup_object("toolhead").homed_axes)
        return motors_on or any(heater.target_c for heater in self.heaters())


def load_config_prefix(section: ConfigSection, printer) -> ControllerFan:
    max_power, off_below = read_fan_options(section)
    fan_speed = section.getfloat("fan_speed", 1.0, minval=0.0, maxval=1.0)
    section.getfloat("idle_speed", fan_speed, minval=0.0, maxval=1.0)  # kept: the idle timeout is not modelled
    section.getint("idle_timeout", 30, minval=0, maxval=86_400)
    section.getlist("stepper", None)
    for heater_section in ("extruder", "heater_bed"):
        printer.load_object(heater_section)
    return ControllerFan(printer, section.get_name(), max_power, off_below,
                         read_heater_names(section, "extruder", printer), fan_speed)
