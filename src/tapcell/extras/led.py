"""`[led NAME]` (and `[neopixel NAME]`, `[dotstar NAME]`, `[pca9533 NAME]`, `[pca9632 NAME]`):
SET_LED and the `color_data` status Mainsail's and Fluidd's LED panels read.

The virtual printer has no LEDs to light: the colour of every LED of the chain is kept and shown
in the status, as Klipper reports it (`color_data`: one [red, green, blue, white] per LED, 0..1).
The wiring options (pins, I2C, colour order) are taken as written. SET_LED LED=<name> [RED=]
[GREEN=] [BLUE=] [WHITE=] [INDEX=] [TRANSMIT=] [SYNC=]; without INDEX every LED of the chain.
"""

from __future__ import annotations

from tapcell.host.config import ConfigSection
from tapcell.host.gcode import GCodeCommand
from tapcell.host.limits import SHARE_RANGE

CHANNELS = ("RED", "GREEN", "BLUE", "WHITE")
MAX_CHAIN = 1024


class Leds:
    def __init__(self, name: str, chain_count: int, initial: list[float]):
        self.name = name
        self.color_data = [list(initial) for _ in range(chain_count)]

    def cmd_SET_LED(self, gcmd: GCodeCommand) -> None:
        color = [gcmd.get_float(channel, 0.0, **SHARE_RANGE) for channel in CHANNELS]
        index = gcmd.get_int("INDEX", None, minval=1, maxval=len(self.color_data))
        gcmd.get_int("TRANSMIT", 1, minval=0, maxval=1)  # always shown at once: there is no strip to update
        gcmd.get_int("SYNC", 1, minval=0, maxval=1)
        for led in range(len(self.color_data)) if index is None else [index - 1]:
            self.color_data[led] = list(color)

    def get_status(self, eventtime=None) -> dict:
        return {"color_data": [list(color) for color in self.color_data]}


def load_config_prefix(section: ConfigSection, printer) -> Leds:
    has_chain = section.get_prefix() in ("neopixel", "dotstar")
    chain_count = section.getint("chain_count", 1, minval=1, maxval=MAX_CHAIN) if has_chain else 1
    initial = [section.getfloat(f"initial_{channel}", 0.0, **SHARE_RANGE) for channel in CHANNELS]
    section.config.mark_section_read(section.get_name())  # pins, colour order, I2C: nothing to drive
    leds = Leds(section.get_name(), chain_count, initial)
    printer.gcode.register_mux_command("SET_LED", "LED", section.get_instance_name(), leds.cmd_SET_LED,
                                       desc="Set the colour of an LED: LED=<name> [RED=] [GREEN=] [BLUE=] "
                                            "[WHITE=] [INDEX=]")
    return leds
