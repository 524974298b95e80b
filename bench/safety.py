"""Safety benchmark: every fault of the virtual printer against every probing command.

Issue 10's targets, per row (fault x command x speed x sensor x drift filter):

* the largest true nozzle-bed force (simulator truth, `SIM_TRUTH`'s peak_force_g) stays at or
  below `force_safety_limit` (a move the host refuses counts as safe: nothing pressed);
* after the command, error or not, the nozzle is clear of the bed (nozzle_clearance_mm >= 0);
* no false Z data: a Z datum (G28 Z), probe result or mesh that the command reports as good is
  within FALSE_Z_MM of the true bed, beyond the lag a trigger-only result has by design;
* no internal error: every failure is a G-code error message.

Each row builds a fresh printer from examples/virtual-printer.cfg (the sensor, its sample rate,
the probing speed and the drift filter set for the row; calibration values written from the
simulator so no weight is needed), homes it, injects the fault with `SIM_FAULT` and runs the
command. The full grid is 10 faults x 8 commands x 4 speeds x 3 sensors x 2 filters = 1920
rows; by default each (fault, command) pair runs its 4 speeds once, with the sensor and the
filter turning over from pair to pair so every pair meets every sensor and filter setting as
often as the grid allows (320 rows, a few minutes on 2 cores). `--full` runs the whole grid.

Run: .venv/bin/python -m bench safety [--full] [--workers W] [--rows] [--only TEXT]
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
# A drift filter that hides a slow tap on this bed (3.26 g/um): the drift window must stop it.
DRIFT_FILTER_HZ = 10.0
FORCE_SAFETY_LIMIT_G = 2000.0
# (fault, SIM_FAULT parameters); WHEN= is replaced by AT= for the command that does not move.
FAULTS = {
    "none": None,
    "stuck at contact": "NAME=stuck WHEN=contact",
    "stuck after trigger": "NAME=stuck WHEN=trigger",
    "disconnected at contact": "NAME=disconnected WHEN=contact",
    "saturated at contact": "NAME=saturation WHEN=contact",
    "chip offset jump": "NAME=chip_reset WHEN=probing_move GAP_S=0.002",
    "corrupt frames": "NAME=corrupt_frame WHEN=probing_move COUNT=3 SPACING_S=0.1",
    "200 g touch, 0.3 s": "NAME=weight WHEN=probing_move GRAMS=200 DURATION=0.3",
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
TRIGGER_ONLY = ("G28 Z", "BED_MESH two_pass", "BED_MESH prusa")
# A reported Z further than this from the true bed (beyond a trigger-only result's lag) is false.
FALSE_Z_MM = 0.1
MESH_CHECK_POINTS = 9           # per axis: where a mesh is compared with the true bed
PROBE_XY_MM = (110.0, 110.0)
START_Z_MM = 3.0                # where each command starts, above the bed


@dataclass(frozen=True)
class Row:
    fault: str
    command: str
    speed_mm_s: float
    sensor: str
    drift_filter: bool


@dataclass
class Outcome:
    row: Row
    result: str                  # ok, refused, error, INTERNAL
    message: str                 # the error message (first line), or ""
    peak_force_g: float
    clearance_mm: float
    z_error_mm: float | None     # worst |reported Z - true bed| of a command that reported Z
    z_allowed_mm: float          # what that error may be (FALSE_Z_MM + a trigger-only lag)
    seconds: float

    @property
    def false_z(self) -> bool:
        return self.z_error_mm is not None and self.z_error_mm > self.z_allowed_mm

    @property
    def safe(self) -> bool:
        return (self.peak_force_g <= FORCE_SAFETY_LIMIT_G and self.clearance_mm >= 0.0 and not self.false_z
                and self.result != "INTERNAL")


def rows(full: bool) -> list[Row]:
    """The grid, or per (fault, command) pair its four speeds with turning sensor and filter."""
    sensors = list(SENSORS)
    if full:
        return [Row(f, c, v, s, d) for f, c, v, s, d in
                itertools.product(FAULTS, COMMANDS, SPEEDS_MM_S, sensors, (False, True))]
    chosen = []
    for pair, (fault, command) in enumerate(itertools.product(FAULTS, COMMANDS)):
        for i, speed in enumerate(SPEEDS_MM_S):
            chosen.append(Row(fault, command, speed, sensors[(pair + i) % 3], bool((pair + i // 2) % 2)))
    return chosen


def config_text(row: Row) -> str:
    """examples/virtual-printer.cfg with the row's sensor, speed and filter, a 3 x 3 mesh and [prusa_probe]."""
    probe_lines, sim_lines = SENSORS[row.sensor]
    speed = row.speed_mm_s
    text = EXAMPLE.read_text()
    text = text.replace("scenario: clean\nseed: 1\n", f"scenario: clean\nseed: 1\n{sim_lines}")
    text = text.replace("max_z_velocity: 15", f"max_z_velocity: {max(speed, 5.0):g}")
    text = text.replace("sensor_type: hx717\nsclk_pin: PA5\ndout_pin: PA4\nsample_rate: 320\n", probe_lines)
    text = text.replace("\nspeed: 5\n", f"\nspeed: {speed:g}\n", 1)
    # Calibrated as LOAD_CELL_CALIBRATE would find it (the virtual cell: 110 counts/g, -38000 at zero).
    extra = "counts_per_gram: 110\nreference_tare_counts: -38000\n"
    if row.drift_filter:
        extra += f"drift_filter_cutoff_frequency: {DRIFT_FILTER_HZ:g}\n"
    text = text.replace("samples: 1\n", f"samples: 1\n{extra}", 1)
    text = text.replace("probe_count: 7, 7", "probe_count: 3, 3").replace("algorithm: bicubic", "algorithm: lagrange")
    text += f"\n[prusa_probe]\nz_fast_speed: {speed:g}\nz_slow_speed: {min(speed, 1.0):g}\n"
    return text


