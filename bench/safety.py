"""Safety benchmark: everything that can press the nozzle into the bed or the pin, on the virtual printer.

Issues 10 and 19's targets, per row:

* the largest true force the nozzle put on the bed or, sideways, on the calibration pin
  (simulator truth, `SIM_TRUTH`'s peak_force_g) stays at or below `force_safety_limit` (a move
  the host refuses counts as safe: nothing pressed);
* after every command of the row's script, error or not, the nozzle is clear of the bed
  (nozzle_clearance_mm >= 0);
* no false Z data: a Z datum (G28 Z), probe result or mesh point that the command reports as
  good is within FALSE_Z_MM of the true bed, beyond the lag a trigger-only result has by design;
* an emergency stop stops: the command fails with the shutdown message and applies nothing;
* no internal error: every failure is a G-code error message.

Each row builds a fresh printer from examples/virtual-printer.cfg (sensor, sample rate, probing
speed, drift filter and bed stiffness set for the row; calibration values written from the
simulator so no weight is needed), homes it and runs its script line by line. Five families:

* probing: every fault of the virtual printer, at every phase of a tap (approach, contact, the
  trigger, the dwell, the pullback, between taps, the mesh travel and NOZZLE_CLEANUP's wipes),
  against every probing command, x 4 speeds x 3 sensors x drift filter off/on x bed stiffness
  2/10/40/150 g/um;
* world: blobs and warps between mesh points (travel at horizontal_z_clearance 0.4 mm) under the
  three mesh methods, x bed stiffness;
* z-move: offsets, templates and macros that move Z below the bed, x bed stiffness x move speed;
* xy: XY probing on the pin, x the toolhead's sideways stiffness (4-150 g/um) x sensor;
* estop: an emergency stop (as from a second API connection) during a mesh, PROBE_ACCURACY,
  G28 Z and a long move, at three moments.

By default the probing family runs each (fault, command) pair's 4 speeds once, with sensor,
filter and stiffness turning over from pair to pair, and the xy family turns its sensor over;
the other families run whole (a few minutes on 2 cores). `--full` runs every combination.

Run: .venv/bin/python -m bench safety [--full] [--workers W] [--rows] [--pairs] [--only TEXT]
"""

from __future__ import annotations

import argparse
import itertools
import os
import tempfile
import time
import traceback
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table

