"""Time per analysed tap against the number of samples (target: 0.3 ms at 600 samples), with the
default (sharp) contact model and with the toe model + the lag from the halt (issue 12).

Run: .venv/bin/python -m bench tap_speed

The Kalico column is the research notes' measurement, not a run beside ours: only
`tapcell benchmark` (bench tap_benchmark) runs Kalico on the same taps in the same run, and on a
shared machine only ratios within one run mean anything.
"""

from __future__ import annotations

import sys
import time

import numpy as np
from rich.console import Console
from rich.table import Table

from tapcell.tap import AnalysisOptions, analyze_tap
from tapcell.tap.synth import synth_tap

TARGET_US_AT_600 = 300.0
# Kalico's analyze() as measured in the research notes (ms), for the nearest tap size.
KALICO_MS = {300: 3.8, 600: 4.6, 2000: 4.8, 15000: 9.7}
# (samples, sample rate): the approach record is stretched to reach the sample count.
SIZES = ((300, 320.0), (600, 660.0), (2000, 2000.0), (15000, 330.0))
TOE = AnalysisOptions(contact_model="toe", sensor_delay_s="halt")


def tap_with_samples(samples: int, sps: float):
    fixed_s = 0.3 + 0.1 / (sps * 0.001) + 0.05 + 0.01  # dwell + pullback (synth default 0.1 mm) + tail + over-travel
    tap = synth_tap(sample_rate_sps=sps, approach_time_s=max(0.05, samples / sps - fixed_s), seed=1)
    return tap


def time_per_tap_us(tap, repeats: int, options: AnalysisOptions | None = None) -> float:
    analyze_tap(tap, options)
    runs = []
    for _ in range(repeats):
        started = time.perf_counter()
        analyze_tap(tap, options)
        runs.append(time.perf_counter() - started)
    return float(np.median(runs)) * 1e6


def main(argv: list[str]) -> int:
    repeats = int(argv[0]) if argv else 200
    table = Table(title=f"analyze_tap time per tap (median of {repeats})")
    for column in ("samples", "sps", "µs per tap", "vs 300 µs target", "toe + halt lag µs", "toe / default",
                   "Kalico ms (notes)"):
        table.add_column(column, justify="right")
    for samples, sps in SIZES:
        tap = tap_with_samples(samples, sps)
        us = time_per_tap_us(tap, repeats)
        toe_us = time_per_tap_us(tap, repeats, TOE)
        table.add_row(str(len(tap.time_s)), f"{sps:g}", f"{us:.0f}", f"{us / TARGET_US_AT_600:.2f}×",
                      f"{toe_us:.0f}", f"{toe_us / us:.2f}×", f"{KALICO_MS[samples]:.1f}")
    Console().print(table)
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
