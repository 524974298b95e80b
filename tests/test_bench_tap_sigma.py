"""bench tap_sigma chooses the weights of z_sigma_um's parts by the worst scenario (issue 21)."""

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the bench package beside tests/

from bench.tap_sigma import (GRID, Scenario, choose_weights, force_error_g, generator_toe_lift_um,  # noqa: E402
                              generator_toe_lifts_um, hidden_toe, lift_table, pooled, ratio_interval, ratio_rms)
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


def test_the_generators_toe_lift_is_where_its_linear_part_meets_zero_force():
    """taplab's loading curve (tapcell.taplab.physics) integrated numerically: past the onset the
    force is linear, and its line meets zero force the lift above the contact."""
    from tapcell.taplab.physics import Contact, loading_force_g
    for power, blend, width in ((0.5, 0.0, 6.0), (1.0, 0.0, 4.0), (0.35, 0.4, 8.0), (0.8, 0.25, 1.5)):
        contact = Contact(stiffness_g_um=3.0, onset_um=width, onset_power=power, onset_blend=blend,
                          unload_ratio=1.0, relax_fraction=(0.0,), relax_tau_s=(0.1,))
        deep = np.array([width + 5.0, width + 10.0])
        force = loading_force_g(deep, contact)
        meets_zero_um = deep[0] - force[0] / ((force[1] - force[0]) / 5.0)
        lift = generator_toe_lift_um({"onset_um": width, "onset_power": power, "onset_blend": blend})
        assert lift == pytest.approx(meets_zero_um, abs=1e-9)
    assert generator_toe_lift_um({"onset_um": 6.0, "onset_power": 0.5, "onset_blend": 0.0}) == pytest.approx(2.0)


def test_the_generators_toes_are_read_from_taplab_labels_only(tmp_path):
    contact = '{"onset_um": 4.0, "onset_power": 1.0, "onset_blend": 0.0}'
    lines = ['{"file": "tap-0001.json", "spec": {"contact": ' + contact + '}}',
             '{"file": "ref_0001.json", "scenario": "clean_hx717", "z_contact_mm": 0.1}', ""]
    (tmp_path / "labels.jsonl").write_text("\n".join(lines), encoding="utf-8")
    assert generator_toe_lifts_um(tmp_path) == {"tap-0001.json": pytest.approx(2.0)}


def _lifted(errors, lifts, sigmas, true=None, expect="accept"):
    true = [float("nan")] * len(errors) if true is None else true
    return Scenario(errors_um=list(errors), parts=[ZSigmaParts(noise_um=s) for s in sigmas], taps=len(errors),
                    lifts_um=list(lifts), true_lifts_um=list(true), expect=expect)


def test_the_lift_table_bins_the_should_accept_taps_by_their_fitted_lift():
    """Two taps below 0.5 µm of lift erring 2 sigma, two beyond 3 µm erring 0.5 sigma; a fouled
    scenario's taps are left out whatever they err."""
    weights = SigmaWeights(noise=1.0)
    clean = _lifted([-1.0, -1.0, 0.5, -0.5], [0.2, 0.4, 3.5, 4.0], [0.5, 0.5, 1.0, 1.0], true=[1.2, 1.4, 3.0, 5.0])
    fouled = _lifted([9.0], [0.1], [0.1], expect="either")
    rows = lift_table({"clean": clean, "ooze": fouled}, weights)
    assert [row[:2] for row in rows] == [("< 0.5", 2), (">= 3", 2)]
    assert rows[0][2:5] == pytest.approx((2.0, -1.0, 0.5))
    assert rows[1][2:5] == pytest.approx((0.5, 0.0, 1.0))
    assert rows[0][5] == pytest.approx(1.3) and rows[1][5] == pytest.approx(4.0)


def test_a_toe_model_that_misses_the_generators_toe_leaves_a_slope():
    """Errors of -0.3 µm per µm of the generator's lift, fitted lifts following it 0.7 µm per µm:
    the slopes come back; the reference (no known toe) gives none."""
    true = np.linspace(0.5, 4.0, 40)
    scenario = _lifted(-0.3 * true + 0.2, 0.7 * true, np.ones(40), true=true)
    taps, corr, slope, fitted = hidden_toe({"clean": scenario})
    assert taps == 40 and corr == pytest.approx(-1.0) and slope == pytest.approx(-0.3) and fitted == pytest.approx(0.7)
    assert hidden_toe({"clean": _lifted(np.zeros(40), np.ones(40), np.ones(40))}) is None
