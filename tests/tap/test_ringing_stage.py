"""Gantry ringing is no two-stage mount (issue 21): the dwell's oscillation weighs the stage checks."""

import math
import sys
from pathlib import Path

import numpy as np
import pytest

from tapcell.tap import analysis as analysis_module
from tapcell.tap import stage
from tapcell.tap.analysis import analyze_tap
from tapcell.tap.readers import tap_from_object

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repository root: bench/
from bench.tap_sweep import CASES, case_taps  # noqa: E402


def _dwell(rate_sps: float, ring_g: float, ring_hz: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """A 0.2 s dwell: 80 g relaxing 3 g (tau 0.15 s), white noise 2 g, a ringing decaying in 50 ms."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 0.2, 1.0 / rate_sps)
    force = 80.0 - 3.0 * (1.0 - np.exp(-t / 0.15)) + rng.normal(0.0, 2.0, len(t))
    return t, force + ring_g * np.exp(-t / 0.05) * np.sin(2.0 * math.pi * ring_hz * t)


@pytest.mark.parametrize("seed", range(5))
def test_a_dwells_ringing_is_found_at_its_frequency(seed):
    t, force = _dwell(4000.0, 7.5, 40.0, seed)
    ringing = stage.dwell_ringing(t, force, 4.0)
    assert ringing is not None
    assert ringing.period_samples == pytest.approx(100.0, rel=0.06)  # 4000 sps / 40 Hz
    # 7.5 g decaying in 50 ms over 0.2 s: a mean square of 7.5^2/2 x 0.05/(2 x 0.2) = 3.5 g^2, of which
    # one frequency holds 2 tau / dwell = a half: 1.76 g^2 (measured 1.6-1.9 over these seeds)
    assert ringing.var_g2 == pytest.approx(1.76, rel=0.25)


@pytest.mark.parametrize("seed", range(20))
def test_white_noise_and_a_relaxation_are_no_ringing(seed):
    t, force = _dwell(4000.0, 0.0, 40.0, seed)
    assert stage.dwell_ringing(t, force, 4.0) is None


def test_a_wander_slower_than_the_dwells_periods_is_no_ringing():
    t, force = _dwell(2000.0, 0.0, 40.0, 3)
    force = force + 3.0 * np.sin(2.0 * math.pi * 10.0 * t)  # two periods in the dwell: a squeeze's shape, a wander
    assert stage.dwell_ringing(t, force, 4.0) is None


def test_what_a_ringing_adds_to_a_stages_noise():
    slow = stage.Ringing(var_g2=2.0, period_samples=100.0)  # 40 Hz at 4000 sps
    assert stage.ringing_noise_g2(slow, 60) == pytest.approx(120.0)  # the departure within a period: all of it
    hum = stage.Ringing(var_g2=2.0, period_samples=6.4)  # 50 Hz at 320 sps
    assert stage.ringing_noise_g2(hum, 60) == pytest.approx(2.0 * 6.4 * 6.4 / 60)
    assert stage.ringing_noise_g2(None, 60) == 0.0


def _sweep_taps(name: str, seed: int, indices: tuple[int, ...]) -> list[tuple[dict, float]]:
    case = next(case for case in CASES if case.name == name)
    taps = case_taps(case, seed, max(indices) + 1, None)
    return [taps[k] for k in indices]


# The sweep's ringing taps the stage checks named TAP_TWO_STAGE_CONTACT before (`python -m bench
# tap_sweep --cases ring2000,ring4000 --seed N`): a 6 g, 40 Hz ringing at a 2-4 mm/s pullback.
RINGING_TAPS = (("ring4000", 1, (1, 18)), ("ring2000", 2, (7, 16)))


@pytest.mark.parametrize("name,seed,indices", RINGING_TAPS)
def test_a_ringing_tap_reproduced_from_its_seed_is_measured(name, seed, indices):
    for tap, truth_mm in _sweep_taps(name, seed, indices):
        result = analyze_tap(tap_from_object(tap))
        assert result.valid, result.error
        error_um = (result.z_mm - truth_mm) * 1000.0
        assert abs(error_um) < 3.0 * max(result.z_sigma_um, 1.0)  # measured 0.2-2.5 um off


@pytest.mark.parametrize("name,seed,indices", RINGING_TAPS)
def test_without_the_dwells_ringing_they_read_as_two_stages(name, seed, indices, monkeypatch):
    """The mechanism, not luck: the same taps weighed against the white noise alone are two stages."""
    monkeypatch.setattr(analysis_module, "dwell_ringing", lambda *args: None)
    for tap, _ in _sweep_taps(name, seed, indices):
        assert analyze_tap(tap_from_object(tap)).error == "TAP_TWO_STAGE_CONTACT"
