"""Repeatability at one spot: each tap alone against the taps pooled (`tapcell analyze --pool`,
tapcell.tap.pool), beside Kalico, on sessions of 10 taps that share their physics (issue 21).

Sets: taplab's sessions (`tapcell.taplab.generate.generate_sessions`, fresh from the seed) and the
reference sessions (../shared/data/reference-sessions.tar.xz from the repository root; left out
with a note when absent). Per scenario: valid %, the within-session sigma a user sees as
PROBE_ACCURACY's standard deviation (per session the population sd of Z over its valid taps, as
PROBE_ACCURACY computes it, then the rms over the sessions, µm; Kalico's over the taps Kalico
accepts of the same files), the bias against the truth, rms(error / sigma), pooled / Kalico, and
the median time one pool takes (`pool_taps` over the session's analyses, ms). Then the same for
pools of the first 3 taps of each session (a retried point, `SAMPLES=3`), and the worst
pooled / Kalico of each set. With --floor N: per set, scenario and pool size, the floor of a tap's
Z with everything its session shares known and only its contact height and baseline unknown
(`bench._tap_pool_floor`: measured from each session's pullbacks and its truth, the same way on both
sets), as PROBE_ACCURACY would show it, over Kalico, beside pooled / Kalico: where floor / Kalico
>= 0.5, no pool can reach 0.5x Kalico. Then, on the first N taplab sessions per scenario, that
measured floor beside taplab's exact Cramér-Rao floor (`tapcell.taplab.bound`, the generator's own
physics) over the same pullbacks and over the whole tap.

With --gap: where the pool loses to that floor (`print_gap`): whether the shared physics it
estimates costs anything (pools of 3 read at their own shared physics and at the whole session's),
and the sharp model's residual scatter across a session's taps by height band.

Run: .venv/bin/python -m bench tap_pool [--sessions N] [--seed N] [--no-kalico] [--floor N] [--gap]
"""

from __future__ import annotations

import argparse
import collections
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from bench import _tap_pool_floor as pool_floor
from tapcell.tap import analyze_tap, read_tap_file
from tapcell.tap.contact import window_mean_and_slope
from tapcell.tap.pool import _fitting, contact_at_shared, contact_at_stiffness_um, pool_taps, shared_physics
from tapcell.taplab.benchmark import (REFERENCE_SESSIONS_NAME, TapSet, default_reference_archive, kalico_command,
                                      kalico_python, read_labels, reference_set, run_analyzer)
from tapcell.taplab import bound
from tapcell.taplab.generate import SESSION_SCENARIOS, RecordedMotion, generate_sessions, make_tap, session_tap_specs


def _rms(values) -> float:
    return float(np.sqrt(np.mean(np.square(values)))) if len(values) else float("nan")


def _within_sd_um(z_by_session: dict[str, list[float]]) -> float:
    """PROBE_ACCURACY's standard deviation (population sd over a session's taps), rms over the sessions."""
    return _rms([np.std(z) * 1000.0 for z in z_by_session.values() if len(z) > 1])


SMALL_POOL_TAPS = 3


