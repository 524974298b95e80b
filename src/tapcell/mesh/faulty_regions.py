"""Faulty regions (`faulty_region_N_min` / `faulty_region_N_max` of `[bed_mesh]`): places the
probe must not tap (a magnet, a clip, a hole in the sheet).

A mesh point inside a region is not probed. Instead the probe taps where the point's row and
column leave the region (up to four places on the region's edges, those within the mesh area)
and the point gets the average of those heights, as Klipper does. Regions must not overlap.

`probing_plan(grid, regions)` lists where every mesh point is probed; the probing method taps
the flat list of places and `ProbingPlan.fold` turns their heights back into one per point.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tapcell.mesh.errors import MeshOptionError
from tapcell.mesh.grid import MeshGrid

SECTION = "bed_mesh"
MAX_REGIONS = 99
# A point on a region's edge counts as inside (Klipper's tolerance).
EDGE_TOLERANCE_MM = 1e-5


@dataclass(frozen=True)
class FaultyRegion:
    number: int  # the N of faulty_region_N_min/max
    min_xy_mm: tuple[float, float]
    max_xy_mm: tuple[float, float]

    def contains(self, x_mm: float, y_mm: float) -> bool:
        return (self.min_xy_mm[0] - EDGE_TOLERANCE_MM <= x_mm <= self.max_xy_mm[0] + EDGE_TOLERANCE_MM
                and self.min_xy_mm[1] - EDGE_TOLERANCE_MM <= y_mm <= self.max_xy_mm[1] + EDGE_TOLERANCE_MM)

    def overlaps(self, other: FaultyRegion) -> bool:
        return all(self.min_xy_mm[a] <= other.max_xy_mm[a] and other.min_xy_mm[a] <= self.max_xy_mm[a]
                   for a in (0, 1))

    def describe(self) -> str:
        return (f"faulty_region_{self.number} ({self.min_xy_mm[0]:g}, {self.min_xy_mm[1]:g}) .. "
                f"({self.max_xy_mm[0]:g}, {self.max_xy_mm[1]:g})")


def make_regions(corners: dict[int, tuple[tuple[float, float], tuple[float, float]]]) -> tuple[FaultyRegion, ...]:
    """Regions from {N: (min corner, max corner)} as configured; corners are put in order (a
    min given larger than its max is swapped), overlapping regions are refused."""
    regions: list[FaultyRegion] = []
    for number in sorted(corners):
        first, second = (tuple(float(v) for v in corner) for corner in corners[number])
        if not all(math.isfinite(v) for v in (*first, *second)):
            raise MeshOptionError(SECTION, f"faulty_region_{number}_min", first, "corners must be finite numbers X, Y")
        region = FaultyRegion(number, (min(first[0], second[0]), min(first[1], second[1])),
                              (max(first[0], second[0]), max(first[1], second[1])))
        for earlier in regions:
            if region.overlaps(earlier):
                raise MeshOptionError(SECTION, f"faulty_region_{number}_min", _pair(first),
                                      f"{region.describe()} overlaps {earlier.describe()}; faulty regions must "
                                      "not overlap (join them into one)")
        regions.append(region)
    return tuple(regions)


def _pair(xy: tuple[float, float]) -> str:
    return f"{xy[0]:g}, {xy[1]:g}"


@dataclass(frozen=True)
class ProbingPlan:
    """Where each mesh point (probing order) is probed: itself, or its substitutes."""

    points_mm: np.ndarray  # (n, 2) the mesh points
    places_mm: tuple[tuple[tuple[float, float], ...], ...]  # per point, the places tapped for it

    @property
    def substituted(self) -> dict[int, tuple[tuple[float, float], ...]]:
        """{point index: the places probed instead} for the points inside a faulty region."""
        return {index: places for index, places in enumerate(self.places_mm)
                if places != ((float(self.points_mm[index][0]), float(self.points_mm[index][1])),)}

    def flat_places_mm(self) -> np.ndarray:
        """(m, 2): every place to tap, in order."""
        return np.array([place for places in self.places_mm for place in places], dtype=float).reshape(-1, 2)

    def fold(self, z_at_places_mm) -> list[float]:
        """One height per mesh point from the heights at the flat places (substitutes averaged)."""
        z = list(z_at_places_mm)
        out, start = [], 0
        for places in self.places_mm:
            out.append(float(np.mean(z[start:start + len(places)])))
            start += len(places)
        return out


def probing_plan(grid: MeshGrid, regions: tuple[FaultyRegion, ...]) -> ProbingPlan:
    """The places to tap for `grid`, avoiding `regions` (MeshOptionError when a point inside a
    region has no substitute within the mesh area)."""
    points = grid.probe_points_mm()
    places = []
    for index, (x_mm, y_mm) in enumerate(points):
        x_mm, y_mm = float(x_mm), float(y_mm)
        region = next((r for r in regions if r.contains(x_mm, y_mm)), None)
        if region is None:
            places.append(((x_mm, y_mm),))
            continue
        (low_x, low_y), (high_x, high_y) = region.min_xy_mm, region.max_xy_mm
        edges = [(low_x, y_mm), (x_mm, low_y), (x_mm, high_y), (high_x, y_mm)]
        if _row_runs_backwards(points, index):
            edges.reverse()  # the serpentine runs toward -X here: keep the travel short
        usable = tuple(edge for edge in edges if _inside_mesh(grid, *edge))
        if not usable:
            raise MeshOptionError(SECTION, f"faulty_region_{region.number}_min", _pair(region.min_xy_mm),
                                  f"mesh point {index} ({x_mm:g}, {y_mm:g}) lies inside {region.describe()} and "
                                  "no edge of the region around it is within the mesh to probe instead; make the "
                                  "region smaller or the mesh larger")
        places.append(usable)
    return ProbingPlan(points, tuple(places))


def _row_runs_backwards(points: np.ndarray, index: int) -> bool:
    """Whether the serpentine runs toward -X at point `index` (odd rows)."""
    same_row = points[np.isclose(points[:, 1], points[index, 1])]
    return len(same_row) > 1 and same_row[0, 0] > same_row[-1, 0]


def _inside_mesh(grid: MeshGrid, x_mm: float, y_mm: float) -> bool:
    if grid.radius_mm is not None:
        return math.hypot(x_mm - grid.origin_x_mm, y_mm - grid.origin_y_mm) <= grid.radius_mm + EDGE_TOLERANCE_MM
    return (grid.min_x_mm - EDGE_TOLERANCE_MM <= x_mm <= grid.max_x_mm + EDGE_TOLERANCE_MM
            and grid.min_y_mm - EDGE_TOLERANCE_MM <= y_mm <= grid.max_y_mm + EDGE_TOLERANCE_MM)
