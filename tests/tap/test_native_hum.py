"""The mains hum's screen in C (tapcell.tap._c_hum) against its numpy twin (tapcell.tap.hum._screen).

The kernel cuts the same ramps, reads the same bins and floors and takes the same medians; only the
powers come from another FFT (Bluestein's chirp-z over power-of-two FFTs, the bins read only, where
numpy runs pocketfft's rfft of the whole padded length), so every ratio agrees to rounding. Measured
over every screen `mains_hz=auto` runs on taplab seed 1 (691), the 960 reference taps (1,269) and the
reference sessions with the real tap (1,036): within 1.4e-14 relative, the same inf every time; the
closest a ratio came to its bar was 6.5e-5 relative (taplab, the amplitude's 0.35), so no decision
lies within rounding of its bar. The tolerance is ten times the first.
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
    # 2 x 120 steps pad to 243 and 2 x 180..186 to 375: odd lengths (the chirp's circle is taken at twice
    # the length); 1013: a prime count of steps. The mains lines, and harmonics as the screen of a
    # detected line's asks for them (one or two, far from the line's band).
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


def test_too_few_floor_bins_is_inf_in_both(monkeypatch):
    # 30 samples: a floor band of ~60 padded bins less the guards leaves too few
    t, force = _noisy_hum(30, 1)
    found = hum._screen(t, force, (50.0,))
    assert found == ((math.inf,), (math.inf,))
    assert twin(monkeypatch, t, force, (50.0,)) == found


def test_bad_arrays_are_errors_not_garbage():
    t, force = _noisy_hum(100, 1)
    args = (hum.SCREEN_STEP_SIGMAS, hum.SCREEN_STEP_NEIGHBOURS, hum.SCREEN_BAND, hum.SCREEN_MIN_HALF_BAND_BINS,
            hum.SCREEN_GUARD_BINS, hum.SCREEN_MIN_FLOOR_BINS, hum.MAD_TO_SIGMA)
    with pytest.raises(ValueError, match="time_s: 99 values, 100 expected"):
        hum._C.screen(t[:99], force, np.array([50.0]), *args)
    with pytest.raises(TypeError, match="float64"):
        hum._C.screen(t, force.astype(np.float32), np.array([50.0]), *args)
    with pytest.raises(ValueError, match="span no time"):
        hum._C.screen(np.zeros(100), force, np.array([50.0]), *args)