def fault_line(row: Row, now_s: float) -> str | None:
    params = FAULTS[row.fault]
    if params is None:
        return None
    if row.command == "LOAD_CELL_TEST_TAP":
        params = " ".join(p for p in params.split() if not p.startswith("WHEN=")) + \
            f" AT={now_s + TEST_TAP_FAULT_DELAY_S:.3f}"
    return f"SIM_FAULT {params}"


def true_bed_z_mm(printer, x_mm, y_mm):
    """The bed's true contact height at toolhead (x, y), in toolhead coordinates."""
    vp = printer.backend
    frame = printer.lookup_object("toolhead").frame_offset_mm
    return np.asarray(vp.truth.contact_z_at(np.asarray(x_mm) - frame["x"], np.asarray(y_mm) - frame["y"])) \
        + frame["z"]


def trigger_lag_mm(printer, speed_mm_s: float) -> float:
    """How far below the bed a trigger-only result lies by design at this speed (simulator truth):
    the trigger depth, then up to 1.5 conversion windows, the ADC pipeline and the stop delay of travel."""
    vp = printer.backend
    p = vp.params
    period_s = 1.0 / p.sample_rate_sps
    pipeline_s = (1.0 if p.chip == "ads1220" else 0.0) * period_s
    travel_s = 1.6 * period_s + pipeline_s + p.stop_delay_s + p.multi_mcu_delay_s
    return (150.0 / vp.truth.stiffness_g_um + speed_mm_s * travel_s * 1000.0) / 1000.0


def z_error_mm(printer, row: Row) -> float | None:
    """Worst |reported Z - true bed| of what the command reported as good (None: it reported none)."""
    if row.command in ("PROBE", "PROBE_ACCURACY"):
        probe = printer.lookup_object("probe")
        x, y, _ = printer.lookup_object("toolhead").get_position()
        return abs(probe.last_z_result - float(true_bed_z_mm(printer, x, y)))
    if row.command.startswith("BED_MESH"):
        mesh = printer.lookup_object("bed_mesh").mesh
        grid = mesh.grid
        xs, ys = np.meshgrid(np.linspace(grid.min_x_mm, grid.max_x_mm, MESH_CHECK_POINTS),
                             np.linspace(grid.min_y_mm, grid.max_y_mm, MESH_CHECK_POINTS))
        return float(np.max(np.abs(np.asarray(mesh.z_at(xs, ys)) - true_bed_z_mm(printer, xs, ys))))
    if row.command == "G28 Z":
        x, y, _ = printer.lookup_object("toolhead").get_position()
        return abs(float(true_bed_z_mm(printer, x, y)))
    return None


def run_row(row: Row) -> Outcome:
    from tapcell.host.config import ConfigError
    from tapcell.host.gcode import GCodeError
    from tapcell.host.printer import Printer

    started = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "printer.cfg"
        path.write_text(config_text(row))
        try:
            printer = Printer.from_config(str(path), responses=[])
        except ConfigError as exc:
            return Outcome(row, "refused", str(exc).splitlines()[0], 0.0, np.inf, None, 0.0,
                           time.perf_counter() - started)
        vp = printer.backend
        # Home X/Y, and Z from the truth (G28 Z is a row of its own, with its faults and speeds).
        printer.gcode.run_script("G28 X Y\nG1 X{:g} Y{:g} F6000".format(*PROBE_XY_MM))
        printer.lookup_object("toolhead").set_z_position(vp.position[2] - vp.truth.contact_z_at(*PROBE_XY_MM))
        printer.gcode.run_script(f"G1 Z{START_Z_MM:g} F600")
        vp.truth.take_peak_force_g()
        line = fault_line(row, vp.now_s)
        script = COMMANDS[row.command] if line is None else f"{line}\n{COMMANDS[row.command]}"
        result, message = "ok", ""
        try:
            printer.gcode.run_script(script)
        except GCodeError as exc:
            message = str(exc).splitlines()[0]
            result = "INTERNAL" if message.startswith("Internal error") else "error"
        except Exception as exc:  # noqa: BLE001 - a bug in tapcell: counted, shown, never hidden
            result, message = "INTERNAL", "".join(traceback.format_exception_only(exc)).strip()
        if result == "error" and "refus" in message.lower():
            result = "refused"
        z_error = z_error_mm(printer, row) if result == "ok" else None
        allowed = FALSE_Z_MM + (trigger_lag_mm(printer, row.speed_mm_s) if row.command in TRIGGER_ONLY else 0.0)
        return Outcome(row, result, message, vp.truth.take_peak_force_g(), vp.truth.nozzle_clearance_mm,
                       z_error, allowed, time.perf_counter() - started)


