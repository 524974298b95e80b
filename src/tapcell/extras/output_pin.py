"""`[output_pin NAME]`: a pin set by SET_PIN PIN=NAME VALUE=; the value is recorded on the virtual printer."""

from __future__ import annotations

from tapcell.host.config import ConfigSection
from tapcell.host.gcode import GCodeCommand
from tapcell.host.limits import SECONDS_RANGE


class OutputPin:
    def __init__(self, printer, name: str, pwm: bool, scale: float, value: float):
        self.printer = printer
        self.name = name
        self.pwm = pwm
        self.scale = scale
        self.value = 0.0
        self.set_value(value)

    def set_value(self, value: float) -> None:
        self.value = value / self.scale
        self.printer.backend.set_output(self.name, self.value)

    def cmd_SET_PIN(self, gcmd: GCodeCommand) -> None:
        value = gcmd.get_float("VALUE", minval=0.0, maxval=self.scale)
        gcmd.get_float("CYCLE_TIME", None, **SECONDS_RANGE)
        if not self.pwm and value not in (0.0, self.scale):
            raise gcmd.param_error(f"Invalid pin value (pin '{self.name}' is not "
                             "pwm: VALUE must be 0 or 1)")
        self.set_value(value)

    def get_status(self, eventtime=None) -> dict:
        return {"value": self.value}


def load_config_prefix(section: ConfigSection, printer) -> OutputPin:
    section.get("pin")
    pwm = section.getboolean("pwm", False)
    scale = section.getfloat("scale", 1.0, above=0.0, maxval=1e6)
    value = section.getfloat("value", 0.0, minval=0.0, maxval=scale)
    section.getfloat("shutdown_value", 0.0, minval=0.0, maxval=scale)
    section.getfloat("cycle_time", 0.100, **SECONDS_RANGE)
    section.getboolean("hardware_pwm", False)
    section.getfloat("maximum_mcu_duration", 0.0, minval=0.0, maxval=5.0)
    pin = OutputPin(printer, section.get_name(), pwm, scale, value)
    printer.gcode.register_mux_command("SET_PIN", "PIN", section.get_instance_name(), pin.cmd_SET_PIN,
                                       desc="Set an [output_pin]: PIN=name VALUE=")
    return pin
