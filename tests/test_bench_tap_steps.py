"""bench/tap_steps: each step of the analysis timed around its call, the analysis left as it was."""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the bench package beside tests/

from bench import tap_steps  # noqa: E402  (after the path)
from tapcell.tap import analysis  # noqa: E402
from tapcell.taplab.generate import generate_set  # noqa: E402


def test_every_step_is_a_function_the_analysis_calls():
    source = Path(analysis.__file__).read_text(encoding="utf-8")
    body = source[source.index("def analyze_tap("):]  # analyze_tap, then _analyze and its steps
    for name in tap_steps.STEPS:
        assert callable(getattr(analysis, name)), name
        assert f"{name}(" in body, name


def test_the_steps_are_timed_and_put_back(tmp_path):
    generate_set(tmp_path, seed=1, taps_per_scenario=1)
    taps = tap_steps._taps(tmp_path)
    assert len(taps) == 15
    before = {name: getattr(analysis, name) for name in tap_steps.STEPS}
    median_us, steps_us, middle_us = tap_steps.step_times_us(taps, rounds=1)
    assert {name: getattr(analysis, name) for name in tap_steps.STEPS} == before
    assert steps_us["split_tap"] > 0 and steps_us["z_from_toe_model"] > 0
    assert 0 < sum(steps_us.values()) <= middle_us and median_us > 0


def test_a_wrong_folder_or_none_is_named(tmp_path, capsys):
    assert tap_steps.main([str(tmp_path / "nowhere")]) == 2
    assert "nowhere: not a folder of tap files" in capsys.readouterr().err
    assert tap_steps.main([str(tmp_path)]) == 2
    assert "no tap files" in capsys.readouterr().err
    assert tap_steps.main([str(tmp_path), "--rounds", "0"]) == 2
    assert "--rounds 0: at least 1" in capsys.readouterr().err