def score_set(tap_set: TapSet, pool_size: int | None, analyses_of: dict, answers: dict | None) -> dict[str, tuple]:
    """Print the set's table (pools of the first `pool_size` taps of each session, None: all);
    return per scenario (pooled, Kalico) within-session sigma (µm)."""
    sessions = collections.defaultdict(list)
    for label in tap_set.labels:
        sessions[label.session].append(label)
    rows = collections.defaultdict(lambda: collections.defaultdict(lambda: collections.defaultdict(list)))
    counts = collections.Counter()
    pool_ms = collections.defaultdict(list)
    for session, labels in sessions.items():
        labels = labels[:pool_size]
        analyses = [analyses_of[label.file] for label in labels]
        started = time.perf_counter()
        pooled = pool_taps(analyses)
        scenario = labels[0].scenario
        pool_ms[scenario].append((time.perf_counter() - started) * 1000.0)
        counts[scenario] += len(labels)
        for label, a, p in zip(labels, analyses, pooled):
            if not a.valid:
                continue
            for name, z, sigma in (("single", a.z_mm, a.z_sigma_um),
                                   ("pooled", p.z_mm if p else None, p.sigma_um if p else None)):
                if z is None:
                    continue
                error_um = (z - label.z_contact_mm) * 1000.0
                rows[scenario][name]["z"].append((session, z))
                rows[scenario][name]["error"].append(error_um)
                rows[scenario][name]["ratio"].append(error_um / sigma if sigma else np.nan)
        for label in labels:
            answer = (answers or {}).get(label.file, {})
            if answer.get("valid") and answer.get("z") is not None:
                rows[label.scenario]["kalico"]["z"].append((label.session, answer["z"]))
                rows[label.scenario]["kalico"]["error"].append((answer["z"] - label.z_contact_mm) * 1000.0)
    size = f"pools of the first {pool_size} taps" if pool_size else "whole sessions pooled"
    print(f"== {tap_set.name}: {tap_set.directory} ({len(sessions)} sessions, {size})")
    header = (f"{'scenario':<20} {'taps':>5} | {'valid %':>7} {'within σ single':>15} {'pooled':>7} {'Kalico':>7} "
              f"{'pooled/K':>8} | {'bias single':>11} {'pooled':>7} {'Kalico':>7} | {'e/σ rms single':>14} {'pooled':>7} "
              f"| {'pool ms':>7}")
    print(header)
    print("-" * len(header))
    worst = 0.0
    within_of = {}
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
        worst = max(worst, ratio) if np.isfinite(ratio) else worst
        within_of[scenario] = (within("pooled"), within("kalico") if by_name["kalico"]["z"] else float("nan"))
        print(f"{scenario:<20} {counts[scenario]:>5} | {valid:>7.1f} {within('single'):>15.3f} {within('pooled'):>7.3f} "
              f"{within('kalico'):>7.3f} {ratio:>8.2f} | {bias('single'):>+11.2f} {bias('pooled'):>+7.2f} "
              f"{bias('kalico'):>+7.2f} | {_rms(by_name['single']['ratio']):>14.2f} {_rms(by_name['pooled']['ratio']):>7.2f} "
              f"| {np.median(pool_ms[scenario]):>7.2f}")
    print(f"worst pooled/Kalico: {worst:.2f}\n")
    return within_of


def kalico_answers(tap_set: TapSet) -> dict[str, dict] | None:
    """Kalico's answer per file (its analysis and classifier on the same files), None when it cannot run."""
    python = kalico_python(None)
    command, env, _ = kalico_command(python, tap_set.files) if python else (None, None, None)
    run = run_analyzer("kalico", command, tap_set.files, env) if command else None
    return run.results if run is not None and not run.failure else None


def print_floor_check(seed: int, sessions: int) -> None:
    """Taplab's exact floor (`tapcell.taplab.bound`: its own physics, each tap's contact and baseline
    unknown, white + 1/f + walk) over the whole tap and over the pullback alone, beside the measured
    floor of bench._tap_pool_floor on the same taps (which the reference sessions get): the check of
    the measured floor against the exact one."""
    print(f"== floor check: taplab sessions (seed {seed}, first {sessions} per scenario), rms over the taps, µm")
    print(f"{'scenario':<20} {'exact whole tap':>15} {'exact pullback':>14} {'measured pullback':>17} "
          f"{'measured/exact':>14}  (white noise alone: exact pullback / measured)")
    unknowns = [p for p in bound.PARAMETERS if p.name in ("z_contact_um", "offset_g")]
    for name in SESSION_SCENARIOS:
        floors = collections.defaultdict(list)
        for session in range(sessions):
            records = []
            for spec, rng in session_tap_specs(name, seed, session, 10):
                tap, truth = make_tap(spec, rng)
                G = bound.parameter_sensitivities(spec, RecordedMotion.of_tap(tap), unknowns)
                pullback = np.flatnonzero(np.asarray(tap["time"]) >= tap["events"]["pullback_start_time"])
                cov = bound.noise_covariance(spec, G.shape[0])
                for key, rows in (("whole", np.arange(G.shape[0])), ("pullback", pullback)):
                    J = G[rows].T @ np.linalg.solve(cov[np.ix_(rows, rows)], G[rows])
                    floors[key].append(float(np.sqrt(np.linalg.inv(J)[0, 0])))
                J = G[pullback].T @ G[pullback] / spec.adc.white_g ** 2
                floors["pullback white"].append(float(np.sqrt(np.linalg.inv(J)[0, 0])))
                records.append(pool_floor.read_record(tap, truth["z_contact"]))
            measured = pool_floor.session_floor_um(records)
            floors["measured"] += measured["coloured"]
            floors["measured white"] += measured["white"]
        rms = {key: _rms_finite(values) for key, values in floors.items()}
        print(f"{name:<20} {rms['whole']:>15.3f} {rms['pullback']:>14.3f} {rms['measured']:>17.3f} "
              f"{rms['measured'] / rms['pullback']:>14.2f}  ({rms['pullback white']:.3f} / {rms['measured white']:.3f})")
    print()


