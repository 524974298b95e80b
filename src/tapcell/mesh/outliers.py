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


def neighbour_planes(points_xy_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each point's neighbours' plane as weights on their heights: (W, has_plane), W (n, n) with row
    i giving the least-squares plane through point i's neighbours, evaluated at point i, as W[i] @ z.
    has_plane is False where there are fewer than 3 neighbours or they lie on one line. The weights
    depend on the positions only, so a mesh computes them once however often its heights change."""
    xy = np.asarray(points_xy_mm, dtype=float)
    n = len(xy)
    weights = np.zeros((n, n))
    has_plane = np.zeros(n, dtype=bool)
    if n < 4:
        return weights, has_plane
    distance = np.hypot(xy[:, 0, None] - xy[None, :, 0], xy[:, 1, None] - xy[None, :, 1])
    np.fill_diagonal(distance, np.inf)
    spacing = float(np.min(distance))
    for i in range(n):
        near = np.flatnonzero(distance[i] <= NEIGHBOUR_SPACINGS * spacing)
        if len(near) < 3:
            continue
        design = np.column_stack([np.ones(len(near)), xy[near, 0] - xy[i, 0], xy[near, 1] - xy[i, 1]])
        if np.linalg.matrix_rank(design) == 3:  # neighbours on one line give no plane
            weights[i, near] = np.linalg.pinv(design)[0]  # the fitted plane's height at point i
            has_plane[i] = True
    return weights, has_plane


def neighbour_residuals_mm(points_xy_mm: np.ndarray, z_mm: np.ndarray,
                           planes: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """|z - the plane fitted through each point's neighbours| at each point (0 without a plane).
    planes: `neighbour_planes(points_xy_mm)` when already computed."""
    weights, has_plane = neighbour_planes(points_xy_mm) if planes is None else planes
    z = np.asarray(z_mm, dtype=float)
    return np.where(has_plane, np.abs(z - weights @ z), 0.0)


def worst_outlier(points_xy_mm: np.ndarray, z_mm: np.ndarray, settled: set[int],
                  limit_mm: float = OUTLIER_MM, planes: tuple[np.ndarray, np.ndarray] | None = None) -> int | None:
    """The index of the point furthest from its neighbours beyond limit_mm, leaving out `settled`
    points (probed again and confirmed); None when no such point is left."""
    residuals = neighbour_residuals_mm(points_xy_mm, z_mm, planes)
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
    planes = neighbour_planes(points_xy_mm)  # the positions do not change between passes
    while (index := worst_outlier(points_xy_mm, z, settled, planes=planes)) is not None:
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
