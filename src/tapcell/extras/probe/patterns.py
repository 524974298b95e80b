"""Where to tap next: the CIRCLE retry pattern and the NOZZLE_CLEANUP serpentine.

Pure functions returning numpy arrays of (x, y) positions in mm.
"""

from __future__ import annotations

import numpy as np

# Unit hexagonal pattern (spacing 1): the centre, the 6 neighbours at distance 1, then the
# second ring of a hexagonal lattice: 6 points at sqrt(3) (between two neighbours) and 6 at 2
# (straight out). Nearest first, so a retry moves as little as possible away from the point
# that was asked for.
_RING_ANGLES_DEG = np.arange(6) * 60.0


def _ring(radius: float, angle_offset_deg: float) -> np.ndarray:
    angles = np.deg2rad(_RING_ANGLES_DEG + angle_offset_deg)
    return radius * np.column_stack([np.cos(angles), np.sin(angles)])


UNIT_HEX_PATTERN = np.vstack([np.zeros((1, 2)), _ring(1.0, 0.0), _ring(np.sqrt(3.0), 30.0), _ring(2.0, 0.0)])
MAX_CIRCLE_RETRIES = len(UNIT_HEX_PATTERN) - 1  # 18 places besides the requested one


def hex_pattern(center_x_mm: float, center_y_mm: float, spacing_mm: float) -> np.ndarray:
    """The 19 candidate tap positions around a point, nearest first (row 0 is the point)."""
    return np.array([center_x_mm, center_y_mm]) + spacing_mm * UNIT_HEX_PATTERN


def next_clean_spot(
    center_x_mm: float, center_y_mm: float, spacing_mm: float, fouled_xy_mm: np.ndarray
) -> tuple[float, float] | None:
    """The nearest pattern position that keeps clear of every fouled place, or None.

    A fouled place is where a bad tap happened earlier in the same command (its ooze may
    still be there). Positions closer than half the spacing to one are skipped, so this also
    avoids spots fouled while probing *other* points (neighbouring mesh points).
    """
    candidates = hex_pattern(center_x_mm, center_y_mm, spacing_mm)
    fouled = np.asarray(fouled_xy_mm, dtype=float).reshape(-1, 2)
    if fouled.size == 0:
        return float(candidates[0, 0]), float(candidates[0, 1])
    distances = np.linalg.norm(candidates[:, None, :] - fouled[None, :, :], axis=2)
    clear = np.all(distances >= 0.5 * spacing_mm - 1e-9, axis=1)
    if not clear.any():
        return None
    first = int(np.argmax(clear))
    return float(candidates[first, 0]), float(candidates[first, 1])


def serpentine_pattern(
    start_x_mm: float, start_y_mm: float, count_x: int, count_y: int, stepover_mm: float
) -> np.ndarray:
    """|count_x| x |count_y| positions row by row, every other row reversed (no long travel back).

    A negative count walks that axis in the negative direction from the start position.
    """
    if count_x == 0 or count_y == 0:
        raise ValueError("serpentine_pattern needs at least one column and one row")
    columns = np.arange(abs(count_x)) * np.sign(count_x) * stepover_mm
    rows = np.arange(abs(count_y)) * np.sign(count_y) * stepover_mm
    points = []
    for row_index, dy in enumerate(rows):
        xs = columns if row_index % 2 == 0 else columns[::-1]
        points.append(np.column_stack([start_x_mm + xs, np.full(xs.shape, start_y_mm + dy)]))
    return np.vstack(points)
