"""`[temperature_sensor NAME]`: a sensor that reads the virtual printer's room temperature."""

from __future__ import annotations

from tapcell.host.config import ConfigSection
from tapcell.host.heaters import TemperatureSensor, lookup_heaters, read_sensor_options, read_temperature_limits


def load_config_prefix(section: ConfigSection, printer) -> TemperatureSensor:
    read_sensor_options(section)
    section.get("gcode_id", None)
    min_temp, max_temp = read_temperature_limits(section)
    sensor = TemperatureSensor(printer, section.get_name(), min_temp, max_temp)
    lookup_heaters(printer).add_sensor(section.get_name(), sensor)
    return sensor
