"""Robust statistics shared by the tap analysis, the hum fit and the probe's tare."""

from __future__ import annotations

import numpy as np

from tapcell.tap import native

_C = native.load("analysis")  # the same statistics in C (tapcell.tap.native); None: numpy

# The median absolute deviation of normal noise times this is its sigma (1 / Phi^-1(3/4)).
MAD_TO_SIGMA = 1.4826


def median(values: np.ndarray) -> float:
    """np.median without its call overhead (a partition of a copy; the mean of the middle two for even n)."""
    if _C is not None and values.dtype == np.float64 and values.flags.c_contiguous:
        return _C.median(values)
    half = len(values) // 2
    ordered = values.copy()  # the method, not np.partition: no Python wrapper in between
    if len(values) % 2:
        ordered.partition(half)
        return float(ordered[half])
    ordered.partition((half - 1, half))
    return 0.5 * float(ordered[half - 1] + ordered[half])


def robust_sigma(deviations: np.ndarray) -> float:
    """Sigma of normal noise from the median absolute deviation: 1.4826 x median |deviation|.

    `deviations` are measured from the centre (residuals of a fit, or values minus their
    median); outliers up to half the samples cannot inflate it.
    """
    return MAD_TO_SIGMA * median(np.abs(deviations))
