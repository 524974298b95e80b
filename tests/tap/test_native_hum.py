"""The mains hum's screen in C (tapcell.tap._c_hum) against its numpy twin (tapcell.tap.hum._screen).

The kernel cuts the same ramps, reads the same bins and floors and takes the same medians; only the
powers come from another FFT (fft.h's mixed-radix FFT, where numpy runs pocketfft's rfft), so every
ratio agrees to rounding. Measured over every screen `mains_hz=auto` runs on taplab seed 1 (691), the
960 reference taps (1,269) and the reference sessions with the real tap (1,036): within 1.3e-14
relative, the same inf every time; the closest a ratio came to its bar was 6.5e-5 relative (taplab,
the amplitude's 0.35), so no decision lies within rounding of its bar. The tolerance is ten times
the first. The fit's exact parts (the spline, its normal equations, the knots, the corner windows)
repeat their twins' arithmetic: compared bit for bit.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from native_kernel_inputs import generated_taps, recorded_calls
from tapcell.tap import AnalysisOptions, hum

pytestmark = pytest.mark.skipif(hum._C is None, reason="the hum kernel is not built (TAPCELL_NATIVE=0)")

RELATIVE = 1.5e-13
AUTO = AnalysisOptions(mains_hz="auto")


def twin(monkeypatch, *args):
    with monkeypatch.context() as patch:
        patch.setattr(hum, "_C", None)
        return hum._screen(*args)


def assert_agree(found, reference):
    for kernel_values, twin_values in zip(found, reference):
        assert len(kernel_values) == len(twin_values)
        for value, expected in zip(kernel_values, twin_values):
            if math.isinf(expected):
                assert value == expected
            else:
                assert value == pytest.approx(expected, rel=RELATIVE, abs=0)


def _noisy_hum(n: int, seed: int, rate_sps: float = 320.0, amplitude_g: float = 2.0, gap_s: float = 0.0):
    """n samples of a ramped tap-like force with a 50 Hz line and white noise, a little jitter in time
    (and `gap_s` missing after the first 60 %)."""
    rng = np.random.default_rng([seed, n])
    t = 10.0 + np.arange(n) / rate_sps + rng.uniform(-2e-6, 2e-6, n) + gap_s * (np.arange(n) >= 0.6 * n)
    force = 150.0 * np.clip((t - t[n // 3]) * 20.0, 0.0, 1.0) + amplitude_g * np.sin(2 * np.pi * 50.0 * t + 0.3)
    return t, force + rng.normal(0.0, 0.5, n)


def test_the_kernel_screens_as_the_twin_on_taplabs_taps(monkeypatch):
    # Every taplab scenario (the hum one among them) at 80-2000 sps: the screen of the mains lines.
    calls = recorded_calls(hum, "_screen", [AUTO], generated_taps(2, 12))
    assert len(calls) >= 30
    assert {len(candidates) for _, _, candidates in calls} >= {2}
    passed = 0
    for call in calls:
        found = hum._screen(*call)
        assert_agree(found, twin(monkeypatch, *call))
        passed += any(c >= hum.SCREEN_MIN_CHI2 for c in found[0])
    assert passed >= 3  # lines seen, not only noise


@pytest.mark.parametrize("lengths", [range(60, 200, 3), (121, 122, 181, 187, 203, 338, 365, 608, 1013, 2500)],
                         ids=("60-199", "odd and prime padded lengths"))
def test_every_length_agrees(monkeypatch, lengths):
    # 2 x 120 steps pad to 243 and 2 x 180..186 to 375: odd lengths (a complex FFT of the whole length,
    # its circle at twice the length); 1013: a prime count of steps; every radix (2, 3, 4, 5) among the
    # padded lengths. The mains lines, and harmonics as the screen of a detected line asks for them (one
    # or two, far from the line's band).
    for k, n in enumerate(lengths):
        t, force = _noisy_hum(n, 3)
        candidates = [(50.0, 60.0), (100.0,), (100.0, 150.0)][k % 3]
        found = hum._screen(t, force, candidates)
        assert_agree(found, twin(monkeypatch, t, force, candidates))


def test_a_clear_line_passes_and_noise_alone_does_not():
    # 2 g at 50 Hz on 0.5 g of noise, 320 sps (seeds 5-7: chi2 347-2388 at 50 Hz, 0.3-5.9 at 60 Hz). The
    # line's steps (1.9 g) outgrow the noise's (0.7 g) and set the step sigma: it reads ~1.45 sigmas.
    t, force = _noisy_hum(700, 5, amplitude_g=2.0)
    clear, hum_to_noise = hum._screen(t, force, (50.0, 60.0))
    assert clear[0] > 300.0 and clear[1] < hum.SCREEN_MIN_CHI2
    assert hum_to_noise[0] == pytest.approx(1.45, abs=0.05)
    t, force = _noisy_hum(700, 5, amplitude_g=0.0)  # noise alone: chi2 5.2 and 0.9, 0.11 sigmas
    clear, hum_to_noise = hum._screen(t, force, (50.0, 60.0))
    assert max(clear) < hum.SCREEN_MIN_CHI2 and max(hum_to_noise) < hum.FIT_MIN_HUM_TO_NOISE


def test_a_gap_in_the_samples_reads_the_line_by_its_own_dft(monkeypatch):
    t, force = _noisy_hum(700, 7, gap_s=0.05)  # 16 samples' worth missing: not evenly spaced
    found = hum._screen(t, force, (50.0, 60.0))
    assert_agree(found, twin(monkeypatch, t, force, (50.0, 60.0)))
    assert found[0][0] > 100.0


@pytest.mark.parametrize("n", [2, 3, 30])
def test_too_few_floor_bins_is_inf_in_both(monkeypatch, n):
    # 30 samples: a floor band of ~60 padded bins less the guards leaves too few; 2: one step
    t, force = _noisy_hum(n, 1)
    found = hum._screen(t, force, (50.0, 60.0))
    assert found == ((math.inf, math.inf), (math.inf, math.inf))
    assert twin(monkeypatch, t, force, (50.0, 60.0)) == found


def test_bad_arrays_are_errors_not_garbage():
    t, force = _noisy_hum(100, 1)
    args = (hum._fast_length(198), hum.SCREEN_STEP_SIGMAS, hum.SCREEN_STEP_NEIGHBOURS, hum.SCREEN_BAND,
            hum.SCREEN_MIN_HALF_BAND_BINS, hum.SCREEN_GUARD_BINS, hum.SCREEN_MIN_FLOOR_BINS, hum.MAD_TO_SIGMA)
    with pytest.raises(ValueError, match="time_s: 99 values, 100 expected"):
        hum._C.screen(t[:99], force, np.array([50.0]), *args)
    with pytest.raises(TypeError, match="float64"):
        hum._C.screen(t, force.astype(np.float32), np.array([50.0]), *args)
    with pytest.raises(ValueError, match="span no time"):
        hum._C.screen(np.zeros(100), force, np.array([50.0]), *args)
    with pytest.raises(ValueError, match="padded length 197, from 198 to 396 allowed"):
        hum._C.screen(t, force, np.array([50.0]), 197, *args[1:])
    for too_long in (397, 2 ** 61):  # the scratch's size overflowed at 2**61 (a crash) before the bound
        with pytest.raises(ValueError, match=f"padded length {too_long}, from 198 to 396 allowed"):
            hum._C.screen(t, force, np.array([50.0]), too_long, *args[1:])


# The fit's exact parts: the same arithmetic in the same order, so bit for bit (np.array_equal).
def _fitted_taps():
    """Taplab taps the fit runs on: the hum scenario and a few others whose weak lines pass the screen."""
    return generated_taps(3, 12, ("mains_hum", "clean_hx717", "clean_ads1220_2000", "hx711_80", "corrupt_frames"))


def test_the_knots_and_the_corner_windows_are_the_twins_bit_for_bit(monkeypatch):
    knot_calls = recorded_calls(hum, "spline_knots", [AUTO], _fitted_taps())
    window_calls = recorded_calls(hum, "windows_holding", [AUTO], _fitted_taps())
    assert len(knot_calls) >= 8 and len(window_calls) == len(knot_calls)
    for call in knot_calls:
        knots = hum.spline_knots(*call)
        with monkeypatch.context() as patch:
            patch.setattr(hum, "_C", None)
            assert np.array_equal(knots, hum.spline_knots(*call))
    for call in window_calls:
        inside = hum.windows_holding(*call)
        assert 0 < np.count_nonzero(inside) < len(inside)
        with monkeypatch.context() as patch:
            patch.setattr(hum, "_C", None)
            assert np.array_equal(inside, hum.windows_holding(*call))


@pytest.mark.parametrize("corners", [[], [0.041, 0.07, 0.5], [0.0, 0.1, 0.05, 0.05, math.nan, -1.0], [0.0401],
                                     [0.6875, 1.8125]],
                         ids=("none", "near and far", "ends, repeats, nan", "next to a grid knot",
                              "exactly a tenth of the spacing away"))
def test_knots_at_the_edges(monkeypatch, corners):
    # (0, 5, 0.625): grid knots at 0.625 k exactly, and 0.6875 exactly 0.0625 = 0.1 x 0.625 from one (kept)
    for first, last, spacing in ((0.0, 0.1, 0.02), (0.0, 0.1, 0.5), (3.0, 3.0 + 1e-3, 0.02), (0.0, 5.0, 0.625)):
        knots = hum.spline_knots(first, last, spacing, corners)
        with monkeypatch.context() as patch:
            patch.setattr(hum, "_C", None)
            assert np.array_equal(knots, hum.spline_knots(first, last, spacing, corners))


def test_the_spline_and_its_normal_equations_are_the_twins_bit_for_bit(monkeypatch):
    calls = recorded_calls(hum, "_fit_groups", [AUTO], _fitted_taps())
    assert len(calls) >= 8
    for spline, waves, force_g, use, _ in calls:
        weight = use.astype(float)
        gram, per_knot = spline.normal_equations(weight, force_g, waves)
        with monkeypatch.context() as patch:
            patch.setattr(hum, "_C", None)
            twin_gram, twin_per_knot = spline.normal_equations(weight, force_g, waves)
        assert np.array_equal(gram, twin_gram) and np.array_equal(per_knot, twin_per_knot)
        assert gram.shape == (spline.count, spline.count) and per_knot.shape == (spline.count, waves.shape[1] + 1)
    spline_calls = recorded_calls(hum, "hat_spline", [AUTO], _fitted_taps())
    for time_s, knots_s in spline_calls:
        spline = hum.hat_spline(time_s, knots_s)
        with monkeypatch.context() as patch:
            patch.setattr(hum, "_C", None)
            twin_spline = hum.hat_spline(time_s, knots_s)
        assert np.array_equal(spline.left, twin_spline.left) and np.array_equal(spline.share, twin_spline.share)


def test_a_knot_without_samples_gets_the_ridge_in_both(monkeypatch):
    # Every sample left out around the middle knot: its row of the gram is the ridge alone.
    time_s = np.arange(200) / 320.0
    knots_s = hum.spline_knots(time_s[0], time_s[-1], 0.02, [])
    spline = hum.hat_spline(time_s, knots_s)
    weight = np.where(np.abs(time_s - knots_s[15]) < 0.021, 0.0, 1.0)
    force_g, waves = np.sin(time_s * 7.0), hum.sinusoid_basis(time_s, (50.0, 100.0))
    gram, per_knot = spline.normal_equations(weight, force_g, waves)
    with monkeypatch.context() as patch:
        patch.setattr(hum, "_C", None)
        twin_gram, twin_per_knot = spline.normal_equations(weight, force_g, waves)
    assert np.array_equal(gram, twin_gram) and np.array_equal(per_knot, twin_per_knot)
    assert gram[15, 15] == pytest.approx(1e-10 * np.trace(gram) / len(knots_s), rel=1e-6) and gram[15, 15] > 0


def test_bad_spline_arrays_are_errors():
    left, share = np.zeros(10, dtype=np.int64), np.zeros(10)
    with pytest.raises(ValueError, match="at least two knots"):
        hum._C.hat_spline(np.zeros(10), np.zeros(1), left, share)
    with pytest.raises(ValueError, match="left: 72 bytes, 80 expected"):
        hum._C.hat_spline(np.zeros(10), np.arange(3.0), left[:9], share)
    gram, per_knot = np.empty((3, 3)), np.empty((3, 1))
    with pytest.raises(ValueError, match="outside 0..1"):
        hum._C.normal_equations(np.full(10, 2, dtype=np.int64), share, np.ones(10), np.ones(10), np.empty((10, 0)),
                                3, 0, gram, per_knot)


def test_strided_arrays_are_read_as_their_values(monkeypatch):
    # every other sample of a longer record: views, not C-contiguous; the kernels get copies
    t, force = _noisy_hum(1400, 9)
    t, force = t[::2], force[::2]
    found = hum._screen(t, force, (50.0, 60.0))
    assert_agree(found, twin(monkeypatch, t, force, (50.0, 60.0)))
    knots = hum.spline_knots(float(t[0]), float(t[-1]), 0.02, [])
    spline = hum.hat_spline(t, knots[::1])
    inside = hum.windows_holding(t, [float(t[100]), float(t[300])], 0.002, 0.003, 0.003)
    with monkeypatch.context() as patch:
        patch.setattr(hum, "_C", None)
        twin_spline = hum.hat_spline(t, knots)
        assert np.array_equal(inside, hum.windows_holding(t, [float(t[100]), float(t[300])], 0.002, 0.003, 0.003))
    assert np.array_equal(spline.left, twin_spline.left) and np.array_equal(spline.share, twin_spline.share)
