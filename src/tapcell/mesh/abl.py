"""Two-pass automatic bed levelling, as in the load-cell ABL paper.

At each point the nozzle descends fast until contact (z1), backs off 1 mm, descends again
slowly at 8 mm/s (z2), and lifts before travelling to the next point. A faster descent
overshoots more before the contact is seen, so the two readings differ; the paper keeps
the weighted value

    z = 0.4 * z1 + 0.6 * z2

(its Table 1 agrees to the last digit). Both descents stop at a travel limit; reaching it
without contact means the bed is not where it should be, and probing stops with
`NoContactError` instead of driving the nozzle further.

The plan is plain data (`point_plan`); `run_two_pass` walks it with a caller-supplied
function that performs one move, which keeps this module free of any hardware.
The topology report summarises the result like the paper's: extremes with their
position, range, mean, and a least-squares tilt plane with what remains after removing it.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from tapcell.mesh.errors import MeshError

FAST_PASS = "fast"
SLOW_PASS = "slow"


@dataclass(frozen=True)
class TwoPassSettings:
    """The paper's numbers by default: Z-2 limit, 120 mm/s fast, 1 mm back-off, 8 mm/s slow, 3 mm lift."""

    travel_limit_z_mm: float = -2.0
    fast_speed_mm_s: float = 120.0
    slow_speed_mm_s: float = 8.0
    back_off_mm: float = 1.0
    lift_mm: float = 3.0
    travel_speed_mm_s: float = 50.0
    fast_weight: float = 0.4

    def __post_init__(self) -> None:
        for name in ("fast_speed_mm_s", "slow_speed_mm_s", "back_off_mm", "lift_mm", "travel_speed_mm_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise MeshError(f"two-pass ABL setting {name} = {value}: must be a positive number")
        if not math.isfinite(self.travel_limit_z_mm):
            raise MeshError(f"two-pass ABL setting travel_limit_z_mm = {self.travel_limit_z_mm}: must be a number")
        if not 0.0 <= self.fast_weight <= 1.0:
            raise MeshError(f"two-pass ABL setting fast_weight = {self.fast_weight}: must be between 0 and 1")


@dataclass(frozen=True)
class PlanStep:
    """One move of the plan.

    kind "travel": move to (x, y) at the current height; "probe": descend toward z_mm (the
    travel limit) and stop at contact; "retract": move up by z_mm from where the nozzle is.
    """

    kind: str
    x_mm: float
    y_mm: float
    z_mm: float
    speed_mm_s: float
    pass_name: str = ""


def weighted_z_mm(z_fast_mm: float | np.ndarray, z_slow_mm: float | np.ndarray, fast_weight: float = 0.4) -> float | np.ndarray:
    """The paper's equation (1): fast_weight * z1 + (1 - fast_weight) * z2."""
    return fast_weight * z_fast_mm + (1.0 - fast_weight) * z_slow_mm


def point_plan(x_mm: float, y_mm: float, settings: TwoPassSettings) -> tuple[PlanStep, ...]:
    """The moves for one point: travel, fast probe, back off, slow probe, lift."""
    limit = settings.travel_limit_z_mm
    return (
        PlanStep("travel", x_mm, y_mm, math.nan, settings.travel_speed_mm_s),
        PlanStep("probe", x_mm, y_mm, limit, settings.fast_speed_mm_s, FAST_PASS),
        PlanStep("retract", x_mm, y_mm, settings.back_off_mm, settings.slow_speed_mm_s),
        PlanStep("probe", x_mm, y_mm, limit, settings.slow_speed_mm_s, SLOW_PASS),
        PlanStep("retract", x_mm, y_mm, settings.lift_mm, settings.travel_speed_mm_s),
    )


@dataclass(frozen=True)
class TwoPassPoint:
    index: int
    x_mm: float
    y_mm: float
    z_fast_mm: float
    z_slow_mm: float
    z_mm: float

    def to_status(self) -> dict:
        return {
            "index": self.index,
            "x_mm": self.x_mm,
            "y_mm": self.y_mm,
            "z_fast_mm": self.z_fast_mm,
            "z_slow_mm": self.z_slow_mm,
            "z_mm": self.z_mm,
        }


class NoContactError(RuntimeError):
    """A probing descent reached the travel limit without contact; probing must stop."""

    def __init__(self, index: int, point_count: int, x_mm: float, y_mm: float, pass_name: str, travel_limit_z_mm: float):
        self.index = index
        self.x_mm = x_mm
        self.y_mm = y_mm
        self.pass_name = pass_name
        self.travel_limit_z_mm = travel_limit_z_mm
        super().__init__(
            f"no contact at point {index + 1} of {point_count} (X={x_mm:.3f} Y={y_mm:.3f}) on the {pass_name} pass "
            f"before the travel limit Z={travel_limit_z_mm:.3f} mm: probing stopped"
        )


# Performs one plan step; for "probe" steps returns the contact Z, or None if the travel
# limit was reached without contact. The return value of other steps is ignored.
MoveFn = Callable[[PlanStep], float | None]


def run_two_pass(points_xy_mm: Sequence[Sequence[float]] | np.ndarray, move: MoveFn, settings: TwoPassSettings) -> list[TwoPassPoint]:
    """Probe every point with the two-pass plan; raises NoContactError at the first miss."""
    results = []
    for index, (x_mm, y_mm) in enumerate(points_xy_mm):
        contacts: dict[str, float] = {}
        for step in point_plan(float(x_mm), float(y_mm), settings):
            outcome = move(step)
            if step.kind != "probe":
                continue
            if outcome is None:
                raise NoContactError(index, len(points_xy_mm), float(x_mm), float(y_mm), step.pass_name, step.z_mm)
            contacts[step.pass_name] = float(outcome)
        z_fast, z_slow = contacts[FAST_PASS], contacts[SLOW_PASS]
        results.append(
            TwoPassPoint(index, float(x_mm), float(y_mm), z_fast, z_slow, weighted_z_mm(z_fast, z_slow, settings.fast_weight))
        )
    return results


@dataclass(frozen=True)
class TopologyReport:
    """The bed surface in numbers. Tilt is the least-squares plane z = a + b x + c y."""

    point_count: int
    min_z_mm: float
    min_at_xy_mm: tuple[float, float]
    max_z_mm: float
    max_at_xy_mm: tuple[float, float]
    range_mm: float
    mean_z_mm: float
    tilt_x_mm_per_mm: float
    tilt_y_mm_per_mm: float
    tilt_deg: float
    plane_z_at_center_mm: float
    flatness_after_tilt_mm: float
    residual_rms_mm: float

    def to_status(self) -> dict:
        return {
            "point_count": self.point_count,
            "min_z_mm": self.min_z_mm,
            "min_at_xy_mm": list(self.min_at_xy_mm),
            "max_z_mm": self.max_z_mm,
            "max_at_xy_mm": list(self.max_at_xy_mm),
            "range_mm": self.range_mm,
            "mean_z_mm": self.mean_z_mm,
            "tilt_x_mm_per_mm": self.tilt_x_mm_per_mm,
            "tilt_y_mm_per_mm": self.tilt_y_mm_per_mm,
            "tilt_deg": self.tilt_deg,
            "plane_z_at_center_mm": self.plane_z_at_center_mm,
            "flatness_after_tilt_mm": self.flatness_after_tilt_mm,
            "residual_rms_mm": self.residual_rms_mm,
        }


def topology_report(x_mm: np.ndarray, y_mm: np.ndarray, z_mm: np.ndarray) -> TopologyReport:
    """Summarise measured bed heights at (x, y); needs 3 points not on one line for the tilt."""
    x, y, z = (np.asarray(v, dtype=float).ravel() for v in (x_mm, y_mm, z_mm))
    if not (x.size == y.size == z.size):
        raise MeshError(f"topology report needs as many x, y and z values; got {x.size}, {y.size}, {z.size}")
    if not np.all(np.isfinite(np.concatenate((x, y, z)))):
        raise MeshError("topology report: a position or height is not a finite number")
    # Centre the coordinates so the intercept is the plane's height in the middle of the points.
    center_x, center_y = x.mean(), y.mean()
    design = np.column_stack((np.ones_like(x), x - center_x, y - center_y))
    if x.size < 3 or np.linalg.matrix_rank(design) < 3:
        raise MeshError("topology report needs at least 3 points that are not on one line to fit the tilt")
    (height, slope_x, slope_y), *_ = np.linalg.lstsq(design, z, rcond=None)
    residual = z - design @ np.array([height, slope_x, slope_y])
    low, high = int(np.argmin(z)), int(np.argmax(z))
    return TopologyReport(
        point_count=int(z.size),
        min_z_mm=float(z[low]),
        min_at_xy_mm=(float(x[low]), float(y[low])),
        max_z_mm=float(z[high]),
        max_at_xy_mm=(float(x[high]), float(y[high])),
        range_mm=float(z[high] - z[low]),
        mean_z_mm=float(z.mean()),
        tilt_x_mm_per_mm=float(slope_x),
        tilt_y_mm_per_mm=float(slope_y),
        tilt_deg=math.degrees(math.atan(math.hypot(slope_x, slope_y))),
        plane_z_at_center_mm=float(height),
        flatness_after_tilt_mm=float(residual.max() - residual.min()),
        residual_rms_mm=float(np.sqrt(np.mean(residual**2))),
    )
