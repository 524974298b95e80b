"""ZMesh lookups, fade, zero reference, status, and G1 move splitting."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tapcell.mesh.errors import MeshError, MeshOptionError
from tapcell.mesh.grid import rectangular_grid
from tapcell.mesh.interpolate import Interpolation
from tapcell.mesh.split import SplitSettings, split_move
from tapcell.mesh.zmesh import (
    Fade,
    adjusted_z_mm,
    build_mesh,
    empty_mesh_status,
    fade_factor,
    fade_target_mm,
    gcode_z_mm,
    resolve_zero_reference,
)

GRID = rectangular_grid((0, 0), (200, 100), 3)
DIRECT = Interpolation("direct", 0, 0)


def ramp_mesh(slope_per_mm=0.001, **kwargs):
    """Bed rising along X only: z = slope * x; probed at x = 0, 100, 200."""
    probed = np.tile(slope_per_mm * GRID.x_positions_mm(), (3, 1))
    return build_mesh(probed, GRID, DIRECT, **kwargs)


def test_fade_factor_arithmetic():
    fade = Fade(start_mm=1.0, end_mm=10.0)
    assert fade_factor(0.2, fade) == 1.0
    assert fade_factor(1.0, fade) == 1.0
    assert fade_factor(5.5, fade) == pytest.approx(0.5)
    assert fade_factor(7.75, fade) == pytest.approx(0.25)
    assert fade_factor(10.0, fade) == 0.0
    assert fade_factor(50.0, fade) == 0.0
    assert fade_factor(50.0, Fade(1.0, 0.0)) == 1.0  # the default: end below start, no fade
    assert not Fade(1.0, 1.0).enabled


def test_adjusted_z_fades_from_the_bed_to_the_target():
    mesh = ramp_mesh()  # bed 0.15 mm at x = 150, average 0.1
    fade = Fade(1.0, 10.0, target_mm=0.0)
    assert adjusted_z_mm(mesh, fade, 150, 50, 0.2) == pytest.approx(0.35)
    assert adjusted_z_mm(mesh, fade, 150, 50, 5.5) == pytest.approx(5.5 + 0.5 * 0.15)
    assert adjusted_z_mm(mesh, fade, 150, 50, 12.0) == pytest.approx(12.0)
    default_target = Fade(1.0, 10.0)
    assert fade_target_mm(mesh, default_target) == pytest.approx(0.1)
    assert adjusted_z_mm(mesh, default_target, 150, 50, 12.0) == pytest.approx(12.1)
    assert adjusted_z_mm(mesh, default_target, 150, 50, 5.5) == pytest.approx(5.5 + 0.1 + 0.5 * 0.05)
    assert adjusted_z_mm(mesh, Fade(), 150, 50, 40.0) == pytest.approx(40.15)  # fade off: always the bed


@pytest.mark.parametrize("z_mm", [0.2, 1.0, 3.3, 9.99, 10.0, 25.0])
def test_gcode_z_inverts_the_adjustment(z_mm):
    mesh = ramp_mesh(slope_per_mm=0.004)
    fade = Fade(1.0, 10.0, target_mm=0.3)
    toolhead = adjusted_z_mm(mesh, fade, 170, 20, z_mm)
    assert gcode_z_mm(mesh, fade, 170, 20, toolhead) == pytest.approx(z_mm, abs=1e-12)
    assert gcode_z_mm(mesh, Fade(), 170, 20, adjusted_z_mm(mesh, Fade(), 170, 20, z_mm)) == pytest.approx(z_mm)


def test_fade_target_outside_the_mesh_range_is_refused():
    mesh = ramp_mesh()
    with pytest.raises(MeshOptionError, match=r"fade_target = 0.5: must be 0 or within the mesh Z range 0.0000 .. 0.2000"):
        fade_target_mm(mesh, Fade(1.0, 10.0, target_mm=0.5))
    assert fade_target_mm(mesh, Fade(1.0, 10.0, target_mm=0.0)) == 0.0


def test_zero_reference_shifts_the_mesh_to_zero_there():
    reference = resolve_zero_reference(GRID, zero_reference_position=(150, 30))
    mesh = ramp_mesh(zero_reference_xy_mm=reference)
    assert mesh.zero_reference_offset_mm == pytest.approx(0.15)
    assert mesh.z_at(150, 30) == pytest.approx(0.0, abs=1e-15)
    assert mesh.probed_matrix_mm[0].tolist() == pytest.approx([-0.15, -0.05, 0.05])


def test_relative_reference_index_becomes_a_zero_reference():
    assert resolve_zero_reference(GRID, relative_reference_index=4) == (100.0, 50.0)
    assert resolve_zero_reference(GRID) is None
    with pytest.raises(MeshOptionError, match="relative_reference_index = 4: cannot be combined with zero_reference"):
        resolve_zero_reference(GRID, (1, 2), 4)


def test_status_has_the_klipper_fields_and_is_json_ready():
    mesh = ramp_mesh(profile_name="pei")
    status = json.loads(json.dumps(mesh.to_status()))
    assert status["profile_name"] == "pei"
    assert status["mesh_min"] == [0.0, 0.0]
    assert status["mesh_max"] == [200.0, 100.0]
    assert status["probed_matrix"][2] == pytest.approx([0.0, 0.1, 0.2])
    assert len(status["mesh_matrix"]) == 3
    assert empty_mesh_status()["profile_name"] == ""


def test_build_mesh_rejects_a_wrong_shape_or_nan():
    with pytest.raises(MeshError, match=r"probed matrix is 2 x 3 \(rows x columns\) but the mesh is 3 x 3"):
        build_mesh(np.zeros((2, 3)), GRID, DIRECT)
    with pytest.raises(MeshError, match="not a finite number"):
        build_mesh(np.array([[0, 0, 0], [0, np.nan, 0], [0, 0, 0]]), GRID, DIRECT)


def test_split_cuts_where_the_mesh_changes_by_split_delta_z():
    mesh = ramp_mesh(slope_per_mm=0.0012)  # 1.2 um per mm along X
    settings = SplitSettings(move_check_distance_mm=5.0, split_delta_z_mm=0.025)
    moves = split_move((10, 50, 0.2, 0), (110, 50, 0.2, 4), mesh, Fade(), settings)
    # The offset changes 6 um per 5 mm check: 4 checks (24 um) stay below 25 um, the 5th
    # (30 um) cuts -> cuts at 35, 60, 85, then the move's end at 110.
    assert moves[:, 0].tolist() == pytest.approx([35, 60, 85, 110])
    assert moves[:, 1].tolist() == pytest.approx([50, 50, 50, 50])
    assert moves[:, 2].tolist() == pytest.approx([0.242, 0.272, 0.302, 0.332])
    assert moves[:, 3].tolist() == pytest.approx([1.0, 2.0, 3.0, 4.0])  # E follows the line


def test_split_with_aggressive_settings_and_every_check_point_within_delta():
    mesh = ramp_mesh(slope_per_mm=0.0023)
    settings = SplitSettings(move_check_distance_mm=3.0, split_delta_z_mm=0.01)
    start, end = np.array([0.0, 0, 0.3, 0]), np.array([120.0, 90, 0.3, 0])
    moves = split_move(start, end, mesh, Fade(), settings)
    # 150 mm move: checks every 3 mm; offset grows 3 * 0.8 * 2.3 = 5.52 um per check -> a cut every 2 checks.
    assert len(moves) == 25
    assert np.linalg.norm(moves[0, :2] - start[:2]) == pytest.approx(6.0)
    offsets = moves[:, 2] - 0.3
    assert offsets == pytest.approx(mesh.z_at(moves[:, 0], moves[:, 1]))
    assert np.all(np.abs(np.diff(offsets)) >= 0.01 - 1e-12)
    assert np.all(np.abs(np.diff(offsets[:-1])) <= 0.012)


def test_moves_without_xy_or_over_a_flat_mesh_are_not_split():
    mesh = ramp_mesh()
    z_only = split_move((50, 50, 0.2, 0), (50, 50, 5.0, 0), mesh, Fade(), SplitSettings())
    np.testing.assert_allclose(z_only, [[50, 50, 5.05, 0]])
    along_y = split_move((50, 0, 0.2, 0), (50, 100, 0.2, 0), mesh, Fade(), SplitSettings())
    np.testing.assert_allclose(along_y, [[50, 100, 0.25, 0]])


def test_split_above_fade_end_follows_the_target_only():
    mesh = ramp_mesh()
    moves = split_move((0, 50, 12, 0), (200, 50, 12, 0), mesh, Fade(1, 10, target_mm=0.0), SplitSettings())
    np.testing.assert_allclose(moves, [[200, 50, 12.0, 0]])


def test_split_settings_validation_names_the_option():
    with pytest.raises(MeshOptionError, match=r"\[bed_mesh\] move_check_distance = 1.0: must be at least 3.0 mm"):
        SplitSettings(move_check_distance_mm=1.0)
    with pytest.raises(MeshOptionError, match=r"\[bed_mesh\] split_delta_z = 0.001: must be at least 0.01 mm"):
        SplitSettings(split_delta_z_mm=0.001)
