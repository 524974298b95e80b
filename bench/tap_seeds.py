"""Clean taps rejected on taplab seeds nobody tuned on, and on the reference sets (issue 21).

Every should-accept tap of taplab seeds 1..12 (generated in process, tap by tap, from the same
random streams `tapcell benchmark --seed N` writes to its files) and every clean tap of the
reference taps and reference sessions is analysed with the defaults; each one rejected is listed
(set, scenario, tap, code, message). Then, per set, what the fouled scenarios did: heavy ooze
rejected (target >= 99 %), short pullback accepted (0), silent failures (valid and > 20 µm off),
mild ooze and the two-stage mount rejected and the accepted taps' bias ± sd, and how many accepted
two-stage taps lie further off than twice their z_sigma_um.

A taplab tap is named as `tapcell benchmark --seed N` names its file (tap-NNNN.json, with the
default 40 taps per scenario) and by scenario and index k (`make_tap` on the stream [seed, scenario
number, k]: `seed_tap(seed, scenario, k)` rebuilds it).

Run: .venv/bin/python -m bench tap_seeds [--seeds 1-12] [--per-scenario 40] [--reference DIR] [--sessions DIR]
     (the reference sets default to ../shared/data/reference-{taps,sessions}.tar.xz from the
     repository root; --no-reference leaves them out)
"""

from __future__ import annotations

import argparse
import collections
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from tapcell.tap import analyze_tap, read_tap_file
from tapcell.tap.readers import tap_from_object
from tapcell.taplab.benchmark import (REFERENCE_NAME, REFERENCE_SESSIONS_NAME, SILENT_UM, TapSet,
                                      default_reference_archive, reference_set)
from tapcell.taplab.generate import SCENARIOS, make_tap

DEFAULT_PER_SCENARIO = 40  # as `tapcell benchmark`: its file names are the ones printed
FOULED = ("mild_ooze", "heavy_ooze", "short_pullback", "two_stage")


@dataclass(frozen=True)
class Answer:
    """One tap's analysis against its truth."""

    set_name: str
    scenario: str
    tap: str  # the file name (taplab: `tapcell benchmark`'s, with the scenario index k)
    expect: str  # accept / reject / either
    valid: bool
    error_um: float | None  # z - truth, when a Z was given
    code: str
    message: str
    sigma_um: float | None = None  # z_sigma_um, when a Z was given


@dataclass
class Tally:
    taps: int = 0
    rejected: int = 0
    errors_um: list[float] = field(default_factory=list)  # accepted taps
    sigmas_um: list[float] = field(default_factory=list)  # their z_sigma_um
    codes: collections.Counter = field(default_factory=collections.Counter)

    @property
    def silent(self) -> int:
        return sum(1 for e in self.errors_um if abs(e) > SILENT_UM)

    @property
    def beyond_two_sigma(self) -> int:
        """Accepted taps further off than twice their z_sigma_um."""
        return sum(1 for e, s in zip(self.errors_um, self.sigmas_um) if abs(e) > 2.0 * s)


def seed_tap(seed: int, scenario: str, k: int) -> tuple[dict, dict]:
    """Tap k of a taplab scenario for a seed: the tap-format object and its truth (as generate_set)."""
    rng = np.random.default_rng([seed, list(SCENARIOS).index(scenario) + 1, k])
    return make_tap(SCENARIOS[scenario].draw(rng), rng)


def file_numbers(seed: int, per_scenario: int) -> dict[tuple[str, int], int]:
    """(scenario, k) -> the number of the file `generate_set` writes it to (its shuffle)."""
    jobs = [(name, k) for name in SCENARIOS for k in range(per_scenario)]
    order = np.random.default_rng([seed, 0]).permutation(len(jobs))
    return {jobs[j]: number for number, j in enumerate(order, start=1)}


def _answer(set_name: str, scenario: str, tap_name: str, expect: str, analysis, truth_mm: float) -> Answer:
    error = None if analysis.z_mm is None else (analysis.z_mm - truth_mm) * 1000.0
    return Answer(set_name, scenario, tap_name, expect, bool(analysis.valid), error,
                  analysis.error or "", analysis.message or "", analysis.z_sigma_um)


def taplab_answers(seed: int, per_scenario: int = DEFAULT_PER_SCENARIO,
                   scenarios: list[str] | None = None, taps: list[int] | None = None) -> list[Answer]:
    """Every tap of the scenarios (default all) of a seed, analysed in process."""
    numbers = file_numbers(seed, per_scenario)
    answers = []
    for name in scenarios or list(SCENARIOS):
        for k in (range(per_scenario) if taps is None else taps):
            tap, truth = seed_tap(seed, name, k)
            analysis = analyze_tap(tap_from_object(tap))
            label = f"tap-{numbers[(name, k)]:04d} (k={k})" if (name, k) in numbers else f"k={k}"
            answers.append(_answer(f"taplab {seed}", name, label, SCENARIOS[name].expect, analysis,
                                   truth["z_contact"]))
    return answers


def set_answers(tap_set: TapSet) -> list[Answer]:
    """Every tap of a labelled directory (the reference sets), analysed in process."""
    answers = []
    for label, path in zip(tap_set.labels, tap_set.files):
        for analysis in map(analyze_tap, read_tap_file(path)):
            answers.append(_answer(tap_set.name, label.scenario, label.file, label.expect, analysis,
                                   label.z_contact_mm))
    return answers


