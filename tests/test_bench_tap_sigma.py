"""bench tap_sigma chooses the weights of z_sigma_um's parts by the worst scenario (issue 21)."""

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the bench package beside tests/

from bench.tap_sigma import (GRID, Scenario, choose_weights, force_error_g, pooled, ratio_interval,  # noqa: E402
                              ratio_rms)
from tapcell.tap.uncertainty import SigmaWeights, ZSigmaParts  # noqa: E402

TRUE = {"noise": 0.75, "shape": 2.0, "misfit": 0.5, "thread": 1.5, "squeeze": 1.25, "film": 1.0, "floor": 2.5}


def _scenario(rng, part: str, taps: int = 400) -> Scenario:
    """Taps whose only uncertain part is `part` (sizes 0.5-2 µm), their errors drawn with TRUE's weight on it."""
    sizes = rng.uniform(0.5, 2.0, taps)
    errors = rng.normal(0.0, TRUE[part] * sizes)
    return Scenario(errors_um=errors.tolist(), parts=[ZSigmaParts(**{part + "_um": s}) for s in sizes], taps=taps)


def test_the_weights_that_make_every_scenario_honest_are_found():
    rng = np.random.default_rng(7)
    sets = {"a": {name: _scenario(rng, name) for name in ("noise", "shape")},
            "b": {name: _scenario(rng, name) for name in ("misfit", "thread", "squeeze", "film", "floor")}}
    chosen, worst = choose_weights(sets)
    for name, weight in TRUE.items():  # within one step of its grid
        step = float(GRID[name][1] - GRID[name][0])
        assert getattr(chosen, name) == pytest.approx(weight, abs=step + 1e-9), name
    assert worst < 1.1
    for scenarios in sets.values():
        for scenario in scenarios.values():
            assert 0.9 < ratio_rms(scenario, chosen) < 1.1


def test_the_ringing_part_is_held_at_its_derived_weight_while_the_others_are_chosen():
    """Taps whose error is their ringing part at weight 1 (uncertainty.ringing_um) and noise at
    TRUE's weight: the choice scores the ringing as the analysis counts it, and finds the noise's."""
    rng = np.random.default_rng(11)
    sizes, rings = rng.uniform(0.5, 2.0, 400), rng.uniform(0.5, 2.0, 400)
    errors = rng.normal(0.0, np.hypot(TRUE["noise"] * sizes, rings))
    scenario = Scenario(errors_um=errors.tolist(), taps=400,
                        parts=[ZSigmaParts(noise_um=s, ringing_um=r) for s, r in zip(sizes, rings)])
    chosen, worst = choose_weights({"a": {"ringing": scenario}})
    assert chosen.ringing == 1.0
    assert chosen.noise == pytest.approx(TRUE["noise"], abs=2 * float(GRID["noise"][1] - GRID["noise"][0]))
    assert 0.9 < ratio_rms(scenario, chosen) < 1.1


def test_a_scenario_without_accepted_taps_has_no_ratio():
    assert ratio_rms(Scenario(taps=40), SigmaWeights()) is None


def test_the_force_error_is_the_error_times_each_taps_stiffness():
    """A soft tap's 2 µm at 1 g/µm is the same force as a hard tap's 0.5 µm at 4 g/µm; a tap whose
    stiffness is unknown is left out, not counted as zero."""
    scenario = Scenario(errors_um=[2.0, -0.5, 7.0], parts=[ZSigmaParts()] * 3, taps=3,
                        stiffness_g_um=[1.0, 4.0, float("nan")])
    assert force_error_g(scenario) == pytest.approx(2.0, rel=1e-12)
    assert force_error_g(Scenario(errors_um=[1.0], parts=[ZSigmaParts()], taps=1,
                                  stiffness_g_um=[float("nan")])) is None
    assert force_error_g(Scenario(taps=40)) is None


def test_seeds_are_judged_together_per_scenario():
    """Two seeds' draws of a scenario are one scenario of 2 x the taps; the interval narrows with them."""
    rng = np.random.default_rng(3)
    one, two = ({"clean": _scenario(rng, "noise", taps=40)} for _ in range(2))
    together = pooled([one, two])
    assert together["clean"].taps == 80 and len(together["clean"].errors_um) == 80
    assert together["clean"].errors_um == one["clean"].errors_um + two["clean"].errors_um
    weights = SigmaWeights(noise=TRUE["noise"])
    lo1, hi1 = ratio_interval(one["clean"], weights)
    lo2, hi2 = ratio_interval(together["clean"], weights)
    assert lo1 < ratio_rms(one["clean"], weights) < hi1 and lo2 < 1.0 < hi2
    assert 0.15 < hi1 - lo1 and hi2 - lo2 < 0.85 * (hi1 - lo1)  # ±25-35 % at 40 taps
    assert ratio_interval(Scenario(taps=40), weights) is None
