"""Line angles on the spec's tap plot scale (Prusa's: 0.1 s of time against 25 g of force).

The spec's figures and its Normalized Decompression Angle measure a line's slope as the angle
it makes on that plot. One place holds the scale so the analysis, the classifier and the
probe's DECOMPRESSION_ANGLE calibration measure the same angle.
"""

from __future__ import annotations

import math

ANGLE_SCALE_S_PER_G = 0.004  # 0.1 s / 25 g


def slope_angle_deg(slope_g_s: float) -> float:
    """Signed angle (degrees) of a force-over-time slope (g/s) on the plot scale."""
    return math.degrees(math.atan(slope_g_s * ANGLE_SCALE_S_PER_G))


def line_angles_deg(lines: list[tuple[float, float]]) -> list[float]:
    """The four angles between consecutive lines of the five (slope, intercept) tap lines."""
    atans = [slope_angle_deg(slope) for slope, _ in lines]
    return [atans[i] - atans[i + 1] for i in range(4)]
