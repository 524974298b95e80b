"""Upsampling a probed matrix into the finer mesh that moves follow, and bilinear lookup.

`mesh_pps` (points per segment) inserts that many points between each pair of probed
points, so an axis with n probed points becomes (n - 1) * (pps + 1) + 1 mesh points. Both
algorithms are separable: each probed row is interpolated along X, then every column of
the result along Y. Each 1-D step is a fixed weight matrix (mesh points x probed points),
so upsampling is two matrix products.

* lagrange: one polynomial through all points of the axis; exact for polynomials of degree
  below the point count, but it swings at the edges with many points, hence the limit of 6.
* bicubic: a cardinal (Hermite) spline per segment; the tangent at a point is
  `bicubic_tension * (next - previous)`. Larger tension means steeper tangents and more
  curvature; 0.5 is the Catmull-Rom spline, which reproduces planes exactly. At the ends the
  missing neighbour is extrapolated along the last segment, so a tilted edge stays straight.
* direct: with mesh_pps 0, 0 nothing is inserted and moves follow the probed points
  bilinearly (the load-cell ABL paper's method).

Lookups between mesh points are bilinear; outside the mesh the position is clamped to the
nearest edge.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tapcell.mesh.errors import MeshOptionError

SECTION = "bed_mesh"
ALGORITHMS = ("lagrange", "bicubic")
LAGRANGE_MAX_POINTS = 6
# Points interpolated between two probed ones; the fine mesh grows with its square.
MAX_MESH_PPS = 10
BICUBIC_MIN_POINTS = 4
TENSION_RANGE = (0.0, 2.0)


@dataclass(frozen=True)
class Interpolation:
    """How the probed matrix is upsampled. `algorithm` is lagrange, bicubic or direct."""

    algorithm: str = "lagrange"
    mesh_x_pps: int = 2
    mesh_y_pps: int = 2
    bicubic_tension: float = 0.2


def resolve_interpolation(
    algorithm: str,
    probe_count: tuple[int, int],
    mesh_pps: int | tuple[int, int] = (2, 2),
    bicubic_tension: float = 0.2,
) -> tuple[Interpolation, str | None]:
    """Check the `[bed_mesh]` interpolation options against the probe count.

    Returns the interpolation actually used and a note for the user when it differs from
    the one asked for (bicubic on an axis of 3 points falls back to lagrange; mesh_pps 0, 0
    means direct), or raises MeshOptionError naming the option.
    """
    x_count, y_count = probe_count
    if algorithm not in ALGORITHMS:
        raise MeshOptionError(SECTION, "algorithm", algorithm, "must be one of: " + ", ".join(ALGORITHMS))
    pps = (mesh_pps, mesh_pps) if isinstance(mesh_pps, int) else tuple(mesh_pps)
    if len(pps) != 2 or not all(isinstance(p, (int, np.integer)) and 0 <= p <= MAX_MESH_PPS for p in pps):
        raise MeshOptionError(SECTION, "mesh_pps", mesh_pps, f"must be one or two integers X, Y from 0 to {MAX_MESH_PPS}")
    low, high = TENSION_RANGE
    if not (math.isfinite(bicubic_tension) and low <= bicubic_tension <= high):
        raise MeshOptionError(SECTION, "bicubic_tension", bicubic_tension, f"must be between {low} and {high}")
    counts = f"{x_count}, {y_count}"
    note = None
    if pps == (0, 0):
        return Interpolation("direct", 0, 0, bicubic_tension), (
            f"mesh_pps 0, 0: no interpolation, moves follow the probed points bilinearly ({algorithm} unused)"
        )
    if algorithm == "bicubic" and min(x_count, y_count) < BICUBIC_MIN_POINTS:
        if max(x_count, y_count) > LAGRANGE_MAX_POINTS:
            raise MeshOptionError(
                SECTION,
                "probe_count",
                counts,
                f"bicubic needs at least {BICUBIC_MIN_POINTS} points on each axis and the lagrange fallback "
                f"allows at most {LAGRANGE_MAX_POINTS}; use at least {BICUBIC_MIN_POINTS} points on each axis",
            )
        note = f"bicubic needs at least {BICUBIC_MIN_POINTS} points on each axis; probe_count {counts} uses lagrange"
        algorithm = "lagrange"
    if algorithm == "lagrange" and max(x_count, y_count) > LAGRANGE_MAX_POINTS:
        raise MeshOptionError(
            SECTION,
            "probe_count",
            counts,
            f"lagrange allows at most {LAGRANGE_MAX_POINTS} points per axis; use algorithm: bicubic for more",
        )
    return Interpolation(algorithm, int(pps[0]), int(pps[1]), float(bicubic_tension)), note


def mesh_positions(probed_count: int, pps: int) -> np.ndarray:
    """Mesh sample positions along one axis, in units of probed-point index."""
    return np.linspace(0.0, probed_count - 1, (probed_count - 1) * (pps + 1) + 1)


def lagrange_weights(probed_count: int, positions: np.ndarray) -> np.ndarray:
    """(len(positions), probed_count) weights of the polynomial through all probed points."""
    nodes = np.arange(probed_count, dtype=float)
    weights = np.ones((len(positions), probed_count))
    for j in range(probed_count):
        for m in range(probed_count):
            if m != j:
                weights[:, j] *= (positions - nodes[m]) / (nodes[j] - nodes[m])
    return weights


def bicubic_weights(probed_count: int, positions: np.ndarray, tension: float) -> np.ndarray:
    """(len(positions), probed_count) weights of the cardinal spline with the given tension."""
    # Neighbours beyond the ends are linear extrapolations: p[-1] = 2 p[0] - p[1], and the
    # same at the far end; written as rows over the real points so everything stays linear.
    extended = np.zeros((probed_count + 2, probed_count))
    extended[1:-1] = np.eye(probed_count)
    extended[0, 0], extended[0, 1] = 2.0, -1.0
    extended[-1, -1], extended[-1, -2] = 2.0, -1.0
    segment = np.clip(np.floor(positions).astype(int), 0, probed_count - 2)
    t = positions - segment
    t2, t3 = t * t, t * t * t
    start_weight = 2 * t3 - 3 * t2 + 1
    end_weight = -2 * t3 + 3 * t2
    start_tangent_weight = tension * (t3 - 2 * t2 + t)
    end_tangent_weight = tension * (t3 - t2)
    weights = np.zeros((len(positions), probed_count))
    for k, s in enumerate(segment):
        # Extended index e = real index + 1; the segment runs from point s to s + 1.
        previous, start, end, after = (extended[s + offset] for offset in range(4))
        weights[k] = (
            start_weight[k] * start
            + end_weight[k] * end
            + start_tangent_weight[k] * (end - previous)
            + end_tangent_weight[k] * (after - start)
        )
    return weights


def _axis_weights(probed_count: int, pps: int, interpolation: Interpolation) -> np.ndarray:
    positions = mesh_positions(probed_count, pps)
    if interpolation.algorithm == "bicubic":
        return bicubic_weights(probed_count, positions, interpolation.bicubic_tension)
    return lagrange_weights(probed_count, positions)


def upsample(probed_matrix_mm: np.ndarray, interpolation: Interpolation) -> np.ndarray:
    """The mesh matrix: probed (y_count, x_count) values upsampled by mesh_pps on each axis."""
    probed = np.asarray(probed_matrix_mm, dtype=float)
    y_count, x_count = probed.shape
    x_weights = _axis_weights(x_count, interpolation.mesh_x_pps, interpolation)
    y_weights = _axis_weights(y_count, interpolation.mesh_y_pps, interpolation)
    return y_weights @ probed @ x_weights.T


def bilinear_at(
    matrix_mm: np.ndarray,
    mesh_min: tuple[float, float],
    mesh_max: tuple[float, float],
    x_mm: np.ndarray | float,
    y_mm: np.ndarray | float,
) -> np.ndarray | float:
    """Bilinear value of a regular-grid matrix at (x, y), positions clamped into the mesh."""
    matrix = np.asarray(matrix_mm, dtype=float)
    rows, columns = matrix.shape
    x = np.clip(np.asarray(x_mm, dtype=float), mesh_min[0], mesh_max[0])
    y = np.clip(np.asarray(y_mm, dtype=float), mesh_min[1], mesh_max[1])
    # Fractional grid indices; the cell is chosen so its far edge is still inside the matrix.
    u = (x - mesh_min[0]) / (mesh_max[0] - mesh_min[0]) * (columns - 1)
    v = (y - mesh_min[1]) / (mesh_max[1] - mesh_min[1]) * (rows - 1)
    column = np.clip(np.floor(u).astype(int), 0, columns - 2)
    row = np.clip(np.floor(v).astype(int), 0, rows - 2)
    fx, fy = u - column, v - row
    front = matrix[row, column] * (1 - fx) + matrix[row, column + 1] * fx
    back = matrix[row + 1, column] * (1 - fx) + matrix[row + 1, column + 1] * fx
    z = front * (1 - fy) + back * fy
    return float(z) if z.ndim == 0 else z