def _rms_finite(values) -> float:
    values = np.asarray(values, dtype=float)
    return _rms(values[np.isfinite(values)])


def print_floor_ratios(tap_set: TapSet, within_by_size: dict) -> float:
    """Per scenario and pool size: the measured floor as PROBE_ACCURACY would show it (a tap's floor,
    rms over the taps, x sqrt((n - 1) / n): the population sd of n taps; the median tap's beside it),
    over Kalico, beside pooled / Kalico. A floor the pool itself beats was not measured (the pool is
    a real estimator: no floor lies above it); it is flagged and left out of the worst. Returns the
    worst floor / Kalico."""
    floors = pool_floor.floors_of_set(tap_set.directory, tap_set.labels)
    print(f"== {tap_set.name}: the floor with everything shared known (bench._tap_pool_floor, pullback, "
          "white + 1/f + walk as measured)")
    print(f"{'scenario':<20} {'pool':>5} | {'floor µm':>8} {'median':>7} {'unmeasured':>10} | {'pooled/K':>8} "
          f"{'floor/K':>7} {'pooled/floor':>12}")
    worst = 0.0
    for scenario, coloured in ((s, f["coloured"]) for s, f in floors.items()):
        unmeasured = int(np.sum(~np.isfinite(coloured)))
        for size, within_of in within_by_size.items():
            if scenario not in within_of:
                continue
            pooled, kalico = within_of[scenario]
            shown = np.sqrt((size - 1) / size) if size else np.sqrt(0.9)
            floor = _rms_finite(coloured) * shown
            beaten = pooled < floor
            if np.isfinite(kalico) and not beaten:
                worst = max(worst, floor / kalico)
            print(f"{scenario:<20} {size or 10:>5} | {floor:>8.3f} {np.median(coloured) * shown:>7.3f} {unmeasured:>10} | "
                  f"{pooled / kalico:>8.2f} {floor / kalico:>7.2f} {pooled / floor:>12.2f}"
                  + ("  the pool beats it: not measured" if beaten else ""))
    print(f"worst floor/Kalico: {worst:.2f} (0.5x Kalico is out of reach where this is >= 0.5)\n")
    return worst


# Height bands (µm from the contact the pool reads) of --gap's residual scatter across a session's taps.
GAP_BANDS_UM = (("deep -60..-40", -60.0, -40.0), ("contact -20..0", -20.0, 0.0), ("free air 0..20", 0.0, 20.0),
                ("free air 20..60", 20.0, 60.0))


def pool_gap(tap_set: TapSet, analyses_of: dict) -> dict[str, dict[str, float]]:
    """Where the pool loses to its floor (`--gap`), per scenario: (1) whether it is the shared physics
    the pool estimates: the within-session sigma of pools of the first 3 taps read (step 2, before the
    common level) at the shared physics of those 3 taps ("own") and at that of the whole session
    ("session"); (2) what the taps do not share: the sharp model's residual at the session's shared
    physics, each tap's at its contact there less its mean in free air 5-40 µm above, its sd across
    the session's taps per height band of GAP_BANDS_UM (g, rms over the bands' 6 µm bins and the
    sessions)."""
    sessions = collections.defaultdict(list)
    for label in tap_set.labels:
        sessions[label.session].append(label)
    small = collections.defaultdict(lambda: collections.defaultdict(dict))
    scatter = collections.defaultdict(lambda: collections.defaultdict(list))
    for session, labels in sessions.items():
        members = [a for a in (analyses_of[label.file] for label in labels) if _fitting(a)]
        if len(members) < 3:
            continue
        scenario = labels[0].scenario
        whole = shared_physics([a.pullback_fit for a in members])
        for name, shared in (("own", shared_physics([a.pullback_fit for a in members[:3]])), ("session", whole)):
            small[scenario][name][session] = [found.z_mm for a in members[:3]
                                              if (found := contact_at_shared(a, shared)) is not None]
        residuals = [found for a in members if (found := _residual_at(a.pullback_fit, whole)) is not None]
        for band, low, high in GAP_BANDS_UM:
            for bin_low in np.arange(low, high, 6.0):
                means = [r[(h >= bin_low) & (h < bin_low + 6.0)].mean() for h, r in residuals
                         if np.any((h >= bin_low) & (h < bin_low + 6.0))]
                if len(means) > 3:
                    scatter[scenario][band].append(float(np.std(means)))
    return {scenario: {"own": _within_sd_um(small[scenario]["own"]), "session": _within_sd_um(small[scenario]["session"]),
                       **{band: _rms(scatter[scenario][band]) for band, *_ in GAP_BANDS_UM}}
            for scenario in small}


