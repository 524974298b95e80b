"""Is `z_sigma_um` honest? rms(error / z_sigma_um) per scenario on taplab and the reference taps,
the parts it is made of (tapcell.tap.uncertainty), and the weights the worst scenario would choose.

Per set and scenario, over the taps the analysis accepts: the rms error (µm, bias included: a
sigma must cover it), the same error times each tap's stiffness at contact ("e·k", g:
`force_error_g`), the rms of each part of the sigma, rms(error / sigma) with the weights in
tapcell.tap.uncertainty ("now"), with the scenario's mean error taken out ("no bias": what the
sigma would score were Z unbiased there), and with the weights this run chooses: on a grid, the weights whose
worst scenario over both sets (every scenario with at least MIN_TAPS accepted taps, fouled ones
included) has rms(error / sigma) closest to 1 (the least max |log ratio|, then the mean one),
over every combination of the grid. A scenario whose taps
are all rejected has no ratio. Re-run after any change to the Z estimator and carry the chosen
weights into tapcell.tap.uncertainty if they differ.

Run: .venv/bin/python -m bench tap_sigma [--seed N ...] [--check-seed N ...] [--per-scenario N] [--reference PATH]
                                         [--per-seed]
     (weights chosen on taplab seeds 1 and 3, their taps together per scenario, and the reference
     taps; seed 2 scored, not used; --per-seed judges seeds 1 and 3 apart, as before 2026-11-27)
     (the reference taps default to ../shared/data/reference-taps.tar.xz from the repository root)
"""

from __future__ import annotations

import argparse
import collections
import dataclasses
import itertools
import math
import tempfile
from pathlib import Path

import numpy as np

from tapcell.tap import analyze_tap, read_tap_file
from tapcell.tap.uncertainty import RINGING_WEIGHT, SigmaWeights, ZSigmaParts, z_sigma_um
from tapcell.taplab.benchmark import TapSet, default_reference_archive, read_labels, reference_set
from tapcell.taplab.generate import generate_set

MIN_TAPS = 5  # fewer accepted taps in a scenario: its rms says little (and it is not used to choose)
# The weights tried (tapcell.tap.uncertainty.SigmaWeights' fields). The squeeze's stops at 1.5: the
# film a tap leaves under the nozzle is about what it squeezed out, not several times it (further up
# the grid's best chases taplab's mild ooze alone: 3 moved the worst scenario from 1.54 to 1.53; 2
# and 1.75 tie it). The optimum is flat: weights within a step of these score within 0.01.
# The film's stops at 2 for the same reason (what a film left is at most the squeeze and the toe's
# lift; on a grid to 6 the best goes to the top, 6, and still leaves taplab seed 3's mild ooze at
# 1.36-1.48: the taps that err most there show no squeeze). The floor's is a force, g.
# The ringing's is not searched: it is held at RINGING_WEIGHT, 1 by its derivation
# (tapcell.tap.uncertainty.ringing_um). No tap of either set shows a gantry ringing in its dwell, only
# a mains hum nobody removed (reference noisy mains, the ADS1220s at 2000 sps); on a grid 0-2 the
# worst scenario and both sets' chosen ranges did not move, and the mean over the others went to 0
# (the reference noisy mains, whose hum the noise, thread and squeeze parts already overstate).
GRID = {"noise": np.arange(0.5, 3.01, 0.125), "shape": np.arange(0.0, 4.01, 0.25), "misfit": np.arange(0.0, 2.01, 0.5),
        "thread": np.arange(0.0, 2.01, 0.25), "squeeze": np.arange(0.0, 1.51, 0.25), "film": np.arange(0.0, 2.01, 0.25),
        "floor": np.arange(0.0, 4.01, 0.25)}
REFINE_STEPS = 2  # the second pass: every combination within this many of GRID's steps of the first pass's best
CHUNK = 4096  # weight combinations scored at once
BOOTSTRAP_DRAWS = 400
TYPICAL_SHARE = 0.25  # the mean |log ratio|'s share in the choice, beside the worst scenario's
PART_NAMES = [f.name for f in dataclasses.fields(ZSigmaParts)]


@dataclasses.dataclass
class Scenario:
    errors_um: list[float] = dataclasses.field(default_factory=list)
    parts: list[ZSigmaParts] = dataclasses.field(default_factory=list)
    taps: int = 0
    stiffness_g_um: list[float] = dataclasses.field(default_factory=list)  # each accepted tap's, at contact


def collect(tap_set: TapSet) -> dict[str, Scenario]:
    """Every tap analysed in process: the accepted taps' errors and sigma parts, per scenario."""
    scenarios: dict[str, Scenario] = collections.defaultdict(Scenario)
    for label in tap_set.labels:
        scenario = scenarios[label.scenario]
        scenario.taps += 1
        analysis = analyze_tap(read_tap_file(str(tap_set.directory / label.file))[0])
        if analysis.valid and analysis.z_mm is not None and analysis.z_sigma_parts is not None:
            scenario.errors_um.append((analysis.z_mm - label.z_contact_mm) * 1000.0)
            scenario.parts.append(analysis.z_sigma_parts)
            scenario.stiffness_g_um.append(analysis.stiffness_decompression_g_um or math.nan)
    return scenarios


