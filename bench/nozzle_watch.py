"""The nozzle watch against issue 19's reproducers: true peak force with the watch off and on.

Each case builds the example printer (examples/virtual-printer.cfg, the calibration written from
the simulator's own scale so no weight is needed, homed), runs the case's G-code once with
`nozzle_watch_height: 0` (the watch off: main before issue 19) and once with the defaults, and
prints the true nozzle-bed peak force (`SIM_TRUTH`'s peak_force_g) as a ratio of
force_safety_limit, the nozzle's clearance after the command (negative: pressed into the bed)
and how the command ended. A row is unsafe when the peak passes force_safety_limit or the
clearance is below 0. The anchor of every row is the same case with the watch off, in this run.

Run: .venv/bin/python -m bench nozzle_watch [--only TEXT]
"""

from __future__ import annotations

import argparse
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table

from tapcell.host.gcode import GCodeError
from tapcell.host.printer import Printer

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "virtual-printer.cfg"
FORCE_SAFETY_LIMIT_G = 2000.0
WATCH_OFF = "nozzle_watch_height: 0"
# The virtual cell's own scale (as bench/safety.py writes it): no calibration weight needed.
CALIBRATION = "counts_per_gram: 110\nreference_tare_counts: -38000\n"
SLOW_ADC = {"sensor_type: hx717": "sensor_type: hx711", "sample_rate: 320": "sample_rate: 80",
            "\nspeed: 5\n": "\nspeed: 2\n"}
# [safe_z_home] without z_hop (Klipper's default): G28 X/Y start wherever Z is.
NO_Z_HOP = (("z_hop: 5\n", "z_hop: 0\n"),)
ZERO_REFERENCE = {"horizontal_z_clearance: 0.4\n": "horizontal_z_clearance: 0.4\nzero_reference_position: 200, 200\n"}


def bump_csv(path: Path, x_mm: float, y_mm: float, height_mm: float, radius_mm: float, gaussian: bool = False) -> str:
    """[virtual_printer] lines for a flat bed (1 mm CSV grid over 235 mm) but for a blob (a cone of
    that radius) or a local warp (a Gaussian bulge of that sigma) at x, y."""
    xs = np.arange(0.0, 236.0)
    grid_x, grid_y = np.meshgrid(xs, xs)
    r = np.hypot(grid_x - x_mm, grid_y - y_mm)
    z = height_mm * (np.exp(-0.5 * (r / radius_mm) ** 2) if gaussian else np.clip(1.0 - r / radius_mm, 0.0, 1.0))
    np.savetxt(path, z, delimiter=",", fmt="%.4f")
    return f"bed_shape: csv\nbed_csv: {path}\n"


@dataclass(frozen=True)
class Case:
    name: str
    script: str
    probe_options: str = ""
    world: str = ""                      # [virtual_printer] lines ("{folder}" is the case's folder)
    replace: tuple[tuple[str, str], ...] = ()
    home_first: bool = True              # G28 and the move to the centre before the script
    bump: tuple | None = None            # bump_csv arguments after the path
    sections: str = ""                   # whole sections added to the config


