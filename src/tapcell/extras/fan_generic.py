"""`[fan_generic NAME]`: a fan set by SET_FAN_SPEED FAN=NAME SPEED=0..1."""

from __future__ import annotations

from tapcell.extras.fan import Fan, read_fan_options
from tapcell.host.config import ConfigSection


def load_config_prefix(section: ConfigSection, printer) -> Fan:
    fan = Fan(printer, section.get_name(), *read_fan_options(section))

    def cmd_set_fan_speed(gcmd) -> None:
        fan.set_speed(gcmd.get_float("SPEED", 0.0, minval=0.0, maxval=1.0))

    printer.gcode.register_mux_command("SET_FAN_SPEED", "FAN", section.get_instance_name(), cmd_set_fan_speed,
                                       desc="Set a [fan_generic] speed: FAN=name SPEED=0..1")
    return fan
