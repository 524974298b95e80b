"""Mesh geometry: where the probe points are and in which order they are probed.

A mesh is a regular grid of `x_count` x `y_count` points spanning `mesh_min`..`mesh_max`.
Matrices are indexed `[row][column]` = `[y index][x index]`, row 0 at the front (min Y).

Points are probed in a serpentine: row 0 left to right, row 1 right to left, and so on,
so the head never crosses the bed between rows. The first point is `mesh_min`.

Round beds (`mesh_radius`, `mesh_origin`, `round_probe_count`) use a square grid around
the origin and skip the points outside the radius; the missing corners of the matrix are
filled from the nearest probed value of the same row so the interpolation still sees a
full rectangle.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tapcell.mesh.errors import MeshError, MeshOptionError

SECTION = "bed_mesh"
MIN_PROBE_COUNT = 3
# 50 x 50 = 2500 taps is about half an hour of probing; more is a typo, not a mesh.
MAX_PROBE_COUNT = 50
# Points exactly on the circle must survive floating-point rounding of the grid positions.
_RADIUS_TOLERANCE_MM = 1e-6


@dataclass(frozen=True)
class MeshGrid:
    """Where a mesh's points are. `radius_mm` is set only for round beds."""

    min_x_mm: float
    max_x_mm: float
    min_y_mm: float
    max_y_mm: float
    x_count: int
    y_count: int
    radius_mm: float | None = None
    origin_x_mm: float = 0.0
    origin_y_mm: float = 0.0

    @property
    def mesh_min(self) -> tuple[float, float]:
        return (self.min_x_mm, self.min_y_mm)

    @property
    def mesh_max(self) -> tuple[float, float]:
        return (self.max_x_mm, self.max_y_mm)

    def x_positions_mm(self) -> np.ndarray:
        return np.linspace(self.min_x_mm, self.max_x_mm, self.x_count)

    def y_positions_mm(self) -> np.ndarray:
        return np.linspace(self.min_y_mm, self.max_y_mm, self.y_count)

    def probe_indices(self) -> np.ndarray:
        """(n, 2) array of [row, column] for each probe point, in probing order."""
        order = []
        for row in range(self.y_count):
            columns = range(self.x_count) if row % 2 == 0 else range(self.x_count - 1, -1, -1)
            order.extend((row, column) for column in columns if self._on_bed(row, column))
        return np.array(order, dtype=int).reshape(-1, 2)

    def probe_points_mm(self) -> np.ndarray:
        """(n, 2) array of [x, y] for each probe point, in probing order."""
        indices = self.probe_indices()
        return np.column_stack(
            (self.x_positions_mm()[indices[:, 1]], self.y_positions_mm()[indices[:, 0]])
        )

    def _on_bed(self, row: int, column: int) -> bool:
        if self.radius_mm is None:
            return True
        dx = self.x_positions_mm()[column] - self.origin_x_mm
        dy = self.y_positions_mm()[row] - self.origin_y_mm
        return math.hypot(dx, dy) <= self.radius_mm + _RADIUS_TOLERANCE_MM


def _count_pair(option: str, probe_count: int | tuple[int, int] | list[int]) -> tuple[int, int]:
    counts = (probe_count, probe_count) if isinstance(probe_count, int) else tuple(probe_count)
    if len(counts) != 2 or not all(isinstance(c, (int, np.integer)) for c in counts):
        raise MeshOptionError(SECTION, option, probe_count, "must be one integer or a pair X, Y of integers")
    if min(counts) < MIN_PROBE_COUNT or max(counts) > MAX_PROBE_COUNT:
        raise MeshOptionError(
            SECTION, option, _format_pair(counts),
            f"must be {MIN_PROBE_COUNT} to {MAX_PROBE_COUNT} points on each axis"
        )
    return int(counts[0]), int(counts[1])


def _format_pair(values: tuple) -> str:
    return ", ".join(str(v) for v in values)


