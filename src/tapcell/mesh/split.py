"""Splitting a G1 move so the nozzle follows the mesh.

The move is checked every `move_check_distance` mm along its length. Whenever the mesh
offset at a check point differs from the offset of the last emitted point by at least
`split_delta_z`, the move is cut there and a sub-move ending at that point (with its own
mesh Z) is emitted. The last sub-move always ends at the move's end. A move without X/Y
travel is never split. The fade factor is taken at the move's end height and held for the
whole move, so a layer change fades once, not along the travel.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from tapcell.mesh.errors import MeshOptionError
from tapcell.mesh.zmesh import Fade, ZMesh, fade_factor, fade_target_mm

SECTION = "bed_mesh"
# The guide's "aggressive" settings are also the smallest allowed: below them each move
# would be cut into sub-moves shorter than the planner can use.
MIN_MOVE_CHECK_DISTANCE_MM = 3.0
MIN_SPLIT_DELTA_Z_MM = 0.01
# Below this an axis counts as not moving (floating-point noise in G-code positions).
_STILL_MM = 1e-10


@dataclass(frozen=True)
class SplitSettings:
    """`move_check_distance` and `split_delta_z` of `[bed_mesh]`, validated on creation."""

    move_check_distance_mm: float = 5.0
    split_delta_z_mm: float = 0.025

    def __post_init__(self) -> None:
        if not (math.isfinite(self.move_check_distance_mm) and self.move_check_distance_mm >= MIN_MOVE_CHECK_DISTANCE_MM):
            raise MeshOptionError(
                SECTION, "move_check_distance", self.move_check_distance_mm, f"must be at least {MIN_MOVE_CHECK_DISTANCE_MM} mm"
            )
        if not (math.isfinite(self.split_delta_z_mm) and self.split_delta_z_mm >= MIN_SPLIT_DELTA_Z_MM):
            raise MeshOptionError(
                SECTION, "split_delta_z", self.split_delta_z_mm, f"must be at least {MIN_SPLIT_DELTA_Z_MM} mm"
            )


def split_move(
    start_xyze: Sequence[float],
    end_xyze: Sequence[float],
    mesh: ZMesh,
    fade: Fade,
    settings: SplitSettings,
) -> np.ndarray:
    """Sub-moves (n, 4) of x, y, toolhead z, e that carry the G-code move start -> end over the mesh.

    `start_xyze` and `end_xyze` are G-code positions (no mesh applied); the returned Z
    values include the mesh offset. Positions of cut points lie on the straight line between
    start and end (E is interpolated with them).
    """
    start = np.asarray(start_xyze, dtype=float)
    end = np.asarray(end_xyze, dtype=float)
    factor = fade_factor(float(end[2]), fade)
    target = fade_target_mm(mesh, fade) if fade.enabled else 0.0

    def offsets_at(points: np.ndarray) -> np.ndarray:
        return target + factor * (mesh.z_at(points[:, 0], points[:, 1]) - target)

    delta = end - start
    length_mm = float(np.linalg.norm(delta[:3]))
    sub_moves = []
    if abs(delta[0]) > _STILL_MM or abs(delta[1]) > _STILL_MM:
        # Check points strictly before the end (the end itself is always emitted below),
        # evaluated on the mesh in one call; the scan for cuts is sequential.
        checked_mm = settings.move_check_distance_mm * np.arange(1, math.ceil(length_mm / settings.move_check_distance_mm))
        checked_mm = checked_mm[checked_mm < length_mm]  # rounding in length / distance can reach the end
        points = start + np.outer(checked_mm / length_mm, delta)
        offsets = offsets_at(points)
        last_offset = float(offsets_at(start[None, :])[0])
        for point, offset in zip(points, offsets):
            if abs(offset - last_offset) >= settings.split_delta_z_mm:
                sub_moves.append((point[0], point[1], point[2] + offset, point[3]))
                last_offset = offset
    sub_moves.append((end[0], end[1], end[2] + float(offsets_at(end[None, :])[0]), end[3]))
    return np.array(sub_moves, dtype=float)
