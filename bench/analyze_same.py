"""Did a speed change change an output? `tapcell analyze --json` on tap sets, with the compiled
kernels and with their numpy twins (TAPCELL_NATIVE=0), recorded once and compared byte for byte
afterwards (all but `elapsed_ms` and `cpu_ms`, which are the clock's).

Run: .venv/bin/python -m bench analyze_same record DIR [--set KEY=VALUE]... SET...   (before the change)
     .venv/bin/python -m bench analyze_same check DIR [--set KEY=VALUE]... SET...    (after: exit 1 on any difference; 2 on a bad command line or a missing record)
A SET is a directory of tap files or one tap file. Each `--set` is passed to `tapcell analyze` as it
is (e.g. `--set mains_hz=auto`); a record made with settings is named after them too, so one DIR can
hold runs with and without. Without arguments: records and checks a small taplab set against itself
(the script's own smoke test).
"""

from __future__ import annotations

import hashlib
import os
import re
import subprocess
import sys
import tempfile
from pathlib import Path

# The two fields a run cannot repeat; every other byte must.
CLOCK_FIELDS = re.compile(rb'"(elapsed_ms|cpu_ms)": [-0-9.e+]+')
KERNELS = {"native": {}, "twins": {"TAPCELL_NATIVE": "0"}}
FILES_PER_RUN = 400  # command lines stay short; each run is one `tapcell analyze` as a user runs it


def tap_files(tap_set: str) -> list[str]:
    path = Path(tap_set)
    if path.is_file():
        return [str(path)]
    return sorted(str(p) for p in path.iterdir() if p.suffix in (".json", ".jsonl", ".csv")
                  and p.name != "labels.jsonl")


def analyze_output(files: list[str], env_changes: dict[str, str], settings: list[str] = ()) -> bytes:
    """The JSON `tapcell analyze --json [--set KEY=VALUE]...` prints for these files, the clock's
    fields blanked."""
    tapcell = Path(sys.executable).with_name("tapcell")
    set_args = [arg for setting in settings for arg in ("--set", setting)]
    out = []
    for start in range(0, len(files), FILES_PER_RUN):
        run = subprocess.run([str(tapcell), "analyze", "--json", *set_args, *files[start:start + FILES_PER_RUN]],
                             env={**os.environ, **env_changes}, capture_output=True, check=False)
        out.append(CLOCK_FIELDS.sub(rb'"\1": -', run.stdout) + b"exit %d\n" % run.returncode)
    return b"".join(out)


def _record_name(tap_set: str, kernels: str, settings: list[str] = ()) -> str:
    """The record's file name: the set's name and path digest, the settings (none: the name records
    had before `--set`), the kernels."""
    digest = hashlib.sha1(str(Path(tap_set).resolve()).encode()).hexdigest()[:10]
    named = "".join("-" + re.sub(r"[^A-Za-z0-9_.]+", "_", setting) for setting in settings)
    return f"{Path(tap_set).name}-{digest}{named}-{kernels}.json"


def _described(tap_set: str, files: list[str], kernels: str, settings: list[str]) -> str:
    return f"{tap_set} ({len(files)} files, {kernels}{''.join(', --set ' + s for s in settings)})"


def record(out_dir: str, tap_sets: list[str], settings: list[str] = ()) -> int:
    Path(out_dir).mkdir(parents=True, exist_ok=True)
    for tap_set in tap_sets:
        files = tap_files(tap_set)
        for kernels, env in KERNELS.items():
            output = analyze_output(files, env, settings)
            (Path(out_dir) / _record_name(tap_set, kernels, settings)).write_bytes(output)
            print(f"recorded {_described(tap_set, files, kernels, settings)}")
    return 0


def check(out_dir: str, tap_sets: list[str], settings: list[str] = ()) -> int:
    differing = 0
    for tap_set in tap_sets:
        files = tap_files(tap_set)
        for kernels, env in KERNELS.items():
            before = (Path(out_dir) / _record_name(tap_set, kernels, settings)).read_bytes()
            now = analyze_output(files, env, settings)
            same = now == before
            differing += not same
            print(f"{'same' if same else 'DIFFERENT'} {_described(tap_set, files, kernels, settings)}")
            if not same:
                _print_differences(before, now)
    return 1 if differing else 0


