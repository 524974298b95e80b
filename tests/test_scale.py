"""Scale math: conversions, calibration checks and diagnostic statistics, with real numbers."""

from __future__ import annotations

import numpy as np
import pytest

from tapcell import scale


def test_percent_uses_positive_full_scale_on_both_sides():
    assert scale.counts_to_percent(0x7FFFFF) == pytest.approx(100.0)
    assert scale.counts_to_percent(-0x7FFFFF) == pytest.approx(-100.0)
    assert scale.counts_to_percent(445903) == pytest.approx(5.3155, abs=1e-4)


def test_saturation_is_either_end_of_the_range():
    mask = scale.saturated_mask([0x7FFFFF, 0x7FFFFE, -0x800000, -0x7FFFFF, 0])
    assert mask.tolist() == [True, False, True, False, False]
    small = scale.CountsRange(min_counts=-2048, max_counts=2047)
    assert scale.saturated_mask([2047, -2048, 100], small).tolist() == [True, True, False]


def test_grams_normal_and_inverted():
    assert scale.counts_to_grams(12345 + 245 * 40, 12345, 245.0) == pytest.approx(40.0)
    assert scale.counts_to_grams(12345 + 245 * 40, 12345, 245.0, inverted=True) == pytest.approx(-40.0)
    counts = scale.grams_to_counts(np.array([0.0, 500.0]), 1000, 100.0, inverted=True)
    assert counts.tolist() == [1000.0, -49000.0]


def test_counts_per_gram_is_positive_whatever_the_direction():
    assert scale.counts_per_gram_from(1000, 1000 + 87944, 1000) == pytest.approx(87.944)
    assert scale.counts_per_gram_from(1000, 1000 - 87944, 1000) == pytest.approx(87.944)


def test_capacity_uses_the_smaller_headroom():
    # tare at +1,000,000 counts: headroom up is 7,388,607 counts, down 9,388,608.
    assert scale.capacity_kg(1_000_000, 100.0) == pytest.approx(73.88607)
    assert scale.capacity_kg(-1_000_000, 100.0) == pytest.approx(73.88607)


def test_calibration_ok_gives_numbers_and_no_warnings():
    result = scale.evaluate_calibration(tare_counts=20_000, loaded_counts=20_000 + 500 * 400, grams=500, any_saturated=False)
    assert result.error is None
    assert result.counts_per_gram == pytest.approx(400.0)
    assert result.capacity_kg == pytest.approx((0x7FFFFF - 20_000) / 400 / 1000)
    assert result.warnings == ()


def test_calibration_refusals():
    saturated = scale.evaluate_calibration(0, 0x7FFFFF, 500, any_saturated=True)
    assert saturated.error.startswith("ERROR: Sensor is saturated with too much load!")
    assert saturated.counts_per_gram is None
    same = scale.evaluate_calibration(1234.4, 1234.2, 500, any_saturated=False)
    assert same.error.startswith("ERROR: Tare and Calibration readings are the same!")
    # 0.5 % of the range: 41943 counts.
    small = scale.evaluate_calibration(0, 41943, 500, any_saturated=False)
    assert small.error.startswith("ERROR: Tare and Calibration readings are less than 1% different! (0.50%)")


def test_calibration_warnings_capacity_and_orientation():
    # 10,000 counts/g leaves 0.84 kg of headroom; 200 counts/g leaves 41.9 kg.
    tiny = scale.evaluate_calibration(0, 5_000_000, 500, any_saturated=False)
    assert tiny.counts_per_gram == pytest.approx(10_000)
    assert any("less than 1kg" in w for w in tiny.warnings)
    assert tiny.capacity_kg == pytest.approx(0.8388607)
    huge = scale.evaluate_calibration(0, 100_000, 500, any_saturated=False, higher_gain="A-128")
    assert huge.capacity_kg == pytest.approx(0x7FFFFF / 200 / 1000)
    assert huge.warnings == ("WARNING: Load cell capacity is more than 25kg! Readings will be coarse; consider a "
                             "higher gain setting (gain: A-128) or a more sensitive load cell.",)
    # Already at the highest gain: nothing to advise, so no warning.
    assert scale.evaluate_calibration(0, 100_000, 500, any_saturated=False).warnings == ()
    wrong_way = scale.evaluate_calibration(0, -200_000, 500, any_saturated=False)
    assert wrong_way.error is None
    assert wrong_way.warnings == (
        "WARNING: The reading moved the opposite way to sensor_orientation: normal, so forces would"
        " read negative. Set sensor_orientation: inverted.",
    )
    right_way_inverted = scale.evaluate_calibration(0, -200_000, 500, any_saturated=False, inverted=True)
    assert right_way_inverted.warnings == ()


def test_tare_warning_on_both_sides():
    assert scale.tare_warning(100_000) is None  # 1.19 %
    assert scale.tare_warning(200_000).startswith("WARNING: tare value is more than 2% away from 0! (2.38%)")
    assert scale.tare_warning(-200_000).startswith("WARNING: tare value is more than 2% away from 0! (-2.38%)")


def test_diagnostic_statistics_real_numbers():
    t_s = np.arange(3200) / 320.0
    counts = np.full(3200, 336_000, dtype=np.int64)
    counts[::2] += 700
    counts[5] = 0x7FFFFF
    stats = scale.diagnostic_statistics(t_s, counts)
    assert stats.samples_collected == 3200
    assert stats.measured_rate_sps == pytest.approx(3200 / (3199 / 320.0))
    assert stats.saturated_samples == 1
    assert stats.good_samples == 3199
    assert stats.unique_values == 3
    assert stats.min_percent == pytest.approx(336_000 / 0x7FFFFF * 100)
    assert stats.max_percent == pytest.approx(100.0)
    assert stats.range_share_of_capacity_percent == pytest.approx((100.0 - 336_000 / 0x7FFFFF * 100) / 2)
    assert stats.min_g is None and stats.max_g is None


def test_diagnostic_statistics_grams_when_calibrated():
    counts = np.array([10_000, 10_400, 9_800])
    stats = scale.diagnostic_statistics(np.array([0.0, 0.1, 0.2]), counts, tare_counts=10_000, counts_per_gram=200.0)
    assert (stats.min_g, stats.max_g) == (pytest.approx(-1.0), pytest.approx(2.0))
    inverted = scale.diagnostic_statistics(
        np.array([0.0, 0.1, 0.2]), counts, tare_counts=10_000, counts_per_gram=200.0, inverted=True
    )
    assert (inverted.min_g, inverted.max_g) == (pytest.approx(-2.0), pytest.approx(1.0))
    assert scale.diagnostic_statistics(np.array([0.0, 0.1]), counts[:2]).measured_rate_sps is None
    with pytest.raises(ValueError):
        scale.diagnostic_statistics(np.array([]), np.array([]))
