"""A whole print on the virtual printer: wall time per 1000 extrusion moves, early and late.

`tapcell run` of a slicer file runs thousands of G1 moves; each must cost the same at move
5000 as at move 1 (a session that slows down as its history grows never finishes a real
print). The print is the example Voron (examples/voron-load-cell.cfg, its load cell read at
each sample rate below): heat, home with safe_z_home, then zig-zag extrusion lines. The anchor
is the first 1000 moves of the same print: the last 1000 / first 1000 ratio should stay near 1.

Measured (2 cores, 2000 moves, 2692 s of printer time): 330 sps 8.0 / 8.1 s per 1000 moves (last /
first 1.01), 167x real time; 2000 sps 24.6 / 24.8 s (1.01), 55x. Most of it is the contact model:
at layer height the hot, oozing nozzle's film reaches the bed, and that path runs per simulated
sample.

`--slicers` runs the slicer-style files of the tests (PrusaSlicer, OrcaSlicer and Cura start
G-code, a cube's layers with extrusion, end G-code) to the end with the nozzle watch on and
prints, per file, the moves the watch guarded, the moves it stopped (a false stop: must be 0),
the largest force the cell read in a watched move against nozzle_watch_force, and the largest
true nozzle-bed force (SIM_TRUTH's peak_force_g).
"""

from __future__ import annotations

import argparse
import importlib.util
import tempfile
import time
from pathlib import Path

from rich.console import Console
from rich.table import Table

from tapcell.host.gcode import GCodeError, UnknownCommandError
from tapcell.host.printer import Printer

VORON = Path(__file__).resolve().parents[1] / "examples" / "voron-load-cell.cfg"
CALIBRATE = ("LOAD_CELL_CALIBRATE\nTARE\nSIM_PLACE_WEIGHT GRAMS=1000\nCALIBRATE GRAMS=1000\nACCEPT\n"
             "SIM_REMOVE_WEIGHT\nSAVE_CONFIG")
BLOCK = 1000


