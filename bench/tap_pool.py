"""Repeatability at one spot: each tap alone against the taps pooled (`tapcell analyze --pool`,
tapcell.tap.pool), beside Kalico, on sessions of 10 taps that share their physics (issue 21).

Sets: taplab's sessions (`tapcell.taplab.generate.generate_sessions`, fresh from the seed) and the
reference sessions (../shared/data/reference-sessions.tar.xz from the repository root; left out
with a note when absent). Per scenario: valid %, the within-session sigma a user sees as
PROBE_ACCURACY's standard deviation (rms over the sessions of each session's sd of Z over its
valid taps, µm), the bias against the truth, rms(error / sigma); and pooled / Kalico.

Run: .venv/bin/python -m bench tap_pool [--sessions N] [--seed N] [--no-kalico]
"""

from __future__ import annotations

import argparse
import collections
import sys
import tempfile
from pathlib import Path

import numpy as np

from tapcell.tap import analyze_tap, read_tap_file
from tapcell.tap.pool import apply_pool
from tapcell.taplab.benchmark import (REFERENCE_SESSIONS_NAME, TapSet, default_reference_archive, kalico_command,
                                      kalico_python, read_labels, reference_set, run_analyzer)
from tapcell.taplab.generate import generate_sessions


def _rms(values) -> float:
    return float(np.sqrt(np.mean(np.square(values)))) if len(values) else float("nan")


def _within_sd_um(z_by_session: dict[str, list[float]]) -> float:
    return _rms([np.std(z, ddof=1) * 1000.0 for z in z_by_session.values() if len(z) > 1])


def score_set(tap_set: TapSet, kalico: bool) -> None:
    sessions = collections.defaultdict(list)
    for label in tap_set.labels:
        sessions[label.session].append(label)
    rows = collections.defaultdict(lambda: collections.defaultdict(lambda: collections.defaultdict(list)))
    counts = collections.Counter()
    for session, labels in sessions.items():
        analyses = [analyze_tap(read_tap_file(str(tap_set.directory / label.file))[0]) for label in labels]
        apply_pool(analyses)
        scenario = labels[0].scenario
        counts[scenario] += len(labels)
        for label, a in zip(labels, analyses):
            if not a.valid:
                continue
            for name, z, sigma in (("single", a.z_mm, a.z_sigma_um), ("pooled", a.z_pooled_mm, a.z_pooled_sigma_um)):
                if z is None:
                    continue
                error_um = (z - label.z_contact_mm) * 1000.0
                rows[scenario][name]["z"].append((session, z))
                rows[scenario][name]["error"].append(error_um)
                rows[scenario][name]["ratio"].append(error_um / sigma if sigma else np.nan)
    if kalico:
        python = kalico_python(None)
        command, env, _ = kalico_command(python, tap_set.files) if python else (None, None, None)
        run = run_analyzer("kalico", command, tap_set.files, env) if command else None
        if run is not None and not run.failure:
            for label in tap_set.labels:
                answer = run.results.get(label.file, {})
                if answer.get("valid") and answer.get("z") is not None:
                    rows[label.scenario]["kalico"]["z"].append((label.session, answer["z"]))
                    rows[label.scenario]["kalico"]["error"].append((answer["z"] - label.z_contact_mm) * 1000.0)
        else:
            print("Kalico: not run (make kalico-venv)")
    print(f"== {tap_set.name}: {tap_set.directory} ({len(sessions)} sessions)")
    header = (f"{'scenario':<20} {'taps':>5} | {'valid %':>7} {'within σ single':>15} {'pooled':>7} {'Kalico':>7} "
              f"{'pooled/K':>8} | {'bias single':>11} {'pooled':>7} {'Kalico':>7} | {'e/σ rms single':>14} {'pooled':>7}")
    print(header)
    print("-" * len(header))
    for scenario, by_name in rows.items():
        def within(name):
            grouped = collections.defaultdict(list)
            for session, z in by_name[name]["z"]:
                grouped[session].append(z)
            return _within_sd_um(grouped)

        def bias(name):
            return float(np.mean(by_name[name]["error"])) if by_name[name]["error"] else float("nan")

        valid = 100.0 * len(by_name["single"]["error"]) / counts[scenario]
        ratio = within("pooled") / within("kalico") if by_name["kalico"]["z"] else float("nan")
        print(f"{scenario:<20} {counts[scenario]:>5} | {valid:>7.1f} {within('single'):>15.2f} {within('pooled'):>7.2f} "
              f"{within('kalico'):>7.2f} {ratio:>8.2f} | {bias('single'):>+11.2f} {bias('pooled'):>+7.2f} "
              f"{bias('kalico'):>+7.2f} | {_rms(by_name['single']['ratio']):>14.2f} {_rms(by_name['pooled']['ratio']):>7.2f}")
    print()


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench tap_pool", description=__doc__.split("\n\n")[0])
    parser.add_argument("--sessions", type=int, default=20, help="taplab sessions per scenario (default 20)")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--reference", help="the reference sessions (archive or directory); default "
                                            "../shared/data/reference-sessions.tar.xz from the repository root")
    parser.add_argument("--no-kalico", action="store_true")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="tap-pool-") as scratch:
        taplab_dir = Path(scratch, "taplab-sessions")
        generate_sessions(taplab_dir, args.seed, args.sessions)
        sets = [TapSet(f"taplab sessions (seed {args.seed})", taplab_dir, read_labels(taplab_dir))]
        source = Path(args.reference) if args.reference else default_reference_archive(REFERENCE_SESSIONS_NAME)
        found = (reference_set(source, Path(scratch, "reference"), "reference sessions", REFERENCE_SESSIONS_NAME)
                 if source.exists() else None)
        if found is None:
            print(f"reference sessions: {source} not found; left out")
        else:
            sets.append(found)
        for tap_set in sets:
            score_set(tap_set, not args.no_kalico)
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