from tapcell.extras.load_cell_probe.safety import DEFAULT_STIFFNESS_G_UM

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "virtual-printer.cfg"
SPEEDS_MM_S = (1.0, 5.0, 20.0, 50.0)
# sensor -> ([load_cell_probe] lines, [virtual_printer] lines); the virtual printer takes the chip,
# its rate and the machine's speeds from the printer's own sections.
SENSORS = {
    "HX711": ("sensor_type: hx711\nsclk_pin: PA5\ndout_pin: PA4\nsample_rate: 80\n", ""),
    "HX717": ("sensor_type: hx717\nsclk_pin: PA5\ndout_pin: PA4\nsample_rate: 320\n", ""),
    "ADS1220": ("sensor_type: ads1220\ncs_pin: PA4\ndata_ready_pin: PA3\nsample_rate: 660\n",
                "white_noise_counts: 60\n"),
}
# The bed's stiffness under the nozzle (frame, cell and sheet in series), g/um: from a soft sheet
# to the stiffest frame the issue met. None: the example's own (3.26 g/um). A bed stiffer than
# max_bed_stiffness's default (100) is declared in its row's config.
STIFFNESSES_G_UM = (2.0, 10.0, 40.0, 150.0)
# A drift filter that hides a slow tap on a soft bed: the drift window must stop it.
DRIFT_FILTER_HZ = 10.0
FORCE_SAFETY_LIMIT_G = 2000.0
# (fault, SIM_FAULT parameters); WHEN= is replaced by AT= for the command that does not move.
FAULTS = {
    "none": None,
    "stuck at contact": "NAME=stuck WHEN=contact",
    "stuck after trigger": "NAME=stuck WHEN=trigger",
    "stuck in the dwell": "NAME=stuck WHEN=halt",
    "stuck in the pullback": "NAME=stuck WHEN=lift",
    "stuck between taps": "NAME=stuck WHEN=lift NTH=2",
    "stuck in travel or wipe": "NAME=stuck WHEN=travel NTH=2",
    "disconnected at contact": "NAME=disconnected WHEN=contact",
    "disconnected in the dwell": "NAME=disconnected WHEN=halt",
    "saturated at contact": "NAME=saturation WHEN=contact",
    "chip offset jump": "NAME=chip_reset WHEN=probing_move GAP_S=0.002",
    "corrupt frames": "NAME=corrupt_frame WHEN=probing_move COUNT=3 SPACING_S=0.1",
    "200 g touch, 0.3 s": "NAME=weight WHEN=probing_move GRAMS=200 DURATION=0.3",
    "200 g touch in travel": "NAME=weight WHEN=travel GRAMS=200 DURATION=0.3",
    "bowden tug 200 g": "NAME=bowden_tug WHEN=probing_move FORCE_G=200",
    "MCU reset at contact": "NAME=mcu_reset WHEN=contact",
}
TEST_TAP_FAULT_DELAY_S = 0.6    # LOAD_CELL_TEST_TAP: the fault comes 0.1 s into the hand tap
COMMANDS = {
    "PROBE": "PROBE",
    "PROBE_ACCURACY": "PROBE_ACCURACY SAMPLES=3",
    "BED_MESH tap": "BED_MESH_CALIBRATE",
    "BED_MESH two_pass": "BED_MESH_CALIBRATE METHOD=two_pass",
    "BED_MESH prusa": "BED_MESH_CALIBRATE METHOD=prusa",
    "G28 Z": "G28 Z",
    "NOZZLE_CLEANUP": "NOZZLE_CLEANUP",
    "LOAD_CELL_TEST_TAP": "SIM_TAP FORCE=300 DELAY=0.5\nLOAD_CELL_TEST_TAP COUNT=1 TIMEOUT=2",
}
MESH_COMMANDS = ("BED_MESH tap", "BED_MESH two_pass", "BED_MESH prusa")
TRIGGER_ONLY = ("G28 Z", "BED_MESH two_pass", "BED_MESH prusa")
# Things on the bed between the first two points of the 3 x 3 mesh (15,15 -> 117.5,15): the travel
# between them runs horizontal_z_clearance (0.4 mm) above the last touch.
BETWEEN_POINTS_MM = (66.25, 15.0)
WORLDS = {
    "blob 1.0 mm between points": ("cone", 1.0, 3.0),
    "blob 1.5 mm between points": ("cone", 1.5, 3.0),
    "bulge 1.2 mm between points": ("gaussian", 1.2, 15.0),
    "warped bed 1.5 mm": ("warped", 1.5, 0.0),
}
# Moves a user's G-code makes below the bed (issue 19, 3): offsets, macros, templates.
Z_MOVES = {
    "SET_GCODE_OFFSET Z=-1.9, G1 Z0.1": ("", "SET_GCODE_OFFSET Z=-1.9\nG1 Z0.1 F{f}"),
    "deactivate_gcode G1 Z-1.5 (G28)": ("deactivate_gcode: G1 Z-1.5 F{f}\n", "G28"),
    "macro G1 Z-1": ("", "DIVE"),
    "template G1 Z{params.Z}": ("", "DIVE_TO Z=-0.8"),
}
Z_MOVE_MACROS = ("\n[gcode_macro DIVE]\ngcode:\n  G1 Z-1 F{f}\n"
                 "\n[gcode_macro DIVE_TO]\ngcode:\n  G1 Z{{params.Z}} F{f}\n")
