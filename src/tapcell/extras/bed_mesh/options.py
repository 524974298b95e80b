"""`[bed_mesh]` options and the parameters of one BED_MESH_CALIBRATE."""

from __future__ import annotations

import re
from dataclasses import dataclass, replace

from tapcell.host.config import ConfigSection
from tapcell.host.gcode import GCodeCommand
from tapcell.host.toolhead import COORDINATE_RANGE, MAX_COORDINATE_MM, SPEED_RANGE
from tapcell.mesh.adaptive import adapt_grid
from tapcell.mesh.errors import MeshOptionError
from tapcell.mesh.faulty_regions import MAX_REGIONS as MAX_FAULTY_REGIONS, FaultyRegion, make_regions, probing_plan
from tapcell.mesh.grid import MAX_PROBE_COUNT, MIN_PROBE_COUNT, MeshGrid, rectangular_grid, round_grid
from tapcell.mesh.interpolate import ALGORITHMS, MAX_MESH_PPS, TENSION_RANGE, Interpolation, resolve_interpolation
from tapcell.mesh.split import MIN_MOVE_CHECK_DISTANCE_MM, MIN_SPLIT_DELTA_Z_MM, SplitSettings
from tapcell.mesh.zmesh import Fade, resolve_zero_reference

from tapcell.extras.bed_mesh.methods import METHODS

SECTION = "bed_mesh"
MAX_CLEARANCE_MM = 50.0  # horizontal_z_clearance: the lift between points
MAX_ADAPTIVE_MARGIN_MM = 100.0


@dataclass(frozen=True)
class BedMeshOptions:
    """The `[bed_mesh]` options, validated (a BED_MESH_CALIBRATE may override some)."""

    speed_mm_s: float
    horizontal_move_z_mm: float
    horizontal_z_clearance_mm: float | None  # lift this much above the last contact between points
    grid: MeshGrid
    interpolation: Interpolation
    interpolation_note: str | None
    algorithm: str  # as configured (interpolation.algorithm may be a fallback)
    mesh_pps: tuple[int, int]
    fade: Fade
    split: SplitSettings
    zero_reference_xy_mm: tuple[float, float] | None
    method: str
    faulty_regions: tuple[FaultyRegion, ...] = ()
    adaptive_margin_mm: float = 0.0
    adaptive_note: str | None = None  # what ADAPTIVE=1 did, for the user


def _pair(values: list, option: str, section: ConfigSection) -> tuple:
    if len(values) == 1:
        return (values[0], values[0])
    if len(values) != 2:
        raise section.error(option, "must be one value or a pair X, Y")
    return tuple(values)


def _mesh_option_error(section: ConfigSection, exc: MeshOptionError):
    return section.error(exc.option, exc.allowed)


def _read_grid(section: ConfigSection) -> MeshGrid:
    round_bed = section.has_option("mesh_radius")
    rectangular = section.has_option("mesh_min") or section.has_option("mesh_max")
    if round_bed and rectangular:
        raise section.error("mesh_radius", "give either mesh_radius (round bed) or mesh_min/mesh_max (rectangular), not both")
    try:
        if round_bed:
            radius = section.getfloat("mesh_radius", above=0.0, maxval=MAX_COORDINATE_MM)
            origin = tuple(section.getfloatlist("mesh_origin", (0.0, 0.0), count=2, **COORDINATE_RANGE))
            count = section.getint("round_probe_count", 5, minval=MIN_PROBE_COUNT, maxval=MAX_PROBE_COUNT)
            return round_grid(radius, origin, count)
        mesh_min = tuple(section.getfloatlist("mesh_min", count=2, **COORDINATE_RANGE))
        mesh_max = tuple(section.getfloatlist("mesh_max", count=2, **COORDINATE_RANGE))
        probe_count = _pair(section.getintlist("probe_count", (3, 3), minval=MIN_PROBE_COUNT, maxval=MAX_PROBE_COUNT),
                            "probe_count", section)
        return rectangular_grid(mesh_min, mesh_max, probe_count)
    except MeshOptionError as exc:
        raise _mesh_option_error(section, exc) from None