def rectangular_grid(
    mesh_min: tuple[float, float], mesh_max: tuple[float, float], probe_count: int | tuple[int, int] = (3, 3)
) -> MeshGrid:
    """The grid of a rectangular bed from the `[bed_mesh]` options of the same names."""
    x_count, y_count = _count_pair("probe_count", probe_count)
    for axis, low, high in (("X", mesh_min[0], mesh_max[0]), ("Y", mesh_min[1], mesh_max[1])):
        if not (math.isfinite(low) and math.isfinite(high)) or high <= low:
            raise MeshOptionError(
                SECTION,
                "mesh_max",
                _format_pair(tuple(mesh_max)),
                f"{axis} must be greater than mesh_min {axis} ({low})",
            )
    return MeshGrid(
        min_x_mm=float(mesh_min[0]),
        max_x_mm=float(mesh_max[0]),
        min_y_mm=float(mesh_min[1]),
        max_y_mm=float(mesh_max[1]),
        x_count=x_count,
        y_count=y_count,
    )


def round_grid(mesh_radius_mm: float, mesh_origin: tuple[float, float] = (0.0, 0.0), round_probe_count: int = 5) -> MeshGrid:
    """The grid of a round bed: a square of side 2 * radius around the origin, corners skipped."""
    if not math.isfinite(mesh_radius_mm) or mesh_radius_mm <= 0:
        raise MeshOptionError(SECTION, "mesh_radius", mesh_radius_mm, "must be a positive number of mm")
    if (not isinstance(round_probe_count, int) or not MIN_PROBE_COUNT <= round_probe_count <= MAX_PROBE_COUNT
            or round_probe_count % 2 == 0):
        raise MeshOptionError(
            SECTION, "round_probe_count", round_probe_count,
            f"must be an odd integer from {MIN_PROBE_COUNT} to {MAX_PROBE_COUNT}"
        )
    origin_x, origin_y = (float(v) for v in mesh_origin)
    return MeshGrid(
        min_x_mm=origin_x - mesh_radius_mm,
        max_x_mm=origin_x + mesh_radius_mm,
        min_y_mm=origin_y - mesh_radius_mm,
        max_y_mm=origin_y + mesh_radius_mm,
        x_count=round_probe_count,
        y_count=round_probe_count,
        radius_mm=float(mesh_radius_mm),
        origin_x_mm=origin_x,
        origin_y_mm=origin_y,
    )


def matrix_from_probes(grid: MeshGrid, z_in_probe_order_mm: np.ndarray | list[float]) -> np.ndarray:
    """Place Z results (in probing order) into a (y_count, x_count) matrix.

    On round beds the skipped corner cells take the value of the nearest probed cell of
    the same row, which keeps the outer ring flat instead of inventing a slope.
    """
    z_values = np.asarray(z_in_probe_order_mm, dtype=float)
    indices = grid.probe_indices()
    if z_values.shape != (len(indices),):
        raise MeshError(f"mesh needs {len(indices)} probe results in probing order, got {z_values.size}")
    matrix = np.full((grid.y_count, grid.x_count), np.nan)
    matrix[indices[:, 0], indices[:, 1]] = z_values
    for row in matrix:
        probed = np.flatnonzero(~np.isnan(row))
        row[: probed[0]] = row[probed[0]]
        row[probed[-1] + 1 :] = row[probed[-1]]
    return matrix


def reference_point_from_index(grid: MeshGrid, relative_reference_index: int) -> tuple[float, float]:
    """The X, Y of probe point number `relative_reference_index` (probing order, from 0)."""
    points = grid.probe_points_mm()
    if not isinstance(relative_reference_index, int) or not 0 <= relative_reference_index < len(points):
        raise MeshOptionError(
            SECTION,
            "relative_reference_index",
            relative_reference_index,
            f"must be a probe point index from 0 to {len(points) - 1}",
        )
    x_mm, y_mm = points[relative_reference_index]
    return float(x_mm), float(y_mm)
