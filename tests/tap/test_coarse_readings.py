"""Readings in coarse steps (a low gain, a big load cell, a file written in whole grams): the noise
sigma is the noise and the rounding together (`robust.grouped_median`), never none, and a tap read
that way is measured as it was. Before, the median of the off-midpoints landed on a lattice value:
0 where most readings repeat, and every check scaled by the noise fired ("more than 4 x the 0.00 g
noise": TAP_ADHESION on a clean reference ADS1220 tap read in 3 g steps)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bench.tap_sweep import Case, _force_quantized, analyse_in_process, case_taps
from tapcell.tap import AnalysisOptions, analysis, analyze_tap, robust
from tapcell.tap.readers import tap_from_object
from tapcell.tap.robust import MAD_TO_SIGMA


def plain_median_sigma(force_g: np.ndarray) -> float:
    """The noise sigma as it was: the off-midpoints' median, read as it falls."""
    off_mid = np.abs(force_g[1:-1] - 0.5 * (force_g[:-2] + force_g[2:]))
    return MAD_TO_SIGMA * robust.median(off_mid) / math.sqrt(1.5)


def in_steps(force_g: np.ndarray, step_g: float) -> np.ndarray:
    return step_g * np.round(force_g / step_g)


def tap_like(rng: np.random.Generator, samples: int = 300) -> np.ndarray:
    """Free air, a ramp of 20 g a sample over 10 samples, a plateau; 1 g of noise, at any level."""
    force_g = np.concatenate([np.zeros(100), 20.0 * np.arange(1, 11), np.full(samples - 110, 200.0)])
    return force_g + rng.normal(0.0, 1.0, samples) + rng.uniform(-50.0, 50.0)


@pytest.mark.usefixtures("kernel_or_twin")
@pytest.mark.parametrize("step_g", [0.5, 1.0, 2.0])
def test_the_noise_of_readings_in_steps_is_the_noise_and_the_rounding(step_g):
    # 40 draws of 300 samples in free air, 1 g of noise: the estimate over sqrt(1 + step^2 / 12)
    # measured 0.98 / 1.01 / 1.02 on average (sd of one draw 0.075 / 0.077 / 0.126: 0.07 is over
    # three standard errors of the mean). The median as it fell read 1.19x at 1 g and 0.76x at 2 g.
    rng = np.random.default_rng([21, int(step_g * 10)])
    ratios = [analysis.noise_sigma_g(in_steps(rng.normal(0.0, 1.0, 300) + rng.uniform(-50.0, 50.0), step_g))
              / math.sqrt(1.0 + step_g ** 2 / 12.0) for _ in range(40)]
    assert np.mean(ratios) == pytest.approx(1.0, abs=0.07)


@pytest.mark.usefixtures("kernel_or_twin")
@pytest.mark.parametrize("step_g", [3.0, 5.0, 8.0])
def test_readings_in_steps_coarser_than_the_noise_never_read_noiseless(step_g):
    # A tap-like series in steps of 3-8 noise sigmas: each of 40 draws read 0.44-2.16x the noise and
    # the rounding together (measured); the median as it fell read 0 in 14-32 of them.
    rng = np.random.default_rng([22, int(step_g)])
    truth_g = math.sqrt(1.0 + step_g ** 2 / 12.0)
    for _ in range(40):
        force_g = in_steps(tap_like(rng), step_g)
        assert 0.4 * truth_g < analysis.noise_sigma_g(force_g) < 2.5 * truth_g


@pytest.mark.usefixtures("kernel_or_twin")
def test_readings_finer_than_the_noise_keep_the_median_as_it_falls():
    # The gate: a sensor's own resolution (the reference taps are written to 0.0001 g, 0.4-3 g of
    # noise), continuous readings, and readings frozen over the last half (a stuck sensor's tap,
    # which its own checks name) all keep the plain median's answer to the last bit.
    rng = np.random.default_rng(23)
    for noise_g in (0.4, 1.0, 3.0):
        continuous = tap_like(rng) * noise_g
        frozen = continuous.copy()
        frozen[150:] = frozen[150]
        for force_g in (continuous, in_steps(continuous, 0.0001), frozen):
            assert analysis.noise_sigma_g(force_g) == plain_median_sigma(force_g)
    # A long record in fine steps holds off-midpoints a single step apart, all on its lattice: the
    # step (0.005 g) is under a twentieth of the median, which a grouped median could not hold.
    long_record = in_steps(rng.normal(0.0, 3.0, 5000), 0.01)
    assert analysis.noise_sigma_g(long_record) == plain_median_sigma(long_record)


@pytest.mark.usefixtures("kernel_or_twin")
@pytest.mark.parametrize("zeros, ones, twos, median_steps", [
    (12, 8, 0, 10 / 12 * 0.5),  # the half count falls in bin 0, [0, step / 2): 10 of its 12
    (9, 9, 2, 0.5 + 1 / 9),     # in bin 1, [step / 2, 3 step / 2): 1 of its 9 past bin 0's 9
])
def test_the_grouped_median_interpolates_within_the_bin_the_half_count_falls_in(zeros, ones, twos, median_steps):
    step = 0.75
    values = np.array([0.0] * zeros + [step] * ones + [2 * step] * twos)
    off_mid_sigma = MAD_TO_SIGMA * median_steps * step / math.sqrt(1.5)
    assert robust.grouped_median(values, robust.median(values)) == pytest.approx(median_steps * step, rel=1e-12)
    # the same off-midpoints from readings: a run of levels whose neighbours' midpoints they miss so
    assert analysis._noise_sigma_of(values) == pytest.approx(off_mid_sigma, rel=1e-12)


