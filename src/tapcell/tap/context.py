"""What the analysis and the classifiers share: the sensor timing, the analysis context handed
to a classifier, and the geometry of the five lines (their intersections, the six points).

Kept apart so the analysis (which runs the classifier) and the classifiers (which may replace
the lines and need the points recomputed) do not import each other.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from tapcell.tap.model import TapData
from tapcell.tap.motion import Motion


@dataclass(eq=False, repr=False)
class SensorTiming:
    """How the sensor's samples lag and average the motion, as this tap is analysed with."""

    delay_s: float
    integration_s: float
    estimate_delay: bool  # "auto": from contact vs break contact
    delay_from_halt: bool  # from the halt (tapcell.tap.toe.lag_from_halt_s)
    sample_period_s: float
    z_step_um: float  # Z resolution of the steppers (the staircase the model does not see)


@dataclass(eq=False, repr=False)
class AnalysisContext:
    """What a classifier may need beyond the result: the tap, its motion and sensor timing."""

    tap: TapData
    motion: Motion | None
    timing: SensorTiming | None


def line_intersection(a: tuple[float, float], b: tuple[float, float], t_ref: float) -> tuple[float, float]:
    """Intersection of two lines; computed around t_ref so large clock values lose nothing."""
    slope_diff = a[0] - b[0]
    if slope_diff == 0:
        return math.nan, math.nan
    fa, fb = a[0] * t_ref + a[1], b[0] * t_ref + b[1]
    dt = (fb - fa) / slope_diff
    return t_ref + dt, fa + a[0] * dt


def _line_at(line: tuple[float, float], t: float) -> float:
    return line[0] * t + line[1]


def recompute_points(lines: list[tuple[float, float]], t_first: float, t_last: float) -> list[tuple[float, float]]:
    """P0 on the approach line at the window start, P1..P4 the intersections, P5 on the departure."""
    t_mid = 0.5 * (t_first + t_last)
    points = [(t_first, _line_at(lines[0], t_first))]
    points += [line_intersection(lines[k], lines[k + 1], t_mid) for k in range(4)]
    points.append((t_last, _line_at(lines[4], t_last)))
    return points