def ratio_rms(scenario: Scenario, weights: SigmaWeights, unbiased: bool = False) -> float | None:
    """rms(error / sigma) over the accepted taps (`unbiased`: the scenario's mean error taken out
    first, what the sigma would score were Z unbiased there)."""
    if not scenario.errors_um:
        return None
    sigmas = np.array([z_sigma_um(p, weights) for p in scenario.parts])
    errors = np.array(scenario.errors_um)
    if unbiased:
        errors = errors - errors.mean()
    return float(np.sqrt(np.mean(np.square(errors / sigmas))))


def force_error_g(scenario: Scenario) -> float | None:
    """rms(error × the tap's stiffness at contact), g: the error as the force the contact model
    misplaces. On both generators it is nearly the same on clean, slow and soft scenarios where the
    error in µm is not (a soft sheet's stiffness is a third to a half of a hard bed's), so a part
    of the sigma that grows as 1 / stiffness is what a soft sheet's error follows."""
    pairs = [(e, k) for e, k in zip(scenario.errors_um, scenario.stiffness_g_um) if math.isfinite(k)]
    if not pairs:
        return None
    return float(np.sqrt(np.mean([(e * k) ** 2 for e, k in pairs])))


def pooled(seed_sets: list[dict[str, Scenario]]) -> dict[str, Scenario]:
    """One generator's scenarios with the taps of several seeds together: each seed is a fresh draw
    of the same scenarios, and 40 taps leave rms(error / sigma) uncertain by about ±25-35 % (the
    90 % bootstrap interval, column "90 %"), so the worst of per-seed scenarios chases that draw."""
    together: dict[str, Scenario] = collections.defaultdict(Scenario)
    for scenarios in seed_sets:
        for name, s in scenarios.items():
            into = together[name]
            into.errors_um += s.errors_um
            into.parts += s.parts
            into.stiffness_g_um += s.stiffness_g_um
            into.taps += s.taps
    return dict(together)


def ratio_interval(scenario: Scenario, weights: SigmaWeights, draws: int = BOOTSTRAP_DRAWS) -> tuple[float, float] | None:
    """The 90 % bootstrap interval of rms(error / sigma) over the scenario's accepted taps (fixed seed)."""
    if len(scenario.errors_um) < MIN_TAPS:
        return None
    ratios = np.array(scenario.errors_um) / np.array([z_sigma_um(p, weights) for p in scenario.parts])
    rng = np.random.default_rng(0)
    resampled = rng.choice(ratios, size=(draws, len(ratios)))
    lo, hi = np.percentile(np.sqrt(np.mean(np.square(resampled), axis=1)), [5.0, 95.0])
    return float(lo), float(hi)


def choose_weights(sets: dict[str, dict[str, Scenario]]) -> tuple[SigmaWeights, float]:
    """The weights on GRID whose worst scenario, over every set, is closest to 1, then the best mean
    over the scenarios; and that worst ratio. Two passes (every combination of GRID at once would be
    millions): every combination of every other value of GRID, then every combination within
    REFINE_STEPS of GRID's steps around the first pass's best."""
    judged = [s for scenarios in sets.values() for s in scenarios.values() if len(s.errors_um) >= MIN_TAPS]
    errors2 = [np.square(s.errors_um) for s in judged]
    fixed = [np.array([p.staircase_um ** 2 + p.delay_um ** 2 + (RINGING_WEIGHT * p.ringing_um) ** 2
                       + p.stage_um ** 2 for p in s.parts])
             for s in judged]
    weighed = [np.array([[getattr(p, name + "_um") ** 2 for name in GRID] for p in s.parts]) for s in judged]
    coarse, _ = _best_on(list(itertools.product(*(values[::2] for values in GRID.values()))), errors2, fixed, weighed)
    near = []
    for name, value in zip(GRID, coarse):
        at = int(np.abs(GRID[name] - value).argmin())
        near.append(GRID[name][max(at - REFINE_STEPS, 0):at + REFINE_STEPS + 1])
    best, worst = _best_on(list(itertools.product(*near)), errors2, fixed, weighed)
    return SigmaWeights(**{name: float(w) for name, w in zip(GRID, best)}), worst


def _best_on(combinations: list[tuple[float, ...]], errors2: list[np.ndarray], fixed: list[np.ndarray],
             weighed: list[np.ndarray]) -> tuple[np.ndarray, float]:
    """The best of these weight combinations by choose_weights' rule, and its worst scenario's ratio."""
    combos = np.array(combinations)
    worst, total = np.zeros(len(combos)), np.zeros(len(combos))
    for start in range(0, len(combos), CHUNK):  # (taps, combinations) arrays of a bounded size
        squared = combos[start:start + CHUNK] ** 2
        for e2, f, w in zip(errors2, fixed, weighed):
            sigma2 = f[:, None] + w @ squared.T
            with np.errstate(divide="ignore"):  # weights that leave a tap no sigma: infinitely off
                off = np.abs(0.5 * np.log(np.mean(e2[:, None] / sigma2, axis=0)))
            worst[start:start + CHUNK] = np.maximum(worst[start:start + CHUNK], off)
            total[start:start + CHUNK] += off
    # The worst scenario first; among weights nearly as good there, the one best on the others
    # (a fouled scenario nothing in the tap explains would otherwise leave the rest arbitrary).
    best = int((worst + TYPICAL_SHARE * total / len(errors2)).argmin())
    return combos[best], math.exp(float(worst[best]))


