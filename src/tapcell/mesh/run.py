"""A mesh probing run: what a probing method hands back, and how it reports progress."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from tapcell.mesh.travel import travel_height_mm

# progress(done, total) after each probed point.
Progress = Callable[[int, int], None]


@dataclass
class MeshProbeRun:
    """What a probing method returns: bed height per point (probing order) and a report."""

    z_mm: list[float]
    report: str = ""
    details: dict | None = None  # JSON-ready, shown in status as last_calibration


def mesh_travel_height_mm(options, contacts_xyz: Sequence[tuple[float, float, float]],
                          next_xy_mm: tuple[float, float] | None) -> float:
    """Toolhead Z to travel at toward the next point (None: the lift after the last point).

    `options`: the command's BedMeshOptions. `horizontal_move_z`, or with `horizontal_z_clearance`
    that much above the bed on the way, the next point's height predicted from the contacts so
    far (`tapcell.mesh.travel`).
    """
    clearance = options.horizontal_z_clearance_mm
    if clearance is None or not contacts_xyz:
        return options.horizontal_move_z_mm
    if next_xy_mm is None:
        return contacts_xyz[-1][2] + clearance
    return travel_height_mm(np.array(contacts_xyz), next_xy_mm, clearance, options.horizontal_move_z_mm)