Z_MOVE_SPEEDS_MM_S = (10.0, 50.0)
# XY probing: the virtual pin (0.3/-0.2 mm off nominal) and the toolhead's sideways stiffness.
XY_PIN = "pin_diameter_mm: 6\npin_x_mm: 225.3\npin_y_mm: 224.8\n"
XY_SECTION = "\n[xy_probe]\npin_x: 225\npin_y: 225\npin_diameter: 6\n"
XY_COMMANDS = {
    "XY_PROBE SPEED=20": "G1 X215 Y224.8 F3000\nG1 Z2 F600\nXY_PROBE DIRECTION=+X SPEED=20",
    "XY_PROBE": "G1 X215 Y224.8 F3000\nG1 Z2 F600\nXY_PROBE DIRECTION=+X",
    "XY_PROBE_PIN": "XY_PROBE_PIN",
}
SIDE_STIFFNESSES_G_UM = (4.0, 40.0, 100.0, 150.0)
# Emergency stop: asked for this long (print time) after the command starts.
ESTOP_COMMANDS = {
    "BED_MESH tap": "BED_MESH_CALIBRATE",
    "BED_MESH two_pass": "BED_MESH_CALIBRATE METHOD=two_pass",
    "BED_MESH prusa": "BED_MESH_CALIBRATE METHOD=prusa",
    "PROBE_ACCURACY": "PROBE_ACCURACY SAMPLES=20",
    "G28 Z": "G28 Z",
    "long move": "G1 X20 Y20 F600\nG1 X220 Y220 F600",
}
ESTOP_CASES = {f"stop after {after_s:g} s": after_s for after_s in (0.5, 2.0, 5.0)}
SHUTDOWN_REASON = "Shutdown due to bench emergency stop"
# A reported Z further than this from the true bed (beyond a trigger-only result's lag) is false.
FALSE_Z_MM = 0.1
MESH_CHECK_POINTS = 9           # per axis: where a mesh is compared with the true bed
PROBE_XY_MM = (110.0, 110.0)
START_Z_MM = 3.0                # where each command starts, above the bed


@dataclass(frozen=True)
class Row:
    family: str                  # probing, world, z-move, xy, estop
    case: str                    # the fault, world, Z move, side stiffness or stop moment
    command: str
    speed_mm_s: float
    sensor: str
    drift_filter: bool
    stiffness_g_um: float | None  # the bed's (xy: the toolhead's sideways); None: the example's


@dataclass
class Outcome:
    row: Row
    result: str                  # ok, refused, error, INTERNAL
    message: str                 # the error message (first line), or ""
    peak_force_g: float          # nozzle on the bed or on the pin, the larger
    clearance_mm: float          # the least after any command of the script
    z_error_mm: float | None     # worst |reported Z - true bed| of a command that reported Z
    z_allowed_mm: float          # what that error may be (FALSE_Z_MM + a trigger-only lag)
    stop_ignored: bool           # an emergency stop row whose command did not fail with it
    seconds: float

    @property
    def false_z(self) -> bool:
        return self.z_error_mm is not None and self.z_error_mm > self.z_allowed_mm

    @property
    def safe(self) -> bool:
        return (self.peak_force_g <= FORCE_SAFETY_LIMIT_G and self.clearance_mm >= 0.0 and not self.false_z
                and not self.stop_ignored and self.result != "INTERNAL")