CASES = (
    Case("SET_GCODE_OFFSET Z=-1.9, G1 Z0.1", "SET_GCODE_OFFSET Z=-1.9\nG1 Z0.1 F600"),
    Case("deactivate_gcode: G1 Z-1.5, G28", "G28", probe_options="deactivate_gcode: G1 Z-1.5 F600", home_first=False),
    Case("1.0 mm blob under mesh travel", "BED_MESH_CALIBRATE", bump=(66.0, 15.0, 1.0, 3.0)),
    Case("1.5 mm blob under mesh travel", "BED_MESH_CALIBRATE", bump=(66.0, 15.0, 1.5, 3.0)),
    Case("1.5 mm blob, 45 deg flanks", "BED_MESH_CALIBRATE", bump=(66.0, 15.0, 1.5, 1.5)),
    Case("1.5 mm blob, 45 deg flanks, HX711 80 sps", "BED_MESH_CALIBRATE", bump=(66.0, 15.0, 1.5, 1.5),
         replace=tuple(SLOW_ADC.items())),
    Case("1.3 mm local warp under mesh travel", "BED_MESH_CALIBRATE", bump=(66.0, 15.0, 1.3, 6.0, True)),
    Case("zero reference 1.18 mm above the datum, G1 Z0.2", "BED_MESH_CALIBRATE\nG1 X117.5 Y117.5 Z0.2 F600",
         world="bed_shape: tilted\nbed_tilt_x_mm: 1.0\nbed_tilt_y_mm: 0.5\n", replace=tuple(ZERO_REFERENCE.items())),
    # From Z 1 (G28 ends at Z 5, too high for 2.5 mm of steps to reach the bed): the last 30 steps press.
    Case("50 steps of 0.05 mm down from Z 1", "G1 Z1 F600\nG91\n" + "G1 Z-0.05 F60\nG4 P200\n" * 50),
    # G28 X / G28 Y with the nozzle low (after a print, a G28 Z without z_hop) over a 1.5 mm blob with
    # 45 deg flanks (a clip, a part left on the bed) between the nozzle and the endstop.
    Case("G28 X at Z 0.3 over a 1.5 mm blob, no z_hop", "G1 Z0.3 F600\nG28 X", bump=(60.0, 110.0, 1.5, 1.5),
         replace=NO_Z_HOP),
    Case("G28 Y at Z 0.3 over a 1.5 mm blob, no z_hop", "G1 Z0.3 F600\nG28 Y", bump=(110.0, 60.0, 1.5, 1.5),
         replace=NO_Z_HOP),
    Case("G28 X at Z 0.3, bed 1.5 mm higher at X 0, no z_hop", "G1 Z0.3 F600\nG28 X",
         world="bed_shape: tilted\nbed_tilt_x_mm: -1.5\n", replace=NO_Z_HOP),
    Case("G28 X at Z 0.3 after M84 (Z not homed), blob, no z_hop", "G1 Z0.3 F600\nM84\nG28 X",
         bump=(60.0, 110.0, 1.5, 1.5), replace=NO_Z_HOP),
    Case("G28 X at Z 0.3 over the blob, z_hop: 5 (the example)", "G1 Z0.3 F600\nG28 X",
         bump=(60.0, 110.0, 1.5, 1.5)),
    # A single stepper driven past the kinematics (extras/force_move.py): a macro's FORCE_MOVE down.
    Case("FORCE_MOVE stepper_z 2.5 mm down from Z 1", "G1 Z1 F600\nFORCE_MOVE STEPPER=stepper_z DISTANCE=-2.5 VELOCITY=5",
         sections="\n[force_move]\nenable_force_move: True\n"),
)


def config_text(case: Case, folder: Path, watch: bool) -> str:
    world = case.world
    if case.bump is not None:
        world += bump_csv(folder / "bed.csv", *case.bump)
    text = EXAMPLE.read_text().replace("scenario: clean\nseed: 1\n", f"scenario: clean\nseed: 1\n{world}")
    for old, new in case.replace:
        text = text.replace(old, new)
    options = CALIBRATION + case.probe_options + ("" if watch else "\n" + WATCH_OFF)
    return text.replace("samples: 1\n", f"samples: 1\n{options}\n", 1) + case.sections


def run_case(case: Case, folder: Path, watch: bool) -> tuple[float, float, str]:
    """(true peak force g, clearance mm after, how it ended)."""
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "printer.cfg"
    path.write_text(config_text(case, folder, watch))
    printer = Printer.from_config(str(path), responses=[])
    if case.home_first:
        printer.gcode.run_script("G28\nG1 X110 Y110 F6000")
    truth = printer.backend.truth
    truth.take_peak_force_g()
    try:
        printer.gcode.run_script(case.script)
        ended = "done, no message"
    except GCodeError as exc:
        text = str(exc)
        ended = "stopped: nozzle collision" if "nozzle collision" in text else text[:60]
    return truth.take_peak_force_g(), truth.nozzle_clearance_mm, ended


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="bench/nozzle_watch.py", description=__doc__)
    parser.add_argument("--only", default="", help="run the cases whose name contains this text")
    args = parser.parse_args(argv)
    cases = [case for case in CASES if args.only in case.name]
    table = Table(title=f"issue 19 reproducers: true peak force / force_safety_limit ({FORCE_SAFETY_LIMIT_G:.0f} g), "
                        "the nozzle watch off (anchor) and on")
    for column in ("case", "off: peak g", "off: clearance mm", "on: peak g", "on: peak / limit", "on: clearance mm",
                   "on: ended", "safe"):
        table.add_column(column, justify="right")
    console = Console(width=200)
    worst = 0.0
    unsafe = 0
    with tempfile.TemporaryDirectory() as folder:
        for index, case in enumerate(cases):
            console.print(f"bench nozzle_watch: {case.name} ...")
            off = run_case(case, Path(folder) / f"{index}-off", watch=False)
            on = run_case(case, Path(folder) / f"{index}-on", watch=True)
            safe = on[0] <= FORCE_SAFETY_LIMIT_G and on[1] >= 0.0
            unsafe += not safe
            worst = max(worst, on[0] / FORCE_SAFETY_LIMIT_G)
            table.add_row(case.name, f"{off[0]:,.0f}", f"{off[1]:.3f}", f"{on[0]:,.0f}",
                          f"{on[0] / FORCE_SAFETY_LIMIT_G:.2f}", f"{on[1]:.3f}", on[2], "yes" if safe else "NO")
    console.print(table)
    console.print(f"{len(cases)} rows, {unsafe} unsafe with the watch on; worst peak {worst:.2f} x force_safety_limit")
    return 0
