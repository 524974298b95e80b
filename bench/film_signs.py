"""What the film and spike rules weigh, on clean and fouled taps (issue 21): the margins behind
PLASTIC_MET_ABOVE_UM and CREDIBLE_NOISE_SHARE.

Per set and scenario:
- the highest point (µm above break contact, less a sample's travel) from which the approach's
  force rose off its free air (`analysis.approach_rise_above_um`), over the taps that reached the
  rule (`_film_met_above`: the adhesion checks' samples and a pull measured; taps an earlier film
  rule named do not reach it), and over those among them whose departure pulls PLASTIC_PULL_SHARE
  of the compression and more (both signs must show for the rule);
- how many taps the rule named (TAP_ADHESION for plastic met above the bed);
- the largest share of a tap's samples standing off their neighbours' midpoint by the spike
  threshold (`analysis.spike_suspects`; above CREDIBLE_NOISE_SHARE the repair weighs no neighbour
  or corner).

The taplab seeds are generated in process as `bench tap_seeds` generates them; the reference sets
are the labelled archives beside the repository.

Run: .venv/bin/python -m bench film_signs [--seeds 1-12] [--per-scenario 40] [--no-reference]
"""

from __future__ import annotations

import argparse
import collections
import contextlib
import math
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table

from bench.tap_seeds import DEFAULT_PER_SCENARIO, parse_seeds, seed_tap
from tapcell.tap import AnalysisOptions, analysis, analyze_tap, read_tap_file
from tapcell.tap.readers import tap_from_object
from tapcell.taplab.benchmark import REFERENCE_NAME, REFERENCE_SESSIONS_NAME, default_reference_archive, reference_set
from tapcell.taplab.generate import SCENARIOS


@dataclass
class Signs:
    """One set and scenario's taps: what the rules saw."""

    taps: int = 0
    reached: int = 0  # taps whose adhesion checks reached the film-met-above rule
    highest_rise_um: float = -math.inf
    highest_rise_pulling_um: float = -math.inf
    named: int = 0
    most_standing_out: float = 0.0


@contextlib.contextmanager
def watching_the_rule(seen: list):
    """`_film_met_above`'s inputs, appended to `seen` while the block analyses taps."""
    rule = analysis._film_met_above

    def watched(pull_g, approach_rise_um, compression_force_g, noise_g):
        named = rule(pull_g, approach_rise_um, compression_force_g, noise_g)
        seen.append((pull_g, approach_rise_um, compression_force_g, named))
        return named

    analysis._film_met_above = watched
    try:
        yield
    finally:
        analysis._film_met_above = rule


def add_tap(signs: Signs, tap, threshold_sigma: float) -> None:
    seen: list = []
    with watching_the_rule(seen):
        analyze_tap(tap)
    signs.taps += 1
    force_g = np.asarray(tap.force_g, dtype=float)
    if len(force_g) >= 5:
        suspects, _, _ = analysis.spike_suspects(force_g, threshold_sigma)
        signs.most_standing_out = max(signs.most_standing_out, len(suspects) / len(force_g))
    for pull_g, rise_um, compression_g, named in seen:
        signs.reached += 1
        signs.named += bool(named)
        if rise_um is None:
            continue
        signs.highest_rise_um = max(signs.highest_rise_um, rise_um)
        if pull_g >= analysis.PLASTIC_PULL_SHARE * compression_g:
            signs.highest_rise_pulling_um = max(signs.highest_rise_pulling_um, rise_um)


def taplab_signs(seeds: list[int], per_scenario: int, threshold_sigma: float) -> dict[tuple[str, str], Signs]:
    out: dict[tuple[str, str], Signs] = collections.defaultdict(Signs)
    label = f"taplab {seeds[0]}-{seeds[-1]}" if len(seeds) > 1 else f"taplab {seeds[0]}"
    for seed in seeds:
        for name in SCENARIOS:
            for k in range(per_scenario):
                tap, _ = seed_tap(seed, name, k)
                add_tap(out[(label, name)], tap_from_object(tap), threshold_sigma)
    return out


def reference_signs(threshold_sigma: float) -> tuple[dict[tuple[str, str], Signs], list[str]]:
    out: dict[tuple[str, str], Signs] = collections.defaultdict(Signs)
    notes = []
    with tempfile.TemporaryDirectory() as scratch:
        for name, archive in (("reference", REFERENCE_NAME), ("sessions", REFERENCE_SESSIONS_NAME)):
            source = default_reference_archive(archive)
            unpacked = Path(scratch) / name
            unpacked.mkdir()
            tap_set = reference_set(source, unpacked, name=name, archive=archive) if source.exists() else None
            if tap_set is None:
                notes.append(f"({name}: {source} is not there; left out)")
                continue
            for label, path in zip(tap_set.labels, tap_set.files):
                for tap in read_tap_file(path):
                    add_tap(out[(name, label.scenario)], tap, threshold_sigma)
    return out, notes


def _um(value: float) -> str:
    return "-" if value == -math.inf else f"{value:.1f}"


def signs_table(signs: dict[tuple[str, str], Signs]) -> Table:
    table = Table(title=f"What the film-met-above rule (from {analysis.PLASTIC_MET_ABOVE_UM:g} um, with a pull of "
                        f"{analysis.PLASTIC_PULL_SHARE:.0%}) and the spike repair's credible noise "
                        f"(at most {analysis.CREDIBLE_NOISE_SHARE:.0%} standing out) saw")
    for column in ("set", "scenario", "taps", "reached the rule", "highest rise um", "pulling: highest rise um",
                   "named", "most standing out"):
        table.add_column(column, justify="right" if column not in ("set", "scenario") else "left")
    for (set_name, scenario), s in signs.items():
        table.add_row(set_name, scenario, str(s.taps), str(s.reached), _um(s.highest_rise_um),
                      _um(s.highest_rise_pulling_um), str(s.named), f"{s.most_standing_out:.1%}")
    return table


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m bench film_signs", description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", default="1-12", help="taplab seeds: 1-12, 2,3 (default 1-12)")
    parser.add_argument("--per-scenario", type=int, default=DEFAULT_PER_SCENARIO)
    parser.add_argument("--no-reference", action="store_true", help="leave out the reference sets")
    return parser


def main(argv: list[str]) -> int:
    args = _parser().parse_args(argv)
    threshold_sigma = AnalysisOptions().outlier_sigma
    signs = taplab_signs(parse_seeds(args.seeds), args.per_scenario, threshold_sigma)
    notes: list[str] = []
    if not args.no_reference:
        reference, notes = reference_signs(threshold_sigma)
        signs.update(reference)
    Console(width=200).print(signs_table(signs))
    for note in notes:
        print(note)
    return 0
