"""`[heater_bed]`: the bed heater on the virtual printer's first-order model (M140/M190, status `heater_bed`)."""

from __future__ import annotations

from tapcell.host.config import ConfigSection
from tapcell.host.heaters import Heater, lookup_heaters, read_heater_options, temperature_commands


def load_config(section: ConfigSection, printer) -> Heater:
    heater = Heater(printer, "heater_bed", read_heater_options(section))
    lookup_heaters(printer).add_heater(heater)
    temperature_commands(heater, "M140", "M190", printer)
    return heater