@pytest.mark.usefixtures("kernel_or_twin")
def test_the_lattice_is_the_coarsest_most_values_keep():
    # A spike repaired to its neighbours' mean leaves an off-midpoint halfway between two (one
    # value at 0.75 among sixteen at 1.5): the step stays 1.5, so bin 0 is [0, 0.75), holding 20
    # of the 37, the half count 18.5 of them. The smallest value as the step read half that.
    values = np.array([0.0] * 20 + [1.5] * 16 + [0.75])
    assert robust.grouped_median(values, robust.median(values)) == pytest.approx(18.5 / 20 * 0.75, rel=1e-12)


@settings(max_examples=300, deadline=None)
@given(st.integers(0, 8).flatmap(lambda still: st.lists(st.sampled_from([0] * still + [-2, -1, 1, 2]), min_size=20, max_size=150)),
       st.booleans(), st.integers(-1000, 1000), st.sampled_from([0.1, 0.37, 1.0, 2.5, 10.0]))
def test_the_kernel_and_the_twin_agree_on_readings_in_steps(moves, held, level, step_g):
    # Readings a step or two either side of a level, or wandering by steps and held for runs between
    # them (`held`): the half count falls in bin 0 (most off-midpoints 0) or in a bin further up.
    counts = np.cumsum(moves) if held else np.array(moves)
    force_g = (counts.astype(float) + level) * step_g
    if analysis._C is None:
        pytest.skip("the compiled kernels are not built here")
    kernel = analysis.noise_sigma_g(force_g)
    twin = 0.0 if len(force_g) < 3 else analysis._noise_sigma_of(np.abs(force_g[1:-1] - 0.5 * (force_g[:-2] + force_g[2:])))
    assert kernel == twin or (math.isnan(kernel) and math.isnan(twin))


def _reference_tap_in_steps(reference_dir, scenario: str, k: int, step_g: float) -> tuple[dict, float]:
    case = Case("steps", f"reference {scenario} in {step_g} g steps", "accept", reference=(scenario, 1),
                transform=_force_quantized(step_g))
    return case_taps(case, 1, k + 1, reference_dir)[k]


@pytest.mark.usefixtures("kernel_or_twin")
@pytest.mark.parametrize("scenario, k, step_g, noise_g", [
    ("clean_ads1220_660", 17, 3.0, (0.5, 2.0)),  # 0.71 g of noise; read "0.00 g", TAP_ADHESION
    ("glitch", 44, 5.0, (1.0, 2.5)),  # 1.37 g; 4 frames repaired between readings: half steps, 0.68 g
])
def test_a_clean_tap_in_coarse_steps_is_measured(reference_dir, scenario, k, step_g, noise_g):
    # Accepted, within 3 of its sigmas of the truth, its noise sigma the noise and the rounding's
    # (sqrt(0.71² + 3²/12) = 1.07 g, sqrt(1.37² + 5²/12) = 1.98 g).
    tap, z_mm = _reference_tap_in_steps(reference_dir, scenario, k, step_g)
    answer = analyse_in_process(tap)
    assert answer["valid"], answer["message"]
    assert abs(answer["z"] - z_mm) * 1000.0 < 3.0 * answer["z_sigma_um"]
    assert noise_g[0] < answer["noise_sigma_g"] < noise_g[1]


def test_with_the_median_as_it_falls_the_same_tap_reads_noiseless(reference_dir, monkeypatch):
    """The mechanism, on the twins (the kernel's median is compiled in)."""
    monkeypatch.setattr(analysis, "_C", None)
    monkeypatch.setattr(analysis, "grouped_median", lambda values, median_value: median_value)
    answer = analyse_in_process(_reference_tap_in_steps(reference_dir, "clean_ads1220_660", 17, 3.0)[0])
    assert answer["error"] == "TAP_ADHESION"
    assert "the 0.00 g noise" in answer["message"]


def test_with_a_hum_taken_out_the_rounding_still_bounds_the_noise(reference_dir):
    # The reference's clean ADS1220 660 tap 52 in 3 g steps, as the printer analyses it (mains_hz
    # auto): its 0.45 g hum is fitted, the readings leave their lattice, and the off-midpoints'
    # median read 0.06 g (TAP_ADHESION). The rounding alone leaves 3 / sqrt(12) = 0.87 g.
    tap, z_mm = _reference_tap_in_steps(reference_dir, "clean_ads1220_660", 52, 3.0)
    answer = analyze_tap(tap_from_object(tap), AnalysisOptions(mains_hz="auto"))
    assert answer.hum is not None
    assert answer.valid, answer.message
    assert answer.noise_sigma_g == pytest.approx(3.0 / math.sqrt(12.0))
    assert abs(answer.z_mm - z_mm) * 1000.0 < 3.0 * answer.z_sigma_um


def test_the_rounding_noise_is_the_readings_step_over_root_twelve():
    rng = np.random.default_rng(24)
    force_g = tap_like(rng)
    assert analysis.rounding_noise_g(in_steps(force_g, 2.5)) == pytest.approx(2.5 / math.sqrt(12.0), rel=1e-12)
    assert analysis.rounding_noise_g(force_g) == 0.0  # continuous readings
    assert analysis.rounding_noise_g(in_steps(force_g, 0.0001)) == 0.0  # a resolution far under their steps