def _read_faulty_regions(section: ConfigSection) -> tuple[FaultyRegion, ...]:
    """`faulty_region_N_min` / `_max` pairs, N from 1 to MAX_FAULTY_REGIONS (only those present are read)."""
    numbers = set()
    for option in section.get_option_names("faulty_region_"):
        found = re.fullmatch(r"faulty_region_(\d+)_(min|max)", option)
        if found is None or not 1 <= int(found[1]) <= MAX_FAULTY_REGIONS:
            raise section.error(option, f"faulty regions are named faulty_region_N_min and faulty_region_N_max, "
                                        f"N from 1 to {MAX_FAULTY_REGIONS}")
        numbers.add(int(found[1]))
    corners = {}
    for number in sorted(numbers):
        low = section.getfloatlist(f"faulty_region_{number}_min", None, count=2, **COORDINATE_RANGE)
        high = section.getfloatlist(f"faulty_region_{number}_max", None, count=2, **COORDINATE_RANGE)
        if low is None or high is None:
            missing = f"faulty_region_{number}_{'max' if high is None else 'min'}"
            raise section.error(missing, f"missing: a faulty region needs both faulty_region_{number}_min and "
                                         f"faulty_region_{number}_max")
        corners[number] = (tuple(low), tuple(high))
    return make_regions(corners)


def read_bed_mesh_options(section: ConfigSection) -> BedMeshOptions:
    """Read and check `[bed_mesh]`; errors name file, section, option, value and what is allowed."""
    grid = _read_grid(section)
    algorithm = section.getchoice("algorithm", list(ALGORITHMS), "lagrange")
    mesh_pps = _pair(section.getintlist("mesh_pps", (2, 2), minval=0, maxval=MAX_MESH_PPS), "mesh_pps", section)
    tension = section.getfloat("bicubic_tension", 0.2, minval=TENSION_RANGE[0], maxval=TENSION_RANGE[1])
    fade = Fade(section.getfloat("fade_start", 1.0, **COORDINATE_RANGE),
                section.getfloat("fade_end", 0.0, **COORDINATE_RANGE),
                section.getfloat("fade_target", None, **COORDINATE_RANGE))
    clearance = section.getfloat("horizontal_z_clearance", None, above=0.0, maxval=MAX_CLEARANCE_MM)
    zero_position = section.getfloatlist("zero_reference_position", None, count=2, **COORDINATE_RANGE)
    reference_index = section.getint("relative_reference_index", None, minval=0,
                                     maxval=MAX_PROBE_COUNT * MAX_PROBE_COUNT - 1)
    adaptive_margin = section.getfloat("adaptive_margin", 0.0, minval=0.0, maxval=MAX_ADAPTIVE_MARGIN_MM)
    try:
        faulty_regions = _read_faulty_regions(section)
        probing_plan(grid, faulty_regions)  # every point inside a region has a substitute
        interpolation, note = resolve_interpolation(algorithm, (grid.x_count, grid.y_count), mesh_pps, tension)
        split = SplitSettings(section.getfloat("move_check_distance", 5.0, minval=MIN_MOVE_CHECK_DISTANCE_MM,
                                               maxval=MAX_COORDINATE_MM),
                              section.getfloat("split_delta_z", 0.025, minval=MIN_SPLIT_DELTA_Z_MM, maxval=10.0))
        zero_reference = resolve_zero_reference(grid, None if zero_position is None else tuple(zero_position),
                                                reference_index)
    except MeshOptionError as exc:
        raise _mesh_option_error(section, exc) from None
    return BedMeshOptions(
        speed_mm_s=section.getfloat("speed", 50.0, **SPEED_RANGE),
        horizontal_move_z_mm=section.getfloat("horizontal_move_z", 5.0, minval=0.0, maxval=MAX_COORDINATE_MM),
        horizontal_z_clearance_mm=clearance,
        grid=grid,
        interpolation=interpolation,
        interpolation_note=note,
        algorithm=algorithm,
        mesh_pps=mesh_pps,
        fade=fade,
        split=split,
        zero_reference_xy_mm=zero_reference,
        method=section.getchoice("method", list(METHODS), "tap"),
        faulty_regions=faulty_regions,
        adaptive_margin_mm=adaptive_margin,
    )


# -- BED_MESH_CALIBRATE parameters -----------------------------------------------------------

