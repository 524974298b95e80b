"""G28 and the nozzle watch on a sensor that corrupts frames, seed by seed, against the clean sensor.

Each seed builds the example printer (examples/virtual-printer.cfg with its [safe_z_home], the
calibration written from the simulator's own scale) twice: the `clean` scenario (the anchor) and
the `glitchy` one (a long unshielded cable: about one flipped bit every 2 s, 595 g to 38,000 g on
this cell). It runs G28, then six watched 210 mm passes at Z 1 over the flat bed (the travel of
tests/probe/test_nozzle_watch_glitches.py), and prints how G28 ended, where it put the bed
(SIM_TRUTH's contact height under the nozzle, in toolhead Z: the trigger-only homing's own bias),
the corrupted frames moved on from, the passes' false stops (nothing touches the nozzle: any stop
is false) and the largest true nozzle force. A seed is unsafe when that force passes
force_safety_limit.

Run: .venv/bin/python -m bench glitchy_sensor [--seeds N]
"""

from __future__ import annotations

import argparse
import tempfile
from dataclasses import dataclass
from pathlib import Path

from rich.console import Console
from rich.table import Table

from tapcell.host.gcode import GCodeError
from tapcell.host.printer import Printer

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "virtual-printer.cfg"
FORCE_SAFETY_LIMIT_G = 2000.0
CALIBRATION = "counts_per_gram: 110\nreference_tare_counts: -38000\n"
PASSES = ["G1 Z1 F600\nG1 X10 Y110 F6000"] + [f"G1 X{220 if i % 2 == 0 else 10} Y{110 + i} F6000" for i in range(6)]
MOVED_ON = "(a corrupted frame)"


@dataclass
class Run:
    homed: str            # "yes" or the start of G28's error
    bed_um: float | None  # the bed's true contact height above toolhead Z 0 after G28
    homing_frames: int    # corrupted frames moved on from during G28
    false_stops: int      # passes that ended with an error
    pass_frames: int      # corrupted frames moved on from during the passes
    peak_g: float         # the largest true nozzle force, G28 and passes


def run_seed(scenario: str, seed: int, folder: Path) -> Run:
    folder.mkdir(parents=True, exist_ok=True)
    text = EXAMPLE.read_text().replace("scenario: clean\nseed: 1\n", f"scenario: {scenario}\nseed: {seed}\n")
    path = folder / "printer.cfg"
    path.write_text(text.replace("samples: 1\n", f"samples: 1\n{CALIBRATION}", 1))
    responses: list[str] = []
    printer = Printer.from_config(str(path), responses=responses)
    truth = printer.backend.truth
    truth.take_peak_force_g()
    try:
        printer.gcode.run_script("G28")
    except GCodeError as exc:
        return Run(str(exc)[:48], None, sum(MOVED_ON in r for r in responses), 0, 0, truth.take_peak_force_g())
    x_mm, y_mm, _ = printer.backend.position
    bed_um = 1000.0 * (float(truth.contact_z_at(x_mm, y_mm)) + printer.lookup_object("toolhead").frame_offset_mm["z"])
    homing_frames = sum(MOVED_ON in r for r in responses)
    peak_g = truth.take_peak_force_g()
    false_stops = 0
    for script in PASSES:
        try:
            printer.gcode.run_script(script)
        except GCodeError:
            false_stops += 1
    pass_frames = sum(MOVED_ON in r for r in responses) - homing_frames
    return Run("yes", bed_um, homing_frames, false_stops, pass_frames, max(peak_g, truth.take_peak_force_g()))


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="bench/glitchy_sensor.py", description=__doc__)
    parser.add_argument("--seeds", type=int, default=10, help="seeds 1..N (default 10)")
    args = parser.parse_args(argv)
    table = Table(title="G28 and six watched passes at Z 1: the glitchy sensor against the clean one (anchor), "
                        "per seed")
    for column in ("seed", "clean: bed um", "glitchy: homed", "glitchy: bed um", "bed diff um", "G28 frames",
                   "pass frames", "false stops", "peak g", "peak / limit", "safe"):
        table.add_column(column, justify="right")
    console = Console(width=200)
    homed = false_stops = unsafe = frames = 0
    worst_diff_um = worst_peak_g = 0.0
    with tempfile.TemporaryDirectory() as folder:
        for seed in range(1, args.seeds + 1):
            console.print(f"bench glitchy_sensor: seed {seed} ...")
            clean = run_seed("clean", seed, Path(folder) / f"{seed}-clean")
            glitchy = run_seed("glitchy", seed, Path(folder) / f"{seed}-glitchy")
            peak_g = max(clean.peak_g, glitchy.peak_g)
            safe = peak_g <= FORCE_SAFETY_LIMIT_G
            unsafe += not safe
            worst_peak_g = max(worst_peak_g, peak_g)
            homed += glitchy.homed == "yes"
            false_stops += glitchy.false_stops
            frames += glitchy.homing_frames + glitchy.pass_frames
            diff = None
            if glitchy.bed_um is not None and clean.bed_um is not None:
                diff = glitchy.bed_um - clean.bed_um
                worst_diff_um = max(worst_diff_um, abs(diff))
            table.add_row(str(seed), "-" if clean.bed_um is None else f"{clean.bed_um:.1f}", glitchy.homed,
                          "-" if glitchy.bed_um is None else f"{glitchy.bed_um:.1f}",
                          "-" if diff is None else f"{diff:+.1f}", str(glitchy.homing_frames),
                          str(glitchy.pass_frames), str(glitchy.false_stops), f"{peak_g:,.0f}",
                          f"{peak_g / FORCE_SAFETY_LIMIT_G:.3f}", "yes" if safe else "NO")
    console.print(table)
    console.print(f"{args.seeds} seeds: G28 homed on {homed}, {frames} corrupted frames moved on from, {false_stops} "
                  f"false stops in {6 * homed} watched passes; bed height within {worst_diff_um:.1f} um of the clean "
                  f"sensor's; {unsafe} unsafe, largest true force {worst_peak_g:,.0f} g "
                  f"({worst_peak_g / FORCE_SAFETY_LIMIT_G:.3f} x force_safety_limit)")
    return 0
