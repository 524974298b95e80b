"""The adhesion dip must be deeper than the free air before contact dips by itself (issue 21's sweep).

A fan shaking the toolhead (`ref_fan660`, `ref_fan2000`: a 1-4 g sine at 20-150 Hz on the reference
ADS1220 taps) or a heater's PWM (`ref_pwm10`) dips the force below its level by more than four
white-noise sigmas wherever it is, after break contact too: TAP_ADHESION on clean taps. The approach
shows the same dips before the nozzle touched anything; ooze cannot have pulled there."""

from __future__ import annotations

import numpy as np
import pytest

from bench.tap_sweep import analyse_in_process
from tapcell.tap import analysis
from tapcell.tap.analysis import free_air_dip_g


# (case, seed, tap): TAP_ADHESION before, dips of 2.5, 2.3, 2.0 and 3.2 g against 4 x 0.54, 0.50,
# 0.46 and 0.69 g of noise; measured now +4.46 (2.0 of its z_sigma_um), -1.10, +0.27 and +0.43 µm.
SHAKEN_TAPS = (("ref_fan660", 2, 39), ("ref_fan660", 3, 22), ("ref_fan2000", 1, 32), ("ref_pwm10", 43, 34))


def test_white_noise_dips_little_by_itself():
    rng = np.random.default_rng(0)
    time_s = np.arange(300) / 660.0
    line = (3.0, 1.0)
    depths = [free_air_dip_g(time_s, line[0] * time_s + line[1] + rng.normal(0.0, 1.0, 300), line, 5)
              for _ in range(50)]
    assert max(depths) < 2.5  # 50 draws: 0.83-1.99 noise sigmas at a run of 5, under the limit's 4


def test_a_sine_dips_by_its_amplitude():
    rng = np.random.default_rng(1)
    time_s = np.arange(300) / 2000.0
    force_g = 3.0 * np.sin(2 * np.pi * 60.0 * time_s) + rng.normal(0.0, 0.5, 300)
    # The mean of a run of 5 (2.5 ms, centred on the trough of a 60 Hz sine) is 2.95 g below it, and
    # the noise's deepest run adds up to 3 of its sigmas (0.5 / sqrt(5) g each): measured 3.40 g.
    trough_g = 3.0 * np.mean(np.cos(2 * np.pi * 60.0 * (np.arange(5) - 2) / 2000.0))
    assert trough_g <= free_air_dip_g(time_s, force_g, (0.0, 0.0), 5) <= trough_g + 3 * 0.5 / np.sqrt(5)


def test_too_few_samples_tell_nothing():
    assert free_air_dip_g(np.arange(6.0), np.zeros(6), (0.0, 0.0), 5) == 0.0


@pytest.mark.parametrize("name,seed,k", SHAKEN_TAPS)
def test_a_shaken_clean_tap_is_measured(measured_within, name, seed, k):
    measured_within(name, seed, k, 2.5)


@pytest.mark.parametrize("name,seed,k", SHAKEN_TAPS)
def test_without_the_free_airs_own_dip_the_tap_is_taken_for_adhesion(sweep_tap, name, seed, k, monkeypatch):
    """The mechanism: the same taps with the free air's dip left out of the limit."""
    monkeypatch.setattr(analysis, "free_air_dip_g", lambda *_: 0.0)
    answer = analyse_in_process(sweep_tap(name, seed, k)[0])
    assert answer["error"] == "TAP_ADHESION"
    assert answer["message"].startswith("the force dips ")


# Rejected with the free air's own dip as the limit alone: the departure's dip passed it by 0.1 g
# (0.2 noise sigmas), 0.1 g (0.2) and 0.2 g (0.4): each dip one draw of the same fan's trough plus the noise's.
NEAR_THE_FREE_AIRS_DIP = (("ref_fan2000", 106, 11), ("ref_fan2000", 106, 12), ("ref_fan660", 107, 2))


@pytest.mark.parametrize("name,seed,k", NEAR_THE_FREE_AIRS_DIP)
def test_a_dip_must_pass_the_free_airs_by_more_than_the_noise(sweep_tap, name, seed, k, monkeypatch):
    tap, z_mm = sweep_tap(name, seed, k)
    answer = analyse_in_process(tap)
    assert answer["valid"], answer["message"]
    assert abs(answer["z"] - z_mm) * 1000.0 < 2.5 * max(answer["z_sigma_um"], 1.0)
    monkeypatch.setattr(analysis, "FREE_AIR_DIP_MARGIN_NOISE", 0.0)
    # no hum removal asked for (the meta's answer): a fan near 50 or 60 Hz would pass for mains hum,
    # and the second look without it would hide the mechanism
    answer = analyse_in_process({**tap, "meta": {**tap.get("meta", {}), "mains_hz": []}})
    assert answer["error"] == "TAP_ADHESION"
    assert "the free air before contact dips by itself" in answer["message"]
