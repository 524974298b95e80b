"""Sections of a real Klipper printer.cfg that tapcell accepts without modelling them.

A user brings the printer.cfg of a real printer: MCUs, stepper drivers, screens, LEDs,
accelerometers, leveling helpers. The virtual printer has nothing of these to drive, so
their options are taken as written (not checked: each has many, often board-specific)
and nothing happens. Sections that *are* modelled (heaters, fans, homing, ...) check
every option name, so a typo there is still an error, as in Klipper.

`startup_notice` lists, once at start, what the virtual printer simulates and what it
only accepted.
"""

from __future__ import annotations

# First word of the section name -> what it is (shown in the start-up notice).
ACCEPTED_SECTIONS: dict[str, str] = {
    "mcu": "micro-controller",
    "board_pins": "pin aliases",
    "duplicate_pin_override": "pin sharing",
    "tmc2130": "stepper driver", "tmc2208": "stepper driver", "tmc2209": "stepper driver",
    "tmc2240": "stepper driver", "tmc2660": "stepper driver", "tmc5160": "stepper driver",
    "stepper_z1": "extra Z motor", "stepper_z2": "extra Z motor", "stepper_z3": "extra Z motor",
    "extruder_stepper": "extra extruder motor",
    "save_variables": "saved variables",
    "firmware_retraction": "firmware retraction",
    "input_shaper": "input shaping",
    "resonance_tester": "resonance testing",
    "adxl345": "accelerometer", "lis2dw": "accelerometer", "mpu9250": "accelerometer",
    "gcode_arcs": "arcs",
    "display_template": "screen", "display_data": "screen", "display_glyph": "screen", "menu": "screen",
    "filament_switch_sensor": "filament sensor", "filament_motion_sensor": "filament sensor",
    "temperature_fan": "temperature-controlled fan",
    "gcode_button": "button",
    "delayed_gcode": "timed G-code",
    "static_digital_output": "pin", "multi_pin": "pin",
    "servo": "servo",
    "static_pwm_clock": "clock output (an ADS131M0x's pwm_clock reads its frequency)",
    "bed_tilt": "leveling",
    "bed_screws": "leveling", "screws_tilt_adjust": "leveling", "skew_correction": "leveling",
    "axis_twist_compensation": "leveling",
    "endstop_phase": "endstop phase",
    "verify_heater": "heater checks",
    "homing_heaters": "heaters off while homing",
    "thermistor": "sensor definition", "adc_temperature": "sensor definition",
    "manual_stepper": "manual stepper",
    "sdcard_loop": "print loops",
    "exclude_object_helper": "slicer helper",
}


# Hardware the virtual printer stands in for: first word of the section name -> how.
SIMULATED_HARDWARE: dict[str, str] = {
    "printer": "motion", "stepper_x": "motion", "stepper_y": "motion", "stepper_z": "motion",
    "extruder": "nozzle heater, E axis without filament",
    "heater_bed": "heater", "heater_generic": "heater",
    "temperature_sensor": "room temperature",
    "fan": "speed recorded", "heater_fan": "speed recorded", "controller_fan": "speed recorded",
    "fan_generic": "speed recorded", "output_pin": "value recorded",
    "load_cell": "load cell", "load_cell_probe": "load cell under the nozzle, bed contact",
    "neopixel": "colour recorded", "led": "colour recorded", "dotstar": "colour recorded",
    "pca9533": "colour recorded", "pca9632": "colour recorded",
    "z_tilt": "one Z motor: nothing to level", "quad_gantry_level": "one Z motor: nothing to level",
    "virtual_sdcard": "prints files", "force_move": "FORCE_MOVE, STEPPER_BUZZ, SET_KINEMATIC_POSITION",
}


def startup_notice(sections: list[str], accepted: list[str]) -> str | None:
    """What the virtual printer simulates and what it only accepted (None: no hardware sections)."""
    simulated = [name for name in sections if name.split()[0] in SIMULATED_HARDWARE]
    if not simulated and not accepted:
        return None
    by_kind: dict[str, list[str]] = {}
    for name in simulated:
        by_kind.setdefault(SIMULATED_HARDWARE[name.split()[0]], []).append(f"[{name}]")
    lines = ["The virtual printer simulates: " + "; ".join(f"{' '.join(names)} ({how})"
                                                           for how, names in by_kind.items())]
    if accepted:
        lines.append("Accepted but not modelled (options kept as written, nothing happens): "
                     + ", ".join(f"[{name}]" for name in accepted))
    return "\n".join(lines)
