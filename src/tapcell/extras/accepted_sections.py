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
    "idle_timeout": "idle timeout",
    "virtual_sdcard": "print files",
    "pause_resume": "pause/resume",
    "save_variables": "saved variables",
    "force_move": "manual stepper moves",
    "firmware_retraction": "firmware retraction",
    "input_shaper": "input shaping",
    "resonance_tester": "resonance testing",
    "adxl345": "accelerometer", "lis2dw": "accelerometer", "mpu9250": "accelerometer",
    "gcode_arcs": "arcs",
    "display_template": "screen", "display_data": "screen", "display_glyph": "screen", "menu": "screen",
    "neopixel": "LEDs", "led": "LEDs", "dotstar": "LEDs", "pca9533": "LEDs", "pca9632": "LEDs",
    "filament_switch_sensor": "filament sensor", "filament_motion_sensor": "filament sensor",
    "temperature_fan": "temperature-controlled fan",
    "gcode_button": "button",
    "delayed_gcode": "timed G-code",
    "static_digital_output": "pin", "multi_pin": "pin",
    "servo": "servo",
    "z_tilt": "leveling", "quad_gantry_level": "leveling", "bed_tilt": "leveling",
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


def is_accepted(section_name: str) -> bool:
    return section_name.split()[0] in ACCEPTED_SECTIONS


def accept_section(config, section_name: str) -> None:
    """Take the section's options as written."""
    config.mark_section_read(section_name)


def startup_notice(simulated: list[str], accepted: list[str]) -> str:
    """What the virtual printer simulates and what it only accepted (section names)."""
    lines = ["The virtual printer simulates: " + ", ".join(f"[{name}]" for name in simulated)]
    if accepted:
        lines.append("Accepted but not modelled (options kept as written, nothing happens): "
                     + ", ".join(f"[{name}]" for name in accepted))
    return "\n".join(lines)
