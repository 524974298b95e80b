"""Adaptive meshes and faulty regions: pure geometry (tapcell.mesh.adaptive, .faulty_regions)."""

import numpy as np
import pytest

from tapcell.mesh.adaptive import adapt_grid
from tapcell.mesh.errors import MeshOptionError
from tapcell.mesh.faulty_regions import make_regions, probing_plan
from tapcell.mesh.grid import rectangular_grid, round_grid

GRID = rectangular_grid((15, 15), (220, 220), (7, 7))  # the example printer's mesh


def square(x0, y0, size):
    return [[x0, y0], [x0 + size, y0], [x0 + size, y0 + size], [x0, y0 + size]]


def test_adaptive_mesh_covers_the_objects_plus_margin_at_the_configured_density():
    adapted = adapt_grid(GRID, [square(100, 100, 20), square(130, 90, 10)], margin_mm=5)
    grid = adapted.grid
    assert (grid.min_x_mm, grid.min_y_mm, grid.max_x_mm, grid.max_y_mm) == (95, 85, 145, 125)
    # 50 mm of the configured 205 mm: ceil(7 * 50 / 205) = 2 -> at least 3; 40 mm -> 2 -> 3.
    assert (grid.x_count, grid.y_count) == (3, 3)
    assert adapted.objects_min_xy_mm == (100, 90) and adapted.objects_max_xy_mm == (140, 120)


def test_adaptive_mesh_is_clipped_to_the_configured_area_and_keeps_bicubic_counts():
    wide = adapt_grid(GRID, [[[0, 100], [235, 110]]], margin_mm=10).grid
    assert (wide.min_x_mm, wide.max_x_mm, wide.min_y_mm, wide.max_y_mm) == (15, 220, 90, 120)
    # X keeps all 7 points (more than lagrange's 6), so Y gets bicubic's minimum of 4, not 3.
    assert (wide.x_count, wide.y_count) == (7, 4)
    # One tiny object: the points stay at least 1 mm apart.
    dot = adapt_grid(GRID, [[[50, 50]]], margin_mm=0).grid
    assert (dot.max_x_mm - dot.min_x_mm, dot.max_y_mm - dot.min_y_mm) == (2.0, 2.0)
    assert (dot.min_x_mm + dot.max_x_mm) / 2 == 50
    assert adapt_grid(GRID, [], 5) is None and adapt_grid(GRID, [[]], 5) is None


def test_adaptive_round_bed_shrinks_only_when_the_circle_fits():
    bed = round_grid(100.0, (0.0, 0.0), 7)
    small = adapt_grid(bed, [square(-10, -10, 20)], margin_mm=0)
    assert small.shrunk and small.grid.radius_mm == pytest.approx(np.hypot(20, 20) / 2)
    assert small.grid.x_count % 2 == 1 and small.grid.x_count >= 3
    edge = adapt_grid(bed, [square(60, 60, 30)], margin_mm=0)
    assert not edge.shrunk and edge.grid == bed


def test_a_point_in_a_faulty_region_is_probed_on_the_region_edges_and_averaged():
    grid = rectangular_grid((0, 0), (200, 200), (3, 3))
    plan = probing_plan(grid, make_regions({1: ((90, 80), (120, 110))}))
    assert plan.substituted == {4: ((120.0, 100.0), (100.0, 110.0), (100.0, 80.0), (90.0, 100.0))}
    places = plan.flat_places_mm()
    assert len(places) == 9 - 1 + 4
    # On a plane the average of the four edge places is not the centre unless symmetric: here
    # X edges at 90/120 (mean 105) and Y edges at 80/110 (mean 95), as Klipper averages them.
    def plane(x, y):
        return 0.001 * x + 0.002 * y

    folded = plan.fold(plane(places[:, 0], places[:, 1]))
    assert folded[4] == pytest.approx((plane(120, 100) + plane(100, 110) + plane(100, 80) + plane(90, 100)) / 4)
    assert folded[0] == plane(0, 0) and folded[8] == plane(200, 200)
    # A region at the mesh's corner: only the edges inside the mesh are probed.
    corner = probing_plan(grid, make_regions({3: ((-10, -10), (20, 30))})).substituted
    assert corner == {0: ((0.0, 30.0), (20.0, 0.0))}


def test_faulty_region_errors_name_the_option():
    with pytest.raises(MeshOptionError) as info:
        make_regions({1: ((0, 0), (50, 50)), 2: ((40, 40), (80, 80))})
    assert info.value.option == "faulty_region_2_min"
    assert "overlaps faulty_region_1 (0, 0) .. (50, 50)" in info.value.allowed
    # Corners given the wrong way round are put in order.
    assert make_regions({1: ((50, 60), (10, 20))})[0].min_xy_mm == (10, 20)
    grid = rectangular_grid((0, 0), (100, 100), (3, 3))
    with pytest.raises(MeshOptionError) as info:
        probing_plan(grid, make_regions({4: ((-10, -10), (110, 110))}))
    assert info.value.option == "faulty_region_4_min"
    assert "mesh point 0 (0, 0) lies inside faulty_region_4" in info.value.allowed
