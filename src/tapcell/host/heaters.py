"""Heaters and temperature sensors: the host side of Klipper's `heaters` object.

A `Heater` is one named heater ("extruder", "heater_bed", "heater_generic chamber"): its
config options, its target, and its temperature read from the virtual printer's thermal
model (`backend.heater_temperature_c(name)`). `PrinterHeaters` (status object `heaters`)
knows every heater and sensor and owns the commands that are not tied to one heater:

    M105                                   report temperatures (`ok T:... B:...`)
    SET_HEATER_TEMPERATURE HEATER=name [TARGET=c]
    TEMPERATURE_WAIT SENSOR=name [MINIMUM=c] [MAXIMUM=c]

Waiting advances the virtual printer's clock, so an M190 takes minutes of simulated time
(and no real time). The wait ends within 1 °C of the target, as Klipper's PID control does.
"""

from __future__ import annotations

from dataclasses import dataclass

from tapcell.host.config import ConfigSection
from tapcell.host.gcode import GCodeCommand, GCodeError
from tapcell.host.limits import MAX_TEMP_C, SECONDS_RANGE, TEMPERATURE_RANGE

# A heater is at its target when within this many degrees (Klipper's PID settle delta).
SETTLE_DELTA_C = 1.0
CONTROLS = ("watermark", "pid")
# Options a heater's temperature sensor may have on a real printer (thermistor, RTD amplifier,
# thermocouple, MCU/host sensors): read and kept, not modelled.
SENSOR_TEXT_OPTIONS = ("sensor_pin", "sensor_mcu", "spi_bus", "spi_software_sclk_pin", "spi_software_mosi_pin",
                       "spi_software_miso_pin", "tc_type", "rtd_reference_r", "rtd_num_of_wires", "rtd_use_50Hz_filter",
                       "i2c_mcu", "i2c_bus", "i2c_address", "i2c_speed", "i2c_software_scl_pin",
                       "i2c_software_sda_pin")
SENSOR_NUMBER_OPTIONS = {"pullup_resistor": (0.0, 1e7), "inline_resistor": (0.0, 1e7), "spi_speed": (1.0, 1e9),
                         "tc_averaging_count": (1.0, 16.0), "rtd_nominal_r": (1.0, 1e5), "adc_voltage": (0.1, 50.0),
                         "voltage_offset": (-50.0, 50.0)}
PID_GAIN_RANGE = {"minval": 0.0, "maxval": 10_000.0}


@dataclass(frozen=True)
class HeaterOptions:
    sensor_type: str
    min_temp_c: float
    max_temp_c: float
    control: str
    max_power: float


def read_sensor_options(section: ConfigSection) -> str:
    """A temperature sensor's options (sensor_type and its wiring); returns sensor_type."""
    sensor_type = section.get("sensor_type")
    for option in SENSOR_TEXT_OPTIONS:
        section.get(option, None)
    for option, (low, high) in SENSOR_NUMBER_OPTIONS.items():
        section.getfloat(option, None, minval=low, maxval=high)
    return sensor_type


def read_temperature_limits(section: ConfigSection) -> tuple[float, float]:
    """min_temp and max_temp (required, as in Klipper)."""
    min_temp = section.getfloat("min_temp", **TEMPERATURE_RANGE)
    max_temp = section.getfloat("max_temp", above=min_temp, maxval=TEMPERATURE_RANGE["maxval"])
    return min_temp, max_temp


def read_heater_options(section: ConfigSection) -> HeaterOptions:
    """The options every Klipper heater has; control parameters are kept, not modelled."""
    section.get("heater_pin")
    sensor_type = read_sensor_options(section)
    max_power = section.getfloat("max_power", 1.0, above=0.0, maxval=1.0)
    section.getfloat("smooth_time", 1.0, **SECONDS_RANGE)
    section.getfloat("pwm_cycle_time", 0.1, above=0.0, maxval=1.0)
    min_temp, max_temp = read_temperature_limits(section)
    control = section.getchoice("control", list(CONTROLS), "pid")
    if control == "pid":
        for option in ("pid_kp", "pid_ki", "pid_kd"):
            section.getfloat(option, None, **PID_GAIN_RANGE)
    else:
        section.getfloat("max_delta", 2.0, above=0.0, maxval=MAX_TEMP_C)
    return HeaterOptions(sensor_type, min_temp, max_temp, control, max_power)


