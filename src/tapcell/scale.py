"""Load-cell scale math: counts <-> grams, percent of range, saturation, calibration
and the statistics behind LOAD_CELL_DIAGNOSTIC.

Plain functions over numpy arrays and plain dataclasses; no printer, no I/O. The
G-code commands in `tapcell.extras.load_cell` format these results for the user.

Conventions (from the load-cell guide):
* A sensor reports signed integer counts in [min_counts, max_counts]; for the 24-bit
  chips that is [-0x800000, 0x7FFFFF]. A sample at either end is *saturated*.
* "Percent" is counts / max_counts * 100 (the same divisor on both sides), so a
  saturated sample reads +/-100 %.
* grams = orientation * (counts - tare_counts) / counts_per_gram, orientation = +1
  (normal) or -1 (inverted). counts_per_gram is always positive: the user picks the
  orientation (sensor_orientation), calibration only measures the magnitude.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

MAX_COUNTS_24BIT = 0x7FFFFF
MIN_COUNTS_24BIT = -0x800000

# LOAD_CELL_CALIBRATE GRAMS= limits (guide / config reference).
MIN_CALIBRATION_GRAMS = 50.0
MAX_CALIBRATION_GRAMS = 25000.0
# counts_per_gram below 1 would mean a sensor with less than 1 count per gram.
MIN_COUNTS_PER_GRAM = 1.0
# A calibration load must move the reading by at least this share of the range.
MIN_CALIBRATION_DIFFERENCE_PERCENT = 1.0
# A tare further than this from 0 % suggests wiring trouble or a preload.
TARE_WARNING_PERCENT = 2.0
# The capacity a sane calibration gives, for warnings.
MIN_SENSIBLE_CAPACITY_KG = 1.0
MAX_SENSIBLE_CAPACITY_KG = 25.0


@dataclass(frozen=True)
class CountsRange:
    """The raw counts a sensor can report; its ends mean saturation."""

    min_counts: int = MIN_COUNTS_24BIT
    max_counts: int = MAX_COUNTS_24BIT


SENSOR_24BIT = CountsRange()


def orientation_sign(inverted: bool) -> int:
    return -1 if inverted else 1


def counts_to_percent(counts, counts_range: CountsRange = SENSOR_24BIT):
    """Share of the sensor's positive full scale, in percent (float or array)."""
    return np.asarray(counts, dtype=np.float64) / counts_range.max_counts * 100.0


def saturated_mask(counts, counts_range: CountsRange = SENSOR_24BIT) -> np.ndarray:
    """True where a sample sits at (or beyond) either end of the sensor's range."""
    counts = np.asarray(counts, dtype=np.int64)
    return (counts >= counts_range.max_counts) | (counts <= counts_range.min_counts)


def counts_to_grams(counts, tare_counts: float, counts_per_gram: float, inverted: bool = False):
    """Force in grams relative to `tare_counts` (float or array)."""
    delta = np.asarray(counts, dtype=np.float64) - float(tare_counts)
    return orientation_sign(inverted) * delta / float(counts_per_gram)


def grams_to_counts(grams, tare_counts: float, counts_per_gram: float, inverted: bool = False):
    """Inverse of counts_to_grams (float counts; round where integers are needed)."""
    return float(tare_counts) + orientation_sign(inverted) * np.asarray(grams, dtype=np.float64) * float(
        counts_per_gram
    )


def counts_per_gram_from(tare_counts: float, loaded_counts: float, grams: float) -> float:
    """Counts per gram from a tare reading and a reading under a known load.

    Always positive: the direction of the change is the orientation's business.
    """
    return abs(float(loaded_counts) - float(tare_counts)) / float(grams)


def capacity_kg(tare_counts: float, counts_per_gram: float, counts_range: CountsRange = SENSOR_24BIT) -> float:
    """The largest force the sensor can still register from this tare, in kg.

    Uses the nearer end of the range (the smaller headroom), so it is the force that
    is safe in both directions.
    """
    headroom_counts = min(counts_range.max_counts - tare_counts, tare_counts - counts_range.min_counts)
    return max(headroom_counts, 0.0) / counts_per_gram / 1000.0


@dataclass(frozen=True)
class CalibrationResult:
    """The outcome of CALIBRATE GRAMS=: the numbers, or the reason it was refused."""

    grams: float
    tare_counts: float
    loaded_counts: float
    counts_per_gram: float | None
    capacity_kg: float | None
    error: str | None
    warnings: tuple[str, ...]


