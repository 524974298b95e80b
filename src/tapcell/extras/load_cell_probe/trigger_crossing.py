"""Sub-sample trigger timing: when the force really crossed a trigger-only probe's threshold.

The firmware trigger fires on the first sample whose filtered force passes the threshold, so
the trigger time (that sample's timestamp) lands on the sensor's sample grid: where the nozzle
is at that time depends on where in a conversion the contact fell. At 8 mm/s and 320 samples/s
that is 25 um of travel per sample, and a trigger-only height read at the trigger time, or at
the halt after it, moves by up to that much between two descents onto the same spot.

Between the sample before the trigger (below the threshold) and the triggering one (at or past
it) the force rises almost linearly: a conversion averages the force over its window, and the
window average of a ramp is the ramp at the window's middle (also for the window that holds the
contact's kink, within 0.4 um at 75 g and 80 g per sample, the virtual printer's fast pass). So
the force crossed the threshold where the straight line between the two samples, placed at
their windows' middles, crosses it. Each sample's window middle is its read time less the
read delay (the MCU polls data-ready ten times a period: on average half of `read_delay_s`),
the chip's pipeline and half a period (`safety.StopTiming`, the probe's own model of the
sensor). The firmware's filtered force is what crossed: `replay_filtered_g` runs the firmware
trigger (the real C code, armed as for the move) over the move's samples to get it.

The crossing time, not the trigger time, then gives the trigger-only height from the move's
own trapezoids: a height that no longer depends on the sample phase.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tapcell.extras.load_cell_probe.safety import StopTiming
from tapcell.mcu.trigger import FirmwareTrigger, TriggerError, TriggerParams


@dataclass(frozen=True)
class ThresholdCrossing:
    """Where the filtered force crossed the threshold, between two samples."""

    time_s: float            # motion time of the crossing (comparable with the move's trapezoids)
    trigger_time_s: float    # the firmware's trigger time (the triggering sample's read time)
    fraction: float          # 0: at the sample before the trigger's window middle, 1: at the trigger's
    interpolated: bool       # False: no usable sample before the trigger; time_s is the trigger's window middle


# The chip's sample grid is fitted to this many samples before the trigger; with fewer the
# read delay is taken as its mean (half the longest).
GRID_FIT_SAMPLES = 64
GRID_FIT_MIN_SAMPLES = 16


def window_middle_times_s(read_times_s: np.ndarray | float, timing: StopTiming) -> np.ndarray:
    """When the motion was where a sample shows it: the middle of its conversion window, from
    its read time less the mean read delay, the chip's pipeline and half a period."""
    return (np.asarray(read_times_s, dtype=float) - 0.5 * timing.read_delay_s - timing.pipeline_s
            - 0.5 * timing.period_s)


def data_ready_times_s(read_times_s: np.ndarray, period_s: float) -> np.ndarray:
    """The chip's data-ready instants behind a run of samples' read times.

    The chip converts back to back on its own clock, so data-ready falls on a regular grid; the
    MCU reads each sample a little after it (polling, task latency), by a different delay each
    time. The grid is fitted to the read times (the chip's period as it really runs, from the
    slope) and put at their lower edge: the least-delayed reads sit almost on it. A sample
    missing from the run (a refused frame) leaves a gap of whole periods."""
    t_s = np.asarray(read_times_s, dtype=float)
    index = np.concatenate(([0.0], np.cumsum(np.maximum(np.round(np.diff(t_s) / period_s), 1.0))))
    slope_s, intercept_s = np.polyfit(index, t_s, 1)
    grid_s = intercept_s + slope_s * index
    return grid_s + np.min(t_s - grid_s)


def sample_window_middles_s(read_times_s: np.ndarray, timing: StopTiming) -> np.ndarray:
    """The window middles of the last samples of a move (up to GRID_FIT_SAMPLES): from the fitted
    data-ready grid when there are GRID_FIT_MIN_SAMPLES, else from each read time (`window_middle_times_s`)."""
    t_s = np.asarray(read_times_s, dtype=float)[-GRID_FIT_SAMPLES:]
    if t_s.size < GRID_FIT_MIN_SAMPLES:
        return window_middle_times_s(t_s, timing)
    return data_ready_times_s(t_s, timing.period_s) - timing.pipeline_s - 0.5 * timing.period_s


def threshold_crossing(read_times_s: np.ndarray, filtered_g: np.ndarray, threshold_g: float,
                       timing: StopTiming) -> ThresholdCrossing:
    """The crossing between the last two samples of a triggered move (the last one triggered).

    `read_times_s`, `filtered_g`: the move's samples up to the trigger (their read times and the
    firmware's filtered force). The trigger passes when |force| reaches the threshold, so the
    crossing is found on the triggering sample's side (a press is positive). Without a sample
    before the trigger, or when the force did not rise between the two (noise on a trigger
    that fired at once), the trigger's own window middle is the answer.
    """
    t_s = np.asarray(read_times_s, dtype=float)
    force_g = np.asarray(filtered_g, dtype=float)
    if t_s.size == 0 or t_s.size != force_g.size:
        raise ValueError(f"threshold_crossing needs the triggering sample: {t_s.size} times, {force_g.size} forces")
    middles = sample_window_middles_s(t_s, timing)
    trigger_time_s = float(t_s[-1])
    sign = 1.0 if force_g[-1] >= 0 else -1.0
    if t_s.size < 2:
        return ThresholdCrossing(float(middles[-1]), trigger_time_s, 1.0, False)
    before_g, after_g = sign * force_g[-2], sign * force_g[-1]
    rise_g = after_g - before_g
    if not rise_g > 0.0:
        return ThresholdCrossing(float(middles[-1]), trigger_time_s, 1.0, False)
    fraction = float(np.clip((threshold_g - before_g) / rise_g, 0.0, 1.0))
    time_s = float(middles[-2] + fraction * (middles[-1] - middles[-2]))
    return ThresholdCrossing(time_s, trigger_time_s, fraction, True)


def replay_filtered_g(params: TriggerParams, tare_counts: float, arm_time_s: float, read_times_s: np.ndarray,
                      counts: np.ndarray, trigger_time_s: float) -> tuple[np.ndarray, np.ndarray] | None:
    """The firmware's filtered force for the samples of a move up to its trigger: the firmware
    trigger armed again as it was (`params`, tare, arm time) and fed the same samples. Returns
    (read times, filtered force in grams) of the samples it consumed, the last the triggering
    one; None when the replay does not trigger on the sample the firmware reported (samples
    missing from the host's copy): then there is nothing to interpolate between."""
    trigger = FirmwareTrigger(params)
    if trigger.arm(int(round(tare_counts)), arm_time_s) != TriggerError.NONE:
        return None
    t_s = np.asarray(read_times_s, dtype=float)
    keep = (t_s > arm_time_s) & (t_s <= trigger_time_s)  # the samples the MCU fed it after the arm
    t_s = t_s[keep]
    result = trigger.feed(t_s, np.asarray(counts)[keep].astype(np.int64), want_filtered=True)
    if result.trigger_index is None or t_s[result.trigger_index] != trigger_time_s:
        return None
    return t_s[:result.consumed], result.filtered_g
