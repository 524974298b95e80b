"""Statistics over repeated probe results: PROBE_ACCURACY and the multi-sample result.

Plain functions over numpy arrays. The accuracy report follows the probe convention
(maximum, minimum, range, average, median, standard deviation) plus the *average delta*:
the mean |z_i - z_(i-1)| between consecutive samples. Slow thermal creep inflates the
range and the standard deviation but hardly touches the average delta, so it separates
"the probe is noisy" from "the machine is drifting".
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

SAMPLES_RESULT_CHOICES = ("average", "median")


@dataclass(frozen=True)
class AccuracyStats:
    """PROBE_ACCURACY results, all in mm."""

    count: int
    maximum_mm: float
    minimum_mm: float
    range_mm: float
    average_mm: float
    median_mm: float
    standard_deviation_mm: float
    average_delta_mm: float

    def to_json(self) -> dict:
        return asdict(self)


def accuracy_stats(z_mm: np.ndarray) -> AccuracyStats:
    """Statistics of a series of probe results (in probing order).

    The standard deviation is the population one (divide by n): the samples are the
    whole set being described, not an estimate of a larger population.
    """
    z = np.asarray(z_mm, dtype=float)
    if z.ndim != 1 or z.size == 0:
        raise ValueError("accuracy_stats needs at least one probe result")
    deltas = np.abs(np.diff(z))
    return AccuracyStats(
        count=int(z.size),
        maximum_mm=float(z.max()),
        minimum_mm=float(z.min()),
        range_mm=float(z.max() - z.min()),
        average_mm=float(z.mean()),
        median_mm=float(np.median(z)),
        standard_deviation_mm=float(z.std()),
        average_delta_mm=float(deltas.mean()) if deltas.size else 0.0,
    )


def format_accuracy(stats: AccuracyStats) -> str:
    """The PROBE_ACCURACY result line."""
    return "probe accuracy results: " + _figures(stats)


def format_single_tap_accuracy(stats: AccuracyStats) -> str:
    """The line before a pooled PROBE_ACCURACY result line: the same figures over each tap's own Z."""
    return (f"single-tap results (each tap analysed alone; the results below pool the {stats.count} taps): "
            + _figures(stats))


def _figures(stats: AccuracyStats) -> str:
    return (
        "maximum %.6f, minimum %.6f, range %.6f, average %.6f, "
        "median %.6f, standard deviation %.6f, average delta %.6f"
        % (
            stats.maximum_mm,
            stats.minimum_mm,
            stats.range_mm,
            stats.average_mm,
            stats.median_mm,
            stats.standard_deviation_mm,
            stats.average_delta_mm,
        )
    )


def combine_samples(z_mm: np.ndarray, samples_result: str) -> float:
    """The single result of a multi-sample probe: `average` or `median`."""
    z = np.asarray(z_mm, dtype=float)
    if samples_result == "median":
        return float(np.median(z))
    if samples_result == "average":
        return float(z.mean())
    raise ValueError(f"samples_result must be one of {', '.join(SAMPLES_RESULT_CHOICES)}, not {samples_result!r}")


def spread_mm(z_mm: np.ndarray) -> float:
    """Largest difference between any two samples (what samples_tolerance limits)."""
    z = np.asarray(z_mm, dtype=float)
    return float(z.max() - z.min()) if z.size else 0.0