def evaluate_calibration(
    tare_counts: float,
    loaded_counts: float,
    grams: float,
    any_saturated: bool,
    inverted: bool = False,
    counts_range: CountsRange = SENSOR_24BIT,
    higher_gain: str | None = None,
) -> CalibrationResult:
    """Checks a calibration reading and derives counts_per_gram and the capacity.

    Refused (error set, no numbers): a saturated reading, a reading identical to the
    tare, or one less than 1 % of the range away from it (too little force or gain
    for a trustworthy slope). Warnings: capacity under 1 kg; over 25 kg when the sensor has
    a higher gain to set (`higher_gain`, its name; None: already the highest, so nothing to
    advise); and a reading that moved the opposite way to the configured orientation.
    """

    def refused(message: str) -> CalibrationResult:
        return CalibrationResult(grams, tare_counts, loaded_counts, None, None, message, ())

    if any_saturated:
        return refused(
            "ERROR: Sensor is saturated with too much load! Use less force for calibration."
        )
    if int(loaded_counts) == int(tare_counts):
        return refused(
            "ERROR: Tare and Calibration readings are the same! Check the wiring and that the"
            " force really rests on the load cell."
        )
    difference_percent = abs(
        float(counts_to_percent(loaded_counts, counts_range)) - float(counts_to_percent(tare_counts, counts_range))
    )
    if difference_percent < MIN_CALIBRATION_DIFFERENCE_PERCENT:
        return refused(
            f"ERROR: Tare and Calibration readings are less than 1% different! ({difference_percent:.2f}%)"
            " Use more force, or a higher gain setting."
        )
    cpg = counts_per_gram_from(tare_counts, loaded_counts, grams)
    capacity = capacity_kg(tare_counts, cpg, counts_range)
    warnings = []
    if capacity < MIN_SENSIBLE_CAPACITY_KG:
        warnings.append(
            f"WARNING: Load cell capacity is less than {MIN_SENSIBLE_CAPACITY_KG:g}kg! A probing tap or"
            " a heavy object may saturate the sensor; consider a lower gain setting."
        )
    if capacity > MAX_SENSIBLE_CAPACITY_KG and higher_gain is not None:
        warnings.append(
            f"WARNING: Load cell capacity is more than {MAX_SENSIBLE_CAPACITY_KG:g}kg! Readings will be"
            f" coarse; consider a higher gain setting (gain: {higher_gain}) or a more sensitive load cell."
        )
    pressed_positive = loaded_counts > tare_counts
    if pressed_positive == inverted:
        # Under load the reading moved the way the orientation calls "negative":
        # forces would come out with the wrong sign.
        warnings.append(
            "WARNING: The reading moved the opposite way to sensor_orientation: "
            f"{'inverted' if inverted else 'normal'}, so forces would read negative."
            f" Set sensor_orientation: {'normal' if inverted else 'inverted'}."
        )
    return CalibrationResult(grams, tare_counts, loaded_counts, cpg, capacity, None, tuple(warnings))


def tare_warning(tare_counts: float, counts_range: CountsRange = SENSOR_24BIT) -> str | None:
    """Warns (on either side of zero) when the unloaded reading is far from 0 %."""
    percent = float(counts_to_percent(tare_counts, counts_range))
    if abs(percent) <= TARE_WARNING_PERCENT:
        return None
    return (
        f"WARNING: tare value is more than {TARE_WARNING_PERCENT:g}% away from 0! ({percent:.2f}%)"
        " The load cell may be preloaded or miswired; check that nothing rests on it and"
        " that the wiring is correct."
    )


@dataclass(frozen=True)
class DiagnosticStats:
    """What LOAD_CELL_DIAGNOSTIC reports about a batch of samples."""

    samples_collected: int
    measured_rate_sps: float | None  # None with fewer than 3 samples (no meaningful span)
    good_samples: int
    saturated_samples: int
    unique_values: int
    min_percent: float
    max_percent: float
    range_share_of_capacity_percent: float  # (max% - min%) / 2: the span over the full +/-100 % range
    min_g: float | None  # None until calibrated
    max_g: float | None


def measured_rate_sps(t_s: np.ndarray) -> float | None:
    """Samples per second over the span of the timestamps (N samples / (t_last - t_first))."""
    t_s = np.asarray(t_s, dtype=np.float64)
    if t_s.size < 3 or t_s[-1] <= t_s[0]:
        return None
    return t_s.size / float(t_s[-1] - t_s[0])


def diagnostic_statistics(
    t_s: np.ndarray,
    counts: np.ndarray,
    *,
    tare_counts: float | None = None,
    counts_per_gram: float | None = None,
    inverted: bool = False,
    counts_range: CountsRange = SENSOR_24BIT,
) -> DiagnosticStats:
    """Health statistics of a sample batch. Grams only when calibrated and tared."""
    counts = np.asarray(counts, dtype=np.int64)
    if counts.size == 0:
        raise ValueError("no samples to analyse")
    saturated = int(np.count_nonzero(saturated_mask(counts, counts_range)))
    lo_counts, hi_counts = int(counts.min()), int(counts.max())
    min_percent = float(counts_to_percent(lo_counts, counts_range))
    max_percent = float(counts_to_percent(hi_counts, counts_range))
    min_g = max_g = None
    if counts_per_gram is not None and tare_counts is not None:
        grams_at_ends = counts_to_grams(np.array([lo_counts, hi_counts]), tare_counts, counts_per_gram, inverted)
        min_g, max_g = float(grams_at_ends.min()), float(grams_at_ends.max())
    return DiagnosticStats(
        samples_collected=int(counts.size),
        measured_rate_sps=measured_rate_sps(t_s),
        good_samples=int(counts.size) - saturated,
        saturated_samples=saturated,
        unique_values=int(np.unique(counts).size),
        min_percent=min_percent,
        max_percent=max_percent,
        range_share_of_capacity_percent=(max_percent - min_percent) / 2.0,
        min_g=min_g,
        max_g=max_g,
    )
