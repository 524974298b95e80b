"""What a taplab scenario's Z scatter is made of: the same taps made again with one thing changed.

`z_sigma_um` must cover a tap's error (`bench tap_sigma`). Where it does not, this says what in the
taps moves Z: each variant re-draws the same taps (same random streams) with one assumption of the
generator changed, and scores the analysis on them (bias ± sd µm, rms sigma, rms(error / sigma)),
with how far the toe fit's own likelihood puts the truth from its best toe ("Δχ² at truth": the
residual at the true contact, the best toe there, over the best anywhere, in noise variances; about
1 when the likelihood is honest about the contact, larger when it is overconfident).

Variants: `as drawn`; `white noise` (no 1/f noise, walk, hum or cable drift: only white noise at
the sensor's output); `delay given` (the analysis told the sensor's true pipeline delay); `Hertzian
toes` and `parabolic toes` (every toe's stiffness rising as depth^0.5 or depth^1, no blend: the two
shapes the toe model holds); `narrow toes` (every onset 2 µm) and `wide toes` (6 µm).

Run: .venv/bin/python -m bench tap_scatter [--scenario NAME] [--taps N] [--seed N]
"""

from __future__ import annotations

import argparse
import json
import math
import tempfile
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np

from tapcell.tap import analyze_tap, read_tap_file
from tapcell.tap.model import AnalysisOptions, TapAnalysis
from tapcell.taplab.generate import SCENARIOS, TapSpec, make_tap


def _white_noise(spec: TapSpec) -> TapSpec:
    return replace(spec, adc=replace(spec.adc, pink_g=0.0), walk_g_per_sqrt_s=0.0, hum_g=(0.0, 0.0, 0.0),
                   drift_g_per_mm=0.0)


def _toe(**changes) -> Callable[[TapSpec], TapSpec]:
    return lambda spec: replace(spec, contact=replace(spec.contact, **changes))


VARIANTS: dict[str, Callable[[TapSpec], TapSpec]] = {
    "as drawn": lambda spec: spec,
    "white noise": _white_noise,
    "delay given": lambda spec: spec,  # the taps as drawn; the analysis is told the delay (`options_for`)
    "Hertzian toes": _toe(onset_power=0.5, onset_blend=0.0),
    "parabolic toes": _toe(onset_power=1.0, onset_blend=0.0),
    "narrow toes": _toe(onset_um=2.0),
    "wide toes": _toe(onset_um=6.0),
}


def options_for(variant: str, spec: TapSpec) -> AnalysisOptions:
    """The analysis' options: its defaults, or for `delay given` the sensor's true pipeline delay."""
    if variant == "delay given":
        return AnalysisOptions(sensor_delay_s=spec.adc.latency_periods * spec.adc.period_s)
    return AnalysisOptions()


def truth_chi2(analysis: TapAnalysis, z_contact_mm: float) -> float | None:
    """How far the toe fit's likelihood puts the true contact from its best toe: the least residual
    over the toes at the true height, less the least anywhere, in the residual variance's units. None
    when Z is not the toe model's or the truth lies outside its grid."""
    grid, origin_mm = analysis.toe_grid, analysis.toe_z_origin_mm
    if analysis.z_method != "toe" or grid is None or origin_mm is None:
        return None
    at_um = (z_contact_mm - origin_mm) * 1000.0
    if not grid.contacts_um[0] <= at_um <= grid.contacts_um[-1]:
        return None
    at_truth = min(float(np.interp(at_um, grid.contacts_um, row)) for row in grid.rss)
    return (at_truth - float(grid.rss.min())) / grid.noise_var


def score_variant(variant: str, scenario: str, taps: int, seed: int, scratch: Path) -> dict[str, float]:
    """The variant's taps analysed: accepted count, bias, sd, rms sigma, rms(e/σ), median Δχ² at truth."""
    errors, sigmas, chi2 = [], [], []
    for k in range(taps):
        rng = np.random.default_rng([seed, 7, k])
        spec = VARIANTS[variant](SCENARIOS[scenario].draw(rng))
        tap, truth = make_tap(spec, rng)
        path = scratch / f"tap-{k}.json"
        path.write_text(json.dumps(tap), encoding="utf-8")
        analysis = analyze_tap(read_tap_file(str(path))[0], options_for(variant, spec))
        if not (analysis.valid and analysis.z_mm is not None and analysis.z_sigma_um):
            continue
        errors.append((analysis.z_mm - truth["z_contact"]) * 1000.0)
        sigmas.append(analysis.z_sigma_um)
        found = truth_chi2(analysis, truth["z_contact"])
        if found is not None:
            chi2.append(found)
    e, s = np.array(errors), np.array(sigmas)
    if not len(e):
        return {"taps": 0}
    return {"taps": len(e), "bias": float(e.mean()), "sd": float(e.std()), "sigma": float(np.sqrt(np.mean(s * s))),
            "ratio": float(np.sqrt(np.mean(np.square(e / s)))),
            "chi2": float(np.median(chi2)) if chi2 else math.nan}


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench tap_scatter", description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenario", default="clean_hx717", choices=sorted(SCENARIOS), help="taplab scenario")
    parser.add_argument("--taps", type=int, default=80, help="taps per variant (default 80)")
    parser.add_argument("--seed", type=int, default=7, help="random stream of the taps (default 7)")
    args = parser.parse_args(argv)
    print(f"taplab {args.scenario}, {args.taps} taps per variant (seed {args.seed}), µm against the truth")
    print(f"{'variant':<16} {'valid':>5} {'bias ± sd':>13} {'rms σ':>6} {'e/σ':>5} {'Δχ² at truth':>12}")
    with tempfile.TemporaryDirectory(prefix="tap-scatter-") as scratch:
        for variant in VARIANTS:
            row = score_variant(variant, args.scenario, args.taps, args.seed, Path(scratch))
            if not row["taps"]:
                print(f"{variant:<16} {0:>5}")
                continue
            print(f"{variant:<16} {row['taps']:>5} {row['bias']:>+6.2f} ± {row['sd']:<4.2f} {row['sigma']:>6.2f} "
                  f"{row['ratio']:>5.2f} {row['chi2']:>12.2f}")
    return 0