def extrusion_moves(count: int) -> list[str]:
    """Zig-zag lines 40 mm long, 0.45 mm apart, relative E, 30 mm/s (an infill)."""
    lines = []
    for k in range(count):
        x = 130.0 if k % 2 else 170.0
        y = 130.0 + 0.45 * (k // 2 % 80)
        lines.append(f"G1 X{x:.3f} Y{y:.3f} E1.33200 F1800")
    return lines


def run_print(sample_rate: int, moves: int, folder: Path) -> tuple[float, float, float, float]:
    """(wall s of the first block, wall s of the last block, wall s in all, printer s in all)."""
    path = folder / f"voron-{sample_rate}.cfg"
    text = VORON.read_text().replace("sample_rate: 2000", f"sample_rate: {sample_rate}")
    if sample_rate < 2000:
        # Fewer samples per second let the nozzle travel further before a stop: the force guard
        # allows an unmeasured bed to be met at 3 mm/s at 330 sps on the toolboard (docs/safety.md).
        text = text.replace("\nspeed: 5\nsamples: 1", "\nspeed: 3\nsamples: 1")
    path.write_text(text)
    printer = Printer.from_config(str(path), responses=[])
    printer.gcode.run_script(CALIBRATE)
    printer.gcode.run_script("G28\nM104 S215\nM109 S215\nG1 Z0.2 F600\nM83")
    run_line = printer.gcode.run_line
    printer_start_s = printer.get_time()
    block_wall_s = []
    start = time.perf_counter()
    lines = extrusion_moves(moves)
    for first in range(0, moves, BLOCK):
        block_start = time.perf_counter()
        for line in lines[first:first + BLOCK]:
            run_line(line)
        block_wall_s.append(time.perf_counter() - block_start)
    return block_wall_s[0], block_wall_s[-1], time.perf_counter() - start, printer.get_time() - printer_start_s


SLICER_FILES = Path(__file__).resolve().parents[1] / "tests" / "klipper" / "slicer_files.py"
SLICERS = ("prusaslicer", "orcaslicer", "cura")
LAYERS_BEGIN = ";LAYER_CHANGE"
# As the slicer tests run them: the example's 5x5 mesh made 3x3 and its sensor read at 330 sps.
SHORTER = {"probe_count: 5, 5": "probe_count: 3, 3", "sample_rate: 2000": "sample_rate: 330",
           "\nspeed: 5\nsamples: 1": "\nspeed: 3\nsamples: 1"}


def slicer_file(slicer: str, layers: int) -> str:
    """The slicer-style file the tests print (tests/klipper/slicer_files.py), loaded from its path."""
    spec = importlib.util.spec_from_file_location("slicer_files", SLICER_FILES)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.slicer_file(slicer, layers=layers)[0]


def print_watched(slicer: str, layers: int, folder: Path) -> dict:
    """Print one slicer file with the nozzle watch on; what the watch and the truth saw."""
    path = folder / f"voron-{slicer}.cfg"
    text = VORON.read_text()
    for old, new in SHORTER.items():
        text = text.replace(old, new)
    path.write_text(text)
    printer = Printer.from_config(str(path), responses=[])
    printer.gcode.run_script(CALIBRATE)
    truth = printer.backend.truth
    lines = slicer_file(slicer, layers).splitlines()
    error = None
    seen: set[str] = set()
    for line in lines:
        if line == LAYERS_BEGIN and line not in seen:
            truth.take_peak_force_g()  # the layers' own peak: not the taps of G28 and the mesh before them
            seen.add(line)
        try:
            printer.gcode.run_line(line)
        except UnknownCommandError:
            continue  # M201/M203/M205: Klipper says "Unknown command" and goes on
        except GCodeError as exc:
            error = str(exc)
            break
    watch = printer.lookup_object("toolhead").nozzle_watch
    return {"lines": len(lines), "watched": watch.watched_moves, "stops": watch.collisions,
            "largest_g": watch.largest_force_g, "limit_g": watch.options.force_g,
            "height_mm": watch.options.height_mm, "truth_peak_g": truth.take_peak_force_g(), "error": error}


def slicer_table(layers: int, console: Console) -> Table:
    table = Table(title=f"slicer files, {layers} layers, nozzle watch on: the largest force a print put on the "
                        "nozzle against the watch's limit (nozzle_watch_force)")
    for column in ("file", "lines", "watched moves", "stopped", "largest g", "limit g", "largest / limit",
                   "true peak g (layers)", "ended"):
        table.add_column(column, justify="right")
    with tempfile.TemporaryDirectory() as folder:
        for slicer in SLICERS:
            console.print(f"bench print_run: {slicer} ...")
            row = print_watched(slicer, layers, Path(folder))
            table.add_row(slicer, str(row["lines"]), str(row["watched"]), str(row["stops"]), f"{row['largest_g']:.1f}",
                          f"{row['limit_g']:.0f}", f"{row['largest_g'] / row['limit_g']:.3f}",
                          f"{row['truth_peak_g']:.1f}", "to the end" if row["error"] is None else row["error"])
    return table


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="bench/print_run.py", description=__doc__)
    parser.add_argument("--moves", type=int, default=2000)
    # 2000 sps (the example's own rate) costs 3x the wall time: `--rates 330 2000` for both.
    parser.add_argument("--rates", type=int, nargs="*", default=[330])
    parser.add_argument("--slicers", action="store_true", help="print the slicer files with the nozzle watch on")
    parser.add_argument("--layers", type=int, default=8, help="layers of the cube in each slicer file")
    args = parser.parse_args(argv)
    if args.slicers:
        console = Console(width=160)
        console.print(slicer_table(args.layers, console))
        return 0
    table = Table(title=f"a print of {args.moves} extrusion moves (anchor: its own first {BLOCK} moves)")
    for column in ("sample rate", "first 1000 s", "last 1000 s", "last / first", "wall s", "printer s",
                   "x real time"):
        table.add_column(column, justify="right")
    console = Console()
    with tempfile.TemporaryDirectory() as folder:
        for rate in args.rates:
            console.print(f"bench print_run: {rate} sps, {args.moves} moves ...")
            first_s, last_s, wall_s, printer_s = run_print(rate, args.moves, Path(folder))
            table.add_row(f"{rate}", f"{first_s:.2f}", f"{last_s:.2f}", f"{last_s / first_s:.2f}", f"{wall_s:.1f}",
                          f"{printer_s:.0f}", f"{printer_s / wall_s:.0f}")
    console.print(table)
    return 0
