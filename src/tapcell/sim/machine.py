"""The machine a printer config describes, as virtual printer parameters.

The virtual printer stands in for the printer a config describes: its travel, speeds and
step sizes ([printer], [stepper_x/y/z]), and the load cell's chip, sample rate and gain
(the probe's cell: [load_cell_probe], else [load_cell], else the first [load_cell NAME]).
When the cell's pins are on another MCU than the Z stepper, the stop is relayed through the
host (multi-MCU homing), which adds MULTI_MCU_STOP_DELAY_S.

Values are read as written, without checks: the modules that own these sections check them
(and report a bad value) while the printer loads. A value that does not parse is skipped.
"""

from __future__ import annotations

import math

from tapcell.host.config import pin_mcu
from tapcell.mcu import ads131m0x
from tapcell.mcu.sensors import SensorConfigError

# Trigger on the sensor's MCU -> host -> stepper MCU: about two USB/CAN message latencies.
MULTI_MCU_STOP_DELAY_S = 0.004
SENSOR_PINS = ("sclk_pin", "dout_pin", "cs_pin", "data_ready_pin")
PHYSICAL_Z_BELOW_BED_MM = 2.0


def _number(config, section: str, option: str, default=None):
    text = config.peek(section, option)
    if text is None:
        return default
    try:
        value = float(text)
    except ValueError:
        return default
    return value if math.isfinite(value) else default


def _gear_ratio(config, section: str) -> float:
    """'80:16' -> 5.0; several stages ('57:11, 2:1') multiply; absent or unreadable: 1."""
    text = config.peek(section, "gear_ratio")
    ratio = 1.0
    try:
        for stage in (text or "").split(","):
            if stage.strip():
                driven, driving = stage.split(":")
                ratio *= float(driven) / float(driving)
    except (ValueError, ZeroDivisionError):
        return 1.0
    return ratio


def probe_cell_section(config) -> str | None:
    """The section of the load cell under the nozzle (the virtual printer's own cell)."""
    for name in ("load_cell_probe", "load_cell"):
        if config.has_section(name):
            return name
    named = [name for name in config.sections() if name.startswith("load_cell ")]
    return named[0] if named else None


def machine_params(config) -> dict[str, tuple[object, str]]:
    """{SimParams name: (value, where the config says it)} for what the config describes."""
    found: dict[str, tuple[object, str]] = {}

    def take(param: str, section: str, option: str, default=None, convert=float):
        value = _number(config, section, option, default)
        if value is not None:
            found[param] = (convert(value), f"[{section}] {option}")

    if config.has_section("printer"):
        max_velocity = _number(config, "printer", "max_velocity")
        max_accel = _number(config, "printer", "max_accel")
        take("max_velocity_mm_s", "printer", "max_velocity")
        take("max_accel_mm_s2", "printer", "max_accel")
        take("max_z_velocity_mm_s", "printer", "max_z_velocity", default=max_velocity)
        take("max_z_accel_mm_s2", "printer", "max_z_accel", default=max_accel)
    for axis in "xy":
        section = f"stepper_{axis}"
        if config.has_section(section):
            take(f"{axis}_position_min_mm", section, "position_min", default=0.0)
            take(f"{axis}_position_max_mm", section, "position_max")
            take(f"{axis}_endstop_mm", section, "position_endstop")
    if config.has_section("stepper_x"):
        # A gearbox makes each step shorter: the distance per motor turn is rotation_distance / ratio.
        take("rotation_distance_xy_mm", "stepper_x", "rotation_distance",
             convert=lambda v: v / _gear_ratio(config, "stepper_x"))
        take("microsteps", "stepper_x", "microsteps", convert=int)
        take("full_steps_per_rotation", "stepper_x", "full_steps_per_rotation", convert=int)
        take("homing_speed_mm_s", "stepper_x", "homing_speed")
    if config.has_section("stepper_z"):
        # position_min is the software limit; the screw goes further: the carriage can always
        # reach PHYSICAL_Z_BELOW_BED_MM below the bed (so G28 Z finds the bed with position_min: 0).
        take("z_position_min_mm", "stepper_z", "position_min", default=0.0,
             convert=lambda v: min(float(v), -PHYSICAL_Z_BELOW_BED_MM))
        take("z_position_max_mm", "stepper_z", "position_max")
        take("rotation_distance_z_mm", "stepper_z", "rotation_distance",
             convert=lambda v: v / _gear_ratio(config, "stepper_z"))
    cell = probe_cell_section(config)
    if cell is not None:
        _sensor_params(config, cell, found)
    return found


def _ads131m0x_rate_sps(config, cell: str, asked_sps: float | None) -> float:
    """The rate an ADS131M0x really runs at: the OSR closest to the asked rate at its clock (0
    when the config does not say enough; [load_cell_probe] then reports what is wrong)."""
    clock = _number(config, cell, "clock_freq")
    pwm_clock = config.peek(cell, "pwm_clock")
    if clock is None and pwm_clock is not None:
        clock = _number(config, f"static_pwm_clock {pwm_clock.strip()}", "frequency")
    chop = (config.peek(cell, "enable_global_chop") or "").strip().lower() in ("true", "1", "yes")
    delay = _number(config, cell, "global_chop_delay") or 16
    if clock is None or clock <= 0:
        return 0.0
    try:
        return ads131m0x.choose_osr(clock, asked_sps or ads131m0x.DEFAULT_SAMPLE_RATE_SPS,
                                    int(delay) if chop else None)[1]
    except SensorConfigError:
        return 0.0


def _sensor_params(config, cell: str, found: dict) -> None:
    chip = (config.peek(cell, "sensor_type") or "").strip().lower()
    if not chip:
        return
    found["chip"] = (chip, f"[{cell}] sensor_type")
    rate = _number(config, cell, "sample_rate")
    # No sample_rate: the chip's default (0 asks the virtual printer for it).
    found["sample_rate_sps"] = (rate or 0.0, f"[{cell}] sample_rate")
    if chip in ads131m0x.CHANNELS:
        found["sample_rate_sps"] = (_ads131m0x_rate_sps(config, cell, rate), f"[{cell}] sample_rate and its clock")
    gain = config.peek(cell, "gain")
    if gain is not None:
        try:
            found["gain"] = (int(gain.strip().split("-")[-1]), f"[{cell}] gain")  # "A-128" or "128"
        except ValueError:
            pass
    else:
        found["gain"] = (128, f"[{cell}] gain")  # every chip's default
    sensor_chips = {pin_mcu(config.peek(cell, pin)) for pin in SENSOR_PINS if config.peek(cell, pin)}
    z_pin = config.peek("stepper_z", "step_pin")
    if sensor_chips and z_pin is not None:
        relayed = pin_mcu(z_pin) not in sensor_chips
        found["multi_mcu_delay_s"] = (MULTI_MCU_STOP_DELAY_S if relayed else 0.0,
                                      f"[{cell}] pins' MCU vs [stepper_z] step_pin")
