"""Mesh geometry and interpolation on surfaces whose true values are known."""

from __future__ import annotations

import numpy as np
import pytest

from tapcell.mesh.errors import MeshOptionError
from tapcell.mesh.grid import matrix_from_probes, rectangular_grid, reference_point_from_index, round_grid
from tapcell.mesh.interpolate import Interpolation, bilinear_at, resolve_interpolation, upsample
from tapcell.mesh.zmesh import build_mesh


def plane(x, y):
    return 0.12 + 0.0015 * x - 0.0008 * y


def sample(grid, surface):
    points = grid.probe_points_mm()
    return matrix_from_probes(grid, surface(points[:, 0], points[:, 1]))


def test_serpentine_order_matches_the_papers_table_1():
    grid = rectangular_grid((0, 0), (400, 400), 3)
    expected = [(0, 0), (200, 0), (400, 0), (400, 200), (200, 200), (0, 200), (0, 400), (200, 400), (400, 400)]
    assert grid.probe_points_mm().tolist() == [list(p) for p in expected]


def test_rectangular_grid_counts_per_axis():
    grid = rectangular_grid((10, 20), (190, 180), (4, 3))
    points = grid.probe_points_mm()
    assert len(points) == 12
    assert points[0].tolist() == [10, 20]
    assert points[4].tolist() == [190, 100]  # second row starts at the right
    assert points[-1].tolist() == [190, 180]


def test_round_bed_skips_corners_and_fills_rows_from_the_nearest_point():
    grid = round_grid(100.0, (10.0, 0.0), 5)
    points = grid.probe_points_mm()
    assert len(points) == 13  # rows of 1, 3, 5, 3, 1
    assert points[0].tolist() == [10, -100]
    assert points[-1].tolist() == [10, 100]
    matrix = matrix_from_probes(grid, np.arange(13.0))
    assert matrix[1].tolist() == [3, 3, 2, 1, 1]  # row probed right to left: 1, 2, 3
    assert matrix[0].tolist() == [0, 0, 0, 0, 0]


def test_grid_errors_name_the_option():
    with pytest.raises(MeshOptionError, match=r"\[bed_mesh\] probe_count = 2, 3: must be 3 to 50 points on each axis"):
        rectangular_grid((0, 0), (100, 100), (2, 3))
    with pytest.raises(MeshOptionError, match=r"mesh_max = 100, 50: Y must be greater than mesh_min Y \(60\)"):
        rectangular_grid((0, 60), (100, 50), 3)
    with pytest.raises(MeshOptionError, match="round_probe_count = 4: must be an odd integer"):
        round_grid(100.0, (0, 0), 4)
    with pytest.raises(MeshOptionError, match="relative_reference_index = 9: must be a probe point index from 0 to 8"):
        reference_point_from_index(rectangular_grid((0, 0), (100, 100), 3), 9)


def test_relative_reference_index_counts_in_probing_order():
    grid = rectangular_grid((0, 0), (100, 100), 3)
    assert reference_point_from_index(grid, 3) == (100.0, 50.0)


@pytest.mark.parametrize(
    ("algorithm", "count", "tension"), [("lagrange", (3, 3), 0.2), ("lagrange", (5, 4), 0.2), ("bicubic", (5, 7), 0.5)]
)
def test_planes_are_exact_everywhere(algorithm, count, tension):
    grid = rectangular_grid((20, 10), (220, 190), count)
    interpolation, _ = resolve_interpolation(algorithm, count, (3, 2), tension)
    mesh = build_mesh(sample(grid, plane), grid, interpolation)
    x, y = np.meshgrid(np.linspace(20, 220, 37), np.linspace(10, 190, 29))
    np.testing.assert_allclose(mesh.z_at(x, y), plane(x, y), atol=1e-12)


def test_bicubic_tension_below_half_bends_a_plane_between_points():
    # Tension sets the tangents: 0.2 (the default) gives flatter tangents than the slope,
    # so a ramp becomes an S between points while staying exact at them.
    grid = rectangular_grid((0, 0), (300, 300), 4)
    soft, _ = resolve_interpolation("bicubic", (4, 4), 2, 0.2)
    mesh = build_mesh(sample(grid, lambda x, y: 0.001 * x), grid, soft)
    # First inserted point of the middle segment (t = 1/3 of the way from x=100 to x=200).
    t = 1 / 3
    s_curve = 0.1 + 0.1 * (3 * t * t - 2 * t**3) + 0.1 * 0.2 * 2 * (t**3 - 2 * t * t + t) + 0.1 * 0.2 * 2 * (t**3 - t * t)
    assert mesh.mesh_matrix_mm[0, 4] == pytest.approx(s_curve, abs=1e-12)
    assert mesh.mesh_matrix_mm[0, 4] != pytest.approx(0.1 + 0.1 * t, abs=1e-3)


