"""How high to travel between mesh points so the nozzle never drags over the bed.

With `horizontal_z_clearance` the nozzle lifts only a little above the last contact before it
travels to the next point. On a tilted bed the next point can be higher than the last by more
than that clearance (a 2 mm tilt over a 3 x 3 mesh rises 1 mm between points): the nozzle would
plough into the bed on the way. So the travel height also covers the next point's bed height,
predicted from the NEIGHBOURS probed points nearest to it:

* a plane through them once they span both directions (any tilt is then known exactly), a line
  along them while they lie on one line (the first row) and the next point is on that line;
* plus the largest misfit of that model on those points (a warped bed is not a plane);
* when nothing predicts the next point (the second point, the first point of the second row),
  the safe height `horizontal_move_z` instead.

The travel is a straight line at that height: over a plane the bed is highest at one end of it,
which the height covers.
"""

from __future__ import annotations

import numpy as np

# Probe positions closer than this count as the same place / on the same line (mm).
SAME_PLACE_MM = 1e-3
NEIGHBOURS = 4


def predicted_bed_height_mm(probed_xyz_mm: np.ndarray, next_xy_mm: tuple[float, float]) -> tuple[float, float] | None:
    """(bed height at next_xy, largest misfit of the model on the probed points), or None when
    the probed points do not predict that place (fewer than two, or it lies off their line)."""
    points = np.asarray(probed_xyz_mm, dtype=float).reshape(-1, 3)
    if len(points) < 2:
        return None
    # The bed near the next point: its nearest contacts (a warp bends the bed far away).
    distances = np.hypot(*(points[:, :2] - np.asarray(next_xy_mm, dtype=float)).T)
    points = points[np.argsort(distances, kind="stable")[:NEIGHBOURS]]
    xy, z = points[:, :2], points[:, 2]
    centre = xy.mean(axis=0)
    _, singular, directions = np.linalg.svd(xy - centre, full_matrices=False)
    spans = int(np.sum(singular > SAME_PLACE_MM))
    if spans == 0:
        return None
    along = directions[:spans]  # the directions the probed points span (1: a line, 2: the plane)
    offset = np.asarray(next_xy_mm, dtype=float) - centre
    if spans == 1 and abs(float(offset @ directions[1])) > SAME_PLACE_MM:
        return None  # off the line: its slope across the line is unknown
    coordinates = (xy - centre) @ along.T
    design = np.column_stack([np.ones(len(points)), coordinates])
    coefficients, *_ = np.linalg.lstsq(design, z, rcond=None)
    misfit_mm = float(np.max(np.abs(design @ coefficients - z)))
    predicted_mm = float(coefficients[0] + (along @ offset) @ coefficients[1:])
    return predicted_mm, misfit_mm


def travel_height_mm(probed_xyz_mm: np.ndarray, next_xy_mm: tuple[float, float], clearance_mm: float,
                     safe_height_mm: float) -> float:
    """The toolhead Z to travel at from the last probed point to next_xy.

    `probed_xyz_mm`: where the nozzle touched so far (toolhead frame, last one last);
    `clearance_mm`: horizontal_z_clearance; `safe_height_mm`: horizontal_move_z, used when the
    next point's height cannot be predicted.
    """
    points = np.asarray(probed_xyz_mm, dtype=float).reshape(-1, 3)
    prediction = predicted_bed_height_mm(points, next_xy_mm)
    if prediction is None:
        above_last_mm = float(points[-1, 2]) + clearance_mm if len(points) else safe_height_mm
        return max(safe_height_mm, above_last_mm)
    predicted_mm, misfit_mm = prediction
    return max(float(points[-1, 2]), predicted_mm + misfit_mm) + clearance_mm