def tallies(answers: list[Answer]) -> dict[tuple[str, str], Tally]:
    out: dict[tuple[str, str], Tally] = collections.defaultdict(Tally)
    for a in answers:
        t = out[(a.set_name, a.scenario)]
        t.taps += 1
        if a.valid and a.error_um is not None:
            t.errors_um.append(a.error_um)
            t.sigmas_um.append(a.sigma_um if a.sigma_um is not None else 0.0)
        else:
            t.rejected += 1
            t.codes[a.code or "NO_Z"] += 1
    return out


def wrongly_rejected(answers: list[Answer]) -> list[Answer]:
    return [a for a in answers if a.expect == "accept" and not a.valid]


def _bias(errors: list[float]) -> str:
    if not errors:
        return "-"
    sd = f" ± {np.std(errors, ddof=1):.2f}" if len(errors) > 1 else ""
    return f"{np.mean(errors):+.2f}{sd}"


def print_rejections(answers: list[Answer]) -> None:
    wrong = wrongly_rejected(answers)
    print(f"\nshould-accept taps rejected: {len(wrong)}")
    if wrong:
        print(f"{'set':<12} {'scenario':<20} {'tap':<26} {'code':<28} message")
        for a in wrong:
            print(f"{a.set_name:<12} {a.scenario:<20} {a.tap:<26} {a.code:<28} {a.message[:110]}")


def print_summary(answers: list[Answer]) -> None:
    """Per set: should-accept rejected (worst scenario), the fouled scenarios, silent failures."""
    by = tallies(answers)
    sets = list(dict.fromkeys(a.set_name for a in answers))
    print(f"\n{'set':<12} {'clean rej':>9} {'worst scenario':<26} {'silent':>6} {'heavy ooze rej':>14} "
          f"{'short pb acc':>12} {'mild ooze rej, bias':<24} {'two-stage rej, bias':<24} {'acc > 2 sigma':>13}")
    for s in sets:
        rows = {sc: t for (name, sc), t in by.items() if name == s}
        clean = {sc: t for sc, t in rows.items() if any(a.expect == "accept" for a in answers
                                                        if a.set_name == s and a.scenario == sc)}
        rejected = sum(t.rejected for t in clean.values())
        worst = max(clean.items(), key=lambda item: item[1].rejected / item[1].taps, default=None)
        worst_text = f"{worst[0]} {100.0 * worst[1].rejected / worst[1].taps:.1f}%" if worst and worst[1].rejected else "-"
        silent = sum(t.silent for t in rows.values())

        def fouled(*names: str) -> Tally | None:
            return next((rows[n] for n in names if n in rows), None)

        heavy = fouled("heavy_ooze", "ooze_heavy")
        short = fouled("short_pullback")
        mild = fouled("mild_ooze", "ooze_mild")
        two = fouled("two_stage")
        heavy_text = f"{100.0 * heavy.rejected / heavy.taps:.1f}%" if heavy else "-"
        short_text = f"{short.taps - short.rejected}" if short else "-"
        mild_text = f"{mild.rejected}/{mild.taps}, {_bias(mild.errors_um)}" if mild else "-"
        two_text = f"{two.rejected}/{two.taps}, {_bias(two.errors_um)}" if two else "-"
        beyond = f"{two.beyond_two_sigma}" if two else "-"
        print(f"{s:<12} {rejected:>4}/{sum(t.taps for t in clean.values()):<4} {worst_text:<26} {silent:>6} "
              f"{heavy_text:>14} {short_text:>12} {mild_text:<24} {two_text:<24} {beyond:>13}")


def parse_seeds(text: str) -> list[int]:
    """'1-12' or '2,3,7' or '1-3,9'."""
    seeds = []
    for part in text.split(","):
        low, sep, high = part.partition("-")
        seeds.extend(range(int(low), int(high) + 1) if sep else [int(low)])
    return seeds


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m bench tap_seeds", description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", default="1-12", help="taplab seeds: 1-12, 2,3 (default 1-12)")
    parser.add_argument("--per-scenario", type=int, default=DEFAULT_PER_SCENARIO)
    parser.add_argument("--scenarios", help="comma-separated taplab scenarios (default all)")
    parser.add_argument("--reference", help="the reference taps (archive or directory)")
    parser.add_argument("--sessions", help="the reference sessions (archive or directory)")
    parser.add_argument("--no-reference", action="store_true", help="leave out both reference sets")
    return parser


def main(argv: list[str]) -> int:
    args = _parser().parse_args(argv)
    scenarios = args.scenarios.split(",") if args.scenarios else None
    answers = []
    for seed in parse_seeds(args.seeds):
        answers += taplab_answers(seed, args.per_scenario, scenarios)
    if not args.no_reference:
        with tempfile.TemporaryDirectory() as scratch:
            for name, given, default in (("reference", args.reference, REFERENCE_NAME),
                                         ("sessions", args.sessions, REFERENCE_SESSIONS_NAME)):
                source = Path(given) if given else default_reference_archive(default)
                if not source.exists():
                    print(f"({name}: {source} is not there; left out)")
                    continue
                unpacked = Path(scratch) / name
                unpacked.mkdir()
                tap_set = reference_set(source, unpacked, name=name, archive=default)
                if tap_set is None:
                    print(f"({name}: no labels.jsonl in {source}; left out)")
                    continue
                answers += set_answers(tap_set)
    print_rejections(answers)
    print_summary(answers)
    return 0
