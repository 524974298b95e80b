"""`[z_thermal_adjust]`: keep the first layer right while the nozzle grows with temperature.

Probing happens with a cool nozzle (no ooze); printing is hotter, and a hot nozzle is longer.
This module is a move transform of the toolhead: every G-code move gets

    adjustment = -temp_coeff * (T - T_at_Z_homing), clamped to +/- max_z_adjustment

added to its Z (`tapcell.mesh.thermal`), with T the nozzle temperature smoothed over
`smooth_time`. The guide's coefficient is negative: the nozzle lengthens toward the bed, so
the toolhead is lifted. Above `z_adjust_off_above` the last adjustment is held.

The sensor: the virtual printer has one temperature, the nozzle's, so the sensor is written
as in the guide: `sensor_type: temperature_combined`, `sensor_list: extruder`.

Commands:
* `SET_Z_THERMAL_ADJUST [ENABLE=0|1] [TEMP_COEFF=] [REF_TEMP=]`
* `Z_THERMAL_CALIBRATE [TEMP_COLD=180] [TEMP_HOT=290] [SAMPLES=10]`: PROBE_ACCURACY at the
  current position at two nozzle temperatures, then the guide's
  temp_coeff = (z_hot - z_cold) / (T_hot - T_cold), where z is the height of the nozzle tip
  (minus the probed bed height: a longer nozzle touches the bed earlier). The result is
  applied at once and queued for SAVE_CONFIG.
"""

from __future__ import annotations

from dataclasses import replace

from tapcell.host.config import ConfigSection
from tapcell.host.gcode import GCodeCommand, GCodeError
from tapcell.mesh.errors import MeshError, MeshOptionError
from tapcell.mesh.thermal import UNLIMITED_MM, ThermalAdjustSettings, ZThermalAdjust, measure_temp_coeff
from tapcell.extras.probe.options import MAX_SAMPLES
from tapcell.host.limits import ABSOLUTE_ZERO_C, MAX_COORDINATE_MM, MAX_TEMP_C

SECTION = "z_thermal_adjust"
COMBINED_SENSOR = "temperature_combined"
COMBINATION_METHODS = ("max", "min", "mean")
VIRTUAL_SENSORS = ("extruder",)
MAX_SMOOTH_TIME_S = 600.0


def read_settings(section: ConfigSection) -> ThermalAdjustSettings:
    """The options of `[z_thermal_adjust]` (or `[z_thermal_adjust NAME]`)."""
    sensor_type = section.get("sensor_type").strip()
    if sensor_type != COMBINED_SENSOR:
        raise section.error("sensor_type", f"the virtual printer has only the nozzle temperature: use "
                                           f"sensor_type: {COMBINED_SENSOR} with sensor_list: extruder")
    sensors = [name.strip() for name in section.getlist("sensor_list")]
    unknown = [name for name in sensors if name not in VIRTUAL_SENSORS]
    if unknown or not sensors:
        raise section.error("sensor_list", f"must list temperature sensors of the virtual printer "
                                           f"(one of: {', '.join(VIRTUAL_SENSORS)})")
    section.getchoice("combination_method", list(COMBINATION_METHODS), "max")
    section.getfloat("maximum_deviation", None, above=0.0, maxval=MAX_TEMP_C)
    section.get("gcode_id", None)
    min_temp = section.getfloat("min_temp", minval=ABSOLUTE_ZERO_C, maxval=MAX_TEMP_C)
    max_temp = section.getfloat("max_temp", above=min_temp, maxval=MAX_TEMP_C)
    try:
        return ThermalAdjustSettings(
            temp_coeff_mm_per_c=section.getfloat("temp_coeff", 0.0, minval=-1.0, maxval=1.0),
            smooth_time_s=section.getfloat("smooth_time", 2.0, above=0.0, maxval=MAX_SMOOTH_TIME_S),
            z_adjust_off_above_mm=section.getfloat("z_adjust_off_above", UNLIMITED_MM, minval=-MAX_COORDINATE_MM,
                                                   maxval=UNLIMITED_MM),
            max_z_adjustment_mm=section.getfloat("max_z_adjustment", UNLIMITED_MM, minval=0.0, maxval=UNLIMITED_MM),
            min_temp_c=min_temp,
            max_temp_c=max_temp,
        )
    except MeshOptionError as exc:
        raise section.error(exc.option, exc.allowed) from None


