"""bench/tap_seeds: the should-accept taps rejected on taplab seeds, named as the benchmark names them."""

import json

from bench import tap_seeds
from tapcell.taplab.generate import SCENARIOS, generate_set


def test_a_tap_is_named_by_the_file_the_benchmark_writes(tmp_path):
    # `tapcell benchmark --seed 3 --per-scenario 2` writes the tap that seed_tap rebuilds to the
    # file that file_numbers names, sample for sample.
    generate_set(tmp_path, seed=3, taps_per_scenario=2)
    numbers = tap_seeds.file_numbers(3, 2)
    assert sorted(numbers.values()) == list(range(1, 2 * len(SCENARIOS) + 1))
    for scenario, k in [("hx711_10", 1), ("cable_drift", 0), ("ringing", 1)]:
        tap, _ = tap_seeds.seed_tap(3, scenario, k)
        written = json.loads((tmp_path / f"tap-{numbers[(scenario, k)]:04d}.json").read_text())
        assert written["force"] == tap["force"] and written["time"] == tap["time"]


def test_the_table_lists_each_rejected_clean_tap_and_counts_the_fouled(capsys):
    # Short pullback must be rejected (expect "reject"): counted, never listed as a wrong rejection.
    answers = tap_seeds.taplab_answers(1, scenarios=["clean_hx717", "short_pullback"], taps=[0, 1, 2])
    assert len(answers) == 6
    tally = tap_seeds.tallies(answers)
    assert tally[("taplab 1", "short_pullback")].rejected == 3
    assert tap_seeds.wrongly_rejected(answers) == [a for a in answers if a.expect == "accept" and not a.valid]
    tap_seeds.print_summary(answers)
    row = capsys.readouterr().out.splitlines()[-1].split()
    assert row[:4] == ["taplab", "1", "0/3", "-"]  # 0 of 3 clean rejected; no short pullback accepted
    assert row[-1] == "-" and row[-2] == "-"  # no mild ooze, no two-stage in this run


def test_parse_seeds():
    assert tap_seeds.parse_seeds("1-3,9") == [1, 2, 3, 9]
    assert tap_seeds.parse_seeds("5") == [5]
