"""What the virtual-printer tests share: the machine most of them start from ([virtual_printer],
[printer] and the steppers) and reading the error a G-code script must raise.

Kept in one place so a change to the machine (limits, steppers) is made once; tests add
the sections they exercise (load cells, probes, meshes) after it.
"""

from __future__ import annotations

import pytest

from tapcell.host.gcode import GCodeError

MACHINE_SECTIONS = """\
[printer]
kinematics: cartesian
max_velocity: 300
max_accel: 3000
max_z_velocity: 15
max_z_accel: 200

[stepper_x]
step_pin: PB13
dir_pin: PB12
microsteps: 16
rotation_distance: 40
endstop_pin: ^PC0
position_endstop: 0
position_max: 235

[stepper_y]
step_pin: PB10
dir_pin: PB2
microsteps: 16
rotation_distance: 40
endstop_pin: ^PC1
position_endstop: 0
position_max: 235

[stepper_z]
step_pin: PB0
dir_pin: PC5
microsteps: 16
rotation_distance: 8
endstop_pin: probe:z_virtual_endstop
position_min: -2
position_max: 250
"""


# The calibrated load-cell probe the printer tests tap with (format counts_per_gram= and
# reference_tare_counts=; the virtual cell's truth is 110 and -38000).
PROBE_SECTION = """
[load_cell_probe]
sensor_type: hx717
sclk_pin: PA5
dout_pin: PA4
sample_rate: 320
counts_per_gram: {counts_per_gram}
reference_tare_counts: {reference_tare_counts}
z_offset: 0
trigger_force: 75
speed: 5
# On this stiff bed (3.26 g/um) break contact comes 30-45 um
# up, inside the first sixth of the default 0.2 mm pullback (the spec wants the middle two thirds);
# 0.15 mm puts it at 20-30 % and leaves room for an ooze strand to tear before the pullback ends.
pullback_distance: 0.15
"""


def machine_config(scenario: str = "clean", seed: int = 1) -> str:
    """Config text of the virtual machine in `scenario` with `seed`."""
    return f"[virtual_printer]\nscenario: {scenario}\nseed: {seed}\n\n{MACHINE_SECTIONS}"


def gcode_error(printer, script: str) -> str:
    """The message of the GCodeError that running `script` on `printer` must raise."""
    with pytest.raises(GCodeError) as info:
        printer.gcode.run_script(script)
    return str(info.value)
