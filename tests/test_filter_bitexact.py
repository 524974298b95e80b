"""The C filter (through cffi) and the Python reference agree bit for bit; both track float64."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import example, given, settings, strategies as st
from scipy import signal

from tapcell.filters import (
    NOTCH_QUALITY_MAX, FilterOptions, QuantizedSos, buzz_cutoff_minimum_hz, design_firmware_filter, design_sos, grams_to_q1615,
    half_rate_hz, q1615_to_grams, reference_sosfilt_q,
)
from tapcell.mcu.trigger import TriggerConfigError, sos_filter_run

SAMPLE_RATES = (10, 80, 320, 330, 660, 1000, 2000)


@st.composite
def valid_designs(draw) -> FilterOptions:
    sps = draw(st.sampled_from(SAMPLE_RATES))
    nyquist = half_rate_hz(sps)
    drift = draw(st.none() | st.floats(0.1, min(20.0, sps / 2 * 0.9)))
    buzz_low = buzz_cutoff_minimum_hz(sps)
    buzz = draw(st.none() | st.floats(buzz_low + 0.01 * (nyquist - buzz_low), nyquist - 0.01 * (nyquist - buzz_low)))
    low, high = (drift or 0.0), (buzz or float(nyquist))
    notches = []   # no room for a notch when the drift cutoff is above the buzz cutoff
    if high - low > 0.1:
        notches = draw(st.lists(st.floats(low + 0.05 * (high - low), high - 0.05 * (high - low)), max_size=2))
    # a notch's width (frequency / quality) must stay below half the sample rate
    q_min = max([0.5] + [1.01 * f0 / (sps / 2) for f0 in notches])
    return FilterOptions(sps, drift, draw(st.sampled_from((1, 2))), buzz, draw(st.sampled_from((1, 2))),
                         tuple(notches), draw(st.floats(q_min, NOTCH_QUALITY_MAX)))


@settings(max_examples=60, deadline=None)
@given(opts=valid_designs(), seed=st.integers(0, 2 ** 32 - 1), big=st.booleans())
def test_c_filter_equals_reference_on_random_designs_and_signals(opts, seed, big):
    qsos = design_firmware_filter(opts)
    rng = np.random.default_rng(seed)
    if big:   # full int32 range: exercises saturation, which must match too
        x = rng.integers(-2 ** 31, 2 ** 31, 200, dtype=np.int64)
    else:
        x = grams_to_q1615(np.clip(np.cumsum(rng.normal(0, 50, 300)), -2000, 2000))
    y_c, overflow_c = sos_filter_run(qsos, x)
    y_ref, overflow_ref = reference_sosfilt_q(qsos, x)
    assert overflow_c == overflow_ref
    assert np.array_equal(y_c, y_ref)


@settings(max_examples=40, deadline=None)
@given(coeff=st.lists(st.lists(st.integers(-2 ** 31 + 1, 2 ** 31 - 1), min_size=5, max_size=5), min_size=1,
                      max_size=4),
       frac_bits=st.integers(1, 30), seed=st.integers(0, 2 ** 32 - 1))
# Saturation in section 1 wraps its rounding error; extreme coefficients in section 2 then
# bring the sums to the edge of int64 (with -2^31 allowed this overflowed: UB in C).
@example(coeff=[[0, 0, 4, 0, 0], [0, 0, -2 ** 31 + 1, 0, 2 ** 31 - 1]], frac_bits=1, seed=0)
def test_c_filter_equals_reference_on_arbitrary_coefficients(coeff, frac_bits, seed):
    qsos = QuantizedSos(coeff=np.array(coeff, dtype=np.int32), frac_bits=frac_bits)
    x = np.random.default_rng(seed).integers(-2 ** 31, 2 ** 31, 60, dtype=np.int64)
    y_c, overflow_c = sos_filter_run(qsos, x)
    y_ref, overflow_ref = reference_sosfilt_q(qsos, x)
    assert overflow_c == overflow_ref
    assert np.array_equal(y_c, y_ref)


def tared_signal(sps: float, seconds: float, seed: int) -> np.ndarray:
    """A tared signal spanning +-2 kg: slow drift, taps, mains hum, noise, a held overload."""
    rng = np.random.default_rng(seed)
    t = np.arange(int(sps * seconds)) / sps
    grams = 300 * np.sin(2 * np.pi * 0.2 * t) + 5 * np.sin(2 * np.pi * 50 * t) + rng.normal(0, 2, t.size)
    for start in np.arange(0.5, seconds, 1.0):
        grams += np.where((t > start) & (t < start + 0.3), 1500 * np.sin(np.pi * (t - start) / 0.3), 0)
    grams[(t > seconds * 0.6) & (t < seconds * 0.75)] = -2000
    return np.clip(grams, -2000, 2000)


def test_both_within_0_05_g_of_float64_on_a_tared_2_kg_signal():
    for opts in (FilterOptions(660, 0.8, 2, 100, 2, (50, 60), 2.0),
                 FilterOptions(330, 0.8, 2, 150, 2, (50, 60), 2.0),
                 FilterOptions(320, 0.5, 2, 100, 2, (), 2.0),
                 FilterOptions(80, 11.2, 1, 39.5, 2, (), 2.0)):
        x = grams_to_q1615(tared_signal(opts.sample_rate_sps, 6.0, seed=3))
        want_g = signal.sosfilt(design_sos(opts), x / 32768.0)
        qsos = design_firmware_filter(opts)
        y_c, overflow = sos_filter_run(qsos, x)
        y_ref, _ = reference_sosfilt_q(qsos, x)
        assert not overflow
        assert np.array_equal(y_c, y_ref)
        assert np.max(np.abs(q1615_to_grams(y_c) - want_g)) < 0.05, opts


def test_a_coefficient_of_minus_2_pow_31_is_refused_by_firmware_and_reference():
    qsos = QuantizedSos(coeff=np.array([[1, 0, 0, 0, -2 ** 31]], dtype=np.int32), frac_bits=30)
    with pytest.raises(TriggerConfigError, match=r"no coefficient equal to -2\^31"):
        sos_filter_run(qsos, np.zeros(4, dtype=np.int32))
    with pytest.raises(ValueError, match=r"-2\^31 is not allowed"):
        reference_sosfilt_q(qsos, np.zeros(4, dtype=np.int32))