SHOWN_DIFFERENCES = 20


def _print_differences(before: bytes, now: bytes) -> None:
    """Which taps' lines differ (each tap is one line of the JSON array, named by its file), at most
    SHOWN_DIFFERENCES of them, and how many; or the first differing line of what is no tap's line
    (an exit status, a message)."""
    taps_before, other_before = _lines_by_file(before)
    taps_now, other_now = _lines_by_file(now)
    changed = sorted(name for name in taps_before.keys() | taps_now.keys()
                     if taps_before.get(name) != taps_now.get(name))
    print(f"  {len(changed)} of {len(taps_before.keys() | taps_now.keys())} taps differ")
    for name in changed[:SHOWN_DIFFERENCES]:
        print(f"    {name}")
    if len(changed) > SHOWN_DIFFERENCES:
        print(f"    ... and {len(changed) - SHOWN_DIFFERENCES} more")
    if other_before != other_now:
        line = next((a for a, b in zip(other_before, other_now) if a != b), None)
        print(f"  outside the taps' lines: {line.decode(errors='replace')[:200] if line else 'a line more or less'}")


def _lines_by_file(output: bytes) -> tuple[dict[str, bytes], list[bytes]]:
    """The output's tap lines by the file each names (a file with several taps: its lines joined),
    and every other line in order."""
    taps: dict[str, bytes] = {}
    other = []
    for line in output.splitlines():
        found = TAP_FILE.match(line)
        if found:
            name = found.group(1).decode(errors="replace")
            taps[name] = taps.get(name, b"") + line + b"\n"
        else:
            other.append(line)
    return taps, other


TAP_FILE = re.compile(rb'\{"file": "((?:[^"\\]|\\.)*)"')


def _smoke() -> int:
    from tapcell.taplab.generate import generate_set

    with tempfile.TemporaryDirectory() as tmp:
        generate_set(Path(tmp) / "taps", seed=1, taps_per_scenario=1)
        tap_set = str(Path(tmp) / "taps")
        record(str(Path(tmp) / "record"), [tap_set])
        return check(str(Path(tmp) / "record"), [tap_set])


def _settings_and_sets(arguments: list[str]) -> tuple[list[str], list[str]] | None:
    """`--set KEY=VALUE` (or `--set=KEY=VALUE`) items and the tap sets, in any order; None when a
    `--set` has no KEY=VALUE."""
    settings, tap_sets = [], []
    items = iter(arguments)
    for item in items:
        if item == "--set":
            item = "--set=" + next(items, "")
        if item.startswith("--set="):
            setting = item[len("--set="):]
            if "=" not in setting:
                return None
            settings.append(setting)
        else:
            tap_sets.append(item)
    return settings, tap_sets


def main(argv: list[str]) -> int:
    if not argv:
        return _smoke()
    parsed = _settings_and_sets(argv[2:]) if len(argv) >= 3 and argv[0] in ("record", "check") else None
    if parsed is None or not parsed[1]:
        print(__doc__, file=sys.stderr)
        return 2
    settings, tap_sets = parsed
    problem = _argument_problem(argv[0], argv[1], tap_sets, settings)
    if problem:
        print(f"analyze_same: {problem}", file=sys.stderr)
        return 2
    return (record if argv[0] == "record" else check)(argv[1], tap_sets, settings)


def _argument_problem(command: str, out_dir: str, tap_sets: list[str], settings: list[str]) -> str | None:
    """What is wrong with the command line, named, before anything runs; None when nothing is."""
    if out_dir.startswith("-"):
        return f"{out_dir!r} where the record folder belongs: `{command} DIR [--set KEY=VALUE]... SET...`"
    for tap_set in tap_sets:
        if not Path(tap_set).exists():
            return f"{tap_set}: no such tap file or folder"
    if command == "check":
        for tap_set in tap_sets:
            for kernels in KERNELS:
                name = Path(out_dir) / _record_name(tap_set, kernels, settings)
                if not name.is_file():
                    shown = "".join(" --set " + s for s in settings) or " without --set"
                    return (f"{name}: no record of {tap_set} ({kernels}){shown}; `record` it first, "
                            f"with the same path and settings")
    return None


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
