"""`[controller_fan NAME]`: on while the steppers are enabled (axes homed) or a heater is on."""

from __future__ import annotations

from tapcell.extras.fan import Fan, read_fan_options
from tapcell.extras.heater_fan import read_heater_names
from tapcell.host.config import ConfigSection


class ControllerFan(Fan):
    def __init__(self, printer, name: str, max_power: float, off_below: float, heater_names: list[str],
                 fan_speed: float, idle_speed: float):
        super().__init__(printer, name, max_power, off_below)
        self.heater_names = heater_names
        self.fan_speed = fan_speed
        self.idle_speed = idle_speed

    def get_status(self, eventtime=None) -> dict:
        heaters = self.printer.lookup_object("heaters").heaters
        motors_on = bool(self.printer.lookup_object("toolhead").homed_axes)
        heating = any(heaters[name].target_c for name in self.heater_names)
        self.set_speed(self.fan_speed if motors_on or heating else 0.0)
        return super().get_status(eventtime)


def load_config_prefix(section: ConfigSection, printer) -> ControllerFan:
    max_power, off_below = read_fan_options(section)
    fan_speed = section.getfloat("fan_speed", 1.0, minval=0.0, maxval=1.0)
    idle_speed = section.getfloat("idle_speed", fan_speed, minval=0.0, maxval=1.0)
    section.getint("idle_timeout", 30, minval=0)
    section.getlist("stepper", None)
    for heater_section in ("extruder", "heater_bed"):
        printer.load_object(heater_section)
    return ControllerFan(printer, section.get_name(), max_power, off_below,
                         read_heater_names(section, "extruder", printer), fan_speed, idle_speed)
