import numpy as np
import pytest

from tapcell.extras.probe.stats import accuracy_stats, combine_samples, format_accuracy, spread_mm


def test_accuracy_stats_hand_values():
    z = np.array([0.010, 0.012, 0.008, 0.014])
    s = accuracy_stats(z)
    assert s.count == 4
    assert s.maximum_mm == pytest.approx(0.014)
    assert s.minimum_mm == pytest.approx(0.008)
    assert s.range_mm == pytest.approx(0.006)
    assert s.average_mm == pytest.approx(0.011)
    assert s.median_mm == pytest.approx(0.011)
    # population deviation: deviations -1, 1, -3, 3 µm -> sqrt(20/4) µm
    assert s.standard_deviation_mm == pytest.approx(np.sqrt(5.0) * 1e-3)
    # |Δ|: 2, 4, 6 µm -> 4 µm
    assert s.average_delta_mm == pytest.approx(0.004)


def test_average_delta_ignores_slow_drift():
    drift = np.linspace(0.0, 0.019, 20)  # 1 µm per sample creep, no noise
    s = accuracy_stats(drift)
    assert s.range_mm == pytest.approx(0.019)
    assert s.average_delta_mm == pytest.approx(0.001)
    assert s.standard_deviation_mm > 5 * s.average_delta_mm


def test_single_sample_and_empty():
    s = accuracy_stats(np.array([0.5]))
    assert (s.range_mm, s.standard_deviation_mm, s.average_delta_mm) == (0.0, 0.0, 0.0)
    with pytest.raises(ValueError):
        accuracy_stats(np.array([]))


def test_format_accuracy_line():
    line = format_accuracy(accuracy_stats(np.array([0.001, 0.003])))
    assert line == (
        "probe accuracy results: maximum 0.003000, minimum 0.001000, range 0.002000, average 0.002000, "
        "median 0.002000, standard deviation 0.001000, average delta 0.002000"
    )


def test_combine_samples_and_spread():
    z = np.array([0.0, 0.0, 0.9])
    assert combine_samples(z, "average") == pytest.approx(0.3)
    assert combine_samples(z, "median") == pytest.approx(0.0)
    assert spread_mm(z) == pytest.approx(0.9)
    with pytest.raises(ValueError, match="average, median"):
        combine_samples(z, "mode")
