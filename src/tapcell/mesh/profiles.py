"""Mesh profiles as stored by SAVE_CONFIG in a `[bed_mesh NAME]` section.

The options, in the order they are written:

    version     profile format version (1)
    points      the probed matrix, one row per line (front row first), values in mm
    x_count, y_count, mesh_x_pps, mesh_y_pps, algo, tension, min_x, max_x, min_y, max_y

`profile_options` turns a mesh into these option strings; `mesh_from_profile_options`
checks them and rebuilds the mesh. Every error names the section, the option and the value.
Points are written with 6 decimals (1 nm), far below anything a probe resolves.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from tapcell.mesh.errors import MeshOptionError
from tapcell.mesh.grid import MIN_PROBE_COUNT, MeshGrid
from tapcell.mesh.interpolate import ALGORITHMS, LAGRANGE_MAX_POINTS, TENSION_RANGE, Interpolation
from tapcell.mesh.zmesh import ZMesh, build_mesh

PROFILE_VERSION = 1
PROFILE_ALGORITHMS = (*ALGORITHMS, "direct")


def profile_section_name(profile_name: str) -> str:
    return f"bed_mesh {profile_name}"


def profile_options(mesh: ZMesh) -> dict[str, str]:
    """The options of the mesh's `[bed_mesh NAME]` section, as strings in the stored order.

    The zero-reference shift is already in the probed matrix, so a loaded profile needs no
    reference to be applied again.
    """
    rows = ["  " + ", ".join(f"{z:.6f}" for z in row) for row in mesh.probed_matrix_mm]
    grid, interpolation = mesh.grid, mesh.interpolation
    return {
        "version": str(PROFILE_VERSION),
        "points": "\n" + "\n".join(rows),
        "x_count": str(grid.x_count),
        "y_count": str(grid.y_count),
        "mesh_x_pps": str(interpolation.mesh_x_pps),
        "mesh_y_pps": str(interpolation.mesh_y_pps),
        "algo": interpolation.algorithm,
        "tension": repr(float(interpolation.bicubic_tension)),
        "min_x": repr(grid.min_x_mm),
        "max_x": repr(grid.max_x_mm),
        "min_y": repr(grid.min_y_mm),
        "max_y": repr(grid.max_y_mm),
    }


def render_profile_section(mesh: ZMesh) -> str:
    """The section as config text (what SAVE_CONFIG appends, before its comment prefix)."""
    lines = [f"[{profile_section_name(mesh.profile_name)}]"]
    for option, value in profile_options(mesh).items():
        # A multi-line value starts on the next line, so nothing trails the "=".
        lines.append(f"{option} ={value}" if value.startswith("\n") else f"{option} = {value}")
    return "\n".join(lines) + "\n"


class _Reader:
    """Typed access to one profile section's options, with errors that name them."""

    def __init__(self, section: str, options: Mapping[str, str]) -> None:
        self.section = section
        self.options = options

    def text(self, option: str) -> str:
        if option not in self.options:
            raise MeshOptionError(self.section, option, "(missing)", "this option is required in a saved mesh profile")
        return str(self.options[option]).strip()

    def integer(self, option: str, minimum: int) -> int:
        value = self.text(option)
        try:
            number = int(value)
        except ValueError:
            raise MeshOptionError(self.section, option, value, f"must be an integer of at least {minimum}") from None
        if number < minimum:
            raise MeshOptionError(self.section, option, value, f"must be an integer of at least {minimum}")
        return number

    def number(self, option: str) -> float:
        value = self.text(option)
        try:
            number = float(value)
        except ValueError:
            number = math.nan
        if not math.isfinite(number):
            raise MeshOptionError(self.section, option, value, "must be a finite number")
        return number


def mesh_from_profile_options(profile_name: str, options: Mapping[str, str]) -> ZMesh:
    """Rebuild a mesh from its `[bed_mesh NAME]` options (strings, as read from the config)."""
    reader = _Reader(profile_section_name(profile_name), options)
    version = reader.text("version")
    if version != str(PROFILE_VERSION):
        raise MeshOptionError(
            reader.section, "version", version, f"this tapcell reads profile version {PROFILE_VERSION}; probe the mesh again"
        )
    x_count = reader.integer("x_count", MIN_PROBE_COUNT)
    y_count = reader.integer("y_count", MIN_PROBE_COUNT)
    interpolation = Interpolation(
        algorithm=_algorithm(reader, x_count, y_count),
        mesh_x_pps=reader.integer("mesh_x_pps", 0),
        mesh_y_pps=reader.integer("mesh_y_pps", 0),
        bicubic_tension=_tension(reader),
    )
    grid = MeshGrid(
        min_x_mm=reader.number("min_x"),
        max_x_mm=reader.number("max_x"),
        min_y_mm=reader.number("min_y"),
        max_y_mm=reader.number("max_y"),
        x_count=x_count,
        y_count=y_count,
    )
    for low, high in (("min_x", "max_x"), ("min_y", "max_y")):
        if reader.number(high) <= reader.number(low):
            raise MeshOptionError(reader.section, high, reader.text(high), f"must be greater than {low} ({reader.text(low)})")
    return build_mesh(_points(reader, x_count, y_count), grid, interpolation, profile_name)


def _algorithm(reader: _Reader, x_count: int, y_count: int) -> str:
    algorithm = reader.text("algo")
    if algorithm not in PROFILE_ALGORITHMS:
        raise MeshOptionError(reader.section, "algo", algorithm, "must be one of: " + ", ".join(PROFILE_ALGORITHMS))
    if algorithm == "lagrange" and max(x_count, y_count) > LAGRANGE_MAX_POINTS:
        raise MeshOptionError(
            reader.section, "algo", algorithm, f"lagrange allows at most {LAGRANGE_MAX_POINTS} points per axis (x_count, y_count = {x_count}, {y_count})"
        )
    return algorithm


def _tension(reader: _Reader) -> float:
    tension = reader.number("tension")
    low, high = TENSION_RANGE
    if not low <= tension <= high:
        raise MeshOptionError(reader.section, "tension", reader.text("tension"), f"must be between {low} and {high}")
    return tension


def _points(reader: _Reader, x_count: int, y_count: int) -> np.ndarray:
    rows = [line for line in reader.text("points").splitlines() if line.strip()]
    if len(rows) != y_count:
        raise MeshOptionError(
            reader.section, "points", f"({len(rows)} rows)", f"must have y_count = {y_count} rows of {x_count} values"
        )
    matrix = np.empty((y_count, x_count))
    for row_index, line in enumerate(rows):
        values = [v.strip() for v in line.split(",")]
        if len(values) != x_count:
            raise MeshOptionError(
                reader.section, "points", line.strip(), f"row {row_index + 1} must have x_count = {x_count} values"
            )
        for column, value in enumerate(values):
            try:
                matrix[row_index, column] = float(value)
            except ValueError:
                matrix[row_index, column] = math.nan
            if not math.isfinite(matrix[row_index, column]):
                raise MeshOptionError(
                    reader.section, "points", value, f"row {row_index + 1} value {column + 1} must be a finite number"
                )
    return matrix
