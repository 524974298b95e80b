"""`[extruder]`: the nozzle heater and the E axis (status `extruder`, M104/M109, SET_PRESSURE_ADVANCE).

The virtual printer has a nozzle heater (its temperature also lengthens the nozzle, which
probing sees) but no filament: E moves are checked as Klipper checks them (cold extrusion,
extrude-only distance, cross section) and take their time, and nothing is extruded.

Without an [extruder] section the printer still has its nozzle heater (0..300 °C, the
defaults below), so M104/M109 work on the bare example config.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from tapcell.host.config import ConfigSection
from tapcell.host.gcode import GCodeCommand, GCodeError
from tapcell.host.heaters import Heater, HeaterOptions, lookup_heaters, read_heater_options, temperature_commands
from tapcell.host.limits import (
    ACCEL_RANGE,
    MAX_COORDINATE_MM,
    MAX_FULL_STEPS_PER_ROTATION,
    MAX_ROTATION_DISTANCE_MM,
    MICROSTEPS,
    SPEED_RANGE,
    TEMPERATURE_RANGE,
)

# The nozzle heater when there is no [extruder] section.
DEFAULT_HEATER = HeaterOptions(sensor_type="virtual", min_temp_c=0.0, max_temp_c=300.0, control="pid",
                               max_power=1.0)
DEFAULT_NOZZLE_DIAMETER_MM = 0.4
DEFAULT_FILAMENT_DIAMETER_MM = 1.75


@dataclass(frozen=True)
class ExtruderOptions:
    nozzle_diameter_mm: float = DEFAULT_NOZZLE_DIAMETER_MM
    filament_diameter_mm: float = DEFAULT_FILAMENT_DIAMETER_MM
    min_extrude_temp_c: float = 170.0
    max_extrude_only_distance_mm: float = 50.0
    max_extrude_only_velocity_mm_s: float | None = None  # None: from max_velocity and the filament
    max_extrude_cross_section_mm2: float | None = None  # None: 4 x nozzle_diameter squared
    pressure_advance: float = 0.0
    pressure_advance_smooth_time_s: float = 0.040

    @property
    def filament_area_mm2(self) -> float:
        return math.pi * (self.filament_diameter_mm / 2.0) ** 2


def read_extruder_options(section: ConfigSection) -> ExtruderOptions:
    for pin in ("step_pin", "dir_pin"):
        section.get(pin)
    section.get("enable_pin", None)
    section.getfloat("rotation_distance", above=0.0, maxval=MAX_ROTATION_DISTANCE_MM)
    section.getchoice("microsteps", list(MICROSTEPS))
    section.getint("full_steps_per_rotation", 200, minval=1, maxval=MAX_FULL_STEPS_PER_ROTATION)
    section.get("gear_ratio", None)
    section.getfloat("step_pulse_duration", None, minval=0.0, maxval=0.001)
    section.getfloat("instantaneous_corner_velocity", 1.0, minval=0.0, maxval=SPEED_RANGE["maxval"])
    section.getfloat("max_extrude_only_accel", None, **ACCEL_RANGE)
    nozzle_mm = section.getfloat("nozzle_diameter", minval=0.01, maxval=10.0)
    filament_mm = section.getfloat("filament_diameter", minval=nozzle_mm, maxval=10.0)
    return ExtruderOptions(
        nozzle_diameter_mm=nozzle_mm,
        filament_diameter_mm=filament_mm,
        min_extrude_temp_c=section.getfloat("min_extrude_temp", 170.0, **TEMPERATURE_RANGE),
        max_extrude_only_distance_mm=section.getfloat("max_extrude_only_distance", 50.0, minval=0.0,
                                                      maxval=MAX_COORDINATE_MM),
        max_extrude_only_velocity_mm_s=section.getfloat("max_extrude_only_velocity", None, **SPEED_RANGE),
        max_extrude_cross_section_mm2=section.getfloat("max_extrude_cross_section", None, above=0.0, maxval=100.0),
        pressure_advance=section.getfloat("pressure_advance", 0.0, minval=0.0, maxval=10.0),
        pressure_advance_smooth_time_s=section.getfloat("pressure_advance_smooth_time", 0.040, above=0.0,
                                                        maxval=0.200),
    )


class Extruder:
    """The nozzle heater plus the E axis limits."""

    def __init__(self, heater: Heater, options: ExtruderOptions, max_velocity_mm_s: float):
        self.heater = heater
        self.options = options
        self.pressure_advance = options.pressure_advance
        self.smooth_time_s = options.pressure_advance_smooth_time_s
        cross_section = options.max_extrude_cross_section_mm2 or 4.0 * options.nozzle_diameter_mm ** 2
        self.max_extrude_ratio = cross_section / options.filament_area_mm2
        self.max_extrude_only_velocity_mm_s = (options.max_extrude_only_velocity_mm_s
                                               or max_velocity_mm_s * self.max_extrude_ratio)

    # the heater (kept under these names: z_thermal_adjust and the API read them)
    @property
    def min_temp_c(self) -> float:
        return self.heater.options.min_temp_c

    @property
    def max_temp_c(self) -> float:
        return self.heater.options.max_temp_c

    @property
    def target_c(self) -> float:
        return self.heater.target_c

    def can_extrude(self) -> bool:
        return self.heater.temperature_c() >= self.options.min_extrude_temp_c

    def check_move(self, xyz_distance_mm: float, e_distance_mm: float) -> None:
        """Klipper's extruder checks, in its words; raises GCodeError."""
        if not e_distance_mm:
            return
        if not self.can_extrude():
            raise GCodeError("Extrude below minimum temp\nSee the 'min_extrude_temp' config option for details")
        ratio = e_distance_mm / xyz_distance_mm if xyz_distance_mm else math.inf
        if not xyz_distance_mm or ratio < 0.0:  # extrude-only move or retraction
            if abs(e_distance_mm) > self.options.max_extrude_only_distance_mm:
                raise GCodeError(f"Extrude only move too long ({abs(e_distance_mm):.3f}mm vs "
                                 f"{self.options.max_extrude_only_distance_mm:.3f}mm)\n"
                                 "See the 'max_extrude_only_distance' config option for details")
            return
        if ratio > self.max_extrude_ratio and e_distance_mm > self.options.nozzle_diameter_mm * self.max_extrude_ratio:
            area = ratio * self.options.filament_area_mm2
            raise GCodeError(f"Move exceeds maximum extrusion ({area:.3f}mm^2 vs "
                             f"{self.max_extrude_ratio * self.options.filament_area_mm2:.3f}mm^2)\n"
                             "See the 'max_extrude_cross_section' config option for details")

    def cmd_SET_PRESSURE_ADVANCE(self, gcmd: GCodeCommand) -> None:
        gcmd.get("EXTRUDER", None)
        self.pressure_advance = gcmd.get_float("ADVANCE", self.pressure_advance, minval=0.0, maxval=10.0)
        self.smooth_time_s = gcmd.get_float("SMOOTH_TIME", self.smooth_time_s, minval=0.0, maxval=0.200)
        gcmd.respond_info(f"pressure_advance: {self.pressure_advance:.6f}\n"
                          f"pressure_advance_smooth_time: {self.smooth_time_s:.6f}")

    def get_status(self, eventtime=None) -> dict:
        return {**self.heater.get_status(eventtime), "can_extrude": self.can_extrude(),
                "pressure_advance": self.pressure_advance, "smooth_time": self.smooth_time_s,
                "min_temp": self.min_temp_c, "max_temp": self.max_temp_c, "motion_queue": None}


def load_extruder(config, printer, max_velocity_mm_s: float) -> Extruder:
    """The `extruder` object from [extruder] (or the bare nozzle heater), with its commands."""
    if config.has_section("extruder"):
        section = config.getsection("extruder")
        heater_options = read_heater_options(section)
        options = read_extruder_options(section)
    else:
        heater_options, options = DEFAULT_HEATER, ExtruderOptions()
    heater = Heater(printer, "extruder", heater_options)
    lookup_heaters(printer).add_heater(heater)
    extruder = Extruder(heater, options, max_velocity_mm_s)
    printer.add_object("extruder", extruder)
    temperature_commands(heater, "M104", "M109", printer)
    printer.gcode.register_command("SET_PRESSURE_ADVANCE", extruder.cmd_SET_PRESSURE_ADVANCE,
                                   desc="Set pressure advance: [ADVANCE=] [SMOOTH_TIME=] (kept, not modelled)")
    return extruder
