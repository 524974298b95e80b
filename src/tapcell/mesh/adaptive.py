"""Adaptive meshes (`BED_MESH_CALIBRATE ADAPTIVE=1`): probe only where the print will be.

The print's objects come as polygons (from `EXCLUDE_OBJECT_DEFINE`, read back through the
`exclude_object` status: `objects[*].polygon`). As in Klipper:

* the mesh area is the objects' bounding box grown by `adaptive_margin` on every side and
  clipped to the configured mesh area;
* each axis keeps the configured point density: count = ceil(configured count x the share of the
  configured length the new area spans), at least 3, and at least 4 on both axes when one has
  more than 6 (bicubic needs 4; lagrange allows at most 6);
* a round bed gets a smaller circle (odd point count) only when it fits inside the configured one.

An area narrower than one millimetre per point interval (a single tiny object) is widened
around its centre, so the points stay apart.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

from tapcell.mesh.grid import MIN_PROBE_COUNT, MeshGrid, rectangular_grid, round_grid

# Bicubic interpolation needs 4 points per axis; more than 6 on an axis rules lagrange out.
BICUBIC_MIN_COUNT = 4
LAGRANGE_MAX_COUNT = 6
MIN_SPACING_MM = 1.0


@dataclass(frozen=True)
class AdaptedMesh:
    grid: MeshGrid
    objects_min_xy_mm: tuple[float, float]  # the objects' bounding box
    objects_max_xy_mm: tuple[float, float]
    shrunk: bool  # False: the objects need the whole configured mesh (a round bed's circle)


def objects_bounds(polygons: Iterable[Sequence[Sequence[float]]]) -> tuple[tuple[float, float], tuple[float, float]] | None:
    """((min x, min y), (max x, max y)) over every polygon vertex; None without any vertex."""
    xs, ys = [], []
    for polygon in polygons:
        for vertex in polygon:
            xs.append(float(vertex[0]))
            ys.append(float(vertex[1]))
    if not xs:
        return None
    return (min(xs), min(ys)), (max(xs), max(ys))


def adapt_grid(grid: MeshGrid, polygons: Iterable[Sequence[Sequence[float]]], margin_mm: float) -> AdaptedMesh | None:
    """The mesh for the objects' area (None when no polygon has a vertex)."""
    bounds = objects_bounds(polygons)
    if bounds is None:
        return None
    (low_x, low_y), (high_x, high_y) = bounds
    area_x = _clip(low_x - margin_mm, high_x + margin_mm, grid.min_x_mm, grid.max_x_mm)
    area_y = _clip(low_y - margin_mm, high_y + margin_mm, grid.min_y_mm, grid.max_y_mm)
    counts = [math.ceil(configured * (area[1] - area[0]) / (full_high - full_low))
              for configured, area, full_low, full_high in ((grid.x_count, area_x, grid.min_x_mm, grid.max_x_mm),
                                                            (grid.y_count, area_y, grid.min_y_mm, grid.max_y_mm))]
    smallest = BICUBIC_MIN_COUNT if max(counts) > LAGRANGE_MAX_COUNT else MIN_PROBE_COUNT
    counts = [max(count, smallest) for count in counts]
    area_x = _widen(area_x, counts[0], grid.min_x_mm, grid.max_x_mm)
    area_y = _widen(area_y, counts[1], grid.min_y_mm, grid.max_y_mm)
    if grid.radius_mm is None:
        adapted = rectangular_grid((area_x[0], area_y[0]), (area_x[1], area_y[1]), tuple(counts))
        return AdaptedMesh(adapted, bounds[0], bounds[1], True)
    radius = math.hypot(area_x[1] - area_x[0], area_y[1] - area_y[0]) / 2.0
    origin = ((area_x[0] + area_x[1]) / 2.0, (area_y[0] + area_y[1]) / 2.0)
    if radius + math.hypot(origin[0] - grid.origin_x_mm, origin[1] - grid.origin_y_mm) >= grid.radius_mm:
        return AdaptedMesh(grid, bounds[0], bounds[1], False)
    count = max(counts)
    count += 1 - count % 2  # a round mesh has an odd count
    return AdaptedMesh(round_grid(radius, origin, count), bounds[0], bounds[1], True)


def _clip(low: float, high: float, full_low: float, full_high: float) -> tuple[float, float]:
    low, high = max(low, full_low), min(high, full_high)
    if low > high:  # the objects lie beside the mesh area: its nearest edge
        edge = full_high if low >= full_high else full_low
        low = high = edge
    return low, high


def _widen(area: tuple[float, float], count: int, full_low: float, full_high: float) -> tuple[float, float]:
    """At least MIN_SPACING_MM between points, around the area's centre, inside the full mesh."""
    span = min((count - 1) * MIN_SPACING_MM, full_high - full_low)
    if area[1] - area[0] >= span:
        return area
    centre = min(max((area[0] + area[1]) / 2.0, full_low + span / 2.0), full_high - span / 2.0)
    return centre - span / 2.0, centre + span / 2.0
