"""Time per analysed tap against the number of samples (target: 0.3 ms at 600 samples), with the
default analysis (the toe model + the lag from the halt, since issue 12) and the sharp model with
lag 0 (the default before) as the anchor, run side by side; and the default again on the numpy
twins of the compiled kernels (tapcell.tap.native), what an install without a C compiler runs.

Run: .venv/bin/python -m bench tap_speed

Kalico's analysis is timed beside ours on the same taps by `tapcell benchmark` (bench
tap_benchmark), which runs it from its own environment; on a shared machine only ratios within
one run mean anything.
"""

from __future__ import annotations

import contextlib
import sys
import time

import numpy as np
from rich.console import Console
from rich.table import Table

from tapcell.tap import AnalysisOptions, analysis, analyze_tap, contact, robust, segments, toe
from tapcell.tap.synth import synth_tap

TARGET_US_AT_600 = 300.0
# (samples, sample rate): the approach record is stretched to reach the sample count.
SIZES = ((300, 320.0), (600, 660.0), (2000, 2000.0), (15000, 330.0))
SHARP_LAG_0 = AnalysisOptions(contact_model="sharp", sensor_delay_s=0.0)
# The modules that call a compiled kernel through their module-level `_C`.
KERNEL_CALLERS = (robust, analysis, segments, contact, toe)


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
    for column in ("samples", "sps", "default µs per tap", "vs 300 µs target", "sharp, lag 0 µs",
                   "default / sharp", "numpy twins µs", "twins / kernels"):
        table.add_column(column, justify="right")
    for samples, sps in SIZES:
        tap = tap_with_samples(samples, sps)
        us = time_per_tap_us(tap, repeats)
        sharp_us = time_per_tap_us(tap, repeats, SHARP_LAG_0)
        with numpy_twins():
            twins_us = time_per_tap_us(tap, repeats)
        table.add_row(str(len(tap.time_s)), f"{sps:g}", f"{us:.0f}", f"{us / TARGET_US_AT_600:.2f}×",
                      f"{sharp_us:.0f}", f"{us / sharp_us:.2f}×", f"{twins_us:.0f}", f"{twins_us / us:.1f}×")
    Console().print(table)
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
