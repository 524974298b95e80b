"""Accuracy of the tap analysis on synthetic taps with known truth.

For each condition: valid rate, bias, sigma, p95 |error| and the worst |error| of a tap
marked valid (µm, against truth.z_contact), beside two limits:
- "σ limit": the issue's best achievable spread, the exact noise-free model fitted to the same
  noisy samples with only the contact height free (stiffness, relaxation, baseline known);
  measured over the same taps (for corrupted frames: the same taps without them, since a
  garbage frame carries no information);
- "CRB nuis.": the Cramér-Rao bound when stiffness, baseline and relaxation are unknown too,
  as they are to any real analysis (mean over the first taps).
Also the P4 line intersection (the classic line-fit answer, same delay correction).
Run: .venv/bin/python -m bench tap_accuracy   (or python bench/tap_accuracy.py [taps])
"""

from __future__ import annotations

import dataclasses
import sys

import numpy as np
from rich.console import Console
from rich.table import Table

from tapcell.tap import AnalysisOptions, analyze_tap
from tapcell.tap.synth import NUISANCE_FIELDS, SynthTap, best_achievable_z, contact_sigma_limit_um, synth_tap

CRB_TAPS = 5

CONDITIONS: list[tuple[str, dict, dict, bool]] = [
    # (name, generator changes, analysis options, drop the delay from the tap's metadata)
    ("80 sps, 2 mm/s, 1 g", dict(sample_rate_sps=80.0, approach_speed_mm_s=2.0), {}, False),
    ("320 sps, 5 mm/s, 1 g", dict(sample_rate_sps=320.0), {}, False),
    ("660 sps, 5 mm/s, 1 g", dict(), {}, False),
    ("2000 sps, 5 mm/s, 1 g", dict(sample_rate_sps=2000.0), {}, False),
    ("660 sps, noise 0.5 g", dict(noise_g=0.5), {}, False),
    ("660 sps, noise 5 g", dict(noise_g=5.0), {}, False),
    ("660 sps, 1 mm/s", dict(approach_speed_mm_s=1.0), {}, False),
    ("660 sps, 10 mm/s", dict(approach_speed_mm_s=10.0), {}, False),
    ("negative polarity", dict(polarity=-1), {}, False),
    ("latency 3 ms, known", dict(sensor_delay_s=0.003), {}, False),
    ("latency 3 ms, unknown", dict(sensor_delay_s=0.003), {}, True),
    ("latency 3 ms, estimated", dict(sensor_delay_s=0.003, approach_speed_mm_s=2.0), {"sensor_delay_s": "auto"}, True),
    ("soft sheet 6 µm", dict(contact_onset_um=6.0), {}, False),
    ("soft sheet, calibrated", dict(contact_onset_um=6.0), {"contact_onset_um": 6.0}, False),
    ("3 corrupted frames", dict(corrupted_frames=3), {}, False),
    ("ooze film 5 µm", dict(film_um=5.0, film_stiffness_g_um=1.0, label="fouled"), {}, False),
    ("ooze film 20 µm", dict(film_um=20.0, film_stiffness_g_um=2.0, label="fouled"), {}, False),
    ("ooze pull 10 g", dict(pull_force_g=10.0, label="fouled"), {}, False),
]


def run_condition(changes: dict, options: dict, hide_delay: bool, taps: int) -> dict[str, float]:
    errors, line_errors, limit_errors, valid, crb = [], [], [], [], []
    for seed in range(taps):
        spec = SynthTap(seed=seed, **changes)
        tap = synth_tap(spec)
        if hide_delay:
            tap.meta.pop("sensor_delay_s")
        result = analyze_tap(tap, AnalysisOptions(**options))
        truth_um = spec.z_contact_mm * 1000
        clean_spec = dataclasses.replace(spec, corrupted_frames=0)
        clean_tap = synth_tap(clean_spec) if spec.corrupted_frames else tap  # same seed: same noise
        limit_errors.append(best_achievable_z(clean_spec, clean_tap) * 1000 - truth_um)
        if seed < CRB_TAPS:
            crb.append(contact_sigma_limit_um(clean_spec, clean_tap, NUISANCE_FIELDS))
        valid.append(result.valid)
        if result.z_mm is not None:
            errors.append(result.z_mm * 1000 - truth_um)
            line_errors.append(result.z_line_mm * 1000 - truth_um)
        else:
            errors.append(np.nan)
            line_errors.append(np.nan)
    errors, line_errors, valid = np.array(errors), np.array(line_errors), np.array(valid)
    ok = valid & np.isfinite(errors)
    limit = float(np.std(limit_errors))
    crb_um = float(np.mean(crb))
    if not ok.any():  # every tap rejected (the ooze rows): no error statistics
        return {"valid": 0.0, "limit": limit, "crb": crb_um, **dict.fromkeys(("bias", "sigma", "p95", "worst", "line_bias",
                                                                "line_sigma"), np.nan)}
    good = errors[ok]
    return {
        "valid": 100.0 * valid.mean(),
        "bias": float(np.mean(good)),
        "sigma": float(np.std(good)),
        "p95": float(np.percentile(np.abs(good), 95)),
        "worst": float(np.max(np.abs(good))),
        "limit": limit,
        "crb": crb_um,
        "line_bias": float(np.mean(line_errors[ok])),
        "line_sigma": float(np.std(line_errors[ok])),
    }


def main(argv: list[str]) -> int:
    taps = int(argv[0]) if argv else 40
    table = Table(title=f"tap analysis accuracy, {taps} synthetic taps per row (µm vs truth)")
    for column in ("condition", "valid %", "bias", "σ", "σ limit", "σ/limit", "CRB nuis.", "σ/CRB", "p95 |err|",
                   "worst valid", "P4-line bias", "P4-line σ"):
        table.add_column(column, justify="left" if column == "condition" else "right")
    for name, changes, options, hide_delay in CONDITIONS:
        row = run_condition(changes, options, hide_delay, taps)
        table.add_row(name, f"{row['valid']:.0f}", f"{row['bias']:+.3f}", f"{row['sigma']:.3f}",
                      f"{row['limit']:.3f}", f"{row['sigma'] / row['limit']:.2f}", f"{row['crb']:.3f}",
                      f"{row['sigma'] / row['crb']:.2f}", f"{row['p95']:.3f}",
                      f"{row['worst']:.2f}", f"{row['line_bias']:+.3f}", f"{row['line_sigma']:.3f}")
    Console(width=190).print(table)
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
