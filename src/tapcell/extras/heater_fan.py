"""`[heater_fan NAME]`: on at fan_speed while its heaters are at or above heater_temp (a hotend fan)."""

from __future__ import annotations

from tapcell.extras.fan import Fan, read_fan_options
from tapcell.host.config import ConfigSection
from tapcell.host.limits import TEMPERATURE_RANGE


class HeaterFan(Fan):
    """A fan that runs at fan_speed while `is_on()` says so (checked whenever its status is read)."""

    def __init__(self, printer, name: str, max_power: float, off_below: float, heater_names: list[str],
                 fan_speed: float, heater_temp_c: float = 50.0):
        super().__init__(printer, name, max_power, off_below)
        self.heater_names = heater_names
        self.fan_speed = fan_speed
        self.heater_temp_c = heater_temp_c

    def heaters(self) -> list:
        known = self.printer.lookup_object("heaters").heaters
        return [known[name] for name in self.heater_names]

    def is_on(self) -> bool:
        return any(heater.target_c or heater.temperature_c() >= self.heater_temp_c for heater in self.heaters())

    def get_status(self, eventtime=None) -> dict:
        self.set_speed(self.fan_speed if self.is_on() else 0.0)
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
                     fan_speed=section.getfloat("fan_speed", 1.0, minval=0.0, maxval=1.0),
                     heater_temp_c=section.getfloat("heater_temp", 50.0, **TEMPERATURE_RANGE))
