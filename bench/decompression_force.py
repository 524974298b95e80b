"""LOW_DECOMPRESSION_FORCE against labelled taps from two sources tapcell did not tune on alone.

The classifier rejects a tap whose force released on the pullback (end of dwell to break contact)
is below MIN_DECOMPRESSION_TO_TRIGGER x the trigger force. Per source and scenario: taps, how
many the code rejects, and the smallest released/trigger ratio of the taps the analysis otherwise
finds valid; then, per label, the worst clean tap's ratio over the cutoff (the anchor: above 1 no
clean tap is rejected, and by how much).

Sources: taplab (our independent generator, --per-scenario taps per scenario, seed 1) and the
outside reference archives given as arguments (`../shared/data/reference-taps.tar.xz`, the
sessions archive; unpacked into a temporary folder, never into the project).

Run: .venv/bin/python -m bench decompression_force [ARCHIVE_OR_DIR ...] [--per-scenario N]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from collections import defaultdict
from pathlib import Path

from tapcell.files import extract_archive
from tapcell.tap import analyze_tap, read_tap_file
from tapcell.tap.classifiers import MIN_DECOMPRESSION_TO_TRIGGER
from tapcell.tap.model import LOW_DECOMPRESSION_FORCE
from tapcell.taplab.generate import generate_set

CLEAN_LABELS = ("clean", "accept")  # the reference archives' label; taplab's `expect`


def label_folders(path: Path, scratch: Path) -> list[Path]:
    """The folders holding labels.jsonl in `path` (an archive is unpacked into `scratch`)."""
    if path.is_file():
        target = scratch / path.name.split(".")[0]
        extract_archive(path, target)
        path = target
    return sorted(labels.parent for labels in path.rglob("labels.jsonl"))


def scan(folder: Path) -> dict[tuple[str, str], dict]:
    """Per (scenario, label): taps, LOW_DECOMPRESSION_FORCE count, worst released/trigger of valid taps."""
    rows: dict[tuple[str, str], dict] = defaultdict(lambda: {"taps": 0, "rejected": 0, "worst": None})
    for line in (folder / "labels.jsonl").read_text().splitlines():
        record = json.loads(line)
        tap = read_tap_file(folder / record["file"])[0]
        result = analyze_tap(tap)
        row = rows[(record["scenario"], record.get("label") or record.get("expect"))]
        row["taps"] += 1
        row["rejected"] += result.error == LOW_DECOMPRESSION_FORCE
        trigger_g = tap.probe.get("trigger_force")
        if trigger_g and len(result.points) == 6 and (result.valid or result.error == LOW_DECOMPRESSION_FORCE):
            ratio = abs(result.points[3][1] - result.points[4][1]) / trigger_g
            row["worst"] = ratio if row["worst"] is None else min(row["worst"], ratio)
    return rows


def print_table(source: str, rows: dict) -> None:
    print(f"\n{source}")
    print(f"{'scenario':<22} {'label':<9} {'taps':>5} {'rejected':>9} {'worst released/trigger':>23}")
    for (scenario, label), row in sorted(rows.items()):
        worst = "-" if row["worst"] is None else f"{row['worst']:.3f}"
        print(f"{scenario:<22} {label:<9} {row['taps']:>5} {row['rejected']:>9} {worst:>23}")
    clean = [row for (_, label), row in rows.items() if label in CLEAN_LABELS]
    worst = [row["worst"] for row in clean if row["worst"] is not None]
    print(f"clean taps rejected: {sum(r['rejected'] for r in clean)} / {sum(r['taps'] for r in clean)}; "
          f"other taps rejected: {sum(r['rejected'] for (_, l), r in rows.items() if l not in CLEAN_LABELS)} / "
          f"{sum(r['taps'] for (_, l), r in rows.items() if l not in CLEAN_LABELS)}")
    if worst:
        print(f"worst clean tap / cutoff {MIN_DECOMPRESSION_TO_TRIGGER:g}: {min(worst) / MIN_DECOMPRESSION_TO_TRIGGER:.3f}x")


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="bench decompression_force")
    parser.add_argument("sources", nargs="*", type=Path, help="reference archives or folders with labels.jsonl")
    parser.add_argument("--per-scenario", type=int, default=20, help="taplab taps per scenario (default 20)")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as scratch_dir:
        scratch = Path(scratch_dir)
        taplab = scratch / "taplab"
        generate_set(taplab, seed=1, taps_per_scenario=args.per_scenario)
        print_table(f"taplab (seed 1, {args.per_scenario} per scenario)", scan(taplab))
        for source in args.sources:
            if not source.exists():
                print(f"\n{source}: not found (skipped)")
                continue
            for folder in label_folders(source, scratch):
                print_table(f"{source.name}: {folder.name}", scan(folder))
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
