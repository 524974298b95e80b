"""ZMesh: a probed matrix with its geometry, ready for Z lookups, plus fade arithmetic.

A mesh gives the bed height `z_at(x, y)` (bilinear in the upsampled mesh, clamped to the
mesh edges outside). Applied to a move at G-code height z, the adjustment is faded out
between `fade_start` and `fade_end`:

    factor = 1 below fade_start, 0 at and above fade_end, linear between
    adjusted z = z + fade_target + factor * (z_at(x, y) - fade_target)

so the first layers follow the bed and, above fade_end, every layer is shifted by the
constant fade_target (default: the mesh average) instead of following the bed.

`zero_reference_position` shifts the whole mesh so that z_at is 0 there. Load cells
measure the nozzle itself, so no reference is needed, but the option is honoured.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from tapcell.mesh.errors import MeshError, MeshOptionError
from tapcell.mesh.grid import MeshGrid, reference_point_from_index
from tapcell.mesh.interpolate import Interpolation, bilinear_at, upsample

SECTION = "bed_mesh"


@dataclass(frozen=True, eq=False)
class ZMesh:
    """A mesh ready for lookups. Build it with `build_mesh`; matrices are [y index][x index]."""

    profile_name: str
    grid: MeshGrid
    interpolation: Interpolation
    probed_matrix_mm: np.ndarray
    mesh_matrix_mm: np.ndarray
    zero_reference_offset_mm: float = 0.0

    def z_at(self, x_mm: np.ndarray | float, y_mm: np.ndarray | float) -> np.ndarray | float:
        """Bed height at (x, y); positions outside the mesh use the nearest edge."""
        return bilinear_at(self.mesh_matrix_mm, self.grid.mesh_min, self.grid.mesh_max, x_mm, y_mm)

    def average_mm(self) -> float:
        return float(self.mesh_matrix_mm.mean())

    def z_range_mm(self) -> tuple[float, float]:
        """(lowest, highest) of the mesh moves follow (the interpolated matrix, as Klipper's `Mesh
        Range`): BED_MESH_CALIBRATE, BED_MESH_OUTPUT and the heat map all give this one range."""
        return float(self.mesh_matrix_mm.min()), float(self.mesh_matrix_mm.max())

    def to_status(self) -> dict:
        """JSON-ready status, the fields of Klipper's `bed_mesh` printer object."""
        return {
            "profile_name": self.profile_name,
            "mesh_min": [self.grid.min_x_mm, self.grid.min_y_mm],
            "mesh_max": [self.grid.max_x_mm, self.grid.max_y_mm],
            "probed_matrix": self.probed_matrix_mm.tolist(),
            "mesh_matrix": self.mesh_matrix_mm.tolist(),
        }


def empty_mesh_status() -> dict:
    """The `bed_mesh` status when no mesh is loaded."""
    return {"profile_name": "", "mesh_min": [0.0, 0.0], "mesh_max": [0.0, 0.0], "probed_matrix": [[]], "mesh_matrix": [[]]}


def build_mesh(
    probed_matrix_mm: np.ndarray,
    grid: MeshGrid,
    interpolation: Interpolation,
    profile_name: str = "default",
    zero_reference_xy_mm: tuple[float, float] | None = None,
) -> ZMesh:
    """Upsample a probed matrix; with a zero reference, shift the mesh to be 0 there."""
    probed = np.array(probed_matrix_mm, dtype=float)
    if probed.shape != (grid.y_count, grid.x_count):
        raise MeshError(
            f"probed matrix is {probed.shape[0]} x {probed.shape[1]} (rows x columns) but the mesh "
            f"is {grid.y_count} x {grid.x_count}"
        )
    if not np.all(np.isfinite(probed)):
        raise MeshError("probed matrix contains a value that is not a finite number")
    mesh_matrix = upsample(probed, interpolation)
    offset_mm = 0.0
    if zero_reference_xy_mm is not None:
        offset_mm = float(bilinear_at(mesh_matrix, grid.mesh_min, grid.mesh_max, *zero_reference_xy_mm))
        probed -= offset_mm
        mesh_matrix -= offset_mm
    return ZMesh(profile_name, grid, interpolation, probed, mesh_matrix, offset_mm)


def resolve_zero_reference(
    grid: MeshGrid,
    zero_reference_position: tuple[float, float] | None = None,
    relative_reference_index: int | None = None,
) -> tuple[float, float] | None:
    """The point where the mesh is zero, from either option (they are exclusive)."""
    if zero_reference_position is not None and relative_reference_index is not None:
        raise MeshOptionError(
            SECTION,
            "relative_reference_index",
            relative_reference_index,
            "cannot be combined with zero_reference_position; keep only one of them",
        )
    if relative_reference_index is not None:
        return reference_point_from_index(grid, relative_reference_index)
    if zero_reference_position is not None:
        x_mm, y_mm = (float(v) for v in zero_reference_position)
        if not (math.isfinite(x_mm) and math.isfinite(y_mm)):
            raise MeshOptionError(SECTION, "zero_reference_position", zero_reference_position, "must be two numbers X, Y")
        return x_mm, y_mm
    return None


@dataclass(frozen=True)
class Fade:
    """`fade_start`, `fade_end`, `fade_target` of `[bed_mesh]`; fade is off when end <= start."""

    start_mm: float = 1.0
    end_mm: float = 0.0
    target_mm: float | None = field(default=None)

    @property
    def enabled(self) -> bool:
        return self.end_mm > self.start_mm


def fade_factor(z_mm: float, fade: Fade) -> float:
    """How much of the mesh applies at G-code height z: 1 below fade_start, 0 from fade_end."""
    if not fade.enabled or z_mm < fade.start_mm:
        return 1.0
    if z_mm >= fade.end_mm:
        return 0.0
    return (fade.end_mm - z_mm) / (fade.end_mm - fade.start_mm)


def fade_target_mm(mesh: ZMesh, fade: Fade) -> float:
    """The height fade converges to: the configured target, or the mesh average.

    A non-zero target outside the mesh's Z range would shift every upper layer beyond what
    the bed ever needs, so it is refused.
    """
    if fade.target_mm is None:
        return mesh.average_mm()
    low, high = mesh.z_range_mm()
    if fade.target_mm != 0.0 and not low <= fade.target_mm <= high:
        raise MeshOptionError(
            SECTION, "fade_target", fade.target_mm, f"must be 0 or within the mesh Z range {low:.4f} .. {high:.4f} mm"
        )
    return float(fade.target_mm)


def mesh_offset_mm(mesh: ZMesh, x_mm: float, y_mm: float, factor: float, target_mm: float) -> float:
    """The Z added to a move at (x, y) when a fraction `factor` of the mesh applies."""
    return target_mm + factor * (float(mesh.z_at(x_mm, y_mm)) - target_mm)


def adjusted_z_mm(mesh: ZMesh, fade: Fade, x_mm: float, y_mm: float, z_mm: float) -> float:
    """The toolhead Z for G-code position (x, y, z) with the mesh and fade applied."""
    factor = fade_factor(z_mm, fade)
    target = fade_target_mm(mesh, fade) if fade.enabled else 0.0
    return z_mm + mesh_offset_mm(mesh, x_mm, y_mm, factor, target)


def gcode_z_mm(mesh: ZMesh, fade: Fade, x_mm: float, y_mm: float, toolhead_z_mm: float) -> float:
    """Inverse of `adjusted_z_mm`: the G-code Z that puts the toolhead at `toolhead_z_mm`.

    The adjusted Z is continuous and piecewise linear in z (three pieces), so the inverse is
    found exactly: try each piece and keep the one whose solution lies inside it.
    """
    bed_mm = float(mesh.z_at(x_mm, y_mm))
    if not fade.enabled:
        return toolhead_z_mm - bed_mm
    target = fade_target_mm(mesh, fade)
    below = toolhead_z_mm - bed_mm
    if below < fade.start_mm:
        return below
    above = toolhead_z_mm - target
    if above >= fade.end_mm:
        return above
    # Between: t = z + target + (end - z)/(end - start) * (bed - target), linear in z.
    slope_per_mm = (bed_mm - target) / (fade.end_mm - fade.start_mm)
    return (toolhead_z_mm - target - fade.end_mm * slope_per_mm) / (1.0 - slope_per_mm)
