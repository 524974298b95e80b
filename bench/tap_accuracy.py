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

Second table: labelled taps from the virtual printer (`tapcell.sim.taps`, the probe's way of
tapping: 75 g trigger, 4-sample dwell, 1 µm per sample pullback) per scenario and speed: valid
rate, bias, σ, p95 and worst |error| of accepted taps, the rejection codes, and the classifier's
confusion (clean accepted %, fouled rejected %) with the error the fouled taps would have had
(their Z with the `empty` classifier, where validation still lets a Z be computed).
Run: .venv/bin/python -m bench tap_accuracy [taps] [sim taps]
"""

from __future__ import annotations

import dataclasses
import sys

import numpy as np
from rich.console import Console
from rich.table import Table

from tapcell.tap import AnalysisOptions, analyze_tap
from tapcell.sim.taps import SimTapSpec, record_sim_tap
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


# (label, scenario, speeds mm/s, pullback mm, spec changes). Slow-adc (80 sps) only at <= 2 mm/s:
# faster, one sample covers more than the whole compression (the probe refuses those speeds).
SIM_ROWS: list[tuple[str, str, tuple[float, ...], float, dict]] = [
    ("clean", "clean", (2.0, 5.0, 10.0), 0.1, {}),
    ("clean, 0.2 mm pullback", "clean", (2.0, 5.0, 10.0), 0.2, {}),
    ("soft-sheet", "soft-sheet", (2.0, 5.0, 10.0), 0.1, {}),
    ("fast-adc", "fast-adc", (2.0, 5.0, 10.0), 0.1, {}),
    ("slow-adc", "slow-adc", (1.0, 2.0), 0.1, {}),
    ("noisy-mains", "noisy-mains", (2.0, 5.0, 10.0), 0.1, {}),
    ("bowden-drift + drift filter", "bowden-drift", (2.0, 5.0, 10.0), 0.1, {"drift_filter_hz": 0.8}),
    ("glitchy", "glitchy", (2.0, 5.0, 10.0), 0.1, {}),
    ("oozy 210 °C, 60 µm", "oozy", (2.0, 5.0, 10.0), 0.1, {}),
    ("oozy 210 °C, 20 µm", "oozy", (2.0, 5.0, 10.0), 0.1, {"overrides": {"ooze_film_um": 20.0}}),
    ("oozy 210 °C, 5 µm", "oozy", (2.0, 5.0, 10.0), 0.1, {"overrides": {"ooze_film_um": 5.0}}),
    ("oozy 230 °C, 2 µm", "oozy", (2.0, 5.0, 10.0), 0.1, {"overrides": {"ooze_film_um": 2.0, "start_nozzle_c": 230.0}}),
]


def run_sim_row(scenario: str, speed_mm_s: float, pullback_mm: float, changes: dict, taps: int) -> dict:
    """Accepted-tap errors (µm) and the classifier's verdicts over `taps` seeds."""
    errors, codes, labels, accepted, unchecked = [], {}, [], [], []
    for seed in range(taps):
        tap = record_sim_tap(SimTapSpec(scenario=scenario, speed_mm_s=speed_mm_s, seed=seed,
                                        pullback_distance_mm=pullback_mm, **changes))
        truth_um = tap.truth["z_contact"] * 1000.0
        result = analyze_tap(tap)
        labels.append(tap.truth["label"])
        accepted.append(result.valid)
        if result.valid:
            errors.append(result.z_mm * 1000.0 - truth_um)
        else:
            codes[result.error] = codes.get(result.error, 0) + 1
        # What the tap would have said with no classifier (validation still has to pass for a Z).
        plain = analyze_tap(tap, AnalysisOptions(tap_classifier="empty"))
        if tap.truth["label"] == "fouled" and plain.z_mm is not None:
            unchecked.append(plain.z_mm * 1000.0 - truth_um)
    errors, labels, accepted = np.array(errors), np.array(labels), np.array(accepted)
    clean, fouled = labels == "clean", labels == "fouled"
    return {
        "valid": 100.0 * accepted.mean(),
        "bias": float(errors.mean()) if len(errors) else np.nan,
        "sigma": float(errors.std()) if len(errors) else np.nan,
        "p95": float(np.percentile(np.abs(errors), 95)) if len(errors) else np.nan,
        "worst": float(np.max(np.abs(errors))) if len(errors) else np.nan,
        "clean_accepted": 100.0 * accepted[clean].mean() if clean.any() else np.nan,
        "fouled_rejected": 100.0 * (~accepted[fouled]).mean() if fouled.any() else np.nan,
        "fouled_would_err": float(np.max(np.abs(unchecked))) if unchecked else np.nan,
        "fouled_z_count": len(unchecked),
        "codes": ", ".join(f"{code} {count}" for code, count in sorted(codes.items())),
    }


def _cell(value: float, fmt: str) -> str:
    return "–" if not np.isfinite(value) else format(value, fmt)


def sim_table(taps: int) -> Table:
    table = Table(title=f"virtual printer taps, {taps} per row (µm vs truth; tap_quality classifier; the analysis "
                        "alone: 4-sample dwell, no hum removal — bench/probe_session shows the probe with both)")
    for column in ("scenario", "mm/s", "valid %", "bias", "σ", "p95 |err|", "worst valid", "clean acc. %",
                   "fouled rej. %", "fouled max |err| unchecked (n)", "rejections"):
        table.add_column(column, justify="left" if column in ("scenario", "rejections") else "right")
    for name, scenario, speeds, pullback_mm, changes in SIM_ROWS:
        for speed in speeds:
            row = run_sim_row(scenario, speed, pullback_mm, changes, taps)
            unchecked = (f"{_cell(row['fouled_would_err'], '.1f')} ({row['fouled_z_count']})"
                         if np.isfinite(row["fouled_rejected"]) else "–")
            table.add_row(f"{name}, {pullback_mm:g} mm", f"{speed:g}", f"{row['valid']:.0f}", _cell(row["bias"], "+.2f"),
                          _cell(row["sigma"], ".2f"), _cell(row["p95"], ".2f"), _cell(row["worst"], ".2f"),
                          _cell(row["clean_accepted"], ".0f"), _cell(row["fouled_rejected"], ".0f"), unchecked,
                          row["codes"])
    return table


def main(argv: list[str]) -> int:
    taps = int(argv[0]) if argv else 40
    sim_taps = int(argv[1]) if len(argv) > 1 else 20
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
    console = Console(width=190)
    console.print(table)
    console.print(sim_table(sim_taps))
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