def test_lagrange_reproduces_a_quadratic_from_three_points():
    def bowl(x, y):
        return 0.05 + 2e-5 * (x - 80) ** 2 - 1e-5 * (y - 30) ** 2 + 3e-7 * x * y

    grid = rectangular_grid((0, 0), (200, 200), 3)
    interpolation, _ = resolve_interpolation("lagrange", (3, 3), 4)
    mesh = build_mesh(sample(grid, bowl), grid, interpolation)
    x, y = np.meshgrid(np.linspace(0, 200, 11), np.linspace(0, 200, 11))  # 2 segments x (4 + 1) + 1
    np.testing.assert_allclose(mesh.mesh_matrix_mm, bowl(x, y), atol=1e-12)


@pytest.mark.parametrize("algorithm", ["lagrange", "bicubic"])
def test_probed_values_are_returned_exactly(algorithm):
    rng = np.random.default_rng(7)
    probed = rng.normal(0, 0.1, size=(5, 6))
    grid = rectangular_grid((0, 0), (250, 200), (6, 5))
    interpolation, _ = resolve_interpolation(algorithm, (6, 5), (2, 3), 0.2)
    mesh = build_mesh(probed, grid, interpolation)
    x, y = np.meshgrid(grid.x_positions_mm(), grid.y_positions_mm())
    np.testing.assert_array_equal(np.round(mesh.z_at(x, y) - probed, 13), 0.0)
    assert mesh.mesh_matrix_mm.shape == (5 + 4 * 3, 6 + 5 * 2)


def test_bilinear_between_four_points_and_clamped_outside():
    matrix = np.array([[0.0, 1.0], [2.0, 4.0]])
    assert bilinear_at(matrix, (0, 0), (10, 10), 5, 5) == pytest.approx(1.75)
    assert bilinear_at(matrix, (0, 0), (10, 10), 2, 0) == pytest.approx(0.2)
    assert bilinear_at(matrix, (0, 0), (10, 10), -50, 99) == pytest.approx(2.0)  # clamped to (0, 10)
    assert bilinear_at(matrix, (0, 0), (10, 10), 30, -3) == pytest.approx(1.0)


def test_direct_mode_is_bilinear_between_probed_points():
    grid = rectangular_grid((0, 0), (100, 100), 3)
    interpolation, note = resolve_interpolation("lagrange", (3, 3), 0)
    assert interpolation == Interpolation("direct", 0, 0, 0.2)
    assert "mesh_pps 0, 0" in note
    probed = np.array([[0, 0, 0], [0, 1.0, 0], [0, 0, 0]])
    mesh = build_mesh(probed, grid, interpolation)
    assert mesh.z_at(25, 50) == pytest.approx(0.5)
    assert mesh.z_at(75, 75) == pytest.approx(0.25)


def test_algorithm_validation_names_the_option():
    with pytest.raises(MeshOptionError, match=r"probe_count = 7, 7: lagrange allows at most 6 points per axis"):
        resolve_interpolation("lagrange", (7, 7))
    with pytest.raises(MeshOptionError, match=r"probe_count = 3, 7: bicubic needs at least 4 points on each axis"):
        resolve_interpolation("bicubic", (3, 7))
    with pytest.raises(MeshOptionError, match=r"algorithm = spline: must be one of: lagrange, bicubic"):
        resolve_interpolation("spline", (5, 5))
    with pytest.raises(MeshOptionError, match=r"bicubic_tension = 2.5: must be between 0.0 and 2.0"):
        resolve_interpolation("bicubic", (5, 5), 2, 2.5)
    with pytest.raises(MeshOptionError, match=r"mesh_pps = \(2, -1\)"):
        resolve_interpolation("bicubic", (5, 5), (2, -1))


def test_bicubic_on_three_points_falls_back_to_lagrange_with_a_note():
    interpolation, note = resolve_interpolation("bicubic", (3, 5), 2, 0.3)
    assert interpolation.algorithm == "lagrange"
    assert note == "bicubic needs at least 4 points on each axis; probe_count 3, 5 uses lagrange"
    assert resolve_interpolation("bicubic", (7, 7))[0].algorithm == "bicubic"


def test_upsample_shape_follows_mesh_pps():
    assert upsample(np.zeros((4, 3)), Interpolation("lagrange", 3, 1)).shape == (7, 9)
