"""`[z_thermal_adjust]`: move Z to compensate thermal growth, here the nozzle's.

The temperature is smoothed with a first-order filter of time constant `smooth_time`:
each reading moves the smoothed value toward it by min(dt / smooth_time, 1) of the gap.
At Z homing the smoothed temperature becomes the reference; afterwards

    adjustment = -temp_coeff * (smoothed - reference), clamped to +/- max_z_adjustment

is added to the toolhead Z. A positive coefficient moves the nozzle down as the
temperature rises; the guide's nozzle coefficient is negative (it lifts the nozzle away
from the bed as it grows). Above `z_adjust_off_above` the last adjustment is held.

The coefficient is measured with PROBE_ACCURACY at two nozzle temperatures:
temp_coeff = (z_hot - z_cold) / (T_hot - T_cold).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from tapcell.mesh.errors import MeshError, MeshOptionError

SECTION = "z_thermal_adjust"
UNLIMITED_MM = 99999999.0


@dataclass(frozen=True)
class ThermalAdjustSettings:
    """The `[z_thermal_adjust]` options (the sensor itself is configured elsewhere)."""

    temp_coeff_mm_per_c: float = 0.0
    smooth_time_s: float = 2.0
    z_adjust_off_above_mm: float = UNLIMITED_MM
    max_z_adjustment_mm: float = UNLIMITED_MM
    min_temp_c: float = 0.0
    max_temp_c: float = 400.0

    def __post_init__(self) -> None:
        if not math.isfinite(self.temp_coeff_mm_per_c):
            raise MeshOptionError(SECTION, "temp_coeff", self.temp_coeff_mm_per_c, "must be a number (mm per degC)")
        if not (math.isfinite(self.smooth_time_s) and self.smooth_time_s > 0):
            raise MeshOptionError(SECTION, "smooth_time", self.smooth_time_s, "must be a positive number of seconds")
        if not (math.isfinite(self.max_z_adjustment_mm) and self.max_z_adjustment_mm >= 0):
            raise MeshOptionError(SECTION, "max_z_adjustment", self.max_z_adjustment_mm, "must be 0 or more mm")
        if not math.isfinite(self.z_adjust_off_above_mm):
            raise MeshOptionError(SECTION, "z_adjust_off_above", self.z_adjust_off_above_mm, "must be a number of mm")
        if not (math.isfinite(self.min_temp_c) and math.isfinite(self.max_temp_c) and self.max_temp_c > self.min_temp_c):
            raise MeshOptionError(SECTION, "max_temp", self.max_temp_c, f"must be greater than min_temp ({self.min_temp_c})")


def smooth_temperature_c(smoothed_c: float, reading_c: float, dt_s: float, smooth_time_s: float) -> float:
    """One step of the smoothing filter: move toward the reading by min(dt / smooth_time, 1)."""
    step = min(max(dt_s, 0.0) / smooth_time_s, 1.0)
    return smoothed_c + (reading_c - smoothed_c) * step


def z_adjustment_mm(smoothed_c: float, reference_c: float, temp_coeff_mm_per_c: float, max_z_adjustment_mm: float) -> float:
    """The Z added to the toolhead: -coeff * (T - T_ref), clamped to +/- max_z_adjustment."""
    adjustment = -temp_coeff_mm_per_c * (smoothed_c - reference_c)
    return max(-max_z_adjustment_mm, min(max_z_adjustment_mm, adjustment))


def measure_temp_coeff(z_cold_mm: float, t_cold_c: float, z_hot_mm: float, t_hot_c: float) -> float:
    """temp_coeff from PROBE_ACCURACY averages at two nozzle temperatures (the guide's formula)."""
    for name, value in (("z_cold", z_cold_mm), ("t_cold", t_cold_c), ("z_hot", z_hot_mm), ("t_hot", t_hot_c)):
        if not math.isfinite(value):
            raise MeshError(f"temp_coeff measurement: {name} = {value} is not a number")
    if abs(t_hot_c - t_cold_c) < 1.0:
        raise MeshError(
            f"temp_coeff measurement: the two temperatures ({t_cold_c} and {t_hot_c} degC) must differ by at least "
            "1 degC; the guide uses 180 and 290"
        )
    return (z_hot_mm - z_cold_mm) / (t_hot_c - t_cold_c)


class ZThermalAdjust:
    """The running state: smoothed temperature, reference, and the applied adjustment."""

    def __init__(self, settings: ThermalAdjustSettings) -> None:
        self.settings = settings
        self.enabled = True
        self.smoothed_c: float | None = None
        self.last_reading_time_s = 0.0
        self.measured_min_c = math.inf
        self.measured_max_c = -math.inf
        self.reference_c: float | None = None
        self.applied_mm = 0.0

    def on_temperature(self, time_s: float, reading_c: float) -> None:
        """Feed one sensor reading; readings outside min_temp..max_temp are a fault."""
        low, high = self.settings.min_temp_c, self.settings.max_temp_c
        if not (math.isfinite(reading_c) and low <= reading_c <= high):
            raise MeshError(
                f"[{SECTION}] temperature {reading_c} degC is outside min_temp {low} .. max_temp {high}: check the sensor"
            )
        if self.smoothed_c is None:
            self.smoothed_c = reading_c
        else:
            dt_s = time_s - self.last_reading_time_s
            self.smoothed_c = smooth_temperature_c(self.smoothed_c, reading_c, dt_s, self.settings.smooth_time_s)
        self.last_reading_time_s = time_s
        self.measured_min_c = min(self.measured_min_c, reading_c)
        self.measured_max_c = max(self.measured_max_c, reading_c)

    def on_z_homed(self) -> None:
        """Z was homed at the current temperature: that temperature needs no adjustment."""
        if self.smoothed_c is None:
            raise MeshError(f"[{SECTION}] no temperature reading yet: cannot take the reference at homing")
        self.reference_c = self.smoothed_c
        self.applied_mm = 0.0

    def adjusted_z_mm(self, z_mm: float) -> float:
        """The toolhead Z for G-code Z; unchanged until homed or while disabled."""
        if not self.enabled or self.reference_c is None or self.smoothed_c is None:
            return z_mm
        if z_mm <= self.settings.z_adjust_off_above_mm:
            self.applied_mm = z_adjustment_mm(
                self.smoothed_c, self.reference_c, self.settings.temp_coeff_mm_per_c, self.settings.max_z_adjustment_mm
            )
        return z_mm + self.applied_mm

    def to_status(self) -> dict:
        return {
            "temperature": self.smoothed_c,
            "measured_min_temp": None if self.smoothed_c is None else self.measured_min_c,
            "measured_max_temp": None if self.smoothed_c is None else self.measured_max_c,
            "current_z_adjust": self.applied_mm,
            "z_adjust_ref_temperature": self.reference_c,
            "enabled": self.enabled,
        }