class Heater:
    """One heater of the virtual printer, by its Klipper name."""

    def __init__(self, printer, name: str, options: HeaterOptions):
        self.printer = printer
        self.name = name
        self.options = options
        self.target_c = 0.0

    @property
    def short_name(self) -> str:
        """'chamber' for 'heater_generic chamber' (the name SET_HEATER_TEMPERATURE takes)."""
        return self.name.split()[-1]

    def temperature_c(self) -> float:
        return self.printer.backend.heater_temperature_c(self.name)

    def set_temperature(self, target_c: float, gcmd: GCodeCommand | None = None) -> None:
        low, high = self.options.min_temp_c, self.options.max_temp_c
        if target_c and not low <= target_c <= high:
            problem = f"Requested temperature ({target_c:.1f}) out of range ({low:.1f}:{high:.1f})"
            raise gcmd.param_error(problem) if gcmd else GCodeError(problem)
        self.target_c = float(target_c)
        self.printer.backend.set_heater_temperature(self.name, self.target_c)

    def wait(self, gcmd: GCodeCommand) -> None:
        """Let the virtual printer's time pass until the heater is at its target."""
        if not self.target_c:
            return
        waited_s = self.printer.backend.wait_for_heater(self.name, SETTLE_DELTA_C)
        gcmd.respond_info(f"{self.name}: {self.temperature_c():.1f}C, target {self.target_c:g}C "
                          f"(waited {waited_s:.1f} s of printer time)")

    def power(self) -> float:
        """A stand-in for the PWM duty: full while heating, the holding share once there."""
        if not self.target_c:
            return 0.0
        temperature = self.temperature_c()
        if self.target_c - temperature > SETTLE_DELTA_C:
            return self.options.max_power
        room = self.printer.backend.room_temperature_c
        if self.options.max_temp_c <= room:
            return self.options.max_power
        return round(min(self.options.max_power, max(0.0, (temperature - room) / (self.options.max_temp_c - room))), 3)

    def get_status(self, eventtime=None) -> dict:
        return {"temperature": round(self.temperature_c(), 2), "target": self.target_c, "power": self.power()}


class TemperatureSensor:
    """A [temperature_sensor NAME]: reads the room temperature of the virtual printer."""

    def __init__(self, printer, name: str, min_temp_c: float, max_temp_c: float):
        self.printer = printer
        self.name = name
        self.min_temp_c = min_temp_c
        self.max_temp_c = max_temp_c
        self.measured_min_c: float | None = None
        self.measured_max_c: float | None = None

    def temperature_c(self) -> float:
        temperature = self.printer.backend.room_temperature_c
        self.measured_min_c = temperature if self.measured_min_c is None else min(self.measured_min_c, temperature)
        self.measured_max_c = temperature if self.measured_max_c is None else max(self.measured_max_c, temperature)
        return temperature

    def get_status(self, eventtime=None) -> dict:
        temperature = self.temperature_c()
        return {"temperature": round(temperature, 2), "measured_min_temp": round(self.measured_min_c, 2),
                "measured_max_temp": round(self.measured_max_c, 2)}


