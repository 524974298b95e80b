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


# A coarse converter (a low gain, a big load cell, readings in whole grams) rounds every reading to
# a step. Once the step nears the noise, |deviations| sit on a lattice of it and their median lands
# on a lattice value: 0 where most readings repeat, which reads as a noiseless sensor (a reference
# ADS1220 660 sps tap in 3 g steps: "more than 4 x the 0.00 g noise", TAP_ADHESION). Read as grouped
# data, interpolated within its step, the median follows the noise and the rounding together
# (sqrt(sigma² + step²/12) to 5 % up to a step of twice the noise). The C twin: median.h.
LATTICE_STEP_SHARE = 0.05  # a step finer than this share of the median leaves the median as it is
ON_LATTICE = 0.05  # a value within this share of a step of a multiple of it is on the lattice
LATTICE_SHARE_MIN = 0.9  # of the values above zero, at least this share on the lattice
LATTICE_MIN_VALUES = 8  # and at least this many (a reading frozen but a few times is no step)
LATTICE_BINS = 32  # a step over a twentieth of the median puts it in bin 20 at most
LATTICE_MAX_DOUBLINGS = 8  # repairs between repairs: a step at most 256 times the smallest value


def _on_lattice(values: np.ndarray, step: float) -> int:
    """How many of `values` lie within ON_LATTICE of a multiple of `step`."""
    ratio = values / step
    return int(np.count_nonzero(np.abs(ratio - np.floor(ratio + 0.5)) <= ON_LATTICE))


def lattice_step(values: np.ndarray, median_value: float) -> float | None:
    """The step of the lattice non-negative `values` sit on, where it is coarse against their median
    (`median_value`; see LATTICE_STEP_SHARE), else None."""
    if len(values) == 0:
        return None
    # What lies at or under `tiny` is the difference of equal readings left in the last bits: a
    # billionth of the median, or where the median is 0, of the largest value.
    if median_value > 0:
        tiny = 1e-9 * median_value
        if np.any((values > tiny) & (values <= LATTICE_STEP_SHARE * median_value)):
            return None  # a value finer than a lattice coarse against the median could be
    else:
        tiny = 1e-9 * max(float(values.max()), 0.0)
    above = values[values > tiny]
    if len(above) < LATTICE_MIN_VALUES:
        return None
    step = float(above.min())
    if not step > LATTICE_STEP_SHARE * median_value:
        return None
    if _on_lattice(above, step) < LATTICE_SHARE_MIN * len(above):
        return None
    # The coarsest lattice most values keep: a spike repaired to its neighbours' mean puts a few
    # values halfway between, and the smallest value alone would halve the step.
    for _ in range(LATTICE_MAX_DOUBLINGS):
        if _on_lattice(above, 2.0 * step) < LATTICE_SHARE_MIN * len(above):
            break
        step *= 2.0
    return step


def grouped_median(values: np.ndarray, median_value: float) -> float:
    """The median of non-negative `values` (`median_value`: their median) read as grouped data where
    they sit on a lattice coarse against it (`lattice_step`), else `median_value`."""
    step = lattice_step(values, median_value)
    if step is None:
        return median_value
    multiple = np.floor(values / step + 0.5)  # 0 for the values at zero, and for those below half a step
    counts = np.bincount(np.minimum(multiple, LATTICE_BINS - 1).astype(np.intp), minlength=LATTICE_BINS)
    # bin 0 holds [0, step / 2), bin j [(j - 1/2) step, (j + 1/2) step): where the half count falls
    half = 0.5 * len(values)
    below, bin_ = 0, 0
    while bin_ < LATTICE_BINS - 1 and below + counts[bin_] <= half:
        below += int(counts[bin_])
        bin_ += 1
    low, width = (0.0, 0.5 * step) if bin_ == 0 else ((bin_ - 0.5) * step, step)
    return low + (half - below) / int(counts[bin_]) * width


def robust_sigma(deviations: np.ndarray) -> float:
    """Sigma of normal noise from the median absolute deviation: 1.4826 x median |deviation|.

    `deviations` are measured from the centre (residuals of a fit, or values minus their
    median); outliers up to half the samples cannot inflate it.
    """
    return MAD_TO_SIGMA * median(np.abs(deviations))
