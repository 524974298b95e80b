"""tapcell.filters: option validation (every message), design, quantization, conversions."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import signal

from tapcell.filters import (
    FilterDesignError, FilterOptions, QuantizedSos, design_firmware_filter, design_sos, grams_to_q1615,
    q1615_to_grams, quantize_sos, reference_sosfilt_q,
)


def test_no_option_means_no_filter():
    assert design_sos(FilterOptions(660)).shape == (0, 6)
    assert design_firmware_filter(FilterOptions(660)) is None


def test_design_order_and_sections_match_scipy():
    sos = design_sos(FilterOptions(660, drift_filter_cutoff_frequency=0.8, buzz_filter_cutoff_frequency=100,
                                   notch_filter_frequencies=(50, 60), notch_filter_quality=2.0))
    assert sos.shape == (4, 6)
    np.testing.assert_allclose(sos[0], [0.99463, -1.98926, 0.99463, 1, -1.98923, 0.98929], atol=6e-6)
    np.testing.assert_allclose(sos[1], [0.13323, 0.26646, 0.13323, 1, -0.73612, 0.26904], atol=6e-6)
    np.testing.assert_allclose(sos[3], [0.87430, -1.47101, 0.87430, 1, -1.47101, 0.74859], atol=6e-6)
    first_order = design_sos(FilterOptions(660, drift_filter_cutoff_frequency=5, drift_filter_delay=1))
    assert first_order.shape == (1, 6) and first_order[0, 2] == 0 and first_order[0, 5] == 0


def test_quantize_q1_30_keeps_numerator_sum_and_falls_back_to_q2_29():
    q = design_firmware_filter(FilterOptions(660, drift_filter_cutoff_frequency=0.8))
    assert q.frac_bits == 30 and q.coeff.dtype == np.int32 and q.n_sections == 1
    b0, b1, b2 = (int(v) for v in q.coeff[0, :3])
    assert b0 + b1 + b2 == 0                       # the high-pass zero at z = 1 is exact
    assert q.coeff.tolist() == [[1067974931, -2135949862, 1067974931, -2135918888, 1062239011]]
    two = quantize_sos(np.array([[1.0, 2.0, 1.0, 1.0, -0.5, 0.25]]))
    assert two.frac_bits == 29
    assert two.coeff.tolist() == [[1 << 29, 1 << 30, 1 << 29, -(1 << 28), 1 << 27]]


@pytest.mark.parametrize("sos, message", [
    (np.zeros((5, 6)), "sos: 'array of shape (5, 6)' is not allowed; allowed: shape (n, 6) with n <= 4"),
    (np.array([[1.0, 0, 0, 2.0, 0, 0]]), "sos: 'a0 column' is not allowed; allowed: finite sections normalised to a0 = 1"),
    (np.array([[2.0 ** 31, 0, 0, 1.0, 0, 0]]),
     "sos: 'coefficient magnitude 2.14748e+09' is not allowed; allowed: coefficients below 2^30"),
])
def test_quantize_rejects_bad_sections(sos, message):
    with pytest.raises(FilterDesignError) as info:
        quantize_sos(sos)
    assert str(info.value) == message


@pytest.mark.parametrize("options, message", [
    (dict(drift_filter_cutoff_frequency=0.09),
     "drift_filter_cutoff_frequency: 0.09 is not allowed; allowed: 0.1 to 20 Hz"),
    (dict(drift_filter_cutoff_frequency=20.5),
     "drift_filter_cutoff_frequency: 20.5 is not allowed; allowed: 0.1 to 20 Hz"),
    (dict(drift_filter_cutoff_frequency=float("nan")),
     "drift_filter_cutoff_frequency: nan is not allowed; allowed: 0.1 to 20 Hz"),
    (dict(drift_filter_cutoff_frequency="fast"),
     "drift_filter_cutoff_frequency: 'fast' is not allowed; allowed: 0.1 to 20 Hz"),
    (dict(drift_filter_delay=3), "drift_filter_delay: 3 is not allowed; allowed: 1 or 2 (the Butterworth order)"),
    (dict(drift_filter_delay=1.5), "drift_filter_delay: 1.5 is not allowed; allowed: 1 or 2 (the Butterworth order)"),
    (dict(buzz_filter_delay=0), "buzz_filter_delay: 0 is not allowed; allowed: 1 or 2 (the Butterworth order)"),
    (dict(buzz_filter_cutoff_frequency=80),
     "buzz_filter_cutoff_frequency: 80 is not allowed; allowed: above 80 Hz and below 330 Hz at 660 sps"),
    (dict(buzz_filter_cutoff_frequency=330),
     "buzz_filter_cutoff_frequency: 330 is not allowed; allowed: above 80 Hz and below 330 Hz at 660 sps"),
    (dict(notch_filter_frequencies=(50, 60, 70)),
     "notch_filter_frequencies: [50, 60, 70] is not allowed; allowed: at most 2 frequencies"),
    (dict(notch_filter_frequencies=(0,)),
     "notch_filter_frequencies: 0 is not allowed; allowed: each above 0 Hz and below 330 Hz (half of 660 sps)"),
    (dict(drift_filter_cutoff_frequency=5, buzz_filter_cutoff_frequency=100, notch_filter_frequencies=(50, 120)),
     "notch_filter_frequencies: 120 is not allowed; allowed: each above the drift cutoff 5 Hz and below the "
     "buzz cutoff 100 Hz"),
    (dict(drift_filter_cutoff_frequency=5, notch_filter_frequencies=(5,)),
     "notch_filter_frequencies: 5 is not allowed; allowed: each above the drift cutoff 5 Hz and below "
     "330 Hz (half of 660 sps)"),
    (dict(notch_filter_frequencies="50"),
     "notch_filter_frequencies: '50' is not allowed; allowed: a list of at most 2 frequencies"),
    (dict(notch_filter_quality=0.4), "notch_filter_quality: 0.4 is not allowed; allowed: 0.5 to 3"),
    # The config reference: "Minimum value is 0.5 and maximum is 3.0".
    (dict(notch_filter_quality=3.5), "notch_filter_quality: 3.5 is not allowed; allowed: 0.5 to 3"),
    (dict(sample_rate_sps=80, notch_filter_frequencies=(30,), notch_filter_quality=0.5),
     "notch_filter_quality: 0.5 is not allowed; allowed: above 0.75 for a notch at 30 Hz (its width, frequency / "
     "quality, must stay below half of 80 sps)"),
    (dict(sample_rate_sps=0), "sample_rate_sps: 0 is not allowed; allowed: a positive sample rate"),
])
def test_every_design_error_names_option_value_and_range(options, message):
    opts = FilterOptions(**{"sample_rate_sps": 660, **options})
    with pytest.raises(FilterDesignError) as info:
        design_sos(opts)
    assert str(info.value) == message
    assert info.value.option == message.split(":")[0]


def test_limits_relative_to_the_sample_rate():
    # 80 sps: the buzz cutoff must lie strictly between 39 and 40 Hz
    design_sos(FilterOptions(80, buzz_filter_cutoff_frequency=39.5))
    with pytest.raises(FilterDesignError, match=r"above 39 Hz and below 40 Hz at 80 sps"):
        design_sos(FilterOptions(80, buzz_filter_cutoff_frequency=39))
    # 320 sps: 80 < f < 160
    design_sos(FilterOptions(320, buzz_filter_cutoff_frequency=159.9))
    # 20 sps: a 15 Hz drift cutoff is within 0.1..20 but above half the rate
    with pytest.raises(FilterDesignError) as info:
        design_sos(FilterOptions(20, drift_filter_cutoff_frequency=15))
    assert str(info.value) == ("drift_filter_cutoff_frequency: 15 is not allowed; allowed: 0.1 to 20 Hz, "
                               "below 10 Hz (half of 20 sps)")
    # the range ends are allowed
    assert design_sos(FilterOptions(660, drift_filter_cutoff_frequency=0.1, notch_filter_quality=3.0,
                                    notch_filter_frequencies=(0.2,))).shape == (2, 6)
    assert design_sos(FilterOptions(660, drift_filter_cutoff_frequency=20, notch_filter_quality=0.5)).shape == (1, 6)


def test_q1615_conversions():
    assert grams_to_q1615(np.array([1.0, -1.0, 0.5 / 32768, -0.5 / 32768])).tolist() == [32768, -32768, 1, 0]
    assert q1615_to_grams(np.array([49152])).tolist() == [1.5]
    with pytest.raises(ValueError, match="within -65536"):
        grams_to_q1615(65536.0)


def test_reference_filter_within_tolerance_of_float_and_passthrough():
    opts = FilterOptions(660, drift_filter_cutoff_frequency=0.8, buzz_filter_cutoff_frequency=100,
                         notch_filter_frequencies=(50, 60))
    q = design_firmware_filter(opts)
    rng = np.random.default_rng(5)
    grams = np.clip(np.cumsum(rng.normal(0, 40, 1500)), -2000, 2000)
    x = grams_to_q1615(grams)
    y, overflowed = reference_sosfilt_q(q, x)
    assert not overflowed
    assert np.max(np.abs(q1615_to_grams(y) - signal.sosfilt(design_sos(opts), x / 32768))) < 0.01
    same, overflowed = reference_sosfilt_q(None, x)
    assert np.array_equal(same, x) and not overflowed


def test_reference_overflow_saturates():
    q = QuantizedSos(coeff=np.array([[3 << 29, 0, 0, 0, 0]], dtype=np.int32), frac_bits=30)
    y, overflowed = reference_sosfilt_q(q, np.array([32768, 50000 * 32768], dtype=np.int64))
    assert overflowed and y.tolist() == [49152, 2 ** 31 - 1]
