"""The adhesion checks hold at the sharp contact where no toe fits (`z_from_toe_model`). Where no toe
has its least residual inside the grid's reach of the sharp contact (on both benchmark sets only
heavy ooze: 11 of the reference's 80), the checks that name a film or a thread ran only after a toe
fit, so such a tap was left to the quality classifier. Read in 3 g steps, one of them passed it
(quality 54) and was accepted 43 µm above the bed."""

from __future__ import annotations

import pytest

from bench.tap_sweep import Case, _force_quantized, analyse_in_process, case_taps
from tapcell.tap import analysis


@pytest.fixture
def toe_fits(monkeypatch) -> list:
    """What each `fit_pullback_toe` call answered."""
    answers = []
    fit = analysis.fit_pullback_toe

    def recorded(*args, **kwargs):
        answers.append(fit(*args, **kwargs))
        return answers[-1]
    monkeypatch.setattr(analysis, "fit_pullback_toe", recorded)
    return answers


def _heavy_ooze(reference_dir, k: int, step_g: float | None = None) -> tuple[dict, float]:
    case = Case("ooze", "reference heavy ooze", "either", reference=("ooze_heavy", 1),
                transform=None if step_g is None else _force_quantized(step_g))
    return case_taps(case, 1, k + 1, reference_dir)[k]


@pytest.mark.parametrize("k, step_g", [(16, None), (17, None), (18, 3.0)])
def test_a_film_no_toe_fits_is_named(reference_dir, toe_fits, k, step_g):
    # Taps 16 and 17 were LOW_TAP_QUALITY; tap 18 in 3 g steps was accepted at +43 µm.
    answer = analyse_in_process(_heavy_ooze(reference_dir, k, step_g)[0])
    assert toe_fits == [None]
    assert answer["error"] == "TAP_ADHESION", answer["message"]
    assert "plastic" in answer["message"]