class PrinterHeaters:
    """Every heater and sensor (status `heaters`) and the commands across them."""

    def __init__(self, printer):
        self.printer = printer
        self.heaters: dict[str, Heater] = {}
        self.sensors: dict[str, object] = {}  # name -> Heater or TemperatureSensor

    def add_heater(self, heater: Heater) -> None:
        self.heaters[heater.name] = heater
        self.sensors[heater.name] = heater

    def add_sensor(self, name: str, sensor) -> None:
        self.sensors[name] = sensor

    def get_status(self, eventtime=None) -> dict:
        return {"available_heaters": list(self.heaters), "available_sensors": list(self.sensors),
                "available_monitors": []}

    def _heater_by_short_name(self, gcmd: GCodeCommand, option: str) -> Heater | object:
        wanted = gcmd.get(option)
        pool = self.heaters if option == "HEATER" else self.sensors
        for name, heater in pool.items():
            if wanted in (name, name.split()[-1]):
                return heater
        known = ", ".join(name.split()[-1] for name in pool) or "none"
        raise gcmd.param_error(f"unknown {option.lower()} '{wanted}' (one of: {known})")

    def cmd_M105(self, gcmd: GCodeCommand) -> None:
        letters = {"extruder": "T0", "heater_bed": "B"}
        parts = [f"{letters.get(name, name.split()[-1])}:{heater.temperature_c():.1f} /{heater.target_c:.1f}"
                 for name, heater in self.heaters.items()]
        gcmd.respond_raw("ok " + " ".join(parts) if parts else "ok T:0")

    def cmd_SET_HEATER_TEMPERATURE(self, gcmd: GCodeCommand) -> None:
        heater = self._heater_by_short_name(gcmd, "HEATER")
        heater.set_temperature(gcmd.get_float("TARGET", 0.0, **TEMPERATURE_RANGE), gcmd)

    def turn_off_heaters(self) -> None:
        for heater in self.heaters.values():
            heater.set_temperature(0.0)

    def cmd_TURN_OFF_HEATERS(self, gcmd: GCodeCommand) -> None:
        self.turn_off_heaters()

    def cmd_TEMPERATURE_WAIT(self, gcmd: GCodeCommand) -> None:
        sensor = self._heater_by_short_name(gcmd, "SENSOR")
        minimum_c = gcmd.get_float("MINIMUM", None, **TEMPERATURE_RANGE)
        maximum_c = gcmd.get_float("MAXIMUM", None, minval=TEMPERATURE_RANGE["minval"] if minimum_c is None
                                   else minimum_c, maxval=MAX_TEMP_C)
        if minimum_c is None and maximum_c is None:
            raise gcmd.param_error("give MINIMUM and/or MAXIMUM")
        temperature = sensor.temperature_c()
        if (minimum_c is None or temperature >= minimum_c) and (maximum_c is None or temperature <= maximum_c):
            return
        goal_c = minimum_c if minimum_c is not None and temperature < minimum_c else maximum_c
        if not isinstance(sensor, Heater):
            raise gcmd.param_error(f"{sensor.name} stays at {temperature:.1f}C on the virtual printer (room "
                                   f"temperature) and never reaches {goal_c:g}C")
        backend = self.printer.backend
        heading_c = max(sensor.target_c, backend.room_temperature_c)  # a heater cannot cool below the room
        if abs(heading_c - temperature) < abs(goal_c - temperature) or (heading_c - temperature) * (goal_c - temperature) < 0:
            raise gcmd.param_error(f"{sensor.name} is heading for {heading_c:.1f}C and never reaches {goal_c:g}C")
        # The approach crosses the goal when the heater is |heading - goal| from where it heads.
        backend.wait_for_heater(sensor.name, abs(heading_c - goal_c) or SETTLE_DELTA_C)


def lookup_heaters(printer) -> PrinterHeaters:
    """The printer's `heaters` object, made (with its commands) by the first heater that needs it."""
    heaters = printer.lookup_object("heaters", None)
    if heaters is None:
        heaters = PrinterHeaters(printer)
        printer.add_object("heaters", heaters)
        gcode = printer.gcode
        gcode.register_command("M105", heaters.cmd_M105, desc="Report the temperatures")
        gcode.register_command("SET_HEATER_TEMPERATURE", heaters.cmd_SET_HEATER_TEMPERATURE,
                               desc="Set a heater's target: HEATER=name [TARGET=celsius]")
        gcode.register_command("TEMPERATURE_WAIT", heaters.cmd_TEMPERATURE_WAIT,
                               desc="Wait for a sensor: SENSOR=name [MINIMUM=celsius] [MAXIMUM=celsius]")
        gcode.register_command("TURN_OFF_HEATERS", heaters.cmd_TURN_OFF_HEATERS, desc="Turn off all heaters")
    return heaters


def temperature_commands(heater: Heater, set_name: str, wait_name: str, printer) -> None:
    """M104/M109-style commands for one heater: `set_name S<c>` and `wait_name S<c>` (sets, then waits)."""

    def set_temperature(gcmd: GCodeCommand) -> None:
        gcmd.get_int("T", None, minval=0, maxval=0)  # the tool: the virtual printer has one
        heater.set_temperature(gcmd.get_float("S", 0.0, minval=0.0, maxval=MAX_TEMP_C), gcmd)

    def set_and_wait(gcmd: GCodeCommand) -> None:
        set_temperature(gcmd)
        heater.wait(gcmd)

    printer.gcode.register_command(set_name, set_temperature,
                                   desc=f"Set the {heater.name} temperature: {set_name} S<celsius>")
    printer.gcode.register_command(wait_name, set_and_wait,
                                   desc=f"Set the {heater.name} temperature and wait: {wait_name} S<celsius>")
