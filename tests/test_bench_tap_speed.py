"""`bench tap_speed`'s start-up table: the start-up and the per-file cost of each command, and the
whole-run ratio against Kalico they give, from runs on one file and on every file."""

from pathlib import Path
from types import SimpleNamespace

from bench import tap_speed
from tapcell.taplab import benchmark
from tapcell.taplab.benchmark import Run


def test_start_up_and_per_file_cost_come_from_one_file_and_every_file(monkeypatch, tmp_path):
    # tapcell: 90 ms of start-up and 0.3 ms a further file; Kalico: 150 ms and 2 ms.
    cost_ms = {"tapcell": (90.0, 0.3), "kalico": (150.0, 2.0)}
    files = [tmp_path / f"tap-{n:04d}.json" for n in range(101)]
    runs = []

    def run_analyzer(name, command, chosen, env=None):
        start_ms, per_file_ms = cost_ms[name]
        runs.append((name, len(chosen)))
        return Run(name, {}, (start_ms + per_file_ms * (len(chosen) - 1)) / 1000.0, 0.0)

    monkeypatch.setattr(benchmark, "run_analyzer", run_analyzer)
    monkeypatch.setattr(benchmark, "kalico_command", lambda python, chosen: (["kalico"], {}, "calibrated"))
    table = tap_speed.startup_table(SimpleNamespace(name="set", files=files), Path("python"))
    cells = [column._cells for column in table.columns]
    assert cells[0] == ["tapcell", "kalico"]
    assert cells[1] == ["90", "150"] and cells[2] == ["120", "350"]
    assert cells[3] == ["0.300", "2.000"]
    # 350 / 120 at 101 files, 2.0 / 0.3 on very many.
    assert cells[4] == ["2.9x (not met)", "-"] and cells[5] == ["6.7x", "-"]
    assert sorted(set(runs)) == [("kalico", 1), ("kalico", 101), ("tapcell", 1), ("tapcell", 101)]
    assert len(runs) == 4 * tap_speed.STARTUP_RUNS
    # In turns: each round runs every command on one file and on all before the next round begins.
    assert runs[:4] == [("tapcell", 1), ("tapcell", 101), ("kalico", 1), ("kalico", 101)]
    assert runs[4:8] == runs[:4]


def test_without_kalico_the_table_has_tapcells_row_alone(monkeypatch, tmp_path):
    files = [tmp_path / "a.json", tmp_path / "b.json"]
    monkeypatch.setattr(benchmark, "run_analyzer", lambda name, command, chosen, env=None:
                        Run(name, {}, 0.1 * len(chosen), 0.0))
    table = tap_speed.startup_table(SimpleNamespace(name="set", files=files), None)
    assert [column._cells for column in table.columns] == [["tapcell"], ["100"], ["200"], ["100.000"], ["-"], ["-"]]


def test_the_kalico_table_takes_the_median_of_rounds_run_in_turns(monkeypatch, tmp_path):
    # Three rounds: the machine slows in the second (both analyzers alike), Kalico fails the third.
    rounds = iter([
        ([Run("tapcell", {}, 0.20, 0.0), Run("kalico", {}, 1.20, 0.0)], {}, {"tapcell": 0.10, "kalico": 1.00}),
        ([Run("tapcell", {}, 0.40, 0.0), Run("kalico", {}, 2.00, 0.0)], {}, {"tapcell": 0.20, "kalico": 2.40}),
        ([Run("tapcell", {}, 0.30, 0.0)], {}, {"tapcell": 0.15}),
    ])
    monkeypatch.setattr(benchmark, "speed_runs", lambda tap_set, python: next(rounds))
    files = [tmp_path / "a.json", tmp_path / "b.json"]
    table = tap_speed.kalico_table([SimpleNamespace(name="set", files=files)], Path("python"))
    cells = [column._cells for column in table.columns]
    assert cells[2] == ["tapcell", "kalico"]
    assert cells[3] == ["0.150", "1.700"] and cells[4] == ["0.30", "1.60"]
    # per tap 10x and 12x (median 11x); runs 6x and 5x (median 5.5x): the rounds Kalico ran alone.
    assert cells[5] == ["11.0x (10.0-12.0)", "-"]
    assert cells[6] == ["5.5x (5.0-6.0)", "-"]