def _fmt(value: float | None) -> str:
    return "-" if value is None else format(value, ".2f")


def _rms(values) -> float:
    return float(np.sqrt(np.mean(np.square(values)))) if len(values) else math.nan


def print_set(name: str, scenarios: dict[str, Scenario], current: SigmaWeights, chosen: SigmaWeights) -> None:
    print(f"== {name}")
    header = (f"{'scenario':<22} {'taps':>4} {'acc':>4} {'rms e':>6} {'e·k g':>6} | " + " ".join(f"{n[:-3]:>9}" for n in PART_NAMES)
              + f" | {'e/σ now':>7} {'90 %':>9} {'chosen':>7} {'no bias':>7}")
    print(header)
    print("-" * len(header))
    for scenario_name, s in sorted(scenarios.items()):
        parts = " ".join(f"{_rms([getattr(p, n) for p in s.parts]):>9.2f}" for n in PART_NAMES)
        interval = ratio_interval(s, current)
        ratios = " ".join([f"{_fmt(ratio_rms(s, current)):>7}",
                           f"{'-' if interval is None else f'{interval[0]:.2f}-{interval[1]:.2f}':>9}",
                           *(f"{_fmt(r):>7}" for r in (ratio_rms(s, chosen), ratio_rms(s, current, unbiased=True)))])
        mark = "" if len(s.errors_um) >= MIN_TAPS else "  (too few to judge)"
        print(f"{scenario_name[:22]:<22} {s.taps:>4} {len(s.errors_um):>4} {_rms(s.errors_um):>6.2f} "
              f"{_fmt(force_error_g(s)):>6} | {parts} | "
              f"{ratios}{mark}")
    judged = [s for s in scenarios.values() if len(s.errors_um) >= MIN_TAPS]
    for label, weights in (("now", current), ("chosen", chosen)):
        ratios = [ratio_rms(s, weights) for s in judged]
        if ratios:
            print(f"rms(e/σ) range {label}: {min(ratios):.2f}..{max(ratios):.2f}")
    print()


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench tap_sigma", description=__doc__.split("\n\n")[0])
    parser.add_argument("--seed", type=int, action="append",
                        help="taplab seed the weights are chosen on, repeatable (default 1 3)")
    parser.add_argument("--check-seed", type=int, action="append", default=None,
                        help="taplab seed scored but not used to choose, repeatable (default 2)")
    parser.add_argument("--per-scenario", type=int, default=40, help="taplab taps per scenario (default 40)")
    parser.add_argument("--reference", metavar="PATH", help="the reference taps (archive or unpacked directory)")
    parser.add_argument("--per-seed", action="store_true",
                        help="judge each taplab seed's scenarios apart (default: the seeds' taps together)")
    args = parser.parse_args(argv)
    seeds, check_seeds = args.seed or [1, 3], args.check_seed if args.check_seed is not None else [2]
    sets, checks, judged = {}, {}, {}
    with tempfile.TemporaryDirectory(prefix="tap-sigma-") as scratch:
        for seed in [*seeds, *check_seeds]:
            directory = Path(scratch) / f"taplab-{seed}"
            generate_set(directory, seed, args.per_scenario)
            target = sets if seed in seeds else checks
            target[f"taplab (seed {seed})" + ("" if seed in seeds else ", not used to choose")] = collect(
                TapSet("taplab", directory, read_labels(directory)))
        source = Path(args.reference) if args.reference else default_reference_archive()
        reference = reference_set(source, Path(scratch) / "reference") if source.exists() else None
        if reference is None:
            print(f"reference taps: {source} not found; left out (choose weights on both sets, not one)")
        else:
            judged[f"reference ({reference.directory})"] = collect(reference)
    if not args.per_seed and len(sets) > 1:
        together = {f"taplab (seeds {', '.join(map(str, seeds))} together)": pooled(list(sets.values()))}
        checks = {**sets, **checks}  # printed per seed too
        sets = together
    judged = {**sets, **judged}
    current = SigmaWeights()
    chosen, worst = choose_weights(judged)
    for name, scenarios in {**judged, **checks}.items():
        print_set(name, scenarios, current, chosen)
    held = f", ringing {RINGING_WEIGHT:g} (held: its derivation)"
    print("weights now:    " + ", ".join(f"{name} {getattr(current, name):g}" for name in GRID) + held)
    print("weights chosen: " + ", ".join(f"{name} {getattr(chosen, name):g}" for name in GRID) + held
          + f" (on {', '.join(judged)}: the worst scenario's rms(e/σ) is off 1 by a factor {worst:.2f})")
    return 0