def _residual_at(fit, shared) -> tuple[np.ndarray, np.ndarray] | None:
    """(height above the contact µm, residual g) of a pullback at the shared physics, the residual
    less its mean 5-40 µm above the contact; None when the contact is not found."""
    contact_um = contact_at_stiffness_um(fit, shared.stiffness_g_um, shared.onset_um)
    if contact_um is None:
        return None
    height_um = fit.x_min_um + 0.5 * fit.span_um - contact_um
    mean, _ = window_mean_and_slope(np.array(contact_um), shared.onset_um, fit.x_min_um, fit.span_um, slope=False)
    residual = fit.force_g - shared.stiffness_g_um * mean
    free = (height_um > 5.0) & (height_um < 40.0)
    return height_um, residual - residual[free].mean()


def print_gap(tap_set: TapSet, analyses_of: dict) -> None:
    print(f"== {tap_set.name}: where the pool loses (--gap)")
    print(f"{'scenario':<20} | {'pools of 3 at their own':>23} {'at the session':>16} | "
          + " ".join(f"{band:>16}" for band, *_ in GAP_BANDS_UM) + "  (residual sd across taps, g)")
    for scenario, row in pool_gap(tap_set, analyses_of).items():
        print(f"{scenario:<20} | {row['own']:>23.3f} {row['session']:>16.3f} | "
              + " ".join(f"{row[band]:>16.2f}" for band, *_ in GAP_BANDS_UM))
    print()


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench tap_pool", description=__doc__.split("\n\n")[0])
    parser.add_argument("--sessions", type=int, default=20, help="taplab sessions per scenario (default 20)")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--reference", help="the reference sessions (archive or directory); default "
                                            "../shared/data/reference-sessions.tar.xz from the repository root")
    parser.add_argument("--no-kalico", action="store_true")
    parser.add_argument("--floor", type=int, default=0, metavar="N",
                        help="also the floor of every session of both sets (bench._tap_pool_floor) against Kalico, "
                             "and its check against taplab's exact floor on the first N taplab sessions per scenario")
    parser.add_argument("--gap", action="store_true",
                        help="also where the pool loses to its floor: the shared physics' share, and the "
                             "residual's scatter across a session's taps by height")
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
        worst = 0.0
        floor_rows = []
        for tap_set in sets:
            analyses = {label.file: analyze_tap(read_tap_file(str(tap_set.directory / label.file))[0])
                        for label in tap_set.labels}
            answers = kalico_answers(tap_set) if not args.no_kalico else None
            if answers is None and not args.no_kalico:
                print("Kalico: not run (make kalico-venv)")
            within_by_size = {size: score_set(tap_set, size, analyses, answers) for size in (None, SMALL_POOL_TAPS)}
            if args.gap:
                print_gap(tap_set, analyses)
            for within_of in within_by_size.values():
                ratios = [pooled / kalico for pooled, kalico in within_of.values() if np.isfinite(kalico)]
                worst = max([worst] + ratios)
            if args.floor and answers is not None:
                floor_rows.append((tap_set, within_by_size))
        if args.no_kalico or not worst:
            print("worst pooled/Kalico over both sets and pool sizes: not measured (Kalico not run)\n")
        else:
            print(f"worst pooled/Kalico over both sets and pool sizes: {worst:.2f} (target <= 0.5)\n")
        for tap_set, within_by_size in floor_rows:
            print_floor_ratios(tap_set, within_by_size)
    if args.floor:
        print_floor_check(args.seed, args.floor)
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