def rows(full: bool) -> list[Row]:
    """The grid, or its default sample (see the module's doc)."""
    sensors = list(SENSORS)
    chosen: list[Row] = []
    if full:
        chosen += [Row("probing", f, c, v, s, d, k) for f, c, v, s, d, k in
                   itertools.product(FAULTS, COMMANDS, SPEEDS_MM_S, sensors, (False, True), STIFFNESSES_G_UM)]
    else:
        for pair, (fault, command) in enumerate(itertools.product(FAULTS, COMMANDS)):
            for i, speed in enumerate(SPEEDS_MM_S):
                chosen.append(Row("probing", fault, command, speed, sensors[(pair + i) % 3],
                                  bool((pair + i // 2) % 2), STIFFNESSES_G_UM[(pair + i) % 4]))
    chosen += [Row("world", w, c, 5.0, "HX717", False, k)
               for w, c, k in itertools.product(WORLDS, MESH_COMMANDS, STIFFNESSES_G_UM)]
    chosen += [Row("z-move", m, m, v, "HX717", False, k)
               for m, v, k in itertools.product(Z_MOVES, Z_MOVE_SPEEDS_MM_S, STIFFNESSES_G_UM)]
    for index, (command, side) in enumerate(itertools.product(XY_COMMANDS, SIDE_STIFFNESSES_G_UM)):
        for sensor in (sensors if full else [sensors[index % 3]]):
            chosen.append(Row("xy", f"side {side:g} g/um", command, 0.0, sensor, False, side))
    chosen += [Row("estop", case, c, 5.0, "HX717", False, None) for c, case in itertools.product(ESTOP_COMMANDS, ESTOP_CASES)]
    return chosen


def stiffness_lines(stiffness_g_um: float | None) -> str:
    """[virtual_printer] lines for a bed of this stiffness: frame, cell and sheet alike, in series."""
    if stiffness_g_um is None:
        return ""
    each = 3.0 * stiffness_g_um
    return f"frame_stiffness_g_um: {each:g}\ncell_stiffness_g_um: {each:g}\nsheet_stiffness_g_um: {each:g}\n"


def world_lines(row: Row, folder: Path) -> str:
    """[virtual_printer] lines for the row's bed (a CSV with the blob or bulge, or a warp)."""
    if row.family != "world":
        return ""
    shape, height_mm, radius_mm = WORLDS[row.case]
    if shape == "warped":
        return f"bed_shape: warped\nbed_warp_mm: {height_mm:g}\nbed_warp_modes: 3\n"
    xs = np.arange(0.0, 236.0, 0.5)
    grid_x, grid_y = np.meshgrid(xs, xs)
    r = np.hypot(grid_x - BETWEEN_POINTS_MM[0], grid_y - BETWEEN_POINTS_MM[1])
    z = height_mm * (np.exp(-0.5 * (r / radius_mm) ** 2) if shape == "gaussian"
                     else np.clip(1.0 - r / radius_mm, 0.0, 1.0))
    path = folder / "bed.csv"
    np.savetxt(path, z, delimiter=",", fmt="%.4f")
    return f"bed_shape: csv\nbed_csv: {path}\n"


def config_text(row: Row, folder: Path) -> str:
    """examples/virtual-printer.cfg with the row's sensor, speed, filter, bed and commands, a 3 x 3 mesh
    and [prusa_probe]."""
    probe_lines, sim_lines = SENSORS[row.sensor]
    speed = row.speed_mm_s if row.family in ("probing", "world") else 5.0
    sim_lines += world_lines(row, folder)
    if row.family == "xy":
        sim_lines += XY_PIN + f"pin_side_stiffness_g_um: {row.stiffness_g_um:g}\n"
    else:
        sim_lines += stiffness_lines(row.stiffness_g_um)
    text = EXAMPLE.read_text()
    text = text.replace("scenario: clean\nseed: 1\n", f"scenario: clean\nseed: 1\n{sim_lines}")
    text = text.replace("max_z_velocity: 15", f"max_z_velocity: {max(speed, 5.0):g}")
    text = text.replace("sensor_type: hx717\nsclk_pin: PA5\ndout_pin: PA4\nsample_rate: 320\n", probe_lines)
    text = text.replace("\nspeed: 5\n", f"\nspeed: {speed:g}\n", 1)
    # Calibrated as LOAD_CELL_CALIBRATE would find it (the virtual cell: 110 counts/g, -38000 at zero).
    extra = "counts_per_gram: 110\nreference_tare_counts: -38000\n"
    if row.family != "xy" and row.stiffness_g_um is not None and row.stiffness_g_um > DEFAULT_STIFFNESS_G_UM:
        # A machine stiffer than the guard's default assumption declares it, as its owner must:
        # the guard holds up to the stiffest bed the config declares (docs/safety.md).
        extra += f"max_bed_stiffness: {row.stiffness_g_um:g}\n"
    if row.drift_filter:
        extra += f"drift_filter_cutoff_frequency: {DRIFT_FILTER_HZ:g}\n"
    if row.family == "z-move":
        extra += Z_MOVES[row.case][0].format(f=row.speed_mm_s * 60.0)
    text = text.replace("samples: 1\n", f"samples: 1\n{extra}", 1)
    text = text.replace("probe_count: 7, 7", "probe_count: 3, 3").replace("algorithm: bicubic", "algorithm: lagrange")
    text += f"\n[prusa_probe]\nz_fast_speed: {speed:g}\nz_slow_speed: {min(speed, 1.0):g}\n"
    if row.family == "z-move":
        text += Z_MOVE_MACROS.format(f=row.speed_mm_s * 60.0)
    if row.family == "xy":
        text += XY_SECTION
    return text


def fault_line(row: Row, now_s: float) -> str | None:
    params = FAULTS[row.case] if row.family == "probing" else None
    if params is None:
        return None
    if row.command == "LOAD_CELL_TEST_TAP":
        params = " ".join(p for p in params.split() if not p.startswith(("WHEN=", "NTH="))) + \
            f" AT={now_s + TEST_TAP_FAULT_DELAY_S:.3f}"
    return f"SIM_FAULT {params}"


def script(row: Row, now_s: float) -> str:
    if row.family == "z-move":
        return Z_MOVES[row.case][1].format(f=row.speed_mm_s * 60.0)
    if row.family == "xy":
        return XY_COMMANDS[row.command]
    if row.family == "estop":
        return ESTOP_COMMANDS[row.command]
    line = fault_line(row, now_s)
    return COMMANDS[row.command] if line is None else f"{line}\n{COMMANDS[row.command]}"


def true_bed_z_mm(printer, x_mm, y_mm):
    """The bed's true contact height at toolhead (x, y), in toolhead coordinates."""
    vp = printer.backend
    frame = printer.lookup_object("toolhead").frame_offset_mm
    return np.asarray(vp.truth.contact_z_at(np.asarray(x_mm) - frame["x"], np.asarray(y_mm) - frame["y"])) \
        + frame["z"]


def trigger_lag_mm(printer, speed_mm_s: float) -> float:
    """How far below the bed a trigger-only result lies by design at this speed (simulator truth):
    the trigger depth, then up to 1.6 conversion windows, the ADC pipeline and the stop delay of travel."""
    vp = printer.backend
    p = vp.params
    period_s = 1.0 / p.sample_rate_sps
    pipeline_s = (1.0 if p.chip == "ads1220" else 0.0) * period_s
    travel_s = 1.6 * period_s + pipeline_s + p.stop_delay_s + p.multi_mcu_delay_s
    return (150.0 / vp.truth.stiffness_g_um + speed_mm_s * travel_s * 1000.0) / 1000.0


def z_error_mm(printer, row: Row) -> float | None:
    """Worst |reported Z - true bed| of what the command reported as good (None: it reported none).
    A mesh is compared on a 9 x 9 grid over a flat bed, at its probed points over a world with
    blobs or warps between them (no 3 x 3 mesh can follow those)."""
    if row.command in ("PROBE", "PROBE_ACCURACY"):
        probe = printer.lookup_object("probe")
        x, y, _ = printer.lookup_object("toolhead").get_position()
        return abs(probe.last_z_result - float(true_bed_z_mm(printer, x, y)))
    if row.command.startswith("BED_MESH"):
        mesh = printer.lookup_object("bed_mesh").mesh
        if mesh is None:
            return None
        grid = mesh.grid
        count = grid.x_count if row.family == "world" else MESH_CHECK_POINTS
        xs, ys = np.meshgrid(np.linspace(grid.min_x_mm, grid.max_x_mm, count),
                             np.linspace(grid.min_y_mm, grid.max_y_mm, count))
        return float(np.max(np.abs(np.asarray(mesh.z_at(xs, ys)) - true_bed_z_mm(printer, xs, ys))))
    if row.command == "G28 Z":
        x, y, _ = printer.lookup_object("toolhead").get_position()
        return abs(float(true_bed_z_mm(printer, x, y)))
    return None


def stop_during(printer, after_s: float) -> dict:
    """Ask for the emergency stop `after_s` of print time from now, as a second API connection would
    (from another thread, at a wall time): here at the sample the virtual printer makes then.
    Returns {"asked": True} once it was asked for (a command over before then never sees it)."""
    vp = printer.backend
    ask_at_s = vp.now_s + after_s
    compute = vp._compute
    stop: dict = {}

    def compute_then_ask(k0: int, k1: int):
        chunk = compute(k0, k1)
        if not stop and vp._timing.window_start_s(k1) > ask_at_s:
            printer.request_emergency_stop(SHUTDOWN_REASON)
            stop["asked"] = True
        return chunk

    vp._compute = compute_then_ask
    return stop


def run_row(row: Row) -> Outcome:
    from tapcell.host.config import ConfigError
    from tapcell.host.gcode import GCodeError
    from tapcell.host.printer import Printer

    started = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "printer.cfg"
        path.write_text(config_text(row, Path(tmp)))
        try:
            printer = Printer.from_config(str(path), responses=[])
        except ConfigError as exc:
            return Outcome(row, "refused", str(exc).splitlines()[0], 0.0, np.inf, None, 0.0, False,
                           time.perf_counter() - started)
        vp = printer.backend
        # Home X/Y, and Z from the truth (G28 Z is a row of its own, with its faults and speeds).
        printer.gcode.run_script("G28 X Y\nG1 X{:g} Y{:g} F6000".format(*PROBE_XY_MM))
        printer.lookup_object("toolhead").set_z_position(vp.position[2] - vp.truth.contact_z_at(*PROBE_XY_MM))
        printer.gcode.run_script(f"G1 Z{START_Z_MM:g} F600")
        vp.truth.take_peak_force_g()
        stop = stop_during(printer, ESTOP_CASES[row.case]) if row.family == "estop" else {}
        result, message, clearance_mm = "ok", "", np.inf
        for line in script(row, vp.now_s).split("\n"):
            try:
                printer.gcode.run_line(line)
            except GCodeError as exc:
                message = str(exc).splitlines()[0]
                result = "INTERNAL" if message.startswith("Internal error") else "error"
            except Exception as exc:  # noqa: BLE001 - a bug in tapcell: counted, shown, never hidden
                result, message = "INTERNAL", "".join(traceback.format_exception_only(exc)).strip()
            clearance_mm = min(clearance_mm, vp.truth.nozzle_clearance_mm)
            if result != "ok":
                break
        if result == "error" and "refus" in message.lower():
            result = "refused"
        stop_ignored = bool(stop) and not message.startswith(SHUTDOWN_REASON)
        z_error = z_error_mm(printer, row) if result == "ok" else None
        if row.family == "estop" and row.command.startswith("BED") and printer.lookup_object("bed_mesh").mesh:
            z_error = np.inf  # a mesh applied by a command the stop aborted is false data
        allowed = FALSE_Z_MM + (trigger_lag_mm(printer, row.speed_mm_s) if row.command in TRIGGER_ONLY else 0.0)
        return Outcome(row, result, message, vp.truth.take_peak_force_g(), clearance_mm, z_error, allowed,
                       stop_ignored, time.perf_counter() - started)


def _counts(group: list[Outcome]) -> dict[str, int]:
    return {r: sum(o.result == r for o in group) for r in ("ok", "refused", "error", "INTERNAL")}


def group_table(outcomes: list[Outcome], key, title: str, names: tuple[str, ...]) -> Table:
    table = Table(title=title)
    for name in (*names, "rows", "ok", "refused", "error", "internal", "peak g", "peak/limit",
                 "min clearance mm", "worst Z error mm", "false Z", "unsafe"):
        table.add_column(name, justify="left" if name in names else "right")
    for group_key, group in itertools.groupby(sorted(outcomes, key=key), key=key):
        group = list(group)
        counts = _counts(group)
        peak = max(o.peak_force_g for o in group)
        errors = [o.z_error_mm for o in group if o.z_error_mm is not None]
        unsafe = sum(not o.safe for o in group)
        table.add_row(*group_key, str(len(group)), *(str(counts[r]) for r in ("ok", "refused", "error", "INTERNAL")),
                      f"{peak:.0f}", f"{peak / FORCE_SAFETY_LIMIT_G:.2f}",
                      f"{min(o.clearance_mm for o in group):.3f}", f"{max(errors):.3f}" if errors else "–",
                      str(sum(o.false_z for o in group)), str(unsafe), style="bold red" if unsafe else None)
    return table


def row_table(outcomes: list[Outcome], title: str) -> Table:
    table = Table(title=title)
    for name in ("family", "case", "command", "mm/s", "sensor", "drift", "g/um", "outcome", "peak g",
                 "clearance mm", "Z error mm", "message"):
        table.add_column(name, justify="right" if name in ("mm/s", "g/um", "peak g", "clearance mm", "Z error mm")
                         else "left")
    for o in outcomes:
        r = o.row
        table.add_row(r.family, r.case, r.command, f"{r.speed_mm_s:g}", r.sensor, "on" if r.drift_filter else "off",
                      "–" if r.stiffness_g_um is None else f"{r.stiffness_g_um:g}", o.result,
                      f"{o.peak_force_g:.0f}", f"{o.clearance_mm:.3f}",
                      "–" if o.z_error_mm is None else f"{o.z_error_mm:.3f}",
                      ("STOP IGNORED: " if o.stop_ignored else "") + o.message[:90],
                      style=None if o.safe else "bold red")
    return table


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="bench safety", description=__doc__.splitlines()[0])
    parser.add_argument("--full", action="store_true", help="every combination of the grid")
    parser.add_argument("--workers", type=int, default=min(os.cpu_count() or 1, 2))
    parser.add_argument("--rows", action="store_true", help="print every row, not only the unsafe ones")
    parser.add_argument("--pairs", action="store_true", help="print the worst row of every (case, command) pair")
    parser.add_argument("--only", default="", help="run only rows whose family, case or command contains this text")
    args = parser.parse_args(argv)
    chosen = [r for r in rows(args.full) if args.only.lower() in f"{r.family} {r.case} {r.command}".lower()]
    if not chosen or args.workers < 1:
        parser.error("no rows chosen (--only), or --workers below 1")
    console = Console(width=220)
    started = time.perf_counter()
    outcomes = []
    with ProcessPoolExecutor(args.workers) as pool:
        for index, outcome in enumerate(pool.map(run_row, chosen, chunksize=2), start=1):
            outcomes.append(outcome)
            if index % 50 == 0 or index == len(chosen):
                console.print(f"  {index}/{len(chosen)} rows, {time.perf_counter() - started:.0f} s", highlight=False)
    elapsed_s = time.perf_counter() - started
    console.print(group_table(outcomes, lambda o: (o.row.family,), "per family", ("family",)))
    console.print(group_table(outcomes, lambda o: ("example" if o.row.stiffness_g_um is None
                                                   else f"{o.row.stiffness_g_um:5g}",),
                              "per stiffness (g/um: the bed's; xy: the toolhead's sideways)", ("stiffness",)))
    if args.pairs:
        console.print(group_table(outcomes, lambda o: (o.row.family, o.row.case, o.row.command),
                                  f"per case and command: worst row (force_safety_limit {FORCE_SAFETY_LIMIT_G:g} g)",
                                  ("family", "case", "command")))
    unsafe = [o for o in outcomes if not o.safe]
    if args.rows or unsafe:
        console.print(row_table(outcomes if args.rows else unsafe, "every row" if args.rows else "unsafe rows"))
    worst = max(outcomes, key=lambda o: o.peak_force_g)
    counts = _counts(outcomes)
    console.print(
        f"{len(outcomes)} rows in {elapsed_s:.0f} s: {counts['ok']} ok, {counts['refused']} refused, "
        f"{counts['error']} errors, {counts['INTERNAL']} internal errors. Worst peak force {worst.peak_force_g:.0f} g "
        f"= {worst.peak_force_g / FORCE_SAFETY_LIMIT_G:.2f} x force_safety_limit ({worst.row.family}: "
        f"{worst.row.case}, {worst.row.command}); rows over the limit: "
        f"{sum(o.peak_force_g > FORCE_SAFETY_LIMIT_G for o in outcomes)}; least clearance after a command "
        f"{min(o.clearance_mm for o in outcomes):.3f} mm (rows below 0: {sum(o.clearance_mm < 0 for o in outcomes)}); "
        f"false Z data {sum(o.false_z for o in outcomes)}; emergency stops ignored "
        f"{sum(o.stop_ignored for o in outcomes)}; unsafe rows {len(unsafe)}.", highlight=False)
    return 0 if not unsafe else 1


if __name__ == "__main__":
    import sys

    raise SystemExit(main(sys.argv[1:]))
