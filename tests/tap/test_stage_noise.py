"""The soft-stage ramp is weighed against what it leaves of the departure when that is more than
the noise estimate (issue 21's sweep).

A heater's 10 Hz PWM on the reference HX717 taps (`ref_pwm10`, a 1-3 g square wave) and a thermal
ramp of 5 g/s (`ref_ramp5`) leave the departure's level wandering by more than the second-difference
noise sees, and the best ramp over it scored 37-68 noise variances (limit 36): TAP_TWO_STAGE_CONTACT
on clean taps. A stage explains its departure down to the noise, a wave does not; the two-stage fit
already weighs its evidence so (`stage._two_stage_grid`)."""

from __future__ import annotations

import numpy as np
import pytest

from bench.tap_sweep import analyse_in_process
from tapcell.tap import analysis, stage

HEIGHTS_UM = np.arange(1.0, 60.0, 1.0)  # above the contact found, one sample a µm
NOISE_G = 0.5

# (case, seed, tap): the clean taps the ramp rejected, at 68.4, 37.3 and 37.1 noise variances.
WANDERING_TAPS = (("ref_pwm10", 42, 34), ("ref_pwm10", 44, 20), ("ref_ramp5", 41, 7))


def ramp_gain_g2(x_um: np.ndarray, force_g: np.ndarray, top_um: float) -> float:
    """What a level and the ramp clip(top - x, 0) remove from the departure's variance, by least squares."""
    model = np.column_stack([np.ones_like(x_um), np.clip(top_um - x_um, 0.0, None)])
    coefficients, *_ = np.linalg.lstsq(model, force_g, rcond=None)
    left = force_g - model @ coefficients
    centred = force_g - force_g.mean()
    return float(centred @ centred - left @ left)


def square_wave_departure(seed: int) -> np.ndarray:
    """A level with a 2 g square wave 20 samples a period (a heater's PWM) and white noise: no stage."""
    rng = np.random.default_rng(seed)
    phase = rng.uniform(0.0, 20.0)
    wave = 2.0 * np.sign(np.sin(2.0 * np.pi * (np.arange(HEIGHTS_UM.size) + phase) / 20.0))
    return 5.0 + wave + rng.normal(0.0, NOISE_G, HEIGHTS_UM.size)


@pytest.mark.parametrize("seed", [2, 3, 4])
def test_a_square_wave_the_noise_estimate_misses_is_no_stage(seed):
    force_g = square_wave_departure(seed)
    found = stage.soft_stage(HEIGHTS_UM, force_g, 0.0, NOISE_G ** 2)
    assert found.chi2 < 10.0  # measured 3.3, 5.6, 2.7
    # Weighed against the white noise alone, the same ramp was a stage (55.7, 99.0, 42.5).
    assert ramp_gain_g2(HEIGHTS_UM, force_g, found.top_um) / NOISE_G ** 2 > stage.STAGE_MIN_CHI2


@pytest.mark.parametrize("seed", range(5))
def test_a_stage_is_still_found_and_weighed_against_the_noise_where_it_leaves_no_more(seed):
    rng = np.random.default_rng(seed)
    force_g = 5.0 + 0.4 * np.clip(20.0 - HEIGHTS_UM, 0.0, None) + rng.normal(0.0, NOISE_G, HEIGHTS_UM.size)
    found = stage.soft_stage(HEIGHTS_UM, force_g, 0.0, NOISE_G ** 2)
    assert abs(found.top_um - 20.0) <= 2.0  # 30 seeds: 18-21 um
    assert found.chi2 > 10.0 * stage.STAGE_MIN_CHI2  # 30 seeds: 698 and more
    assert stage.shows_soft_stage(found, 4.0, 0.0)
    gain_g2 = ramp_gain_g2(HEIGHTS_UM, force_g, found.top_um)
    left_var_g2 = (float(((force_g - force_g.mean()) ** 2).sum()) - gain_g2) / (HEIGHTS_UM.size - 3)
    assert found.chi2 == pytest.approx(gain_g2 / max(NOISE_G ** 2, left_var_g2), rel=1e-9)


def test_the_kernel_weighs_a_square_wave_as_its_twin_does(monkeypatch):
    if stage._C is None:
        pytest.skip("the compiled kernels are not built here")
    x_lo, x_hi = HEIGHTS_UM - 0.5, HEIGHTS_UM + 0.5
    for seed in range(5):
        force_g = square_wave_departure(seed)
        native = stage.departure_soft_stage(x_lo, x_hi, force_g, 0.0, 0.0, NOISE_G ** 2, 0.0)
        with monkeypatch.context() as patched:
            patched.setattr(stage, "_C", None)
            twin = stage.departure_soft_stage(x_lo, x_hi, force_g, 0.0, 0.0, NOISE_G ** 2, 0.0)
        assert (native.chi2, native.top_um, native.slope_g_um) == (twin.chi2, twin.top_um, twin.slope_g_um)


@pytest.mark.parametrize("name,seed,k", WANDERING_TAPS)
def test_a_clean_tap_under_a_pwm_or_a_thermal_ramp_is_measured(measured_within, name, seed, k):
    measured_within(name, seed, k, 3.0)  # measured 2.74, -0.40, 0.38 um


@pytest.mark.parametrize("name,seed,k", WANDERING_TAPS)
def test_weighed_against_the_noise_alone_the_ramp_rejects_them(sweep_tap, name, seed, k, monkeypatch):
    """The mechanism: the same taps with the ramp's gain over the noise estimate alone."""
    measured = analysis.departure_soft_stage

    def against_the_noise(x_lo_um, x_hi_um, force_g, drift_g_um, contact_um, white_var_g2, walk_var_g2,
                          ringing=None):
        found = measured(x_lo_um, x_hi_um, force_g, drift_g_um, contact_um, white_var_g2, walk_var_g2, ringing)
        if found is not None:
            x_um = 0.5 * (x_lo_um + x_hi_um)
            near = stage.departure_near(x_um, contact_um)
            noise_var_g2 = white_var_g2 + walk_var_g2 * int(near.sum()) / 6.0
            if ringing is not None:
                noise_var_g2 += stage.ringing_noise_g2(ringing, int(near.sum()))
            found.chi2 = ramp_gain_g2(x_um[near], force_g[near] - drift_g_um * x_um[near], found.top_um) / noise_var_g2
        return found

    monkeypatch.setattr(analysis, "departure_soft_stage", against_the_noise)
    answer = analyse_in_process(sweep_tap(name, seed, k)[0])
    assert answer["error"] == "TAP_TWO_STAGE_CONTACT"
    assert "soft stage" in answer["message"]
