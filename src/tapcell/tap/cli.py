"""`tapcell analyze [--json] [--pool] [--plot OUT.png] [--set key=value ...] FILE...`"""

from __future__ import annotations

import gc
import sys
from types import SimpleNamespace
from typing import TYPE_CHECKING

from tapcell.tap import native
from tapcell.tap.analysis import analyze_tap
from tapcell.tap.classifiers import UnknownClassifierError, get_classifier
from tapcell.tap.model import AnalysisOptions, TapAnalysis, TapFileError
from tapcell.tap.readers import read_tap_file

if TYPE_CHECKING:
    import argparse


# json.dumps in C for a tap's result (c/output.c, byte for byte: tests/tap/test_native_output.py).
_C = native.load("output")


def json_text(value) -> str:
    """json.dumps(value) with its defaults: through the output kernel when it was built (a result's
    floats are short decimals, written without dtoa: a third of the CPU of writing a tap), else json.
    What the kernel does not take (a key that is not a str, a type json may refuse) goes to json."""
    if _C is not None:
        try:
            return _C.json_text(value)
        except TypeError:
            pass
    import json  # here, not at the top: with the kernel, a run seldom needs it (1.5 ms of start-up)

    return json.dumps(value)


def _parser() -> argparse.ArgumentParser:
    import argparse  # here, not at the top: the common call is read without it (_arguments)

    parser = argparse.ArgumentParser(
        prog="tapcell analyze",
        description="Analyse tap files: Z at break contact, validation, quality.")
    parser.add_argument("files", nargs="+", metavar="FILE", help="tap files (.json, .jsonl, .csv)")
    parser.add_argument("--json", action="store_true", help="print one JSON array instead of a table")
    parser.add_argument("--plot", metavar="OUT.png",
                        help="draw each tap: the first to OUT.png, the next to OUT-2.png, OUT-3.png, ... "
                             "(the files written are listed after the results)")
    parser.add_argument("--pool", action="store_true",
                        help="the taps were made at one spot (PROBE_ACCURACY, SAMPLES=): estimate what they share "
                             "(stiffness, onset, sensor lag, toe) jointly and add each tap's pooled Z "
                             "(z_pooled, z_pooled_sigma_um)")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="analysis option, e.g. sensor_delay_s=0.002 or decompression_angle=80")
    return parser


def _arguments(argv: list[str]) -> argparse.Namespace | SimpleNamespace:
    """The command line's options. The common call, `[--json] FILE...` with no FILE starting with
    '-', is read here: the values argparse would give (tests/tap/test_cli_arguments.py holds it to
    argparse's answer), without importing it and building its parser (~20 M instructions: 4 % of a
    one-file run). Anything else goes to argparse, which also names what is wrong."""
    flags = 0
    while flags < len(argv) and argv[flags] == "--json":
        flags += 1
    files = argv[flags:]
    if files and not any(name.startswith("-") for name in files):
        return SimpleNamespace(files=files, json=flags > 0, plot=None, pool=False, set=[])
    return _parser().parse_args(argv)


def options_from_settings(settings: list[str]) -> AnalysisOptions:
    """AnalysisOptions from `--set KEY=VALUE` items; ValueError names what is wrong."""
    overrides = {}
    for item in settings:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise ValueError(f"--set '{item}': expected KEY=VALUE")
        overrides[key.strip()] = value.strip()
    options = AnalysisOptions().with_overrides(overrides)
    get_classifier(options.tap_classifier, options)
    return options


def _fmt(value: float | None, spec: str) -> str:
    return "-" if value is None else format(value, spec)


def main(argv: list[str]) -> int:
    args = _arguments(argv)
    try:
        options = options_from_settings(args.set)
    except (ValueError, UnknownClassifierError) as problem:
        print(f"tapcell analyze: {problem}", file=sys.stderr)
        return 2
    # Reading and analysing a tap leaves no reference cycles (measured: none on 600 taplab and
    # reference taps), so reference counting frees all of it: the cycle collector would only walk
    # the growing results over and over (~1 % of a run's CPU). Drawing (matplotlib) makes cycles.
    collecting = gc.isenabled()
    if not args.plot:
        gc.disable()
    try:
        return _analyze_files(args, options)
    finally:
        if collecting:
            gc.enable()


def _analyze_files(args: argparse.Namespace | SimpleNamespace, options: AnalysisOptions) -> int:
    # Each tap's output line is made as soon as it is analysed and its analysis dropped (~34 kB a
    # tap: the toe grid, the pullback's samples), unless the pool needs them all at the end: a run's
    # memory grows by a line a tap instead of by a page fault every few kB.
    pooled = []  # (name, index, count, analysis) with --pool
    lines = []  # each tap's output line, in order
    unreadable = 0
    plots = []  # (file written, the tap it shows)
    for name in args.files:
        try:
            taps = read_tap_file(name)
        except TapFileError as problem:
            unreadable += 1
            print(f"tapcell analyze: {problem}", file=sys.stderr)
            continue
        for index, tap in enumerate(taps):
            analysis = analyze_tap(tap, options)
            if args.plot:
                # Imported here: matplotlib (and pathlib) would slow every run that draws nothing.
                from pathlib import Path

                from tapcell.tap.plot import plot_tap

                out = Path(args.plot)
                target = out if not plots else out.with_name(f"{out.stem}-{len(plots) + 1}{out.suffix}")
                label = name + (f"#{index + 1}" if len(taps) > 1 else "")
                plot_tap(tap, analysis, target, title=f"{name}" + (f" #{index + 1}" if len(taps) > 1 else ""))
                plots.append((target, label))
            if args.pool:
                pooled.append((name, index, len(taps), analysis))
            else:
                lines.append(_output_line(args, name, index, len(taps), analysis))
    if args.pool:
        # Imported here: only a pooled run needs it.
        from tapcell.tap.pool import apply_pool

        apply_pool([analysis for *_, analysis in pooled])
        lines = [_output_line(args, *row) for row in pooled]
    if args.json:
        # One tap per line (indent= would take json's pure-Python encoder, ~0.2 ms a tap).
        print("[\n" + ",\n".join(lines) + "\n]")
    else:
        pooled_header = f" {'pooled Z':>11} {'±σ (µm)':>8}" if args.pool else ""
        print(f"{'file':<32} {'valid':<6} {'Z (mm)':>11} {'±σ (µm)':>8}{pooled_header} {'quality':>8}  code")
        for line in lines:
            print(line)
    # The plot files written, one a line (on stderr with --json: stdout is the JSON alone).
    for target, label in plots:
        print(f"plot {target}: {label}", file=sys.stderr if args.json else sys.stdout)
    return 1 if unreadable else 0


def _output_line(args: argparse.Namespace | SimpleNamespace, name: str, index: int, count: int, a: TapAnalysis) -> str:
    """A tap's line of the output: its JSON object (--json), else its row of the table."""
    if args.json:
        return json_text({"file": name, **a.to_json()})
    label = name if count == 1 else f"{name}#{index + 1}"
    code = a.error or ""
    pooled = f" {_fmt(a.z_pooled_mm, '11.5f'):>11} {_fmt(a.z_pooled_sigma_um, '8.3f'):>8}" if args.pool else ""
    return (f"{label:<32} {'yes' if a.valid else 'no':<6} {_fmt(a.z_mm, '11.5f'):>11} "
            f"{_fmt(a.z_sigma_um, '8.3f'):>8}{pooled} {_fmt(a.quality, '8.1f'):>8}  {code}")
