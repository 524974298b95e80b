"""Points far from their neighbours' plane (the trigger-only mesh check)."""

from __future__ import annotations

import numpy as np

from tapcell.mesh.outliers import OUTLIER_MM, neighbour_residuals_mm, worst_outlier


def grid(n: int = 5) -> np.ndarray:
    xs = np.linspace(15.0, 220.0, n)
    x, y = np.meshgrid(xs, xs)
    return np.column_stack([x.ravel(), y.ravel()])


def test_a_tilted_bed_has_no_outlier_and_a_false_point_is_the_worst():
    xy = grid()
    tilted = 0.4 * xy[:, 0] / 235.0 - 0.25 * xy[:, 1] / 235.0
    assert np.max(neighbour_residuals_mm(xy, tilted)) < 1e-12
    assert worst_outlier(xy, tilted, set()) is None
    fooled = tilted.copy()
    fooled[7] += 5.0                      # a touch in the air: 5 mm "above the bed"
    assert worst_outlier(xy, fooled, set()) == 7
    assert worst_outlier(xy, fooled, {7}) is not None          # its neighbours' planes lean toward it
    assert worst_outlier(xy, tilted, {7}) is None


def test_small_honest_bumps_are_left_alone():
    xy = grid(7)
    bumpy = 0.1 * np.sin(xy[:, 0] / 80.0) * np.cos(xy[:, 1] / 90.0)
    assert np.max(neighbour_residuals_mm(xy, bumpy)) < OUTLIER_MM
