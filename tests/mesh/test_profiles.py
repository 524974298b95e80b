"""Mesh profiles through the config text form SAVE_CONFIG writes."""

from __future__ import annotations

import configparser

import numpy as np
import pytest

from tapcell.mesh.errors import MeshOptionError
from tapcell.mesh.grid import rectangular_grid
from tapcell.mesh.interpolate import resolve_interpolation
from tapcell.mesh.profiles import mesh_from_profile_options, profile_options, render_profile_section
from tapcell.mesh.zmesh import build_mesh

PROBED = np.array(
    [
        [0.012345, -0.020000, 0.031000, 0.0],
        [0.100000, 0.050500, -0.007000, 0.002],
        [-0.044444, 0.000001, 0.070000, 0.013],
        [0.2, 0.1, 0.0, -0.1],
    ]
)


def saved_mesh():
    grid = rectangular_grid((15.5, 10), (215.5, 190), 4)
    interpolation, _ = resolve_interpolation("bicubic", (4, 4), (3, 2), 0.35)
    return build_mesh(PROBED, grid, interpolation, profile_name="textured sheet")


def read_section(text: str, section: str) -> dict[str, str]:
    parser = configparser.RawConfigParser()
    parser.read_string(text)
    return dict(parser[section])


def test_rendered_section_text():
    text = render_profile_section(saved_mesh())
    lines = text.splitlines()
    assert lines[0] == "[bed_mesh textured sheet]"
    assert lines[1:4] == ["version = 1", "points =", "  0.012345, -0.020000, 0.031000, 0.000000"]
    assert lines[7:] == [
        "x_count = 4",
        "y_count = 4",
        "mesh_x_pps = 3",
        "mesh_y_pps = 2",
        "algo = bicubic",
        "tension = 0.35",
        "min_x = 15.5",
        "max_x = 215.5",
        "min_y = 10.0",
        "max_y = 190.0",
    ]


def test_round_trip_through_the_config_text():
    original = saved_mesh()
    options = read_section(render_profile_section(original), "bed_mesh textured sheet")
    loaded = mesh_from_profile_options("textured sheet", options)
    np.testing.assert_array_equal(loaded.probed_matrix_mm, PROBED)
    np.testing.assert_allclose(loaded.mesh_matrix_mm, original.mesh_matrix_mm, atol=1e-15)
    assert loaded.grid == original.grid
    assert loaded.interpolation == original.interpolation
    assert loaded.to_status()["profile_name"] == "textured sheet"


def broken(option: str, value: str) -> dict[str, str]:
    options = profile_options(saved_mesh())
    if value is None:
        del options[option]
    else:
        options[option] = value
    return options


@pytest.mark.parametrize(
    ("option", "value", "message"),
    [
        ("version", "2", r"\[bed_mesh p\] version = 2: this tapcell reads profile version 1"),
        ("x_count", "three", r"\[bed_mesh p\] x_count = three: must be an integer of at least 3"),
        ("y_count", "2", r"y_count = 2: must be an integer of at least 3"),
        ("algo", "cubic", r"algo = cubic: must be one of: lagrange, bicubic, direct"),
        ("tension", "3", r"tension = 3: must be between 0.0 and 2.0"),
        ("min_x", "nan", r"min_x = nan: must be a finite number"),
        ("max_y", "5", r"max_y = 5: must be greater than min_y \(10.0\)"),
        ("points", "\n1, 2, 3, 4\n1, 2, 3, 4", r"points = \(2 rows\): must have y_count = 4 rows of 4 values"),
        ("points", "\n1,2,3,4\n1,2,3\n1,2,3,4\n1,2,3,4", r"points = 1,2,3: row 2 must have x_count = 4 values"),
        ("points", "\n1,2,3,4\n1,2,3,4\n1,x,3,4\n1,2,3,4", r"points = x: row 3 value 2 must be a finite number"),
        ("mesh_x_pps", None, r"mesh_x_pps = \(missing\): this option is required"),
    ],
)
def test_bad_profiles_name_section_option_and_value(option, value, message):
    with pytest.raises(MeshOptionError, match=message):
        mesh_from_profile_options("p", broken(option, value))


def test_lagrange_profile_with_too_many_points_is_refused():
    options = profile_options(
        build_mesh(np.zeros((3, 7)), rectangular_grid((0, 0), (60, 20), (7, 3)), resolve_interpolation("bicubic", (7, 7))[0])
    )
    options["algo"] = "lagrange"
    with pytest.raises(MeshOptionError, match=r"algo = lagrange: lagrange allows at most 6 points per axis"):
        mesh_from_profile_options("wide", options)


def test_round_trip_through_save_config(tmp_path):
    from tapcell.host.config import ConfigFile

    path = tmp_path / "printer.cfg"
    path.write_text("[printer]\nkinematics: cartesian\n")
    config = ConfigFile.read(path)
    for option, value in profile_options(saved_mesh()).items():
        config.set("bed_mesh textured sheet", option, value)
    config.save()
    reread = ConfigFile.read(path)
    loaded = mesh_from_profile_options("textured sheet", reread.section_options("bed_mesh textured sheet"))
    np.testing.assert_array_equal(loaded.probed_matrix_mm, PROBED)
    assert loaded.interpolation == saved_mesh().interpolation
