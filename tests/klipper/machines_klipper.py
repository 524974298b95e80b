"""Printers for the Klipper-compatibility tests: the Voron-style example printer.cfg (a real
user's file, with a load cell) and a small bed slinger whose Z is homed by [homing_override]
(no taps needed, so the G-code tests stay fast)."""

from __future__ import annotations

import shutil
from pathlib import Path

from machines import MACHINE_SECTIONS
from tapcell.host.printer import Printer

VORON = Path(__file__).resolve().parents[2] / "examples" / "voron-load-cell.cfg"
CALIBRATE = ("LOAD_CELL_CALIBRATE\nTARE\nSIM_PLACE_WEIGHT GRAMS=1000\nCALIBRATE GRAMS=1000\nACCEPT\n"
             "SIM_REMOVE_WEIGHT")

# Z "homed" at 10 mm by the override itself: the moves and offsets can be tested without a probe.
BED_SLINGER = f"""\
[virtual_printer]
scenario: clean
seed: 1

{MACHINE_SECTIONS}
[extruder]
step_pin: PB3
dir_pin: PB4
enable_pin: !PD1
microsteps: 16
rotation_distance: 33.5
nozzle_diameter: 0.4
filament_diameter: 1.75
heater_pin: PC8
sensor_type: EPCOS 100K B57560G104F
sensor_pin: PA0
control: pid
pid_kp: 21.5
pid_ki: 1.06
pid_kd: 108.5
min_temp: 0
max_temp: 250
max_extrude_only_distance: 50

[heater_bed]
heater_pin: PC9
sensor_type: EPCOS 100K B57560G104F
sensor_pin: PC4
control: watermark
min_temp: 0
max_temp: 130

[fan]
pin: PA8

[homing_override]
axes: xyz
set_position_z: 10
gcode:
    G28 X Y

[display_status]

[respond]

[exclude_object]
"""


def start(tmp_path: Path, text: str, name: str = "printer.cfg") -> tuple[Printer, list[str]]:
    path = tmp_path / name
    path.write_text(text)
    responses: list[str] = []
    return Printer.from_config(str(path), responses=responses), responses


def voron_text(replace: dict[str, str] | None = None) -> str:
    text = VORON.read_text()
    for old, new in (replace or {}).items():
        assert old in text, old
        text = text.replace(old, new)
    return text


def calibrated_voron(tmp_path: Path, replace: dict[str, str] | None = None) -> Path:
    """The example Voron config in tmp_path, calibrated and saved (as a user would leave it)."""
    path = tmp_path / "printer.cfg"
    if replace:
        path.write_text(voron_text(replace))
    else:
        shutil.copy(VORON, path)
    printer = Printer.from_config(str(path), responses=[])
    printer.gcode.run_script(CALIBRATE + "\nSAVE_CONFIG")
    return path


def run(printer: Printer, responses: list[str], script: str) -> list[str]:
    responses.clear()
    printer.gcode.run_script(script)
    return list(responses)
