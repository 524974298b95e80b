"""Mesh points far from their neighbours: where a trigger-only probe may have been fooled.

A threshold probe (METHOD=two_pass, METHOD=prusa) has no tap shape to judge, so a push on
the nozzle in the air (a touch, a tug on the bowden tube, a jump of the ADC's offset) can
stop it millimetres above the bed. Beds are smooth between mesh points: a point is compared
with the plane through its neighbours (the points within 1.5 grid spacings, least squares),
and the one furthest from its plane is the first to probe again.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from tapcell.mesh.errors import MeshError

NEIGHBOUR_SPACINGS = 1.5   # neighbours: within this many nearest-point spacings (diagonals included)
# A point further than this from its neighbours' plane is probed again. On the virtual printer's
# warped bed (0.25 mm modes) honest points lie up to 0.18 mm off at 7 x 7 and 0.77 mm at 3 x 3:
# those cost a second probe each, which then agrees.
OUTLIER_MM = 0.15


def neighbour_residuals_mm(points_xy_mm: np.ndarray, z_mm: np.ndarray) -> np.ndarray:
    """|z - the plane fitted through each point's neighbours| at each point (0 with < 3 neighbours)."""
    xy = np.asarray(points_xy_mm, dtype=float)
    z = np.asarray(z_mm, dtype=float)
    distance = np.hypot(xy[:, 0, None] - xy[None, :, 0], xy[:, 1, None] - xy[None, :, 1])
    np.fill_diagonal(distance, np.inf)
    if len(z) < 4:
        return np.zeros(len(z))
    spacing = float(np.min(distance))
    residuals = np.zeros(len(z))
    for i in range(len(z)):
        near = np.flatnonzero(distance[i] <= NEIGHBOUR_SPACINGS * spacing)
        if len(near) < 3:
            continue
        design = np.column_stack([np.ones(len(near)), xy[near, 0] - xy[i, 0], xy[near, 1] - xy[i, 1]])
        coefficients, _, rank, _ = np.linalg.lstsq(design, z[near], rcond=None)
        if rank == 3:  # neighbours on one line give no plane
            residuals[i] = abs(z[i] - coefficients[0])
    return residuals


def worst_outlier(points_xy_mm: np.ndarray, z_mm: np.ndarray, settled: set[int],
                  limit_mm: float = OUTLIER_MM) -> int | None:
    """The index of the point furthest from its neighbours beyond limit_mm, leaving out `settled`
    points (probed again and confirmed); None when no such point is left."""
    residuals = neighbour_residuals_mm(points_xy_mm, z_mm)
    residuals[list(settled)] = 0.0
    worst = int(np.argmax(residuals))
    return worst if residuals[worst] > limit_mm else None


class UnsettledPointError(MeshError):
    """A point far from its neighbours was probed three times and no two heights agreed."""


def recheck_outliers(points_xy_mm: np.ndarray, z_mm: list[float], probe_again: Callable[[int], float],
                     tolerance_mm: float, say: Callable[[str], None]) -> list[float]:
    """Probe the point furthest from its neighbours again until none is left (`worst_outlier`).

    It keeps its height when the new probe (`probe_again(index)`) agrees within tolerance_mm;
    otherwise a third probe must agree with the second and replaces it (`say` tells the user);
    three heights that all disagree raise UnsettledPointError. Returns the heights (probing order).
    """
    z = list(z_mm)
    settled: set[int] = set()
    while (index := worst_outlier(points_xy_mm, z, settled)) is not None:
        x_mm, y_mm = points_xy_mm[index]
        first = z[index]
        second = probe_again(index)
        if abs(second - first) > tolerance_mm:
            third = probe_again(index)
            if abs(third - second) > tolerance_mm:
                raise UnsettledPointError(
                    f"point {index + 1} at {x_mm:.3f},{y_mm:.3f} gave {first:.3f}, {second:.3f} and {third:.3f} mm: "
                    "something keeps pushing on the nozzle or the sensor jumps; check the toolhead and the load cell")
            say(f"Point {index + 1} at {x_mm:.3f},{y_mm:.3f}: {first:.3f} mm was far from its neighbours; probed "
                f"again: {second:.3f} and {third:.3f} mm")
            z[index] = third
        settled.add(index)
    return z
