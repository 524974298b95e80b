"""Text and image reports of a mesh."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from tapcell.mesh.abl import TwoPassPoint, topology_report
from tapcell.mesh.grid import rectangular_grid
from tapcell.mesh.interpolate import Interpolation, resolve_interpolation
from tapcell.mesh.faulty_regions import make_regions, probing_plan
from tapcell.mesh.report import (
    mesh_error,
    render_generated_points,
    render_mesh,
    render_mesh_error,
    render_mesh_map,
    render_probed_matrix,
    render_topology,
    mesh_figure,
    write_mesh_png,
)
from tapcell.mesh.zmesh import build_mesh

GRID = rectangular_grid((0, 0), (200, 100), 3)
PROBED = np.array([[0.0, 0.01, 0.02], [0.03, 0.04, 0.05], [0.06, 0.07, 0.08]])


def test_bed_mesh_output_in_klippers_format():
    """Klipper prints the probed rows front first, then the interpolated mesh back row first."""
    mesh = build_mesh(PROBED, GRID, resolve_interpolation("lagrange", (3, 3))[0], profile_name="default")
    assert render_probed_matrix(mesh).splitlines() == [
        "Mesh Leveling Probed Z positions:",
        " 0.000000 0.010000 0.020000",
        " 0.030000 0.040000 0.050000",
        " 0.060000 0.070000 0.080000",
    ]
    lines = render_mesh(mesh, 5.0, (0.0, -1.5)).splitlines()
    assert lines[:7] == [
        "Mesh X,Y: 7,7",
        "Search Height: 5",
        "Mesh Offsets: X=0.0000, Y=-1.5000",
        "Mesh Average: 0.04",
        "Mesh Range: min=0.0000 max=0.0800",
        "Interpolation Algorithm: lagrange",
        "Measured points:",
    ]
    # A plane stays a plane: 7 x 7 points (2 between probed ones), 0.01 / 3 mm per column,
    # 0.03 / 3 mm per row, back row first.
    rows = [[float(v) for v in line.split()] for line in lines[7:]]
    expected = [[0.01 * row + 0.01 / 3 * column for column in range(7)] for row in range(6, -1, -1)]
    assert np.array(rows) == pytest.approx(np.array(expected), abs=1e-6)
    assert lines[7].startswith("  0.060000  0.063333")


def test_bed_mesh_map_and_generated_points():
    mesh = build_mesh(PROBED, GRID, Interpolation("direct", 0, 0), zero_reference_xy_mm=(100, 50))
    mapped = json.loads(render_mesh_map(mesh).removeprefix("mesh_map_output "))
    assert mapped["mesh_min"] == [0.0, 0.0] and mapped["mesh_max"] == [200.0, 100.0]
    # The probed heights after the zero reference shift (0.04 mm at 100, 50).
    assert np.array(mapped["z_positions"]) == pytest.approx(PROBED - 0.04, abs=1e-12)
    assert render_mesh_map(mesh).startswith("mesh_map_output {")
    plan = probing_plan(GRID, make_regions({1: ((90, 40), (110, 60))}))
    assert render_generated_points(plan, (0.0, 10.0), (100, 50)).splitlines() == [
        "bed_mesh: generated points",
        "Index |  Tool Adjusted  |   Probe",
        "  0   | (0.0, -10.0)    | (0.0, 0.0)",
        "  1   | (100.0, -10.0)  | (100.0, 0.0)",
        "  2   | (200.0, -10.0)  | (200.0, 0.0)",
        "  3   | (200.0, 40.0)   | (200.0, 50.0)",
        "  4   | (100.0, 40.0)   | (100.0, 50.0)",
        "  5   | (0.0, 40.0)     | (0.0, 50.0)",
        "  6   | (0.0, 90.0)     | (0.0, 100.0)",
        "  7   | (100.0, 90.0)   | (100.0, 100.0)",
        "  8   | (200.0, 90.0)   | (200.0, 100.0)",
        "bed_mesh: zero_reference_position is (100.00, 50.00)",
        "bed_mesh: faulty region points",
        # Row 1 runs toward -X: the substitutes come from the +X edge first.
        "4 (100.00, 50.00), substituted points: [(110.0, 50.0), (100.0, 60.0), (100.0, 40.0), (90.0, 50.0)]",
    ]


def test_mesh_error_against_a_truth_with_a_bump_between_points():
    def truth(x, y):
        # A plane plus a 10 um bump at (50, 25): zero at every probed point.
        return 0.0001 * x + 0.0006 * y + 0.01 * np.exp(-((x - 50) ** 2 + (y - 25) ** 2) / 50.0)

    x, y = np.meshgrid(GRID.x_positions_mm(), GRID.y_positions_mm())
    measured = 0.0001 * x + 0.0006 * y
    measured[1, 1] += 0.002  # the probe read 2 um high in the middle
    mesh = build_mesh(measured, GRID, Interpolation("direct", 0, 0))
    summary = mesh_error(mesh, truth, samples_per_axis=41)
    assert summary.max_abs_at_probed_um == pytest.approx(2.0, abs=1e-6)
    assert summary.rms_at_probed_um == pytest.approx(2.0 / 3.0, abs=1e-6)
    # Truth 10 um up; the mesh carries a quarter of the 2 um centre reading there: 10 - 0.5.
    assert summary.max_abs_over_area_um == pytest.approx(9.5, abs=1e-9)
    assert summary.worst_over_area_xy_mm == (50.0, 25.0)
    assert json.loads(json.dumps(summary.to_status()))["worst_over_area_xy_mm"] == [50.0, 25.0]
    text = render_mesh_error(summary)
    assert "at the probed points: largest error 2.00 um, typical (RMS) 0.67 um" in text
    assert "everywhere in between: largest error 9.50 um at X 50.0 Y 25.0" in text


def test_render_topology_table():
    points = [
        TwoPassPoint(0, 0.0, 0.0, 0.11, 0.32, 0.236),
        TwoPassPoint(1, 200.0, 0.0, 0.35, 0.55, 0.47),
        TwoPassPoint(2, 200.0, 200.0, 0.4, 0.61, 0.526),
    ]
    topology = topology_report([p.x_mm for p in points], [p.y_mm for p in points], [p.z_mm for p in points])
    lines = render_topology(points, topology).splitlines()
    assert lines[2] == "      1      0.0      0.0     0.110     0.320     0.236"
    assert lines[5] == (
        "  lowest 0.236 mm at (0.0, 0.0), highest 0.526 mm at (200.0, 200.0), range 0.290 mm, mean 0.411 mm"
    )
    assert lines[6] == "  tilt: +0.117 mm per 100 mm in X, +0.028 mm per 100 mm in Y (0.069 deg)"


def test_heat_map_png_has_two_panels_with_truth(tmp_path):
    import matplotlib.image

    mesh = build_mesh(PROBED, GRID, resolve_interpolation("lagrange", (3, 3))[0])
    single = write_mesh_png(tmp_path / "mesh.png", mesh, samples_per_axis=21)
    double = write_mesh_png(tmp_path / "mesh_and_error.png", mesh, lambda x, y: 0.0003 * x, samples_per_axis=21)
    assert matplotlib.image.imread(single).shape[:2] == (520, 550)
    assert matplotlib.image.imread(double).shape[:2] == (520, 1100)


def test_heat_map_in_mm_with_the_meshs_one_range():
    """The heat map reports the same range as BED_MESH_OUTPUT and BED_MESH_CALIBRATE, in mm, with
    a labelled colour bar whose ends are that range."""
    mesh = build_mesh(PROBED, GRID, resolve_interpolation("lagrange", (3, 3))[0])
    figure = mesh_figure(mesh, lambda x, y: 0.0003 * x, samples_per_axis=21)
    height, height_bar, error, error_bar = figure.axes
    low, high = mesh.z_range_mm()
    range_line = next(line for line in render_mesh(mesh, 5, (0, 0)).splitlines() if line.startswith("Mesh Range"))
    assert range_line == f"Mesh Range: min={low:.4f} max={high:.4f}"
    assert height.get_title() == f"Mesh: bed height\nmin {low:.4f} mm, max {high:.4f} mm, range {high - low:.4f} mm"
    assert height_bar.get_ylabel() == "bed height (mm)" and error_bar.get_ylabel() == "mesh - true bed (µm)"
    assert height.images[0].get_clim() == (low, high)
    assert float(np.max(height.images[0].get_array())) == pytest.approx(high)  # mm, not µm
    assert [t.get_text() for t in height.get_legend().get_texts()] == ["probed points"]


def test_heat_map_shows_edge_points_whole_keeps_the_legend_off_the_map_and_marks_the_worst_spot():
    """The issue's pictures: edge dots cut in half by the frame, the legend over the map, the error
    map without its worst spot or a word that only a simulator knows the true bed."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    mesh = build_mesh(PROBED, GRID, resolve_interpolation("lagrange", (3, 3))[0])

    def truth(x, y):
        return 0.0003 * x + 0.00002 * (x - 60.0) ** 2 * (y > 150)

    figure = mesh_figure(mesh, truth, samples_per_axis=21)
    FigureCanvasAgg(figure).draw()
    height, _, error, _ = figure.axes
    probed = GRID.probe_points_mm()
    for axes in (height, error):
        (low_x, high_x), (low_y, high_y) = axes.get_xlim(), axes.get_ylim()
        assert low_x < probed[:, 0].min() and probed[:, 0].max() < high_x
        assert low_y < probed[:, 1].min() and probed[:, 1].max() < high_y
        # The legend sits below the map, not on it.
        assert axes.get_legend().get_window_extent().y1 < axes.get_window_extent().y0
    assert error.get_title().startswith("Mesh - true bed (simulator only: a real printer\ndoes not know its true bed)")
    summary = mesh_error(mesh, truth, samples_per_axis=21)
    (label,) = [t.get_text() for t in error.get_legend().get_texts() if t.get_text().startswith("largest")]
    x_mm, y_mm = (float(v) for v in re.search(r"at X (\S+) Y (\S+)$", label).groups())
    worst_um = float(re.search(r"largest error ([+-]\d+\.\d) µm", label).group(1))
    assert abs(worst_um) == pytest.approx(summary.max_abs_over_area_um, abs=0.05)
    assert (x_mm, y_mm) == pytest.approx(summary.worst_over_area_xy_mm, abs=0.05)
    assert abs((mesh.z_at(np.array(x_mm), np.array(y_mm)) - truth(x_mm, y_mm)) * 1000.0) == pytest.approx(
        abs(worst_um), abs=0.05)
