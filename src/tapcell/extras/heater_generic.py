"""`[heater_generic NAME]`: another heater (a chamber, ...) on the virtual printer's first-order model.

Set with SET_HEATER_TEMPERATURE HEATER=NAME TARGET=, waited for with TEMPERATURE_WAIT.
"""

from __future__ import annotations

from tapcell.host.config import ConfigSection
from tapcell.host.heaters import Heater, lookup_heaters, read_heater_options


def load_config_prefix(section: ConfigSection, printer) -> Heater:
    section.get("gcode_id", None)
    heater = Heater(printer, section.get_name(), read_heater_options(section))
    lookup_heaters(printer).add_heater(heater)
    return heater
