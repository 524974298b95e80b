"""`[heater_fan NAME]`: on at fan_speed while its heaters are at or above heater_temp (a hotend fan)."""

from __future__ import annotations

from tapcell.extras.fan import Fan, read_fan_options
from tapcell.host.config import ConfigSection


class HeaterFan(Fan):
    def __init__(self, printer, name: str, max_power: float, off_below: float, heater_names: list[str],
                 heater_temp_c: float, fan_speed: float):
        super().__init__(printer, name, max_power, off_below)
        self.heater_names = heater_names
        self.heater_temp_c = heater_temp_c
        self.fan_speed = fan_speed

    def get_status(self, eventtime=None) -> dict:
        heaters = self.printer.lookup_object("heaters").heaters
        hot = any(heaters[name].target_c or heaters[name].temperature_c() >= self.heater_temp_c
                  for name in self.heater_names)
        self.set_speed(self.fan_speed if hot else 0.0)
        return super().get_status(eventtime)


def read_heater_names(section: ConfigSection, default: str, printer) -> list[str]:
    names = section.getlist("heater", [default])
    known = printer.lookup_object("heaters").heaters
    for name in names:
        if name not in known:
            raise section.error("heater", f"unknown heater '{name}' (one of: {', '.join(known)})")
    return names


def load_config_prefix(section: ConfigSection, printer) -> HeaterFan:
    max_power, off_below = read_fan_options(section)
    for heater_section in ("extruder", "heater_bed"):  # the heaters a fan may name must exist first
        printer.load_object(heater_section)
    return HeaterFan(printer, section.get_name(), max_power, off_below,
                     read_heater_names(section, "extruder", printer),
                     section.getfloat("heater_temp", 50.0), section.getfloat("fan_speed", 1.0, minval=0.0, maxval=1.0))
