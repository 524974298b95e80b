"""Where a tap's analysis time goes, step by step (the speed passes of issue 21 report these).

Each named step of `tapcell.tap.analysis` (`STEPS`: the functions `_analyze` calls in turn) is timed
around its call while every tap of a folder is analysed, after one warm pass, ROUNDS times over. The
taps around the median total (the middle fifth) are averaged per step: what a typical tap spends
where, not what the slowest ones do. Wall time (`perf_counter_ns`) with the cycle collector off, in
this process: a step's cost warm, not the CLI's cold one (`bench tap_speed` measures that, beside
Kalico). The step wrappers add ~0.2 µs a call; the sum of the steps is printed beside the total.

Run: .venv/bin/python -m bench tap_steps [DIR] [--rounds N]
     (DIR: a folder of tap files; default: taplab seed 1, 20 taps a scenario, generated for the run)
"""

from __future__ import annotations

import argparse
import contextlib
import gc
import statistics
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

from bench.analyze_same import tap_files
from tapcell.tap import TapFileError, analysis
from tapcell.tap.cli import options_from_settings
from tapcell.tap.readers import read_tap_file
from tapcell.taplab.generate import generate_set

# The steps of `analysis.analyze_tap` and `_analyze`, in their order.
STEPS = ("split_tap", "result_of_split", "lag_before_the_fits", "check_split", "model_window",
         "fit_contact_models", "check_contact_heights", "apply_delay_estimate", "z_from_sharp_model_or_lines",
         "z_from_toe_model", "check_decompression_samples", "z_uncertainty", "compression_stiffness",
         "run_classifier", "AnalysisContext")


@contextlib.contextmanager
def timed_steps(spent_ns: dict[str, int]) -> Iterator[None]:
    """While inside, each step of STEPS adds its wall time (ns) to spent_ns[step]; restored after."""
    originals = {name: getattr(analysis, name) for name in STEPS}

    def timed(name, step):
        def call(*args, **kwargs):
            started = time.perf_counter_ns()
            try:
                return step(*args, **kwargs)
            finally:
                spent_ns[name] = spent_ns.get(name, 0) + time.perf_counter_ns() - started
        return call

    try:
        for name, step in originals.items():
            setattr(analysis, name, timed(name, step))
        yield
    finally:
        for name, step in originals.items():
            setattr(analysis, name, step)


def step_times_us(taps: list, rounds: int) -> tuple[float, dict[str, float], float]:
    """(median total µs, each step's mean µs over the taps around the median, their mean total µs)."""
    options = options_from_settings([])
    rows: list[tuple[int, dict[str, int]]] = []
    collecting = gc.isenabled()
    gc.disable()
    try:
        for tap in taps:  # warm: imports, caches, the kernels' kept tables
            analysis.analyze_tap(tap, options)
        spent_ns: dict[str, int] = {}
        with timed_steps(spent_ns):
            for _ in range(rounds):
                for tap in taps:
                    spent_ns.clear()
                    started = time.perf_counter_ns()
                    analysis.analyze_tap(tap, options)
                    rows.append((time.perf_counter_ns() - started, dict(spent_ns)))
    finally:
        if collecting:
            gc.enable()
    rows.sort(key=lambda row: row[0])
    middle = rows[len(rows) // 2 - len(rows) // 10: len(rows) // 2 + len(rows) // 10 + 1]
    steps_us = {name: statistics.mean(row[1].get(name, 0) for row in middle) / 1000.0 for name in STEPS}
    return rows[len(rows) // 2][0] / 1000.0, steps_us, statistics.mean(row[0] for row in middle) / 1000.0


def _taps(folder: Path) -> list:
    return [tap for path in tap_files(str(folder)) for tap in read_tap_file(path)]


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench tap_steps", description=__doc__.splitlines()[0])
    parser.add_argument("folder", type=Path, nargs="?", help="a folder of tap files (default: taplab seed 1)")
    parser.add_argument("--rounds", type=int, default=3, help="passes over the taps (default 3)")
    args = parser.parse_args(argv)
    if args.folder is None:
        with tempfile.TemporaryDirectory(prefix="tap-steps-") as scratch:
            generate_set(Path(scratch), seed=1, taps_per_scenario=20)
            return _report(Path(scratch), args.rounds)
    return _report(args.folder, args.rounds)


def _report(folder: Path, rounds: int) -> int:
    if not folder.is_dir():
        print(f"tap_steps: {folder}: not a folder of tap files", file=sys.stderr)
        return 2
    if rounds < 1:
        print(f"tap_steps: --rounds {rounds}: at least 1", file=sys.stderr)
        return 2
    try:
        taps = _taps(folder)
    except TapFileError as problem:
        print(f"tap_steps: {problem}", file=sys.stderr)
        return 2
    if not taps:
        print(f"tap_steps: {folder}: no tap files", file=sys.stderr)
        return 2
    median_us, steps_us, middle_us = step_times_us(taps, rounds)
    print(f"{len(taps)} taps x {rounds} rounds; median tap {median_us:.1f} µs")
    for name in STEPS:
        print(f"{name:<30} {steps_us[name]:7.1f} µs")
    print(f"{'sum of the steps':<30} {sum(steps_us.values()):7.1f} µs of {middle_us:.1f} (the middle fifth's mean)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