def command_options(options: BedMeshOptions, gcmd: GCodeCommand, print_objects: list | None = None) -> BedMeshOptions:
    """The options of one BED_MESH_CALIBRATE: the config with the command's parameters applied.

    `print_objects`: the `exclude_object` status `objects` (None without [exclude_object]),
    which ADAPTIVE=1 shrinks the mesh to.
    """
    mesh_min = gcmd.get_floatlist("MESH_MIN", None, count=2, **COORDINATE_RANGE)
    mesh_max = gcmd.get_floatlist("MESH_MAX", None, count=2, **COORDINATE_RANGE)
    counts = gcmd.get_intlist("PROBE_COUNT", None, minval=MIN_PROBE_COUNT, maxval=MAX_PROBE_COUNT)
    algorithm = gcmd.get("ALGORITHM", options.algorithm).strip().lower()
    method = gcmd.get_choice("METHOD", list(METHODS), options.method)
    clearance = gcmd.get_float("HORIZONTAL_Z_CLEARANCE", options.horizontal_z_clearance_mm, above=0.0,
                               maxval=MAX_CLEARANCE_MM)
    grid = options.grid
    try:
        if mesh_min is not None or mesh_max is not None or counts is not None:
            if grid.radius_mm is not None and (mesh_min is not None or mesh_max is not None):
                raise MeshOptionError(SECTION, "mesh_min", mesh_min or mesh_max, "a round bed uses mesh_radius")
            if counts is not None and len(counts) not in (1, 2):
                raise MeshOptionError(SECTION, "probe_count", gcmd.get("PROBE_COUNT"), "must be one integer or a pair X, Y")
            count_pair = (grid.x_count, grid.y_count) if counts is None else tuple(_repeat(counts))
            grid = rectangular_grid(mesh_min or grid.mesh_min, mesh_max or grid.mesh_max, count_pair)
        grid, adaptive_note = _adaptive_grid(options, gcmd, grid, print_objects)
        interpolation, note = resolve_interpolation(algorithm, (grid.x_count, grid.y_count), options.mesh_pps,
                                                    options.interpolation.bicubic_tension)
    except MeshOptionError as exc:
        shown = gcmd.get(exc.option.upper(), exc.value)  # the value as the user wrote it, when given
        raise gcmd.param_error(f"{exc.option.upper()}={shown}: {exc.allowed}") from None
    return replace(options, grid=grid, interpolation=interpolation, interpolation_note=note,
                   horizontal_z_clearance_mm=clearance, method=method, adaptive_note=adaptive_note)


def _adaptive_grid(options: BedMeshOptions, gcmd: GCodeCommand, grid: MeshGrid,
                   print_objects: list | None) -> tuple[MeshGrid, str | None]:
    """ADAPTIVE=1: the grid for the print's objects, and what was done (for the user)."""
    if not gcmd.get_int("ADAPTIVE", 0, minval=0, maxval=1):
        return grid, None
    margin_mm = gcmd.get_float("ADAPTIVE_MARGIN", options.adaptive_margin_mm, minval=0.0,
                               maxval=MAX_ADAPTIVE_MARGIN_MM)
    if print_objects is None:
        return grid, ("Exclude objects not enabled ([exclude_object] is missing): ADAPTIVE=1 has no objects "
                      "to fit. Using the full mesh")
    adapted = adapt_grid(grid, [obj.get("polygon") or () for obj in print_objects], margin_mm)
    if adapted is None:
        return grid, "No objects defined (EXCLUDE_OBJECT_DEFINE with POLYGON=): using the full mesh"
    found = (f"Found {len(print_objects)} objects, within ({adapted.objects_min_xy_mm[0]:.1f}, "
             f"{adapted.objects_min_xy_mm[1]:.1f}) .. ({adapted.objects_max_xy_mm[0]:.1f}, "
             f"{adapted.objects_max_xy_mm[1]:.1f})")
    if not adapted.shrunk:
        return grid, f"{found}: they need the whole mesh"
    new = adapted.grid
    return new, (f"{found}; adaptive_margin {margin_mm:g} mm. Adapted mesh: ({new.min_x_mm:.1f}, "
                 f"{new.min_y_mm:.1f}) .. ({new.max_x_mm:.1f}, {new.max_y_mm:.1f}), {new.x_count} x "
                 f"{new.y_count} points (configured: ({grid.min_x_mm:.1f}, {grid.min_y_mm:.1f}) .. "
                 f"({grid.max_x_mm:.1f}, {grid.max_y_mm:.1f}), {grid.x_count} x {grid.y_count})")


def _repeat(values: list[int]) -> list[int]:
    return values * 2 if len(values) == 1 else values
