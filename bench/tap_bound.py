"""The floor of the contact height on the independent generator's taps, beside what analyses reach.

Per should-accept scenario (clean taps of four sensors, soft sheet, cable drift, latency, hum):
the Cramér-Rao bound of z_contact (`tapcell.taplab.bound`, sqrt of the mean bound² over the taps)
with white noise and with white + 1/f + random walk, for four sets of unknowns (everything; the
toe's shape known; the whole toe known; only z unknown), the Van Trees (Bayesian) bound of the
scenario with everything unknown, and the σ that tapcell (toe model + halt lag) and Kalico
(when `.venv-kalico` holds it) reach on the same taps. Then the mild-ooze floor: the residual
film the analysis cannot see (mean over the taps each analysis accepts). With --twins N, the
two-point floor on the first N taps per scenario: for each, the nearest twin (another tap of the
scenario's ranges, --twin-shift µm higher or lower) and the least rms error any analysis can have
over the pair.

Run: .venv/bin/python -m bench tap_bound [--per-scenario N] [--seed N] [--no-kalico] [--twins N]
     (default: 40 taps per scenario, seed 1: the taps of `tapcell benchmark --seed 1`)
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

from tapcell.taplab import bound
from tapcell.taplab.benchmark import kalico_command, kalico_python, run_analyzer
from tapcell.taplab.generate import SCENARIOS, RecordedMotion, make_tap

ACCEPT = ("clean_hx717", "clean_ads1220_660", "clean_ads1220_2000", "hx711_80", "soft_sheet", "cable_drift",
          "latency", "mains_hum")
TOE_HALT = ["--set", "contact_model=toe", "--set", "sensor_delay_s=halt"]
SETS = tuple(bound.UNKNOWN_SETS)


def _taps(name: str, seed: int, count: int):
    """(spec, tap, truth) of a scenario, the same streams as `generate_set`."""
    index = list(SCENARIOS).index(name)
    for k in range(count):
        rng = np.random.default_rng([seed, index + 1, k])
        spec = SCENARIOS[name].draw(rng)
        tap, truth = make_tap(spec, rng)
        yield k, spec, tap, truth


def _rms(values) -> float:
    return float(np.sqrt(np.mean(np.square(values))))


def _analyse(files: list[Path], use_kalico: bool) -> dict[str, dict[str, dict]]:
    """Answers per analyzer, per file name."""
    runs = {"tapcell toe+halt": run_analyzer("tapcell", [sys.executable, "-m", "tapcell", "analyze", "--json",
                                                         *TOE_HALT], files)}
    python = kalico_python(None) if use_kalico else None
    if python is not None:
        command, env, _ = kalico_command(python, files)
        if command:
            runs["Kalico"] = run_analyzer("kalico", command, files, env)
    answers = {}
    for name, run in runs.items():
        if run.failure:
            print(f"{name}: {run.failure}", file=sys.stderr)
        else:
            answers[name] = run.results
    return answers


def _measured(answers: dict[str, dict], truths: dict[str, dict], files: list[str]) -> tuple[float, float, int]:
    errors = [(answers[f]["z"] - truths[f]["z_contact"]) * 1000.0 for f in files
              if f in answers and answers[f].get("valid") and answers[f].get("z") is not None]
    if not errors:
        return float("nan"), float("nan"), 0
    return float(np.mean(errors)), float(np.std(errors)), len(errors)


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="bench tap_bound", description=__doc__.split("\n\n")[0])
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--per-scenario", type=int, default=40)
    parser.add_argument("--scenarios", default=",".join(ACCEPT), help="comma-separated should-accept scenarios")
    parser.add_argument("--no-kalico", action="store_true")
    parser.add_argument("--twins", type=int, default=0, metavar="N", help="two-point floor on N taps per scenario "
                        "(slow: 5-60 s per tap)")
    parser.add_argument("--twin-shift", type=float, default=1.5, metavar="UM")
    parser.add_argument("--twin-noise", choices=("white", "coloured"), default="coloured")
    args = parser.parse_args(argv)
    names = args.scenarios.split(",")
    unknown = [n for n in names if n not in ACCEPT]
    if unknown:
        print(f"bench tap_bound: not a should-accept scenario: {', '.join(unknown)} (one of {', '.join(ACCEPT)})",
              file=sys.stderr)
        return 2

    floors: dict[str, list[bound.TapFloor]] = {}
    twins: dict[str, list[bound.Twin]] = {}
    ranges = {name: bound.prior_ranges(SCENARIOS[name]) for name in names}
    truths: dict[str, dict] = {}
    files: dict[str, list[str]] = {}
    with tempfile.TemporaryDirectory(prefix="tap-bound-") as scratch:
        for name in [*names, "mild_ooze"]:
            files[name] = []
            for k, spec, tap, truth in _taps(name, args.seed, args.per_scenario):
                file_name = f"{name}-{k:03d}.json"
                Path(scratch, file_name).write_text(json.dumps(tap), encoding="utf-8")
                truths[file_name] = truth
                files[name].append(file_name)
                if name != "mild_ooze":
                    motion = RecordedMotion.of_tap(tap)
                    floors.setdefault(name, []).append(bound.tap_floor(spec, motion))
                    if k < args.twins:  # the closer of a twin above and one below
                        pair = [bound.nearest_twin(spec, motion, sign * args.twin_shift, ranges[name],
                                                   coloured=args.twin_noise == "coloured") for sign in (1, -1)]
                        twins.setdefault(name, []).append(max(pair, key=lambda twin: twin.floor_um))
            print(f"  {name}: {len(files[name])} taps", file=sys.stderr, flush=True)
        answers = _analyse([Path(scratch, f) for fs in files.values() for f in fs], not args.no_kalico)

    priors = {name: bound.prior_information(ranges[name]) for name in names}
    print(f"\nCramér-Rao floor of z_contact (µm; sqrt of the mean bound² over {args.per_scenario} taps per scenario, "
          f"seed {args.seed}); VT: Van Trees, everything unknown, smoothed priors")
    for noise in ("white", "coloured"):
        print(f"\n{noise} noise" + (" (adc.white_g)" if noise == "white" else " (white + 1/f + random walk)"))
        header = f"{'scenario':<20}" + "".join(f"{s:>17}" for s in SETS) + f"{'median all':>12}{'VT':>7}{'degen.':>7}"
        print(header)
        print("-" * len(header))
        for name in names:
            per_set = {s: [getattr(f, noise)[s] for f in floors[name]] for s in SETS}
            cells = "".join(f"{_rms([b.sigma_um for b in per_set[s]]):>17.2f}" for s in SETS)
            median = float(np.median([b.sigma_um for b in per_set['all unknown']]))
            fishers = [getattr(f, f"fisher_{noise}") for f in floors[name]]
            vt = bound.van_trees_sigma_um(fishers, priors[name], bound.UNKNOWN_SETS["all unknown"])
            degenerate = sum(b.degenerate for s in SETS for b in per_set[s])
            print(f"{name:<20}{cells}{median:>12.2f}{vt.sigma_um:>7.2f}{degenerate:>7}")

    if twins:
        print(f"\ntwo-point floor: nearest twin {args.twin_shift} µm higher or lower (contact inside the central "
              f"{100 - 200 * bound.TWIN_INTERIOR:.0f} % of each range), {args.twin_noise} noise")
        print(f"{'scenario':<20}{'taps':>6}{'median distance':>17}{'rms pair floor':>16}{'pair floor >= 0.4':>19}")
        for name in names:
            found = twins[name]
            floor = [t.floor_um for t in found]
            print(f"{name:<20}{len(found):>6}{np.median([t.distance for t in found]):>17.2f}{_rms(floor):>16.2f}"
                  f"{np.mean(np.array(floor) >= 0.4):>19.0%}")

    print("\nmeasured on the same taps (bias ± σ over valid taps, µm)")
    print(f"{'scenario':<20}" + "".join(f"{a:>22}" for a in answers))
    for name in names:
        cells = ""
        for results in answers.values():
            bias, sd, valid = _measured(results, truths, files[name])
            cells += f"{f'{bias:+.2f} ± {sd:.2f} ({valid})':>22}"
        print(f"{name:<20}{cells}")

    print("\nmild ooze: the residual film lifts the surface the nozzle touches and nothing in the samples depends on it")
    mild = files["mild_ooze"]
    residual = {f: truths[f]["spec"]["ooze"]["film_residual_um"] for f in mild}
    left = {f: truths[f]["film_left_um"] for f in mild}
    print(f"  all {len(mild)} taps: residual film {np.mean(list(residual.values())):.2f} µm, "
          f"film left at break contact {np.mean(list(left.values())):.2f} µm (means)")
    for analyzer, results in answers.items():
        accepted = [f for f in mild if results.get(f, {}).get("valid")]
        bias, _, _ = _measured(results, truths, accepted)
        if accepted:
            print(f"  {analyzer}: {len(accepted)} accepted, mean error {bias:+.2f} µm; over those, residual "
                  f"{np.mean([residual[f] for f in accepted]):.2f} µm, film left {np.mean([left[f] for f in accepted]):.2f} µm")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
