"""`make bench` shows progress on long benchmarks (bench._progress), so a run of minutes is not
silent (bench/tap_safety printed nothing for 25 minutes)."""

import re
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the bench package beside tests/

from bench._progress import with_progress  # noqa: E402  (after the path)


def test_progress_lines_while_the_items_are_consumed(capsys):
    seen, lines = [], 0
    for item in with_progress(range(95), 95, "taps"):
        seen.append(item)
        # A line comes as soon as the items it counts are done (when the next one is asked for),
        # not all at the end.
        printed = capsys.readouterr().out
        if printed:
            assert re.fullmatch(r"  taps: (\d+)/95 \(\d+%\), \d+ s\n", printed)
            assert int(re.match(r"  taps: (\d+)", printed)[1]) == len(seen) - 1
            lines += 1
    assert seen == list(range(95)) and lines == 10  # every 9 items: 9, 18, ..., 90 (95 comes after)


def test_about_ten_lines_and_the_last_one_says_done(capsys):
    list(with_progress(iter(range(2400)), 2400, "taps"))
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == 10
    assert lines[-1].startswith("  taps: 2400/2400 (100%), ")
