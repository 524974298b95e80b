"""A ringing's trough is no adhesion dip (issue 21's sweep): the dip averages over half the period
of a ringing the dwell shows (`analysis.adhesion_run_samples`).

At 2000 sps a run of 5 samples lasts 2.5 ms, a tenth of a 40 Hz ringing's period: a ringing the
pullback's start excites swings the departure about its level, and its trough read as a dip of
4.2-6 noise sigmas (TAP_ADHESION on 1 of 40 taplab ring2000 taps on seeds 4, 6 (2) and 10, and on
4-6 % of the reference's ADS1220 2000 taps under the sweep's toolhead ringing)."""

from __future__ import annotations

import pytest

from bench.tap_sweep import CASES, analyse_in_process, case_taps
from tapcell.tap import analysis
from tapcell.tap.stage import Ringing
from tapcell.tap.toe import ADHESION_RUN_SAMPLES

CASE = {case.name: case for case in CASES}

# (seed, taps) of the sweep's ring2000 that were TAP_ADHESION with runs of 5 samples.
RUNG_DEPARTURES = ((4, (7,)), (6, (6, 28)), (10, (4,)))


def test_the_run_is_half_a_ringing_period_when_that_is_longer():
    assert analysis.adhesion_run_samples(None) == ADHESION_RUN_SAMPLES == 5
    assert analysis.adhesion_run_samples(Ringing(var_g2=2.0, period_samples=50.3)) == 25  # 40 Hz at 2000 sps
    assert analysis.adhesion_run_samples(Ringing(var_g2=2.0, period_samples=6.4)) == 5  # 50 Hz at 320 sps


def _taps(seed: int, indices: tuple[int, ...]) -> list[tuple[dict, float]]:
    taps = case_taps(CASE["ring2000"], seed, max(indices) + 1, None)
    return [taps[k] for k in indices]


@pytest.mark.parametrize("seed,indices", RUNG_DEPARTURES)
def test_a_rung_departure_is_measured(seed, indices):
    for tap, z_mm in _taps(seed, indices):
        answer = analyse_in_process(tap)
        assert answer["valid"], answer["message"]
        assert abs(answer["z"] - z_mm) * 1000.0 < 3.0  # measured +0.67..+1.88 µm


@pytest.mark.parametrize("seed,indices", RUNG_DEPARTURES)
def test_with_five_sample_runs_the_trough_is_a_dip(seed, indices, monkeypatch):
    """The mechanism: the same taps with the dip's run kept at 5 samples (and the free air's own dip,
    which since also keeps seed 10's tap 4, left out)."""
    monkeypatch.setattr(analysis, "adhesion_run_samples", lambda ringing: ADHESION_RUN_SAMPLES)
    monkeypatch.setattr(analysis, "free_air_dip_g", lambda *_: 0.0)
    for tap, _ in _taps(seed, indices):
        # no hum removal asked for (the meta's answer): the second look without taplab's hum would
        # hide the mechanism
        answer = analyse_in_process({**tap, "meta": {**tap.get("meta", {}), "mains_hz": []}})
        assert answer["error"] == "TAP_ADHESION"
        assert "dips" in answer["message"]
