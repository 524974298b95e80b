"""PROBE_ACCURACY on the virtual printer: the pooled standard deviation beside the single taps', and the pool's cost.

For each scenario and seed: calibrate, G28, PROBE HOME=Z, then PROBE_ACCURACY SAMPLES=10 from 0.4 mm
clearance, as a user runs it. The printer reports Klipper's line over the pooled Zs and the single-tap line
beside it (docs/probing.md, "Pooling"); this reads both from the probe (`last_accuracy`,
`last_accuracy_single`). Columns: the standard deviation of the single taps' Zs and of the pooled Zs (µm,
rms over the seeds), their ratio (the worst seed's too), the bias of each average against the simulator's
true contact (µm, mean over the seeds), and the cost: the process time of pooling the 10 taps (tapcell.tap.pool.apply_pool on
copies of the printer's analyses, median of 5) against analysing the same 10 taps again in the same run.
"""

from __future__ import annotations

import copy
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table

from bench.probe_session import EXAMPLE
from tapcell.host.printer import Printer
from tapcell.tap import analyze_tap
from tapcell.tap.pool import apply_pool

SCENARIOS = ("clean", "soft-sheet", "slow-adc", "noisy-mains", "bowden-drift")
SEEDS = (1, 2, 3, 4, 5)
TAPS = 10
TIMING_REPEATS = 5


def make_printer(scenario: str, seed: int, workdir: Path, responses: list[str]) -> Printer:
    text = EXAMPLE.read_text().replace("scenario: clean\nseed: 1\n", f"scenario: {scenario}\nseed: {seed}\n")
    if scenario == "slow-adc":  # an HX711 at 80 sps; G28 meets an unmeasured bed at 2 mm/s there (docs/safety.md)
        text = text.replace("sensor_type: hx717", "sensor_type: hx711").replace("sample_rate: 320", "sample_rate: 80")
        text = text.replace("\nspeed: 5\n", "\nspeed: 2\n", 1)
    path = workdir / f"{scenario}-{seed}.cfg"
    path.write_text(text)
    printer = Printer.from_config(str(path), responses=responses)
    printer.gcode.run_script("LOAD_CELL_CALIBRATE\nTARE\nSIM_PLACE_WEIGHT GRAMS=1000\nCALIBRATE GRAMS=1000\n"
                             "ACCEPT\nSIM_REMOVE_WEIGHT\nG28\nG1 X110 Y110 F6000\nPROBE HOME=Z\nG1 Z0.4")
    return printer


def _median_s(run) -> float:
    times = []
    for _ in range(TIMING_REPEATS):
        start = time.process_time()
        run()
        times.append(time.process_time() - start)
    return statistics.median(times)


def run_session(scenario: str, seed: int, workdir: Path) -> dict:
    responses: list[str] = []
    printer = make_printer(scenario, seed, workdir, responses)
    printer.gcode.run_script(f"PROBE_ACCURACY SAMPLES={TAPS} SAMPLE_RETRACT_DIST=0.4")
    probe = printer.lookup_object("probe")
    device = printer.lookup_object("load_cell_probe")
    recorded = list(device.last_taps)[-TAPS:]
    settings = device.config_settings.analysis
    vp = printer.backend
    x_mm, y_mm, _ = vp.position
    # The bed's true contact under the nozzle in the toolhead's frame (the simulator's truth, never the analysis's).
    truth_mm = float(vp.truth.contact_z_at(x_mm, y_mm)) + device.motion.frame_offset_mm["z"] - probe.options.z_offset_mm

    def pool_copies():
        apply_pool([copy.copy(r.analysis) for r in recorded])

    return {"pooled": probe.last_accuracy_pooled, "lines": responses[-2:],
            "single_um": probe.last_accuracy_single.standard_deviation_mm * 1000.0,
            "pooled_um": probe.last_accuracy.standard_deviation_mm * 1000.0,
            "bias_single_um": (probe.last_accuracy_single.average_mm - truth_mm) * 1000.0,
            "bias_pooled_um": (probe.last_accuracy.average_mm - truth_mm) * 1000.0,
            "pool_ms": _median_s(pool_copies) * 1000.0,
            "analysis_ms": _median_s(lambda: [analyze_tap(r.tap, settings) for r in recorded]) * 1000.0}


def _rms(values) -> float:
    return float(np.sqrt(np.mean(np.square(values))))


def main(argv: list[str]) -> int:
    table = Table(title=f"PROBE_ACCURACY SAMPLES={TAPS} on the virtual printer, seeds {SEEDS[0]}-{SEEDS[-1]}: "
                        "standard deviation (µm) of the single taps and of the pooled Zs")
    for column in ("scenario", "pooled", "single σ", "pooled σ", "pooled/single", "worst seed", "bias single",
                   "bias pooled", "pool ms", "10 analyses ms", "pool/analyses"):
        table.add_column(column, justify="left" if column == "scenario" else "right")
    first_lines: list[str] = []
    with tempfile.TemporaryDirectory() as tmp:
        for scenario in SCENARIOS:
            rows = [run_session(scenario, seed, Path(tmp)) for seed in SEEDS]
            first_lines = first_lines or rows[0]["lines"]
            single, pooled = _rms([r["single_um"] for r in rows]), _rms([r["pooled_um"] for r in rows])
            pool_ms = statistics.median(r["pool_ms"] for r in rows)
            analysis_ms = statistics.median(r["analysis_ms"] for r in rows)
            table.add_row(scenario, f"{sum(r['pooled'] for r in rows)}/{len(rows)}", f"{single:.3f}", f"{pooled:.3f}",
                          f"{pooled / single:.2f}", f"{max(r['pooled_um'] / r['single_um'] for r in rows):.2f}",
                          f"{np.mean([r['bias_single_um'] for r in rows]):+.2f}",
                          f"{np.mean([r['bias_pooled_um'] for r in rows]):+.2f}", f"{pool_ms:.2f}", f"{analysis_ms:.1f}",
                          f"{pool_ms / analysis_ms:.3f}")
    Console(width=200).print(table)
    print(f"The printer's last two lines, {SCENARIOS[0]} seed {SEEDS[0]}:")
    print("\n".join(first_lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main([]))