def pair_table(outcomes: list[Outcome]) -> Table:
    table = Table(title=f"per fault and command: worst row (force_safety_limit {FORCE_SAFETY_LIMIT_G:g} g)")
    for name in ("fault", "command", "rows", "ok", "refused", "error", "internal", "peak g", "peak/limit",
                 "min clearance mm", "worst Z error mm", "false Z", "unsafe"):
        table.add_column(name, justify="left" if name in ("fault", "command") else "right")
    for (fault, command), group in itertools.groupby(outcomes, key=lambda o: (o.row.fault, o.row.command)):
        group = list(group)
        counts = {r: sum(o.result == r for o in group) for r in ("ok", "refused", "error", "INTERNAL")}
        peak = max(o.peak_force_g for o in group)
        errors = [o.z_error_mm for o in group if o.z_error_mm is not None]
        unsafe = sum(not o.safe for o in group)
        table.add_row(fault, command, str(len(group)), *(str(counts[r]) for r in ("ok", "refused", "error", "INTERNAL")),
                      f"{peak:.0f}", f"{peak / FORCE_SAFETY_LIMIT_G:.2f}",
                      f"{min(o.clearance_mm for o in group):.3f}", f"{max(errors):.3f}" if errors else "–",
                      str(sum(o.false_z for o in group)), str(unsafe), style="bold red" if unsafe else None)
    return table


def row_table(outcomes: list[Outcome], title: str) -> Table:
    table = Table(title=title)
    for name in ("fault", "command", "mm/s", "sensor", "drift", "outcome", "peak g", "clearance mm",
                 "Z error mm", "message"):
        table.add_column(name, justify="right" if name in ("mm/s", "peak g", "clearance mm", "Z error mm") else "left")
    for o in outcomes:
        r = o.row
        table.add_row(r.fault, r.command, f"{r.speed_mm_s:g}", r.sensor, "on" if r.drift_filter else "off", o.result,
                      f"{o.peak_force_g:.0f}", f"{o.clearance_mm:.3f}",
                      "–" if o.z_error_mm is None else f"{o.z_error_mm:.3f}", o.message[:90],
                      style=None if o.safe else "bold red")
    return table


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="bench safety", description=__doc__.splitlines()[0])
    parser.add_argument("--full", action="store_true", help="every row of the grid (1920)")
    parser.add_argument("--workers", type=int, default=min(os.cpu_count() or 1, 2))
    parser.add_argument("--rows", action="store_true", help="print every row, not only the unsafe ones")
    parser.add_argument("--only", default="", help="run only rows whose fault or command contains this text")
    args = parser.parse_args(argv)
    chosen = [r for r in rows(args.full) if args.only.lower() in f"{r.fault} {r.command}".lower()]
    if not chosen or args.workers < 1:
        parser.error("no rows chosen (--only), or --workers below 1")
    console = Console(width=200)
    started = time.perf_counter()
    outcomes = []
    with ProcessPoolExecutor(args.workers) as pool:
        for index, outcome in enumerate(pool.map(run_row, chosen, chunksize=2), start=1):
            outcomes.append(outcome)
            if index % 20 == 0 or index == len(chosen):
                console.print(f"  {index}/{len(chosen)} rows, {time.perf_counter() - started:.0f} s", highlight=False)
    elapsed_s = time.perf_counter() - started
    console.print(pair_table(outcomes))
    unsafe = [o for o in outcomes if not o.safe]
    if args.rows or unsafe:
        console.print(row_table(outcomes if args.rows else unsafe, "every row" if args.rows else "unsafe rows"))
    peak = max(o.peak_force_g for o in outcomes)
    counts = {r: sum(o.result == r for o in outcomes) for r in ("ok", "refused", "error", "INTERNAL")}
    console.print(
        f"{len(outcomes)} rows in {elapsed_s:.0f} s: {counts['ok']} ok, {counts['refused']} refused, "
        f"{counts['error']} errors, {counts['INTERNAL']} internal errors. Peak force {peak:.0f} g "
        f"({peak / FORCE_SAFETY_LIMIT_G:.2f} x the limit; rows over it: "
        f"{sum(o.peak_force_g > FORCE_SAFETY_LIMIT_G for o in outcomes)}); least clearance after a command "
        f"{min(o.clearance_mm for o in outcomes):.3f} mm (rows below 0: {sum(o.clearance_mm < 0 for o in outcomes)}); "
        f"false Z data {sum(o.false_z for o in outcomes)}; unsafe rows {len(unsafe)}.", highlight=False)
    return 0 if not unsafe else 1


if __name__ == "__main__":
    import sys

    raise SystemExit(main(sys.argv[1:]))