class ZThermalAdjuster:
    """The `[z_thermal_adjust]` object: move transform, commands, status."""

    def __init__(self, section: ConfigSection, printer):
        self.printer = printer
        self.section_name = section.get_name()
        self.state = ZThermalAdjust(read_settings(section))
        self.backend = printer.backend
        self.toolhead = printer.lookup_object("toolhead")
        self.next_target = self.toolhead.set_move_transform(self)
        printer.register_event_handler("toolhead:z_homed", self._on_z_homed)
        gcode = printer.gcode
        gcode.register_command("SET_Z_THERMAL_ADJUST", self.cmd_SET_Z_THERMAL_ADJUST,
                               desc="Thermal Z adjustment: [ENABLE=0|1] [TEMP_COEFF=] [REF_TEMP=]")
        gcode.register_command("Z_THERMAL_CALIBRATE", self.cmd_Z_THERMAL_CALIBRATE,
                               desc="Measure temp_coeff: PROBE_ACCURACY at TEMP_COLD= and TEMP_HOT= [SAMPLES=]")

    def _read_temperature(self) -> None:
        try:
            self.state.on_temperature(self.backend.now_s, float(self.backend.nozzle_temperature_c))
        except MeshError as exc:
            raise GCodeError(str(exc)) from None

    def _on_z_homed(self) -> None:
        self._read_temperature()
        self.state.on_z_homed()

    # -- the move transform -------------------------------------------------------------
    def get_position(self) -> tuple[float, float, float]:
        x, y, z = self.next_target.get_position()
        return (x, y, z - self.state.applied_mm)

    def move(self, position_xyz, speed_mm_s: float) -> None:
        self._read_temperature()
        x, y, z = position_xyz
        self.next_target.move((x, y, self.state.adjusted_z_mm(z)), speed_mm_s)

    # -- commands -------------------------------------------------------------------------
    def cmd_SET_Z_THERMAL_ADJUST(self, gcmd: GCodeCommand) -> None:
        enable = gcmd.get_int("ENABLE", None, minval=0, maxval=1)
        coeff = gcmd.get_float("TEMP_COEFF", None, minval=-1.0, maxval=1.0)
        reference = gcmd.get_float("REF_TEMP", None, minval=ABSOLUTE_ZERO_C, maxval=MAX_TEMP_C)
        state = self.state
        if enable is not None:
            state.enabled = bool(enable)
        if coeff is not None:
            state.settings = replace(state.settings, temp_coeff_mm_per_c=coeff)
        if reference is not None:
            state.reference_c = reference
        self._read_temperature()
        gcmd.respond_info(self.describe())

    def describe(self) -> str:
        state = self.state
        reference = "not set (home Z)" if state.reference_c is None else f"{state.reference_c:.2f} C"
        return (f"z_thermal_adjust: {'enabled' if state.enabled else 'disabled'}, "
                f"temp_coeff {state.settings.temp_coeff_mm_per_c:.8f} mm/C, reference {reference}, "
                f"temperature {state.smoothed_c:.2f} C, current adjustment {state.applied_mm * 1000:+.1f} um")

    def cmd_Z_THERMAL_CALIBRATE(self, gcmd: GCodeCommand) -> None:
        cold_c = gcmd.get_float("TEMP_COLD", 180.0, above=0.0, maxval=MAX_TEMP_C)
        hot_c = gcmd.get_float("TEMP_HOT", 290.0, above=0.0, maxval=MAX_TEMP_C)
        samples = gcmd.get_int("SAMPLES", 10, minval=2, maxval=MAX_SAMPLES)
        if hot_c - cold_c < 1.0:
            raise gcmd.param_error(f"TEMP_HOT ({hot_c:g}) must be above TEMP_COLD "
                                   f"({cold_c:g}); the guide uses 180 and 290")
        probe = self.printer.lookup_object("probe", None)
        if probe is None:
            raise gcmd.error("Z_THERMAL_CALIBRATE needs a probe: add a [load_cell_probe] section")
        gcode = self.printer.gcode
        bed_z = {}
        for temp_c in (cold_c, hot_c):
            gcmd.respond_info(f"Measuring the bed with the nozzle at {temp_c:g} C")
            # A nozzle this hot oozes: a fouled tap moves to a clean spot nearby (the guide's CIRCLE)
            # instead of failing the measurement.
            gcode.run_script(f"M109 S{temp_c:g}\nPROBE_ACCURACY SAMPLES={samples} BAD_PROBE_STRATEGY=circle")
            bed_z[temp_c] = probe.last_z_result
        # The nozzle tip's height is minus the probed bed height: a longer nozzle sees the bed higher.
        coeff = measure_temp_coeff(-bed_z[cold_c], cold_c, -bed_z[hot_c], hot_c)
        self.state.settings = replace(self.state.settings, temp_coeff_mm_per_c=coeff)
        self.printer.config.set(self.section_name, "temp_coeff", f"{coeff:.8f}")
        growth_um = (bed_z[hot_c] - bed_z[cold_c]) * 1000.0
        gcmd.respond_info(
            f"Bed seen at {bed_z[cold_c]:.6f} mm at {cold_c:g} C and {bed_z[hot_c]:.6f} mm at {hot_c:g} C: "
            f"the nozzle grew {growth_um:.1f} um\n"
            f"temp_coeff = {coeff:.8f} mm/C (applied now; SAVE_CONFIG writes it to [{self.section_name}])")

    def get_status(self, eventtime=None) -> dict:
        return self.state.to_status()


def load_config(section: ConfigSection, printer) -> ZThermalAdjuster:
    return ZThermalAdjuster(section, printer)


def load_config_prefix(section: ConfigSection, printer) -> ZThermalAdjuster:
    return ZThermalAdjuster(section, printer)
