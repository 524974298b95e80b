"""How speed is measured (issue 21): per tap in process CPU time, not wall time; every analyzer's
numpy on one OpenBLAS thread; the ratios against Kalico from the same run."""

import sys

import pytest

from tapcell.tap import analysis, analyze_tap
from tapcell.tap.synth import synth_tap
from tapcell.taplab import benchmark
from tapcell.taplab.benchmark import PER_TAP, Label, Run, score, targets


def test_analyze_tap_reports_its_process_cpu_beside_the_wall_time(monkeypatch):
    """cpu_ms comes from the process's CPU clock, elapsed_ms from the wall clock (a busy machine
    stretches the second, not the first)."""
    cpu = iter([10.0, 10.25])  # s: the analysis took 250 ms of CPU
    monkeypatch.setattr(analysis.time, "process_time", lambda: next(cpu))
    result = analyze_tap(synth_tap(seed=2))
    assert result.cpu_ms == pytest.approx(250.0)
    assert 0.0 < result.elapsed_ms < 250.0  # the wall clock is another clock
    assert result.to_json()["cpu_ms"] == pytest.approx(250.0)


def _run(name: str, cpu_ms: list[float | None], elapsed_ms: list[float], cpu_s: float) -> Run:
    answers = {}
    for k, (cpu, wall) in enumerate(zip(cpu_ms, elapsed_ms)):
        answers[f"t{k}"] = {"valid": True, "z": 0.0, "elapsed_ms": wall, **({} if cpu is None else {"cpu_ms": cpu})}
    return Run(name, answers, cpu_s, 0.0)


LABELS = [Label(f"t{k}", "clean", "accept", 0.0) for k in range(3)]


def test_per_tap_speed_is_the_median_cpu_and_the_ratio_is_against_kalico(capsys):
    # Kalico's wall times were stretched by a busy machine; its CPU times were not.
    ours = _run("tapcell", [0.3, 0.2, 0.25], [0.3, 0.2, 0.25], 0.5)
    kalico = _run("kalico", [2.0, 2.6, 2.5], [9.0, 9.0, 9.0], 2.5)
    twins = _run("tapcell-numpy", [1.0, 1.2, 1.1], [1.0, 1.2, 1.1], 2.0)
    scored = {run.name: score(run, LABELS) for run in (ours, kalico, twins)}
    per_tap = {name: targets(s)[PER_TAP] for name, s in scored.items()}
    assert per_tap == {"tapcell": 0.25, "kalico": 2.5, "tapcell-numpy": 1.1}
    benchmark.print_speed([ours, kalico, twins], scored, per_tap)
    out = capsys.readouterr().out
    assert "tapcell against kalico: 10.0× less CPU per tap, 5.0× less CPU for the whole run" in out
    assert "tapcell-numpy against kalico: 2.3× less CPU per tap, 1.2× less CPU for the whole run" in out
    assert "time.process_time" in out and "wall time" not in out


def test_an_analyzer_without_cpu_times_is_timed_by_its_wall_clock_and_named():
    other = _run("other", [None, None, None], [1.0, 3.0, 2.0], 1.0)
    scores = score(other, LABELS)
    assert targets(scores)[PER_TAP] == 2.0
    assert scores["clean"].wall_clock_taps == 3


def test_every_analyzer_runs_numpy_on_one_openblas_thread(monkeypatch, tmp_path):
    monkeypatch.delenv("OPENBLAS_NUM_THREADS", raising=False)
    reports = [sys.executable, "-c", "import json, os, sys; print(json.dumps([{'file': f, 'valid': False, "
               "'blas': os.environ.get('OPENBLAS_NUM_THREADS')} for f in sys.argv[1:]]))"]
    run = benchmark.run_analyzer("env", reports, [tmp_path / "a.json"])
    assert run.results["a.json"]["blas"] == "1"
    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "2")  # the caller's choice wins, for every analyzer alike
    run = benchmark.run_analyzer("env", reports, [tmp_path / "a.json"], env={"PATH": "/usr/bin"})
    assert run.results["a.json"]["blas"] == "2"
    assert run.command.endswith("FILE...")


def test_ours_is_compared_with_kalico_or_another_analyzer_never_with_our_own_numpy_twins():
    ours, twins, kalico, other = (Run(name, {}, 1.0, 1.0) for name in ("tapcell", "tapcell-numpy", "kalico", "mine"))
    assert benchmark.anchor_run([ours, kalico, twins]) is kalico
    assert benchmark.anchor_run([ours, twins, other, kalico]) is kalico
    assert benchmark.anchor_run([ours, twins, other]) is other
    assert benchmark.anchor_run([ours, twins]) is None
