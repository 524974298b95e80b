"""`[bed_mesh]`: probe the bed, keep the mesh, and make G-code moves follow it.

Commands:

* `BED_MESH_CALIBRATE [PROFILE=default] [METHOD=tap|two_pass|prusa] [BAD_PROBE_STRATEGY=CIRCLE]
  [HORIZONTAL_Z_CLEARANCE=mm] [MESH_MIN=x,y] [MESH_MAX=x,y] [PROBE_COUNT=n[,m]] [ALGORITHM=...]`
  (+ any probe option override, e.g. SAMPLES=2): probe every point in serpentine order,
  build the mesh, make it active and store it in profile PROFILE (SAVE_CONFIG keeps it).
  Methods: `tap` (the load-cell probe's tap analysis, the default), `two_pass` (the ABL
  paper's fast + slow pass, `tapcell.extras.bed_mesh.two_pass`), `prusa` (Prusa-matched thresholds and tare
  plan, `tapcell.extras.prusa_probe`; needs a `[prusa_probe]` section).
* `BED_MESH_OUTPUT [PGP=1]`: the active mesh as a table (PGP=1: the probe points in order).
* `BED_MESH_PROFILE SAVE=name | LOAD=name | REMOVE=name`: profiles live in `[bed_mesh name]`
  sections written by SAVE_CONFIG; `default` is loaded at start-up.
* `BED_MESH_CLEAR`: moves stop following the mesh.

The bed mesh is a move transform of the toolhead (`Toolhead.set_move_transform`): a G1 is
split every `move_check_distance` where the mesh changes by `split_delta_z` (see
`tapcell.mesh.split`), each piece raised by the mesh height there, faded out between
`fade_start` and `fade_end`. Probing moves do not go through it.

Progress: each probed point sends the printer event `bed_mesh:progress(done, total)`, which a
front end can show as a progress bar (the demo does).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np

from tapcell.host.config import ConfigSection
from tapcell.host.gcode import GCodeCommand, GCodeError
from tapcell.mesh.errors import MeshError, MeshOptionError
from tapcell.mesh.grid import MeshGrid, matrix_from_probes, rectangular_grid, round_grid
from tapcell.mesh.interpolate import ALGORITHMS, Interpolation, resolve_interpolation
from tapcell.mesh.profiles import mesh_from_profile_options, profile_options, profile_section_name
from tapcell.mesh.report import render_mesh
from tapcell.mesh.split import SplitSettings, split_move
from tapcell.mesh.travel import travel_height_mm
from tapcell.mesh.zmesh import (
    Fade,
    ZMesh,
    build_mesh,
    empty_mesh_status,
    fade_target_mm,
    gcode_z_mm,
    resolve_zero_reference,
)

SECTION = "bed_mesh"
DEFAULT_PROFILE = "default"
METHODS = ("tap", "two_pass", "prusa")
PROGRESS_EVENT = "bed_mesh:progress"


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
            radius = section.getfloat("mesh_radius", above=0.0)
            origin = tuple(section.getfloatlist("mesh_origin", (0.0, 0.0), count=2))
            count = section.getint("round_probe_count", 5, minval=3)
            return round_grid(radius, origin, count)
        mesh_min = tuple(section.getfloatlist("mesh_min", count=2))
        mesh_max = tuple(section.getfloatlist("mesh_max", count=2))
        probe_count = _pair(section.getintlist("probe_count", (3, 3)), "probe_count", section)
        return rectangular_grid(mesh_min, mesh_max, probe_count)
    except MeshOptionError as exc:
        raise _mesh_option_error(section, exc) from None


def read_bed_mesh_options(section: ConfigSection) -> BedMeshOptions:
    """Read and check `[bed_mesh]`; errors name file, section, option, value and what is allowed."""
    grid = _read_grid(section)
    algorithm = section.getchoice("algorithm", list(ALGORITHMS), "lagrange")
    mesh_pps = _pair(section.getintlist("mesh_pps", (2, 2)), "mesh_pps", section)
    tension = section.getfloat("bicubic_tension", 0.2, minval=0.0, maxval=2.0)
    fade = Fade(section.getfloat("fade_start", 1.0), section.getfloat("fade_end", 0.0),
                section.getfloat("fade_target", None))
    clearance = section.getfloat("horizontal_z_clearance", None, above=0.0)
    zero_position = section.getfloatlist("zero_reference_position", None, count=2)
    reference_index = section.getint("relative_reference_index", None, minval=0)
    try:
        interpolation, note = resolve_interpolation(algorithm, (grid.x_count, grid.y_count), mesh_pps, tension)
        split = SplitSettings(section.getfloat("move_check_distance", 5.0),
                              section.getfloat("split_delta_z", 0.025))
        zero_reference = resolve_zero_reference(grid, None if zero_position is None else tuple(zero_position),
                                                reference_index)
    except MeshOptionError as exc:
        raise _mesh_option_error(section, exc) from None
    return BedMeshOptions(
        speed_mm_s=section.getfloat("speed", 50.0, above=0.0),
        horizontal_move_z_mm=section.getfloat("horizontal_move_z", 5.0),
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
    )


# -- BED_MESH_CALIBRATE parameters -----------------------------------------------------------

def _gcode_floats(gcmd: GCodeCommand, name: str, count: int | None) -> list[float] | None:
    text = gcmd.get(name, None)
    if text is None:
        return None
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        values = []
    if not values or not all(math.isfinite(v) for v in values) or (count is not None and len(values) != count):
        shape = f"{count} numbers separated by commas" if count else "numbers separated by commas"
        raise gcmd.error(f"Error on '{gcmd.get_commandline()}': {name}={text}: expected {shape}")
    return values


def command_options(options: BedMeshOptions, gcmd: GCodeCommand) -> BedMeshOptions:
    """The options of one BED_MESH_CALIBRATE: the config with the command's parameters applied."""
    mesh_min = _gcode_floats(gcmd, "MESH_MIN", 2)
    mesh_max = _gcode_floats(gcmd, "MESH_MAX", 2)
    counts = _gcode_floats(gcmd, "PROBE_COUNT", None)
    algorithm = gcmd.get("ALGORITHM", options.algorithm).strip().lower()
    method = gcmd.get("METHOD", options.method).strip().lower()
    if method not in METHODS:
        raise gcmd.error(f"Error on '{gcmd.get_commandline()}': METHOD={method}: must be one of {', '.join(METHODS)}")
    clearance = gcmd.get_float("HORIZONTAL_Z_CLEARANCE", options.horizontal_z_clearance_mm, above=0.0)
    grid = options.grid
    try:
        if mesh_min is not None or mesh_max is not None or counts is not None:
            if grid.radius_mm is not None and (mesh_min is not None or mesh_max is not None):
                raise MeshOptionError(SECTION, "mesh_min", mesh_min or mesh_max, "a round bed uses mesh_radius")
            if counts is not None and (len(counts) not in (1, 2) or any(c != int(c) for c in counts)):
                raise MeshOptionError(SECTION, "probe_count", gcmd.get("PROBE_COUNT"), "must be one integer or a pair X, Y")
            count_pair = (grid.x_count, grid.y_count) if counts is None else tuple(int(c) for c in _repeat(counts))
            grid = rectangular_grid(mesh_min or grid.mesh_min, mesh_max or grid.mesh_max, count_pair)
        interpolation, note = resolve_interpolation(algorithm, (grid.x_count, grid.y_count), options.mesh_pps,
                                                    options.interpolation.bicubic_tension)
    except MeshOptionError as exc:
        shown = gcmd.get(exc.option.upper(), exc.value)  # the value as the user wrote it, when given
        raise gcmd.error(f"Error on '{gcmd.get_commandline()}': {exc.option.upper()}={shown}: {exc.allowed}") from None
    return replace(options, grid=grid, interpolation=interpolation, interpolation_note=note,
                   horizontal_z_clearance_mm=clearance, method=method)


def _repeat(values: list[float]) -> list[float]:
    return values * 2 if len(values) == 1 else values


# -- probing ----------------------------------------------------------------------------------

# progress(done, total) after each probed point.
Progress = Callable[[int, int], None]


@dataclass
class MeshProbeRun:
    """What a probing method returns: bed height per point (probing order) and a report."""

    z_mm: list[float]
    report: str = ""
    details: dict | None = None  # JSON-ready, shown in status as last_calibration


def probe_points_by_tapping(printer, options: BedMeshOptions, gcmd: GCodeCommand,
                            points_xy_mm: np.ndarray, progress: Progress) -> MeshProbeRun:
    """The `tap` method: one probe session (with the command's overrides) over every point.

    Between points the nozzle lifts to `horizontal_move_z`, or with `horizontal_z_clearance`
    only that much above the bed on the way to the next point (`mesh_travel_height_mm`).
    """
    probe = printer.lookup_object("probe", None)
    if probe is None:
        raise GCodeError("BED_MESH_CALIBRATE needs a probe: add a [load_cell_probe] section")
    toolhead = printer.lookup_object("toolhead")
    x_offset, y_offset = probe.options.x_offset_mm, probe.options.y_offset_mm
    z_values = []
    attempts = []
    contacts_xyz: list[tuple[float, float, float]] = []  # where the nozzle touched (toolhead Z)
    with probe.session(gcmd) as session:
        lift_speed = session.options.effective_lift_speed_mm_s
        for index, (x_mm, y_mm) in enumerate(points_xy_mm):
            travel_z = mesh_travel_height_mm(options, contacts_xyz, (float(x_mm), float(y_mm)))
            if toolhead.get_position()[2] < travel_z:
                toolhead.move_to(z=travel_z, speed_mm_s=lift_speed)
            toolhead.move_to(x=float(x_mm) - x_offset, y=float(y_mm) - y_offset, speed_mm_s=options.speed_mm_s)
            result = session.probe_point(float(x_mm), float(y_mm))
            z_values.append(result.z_mm)
            attempts.append(result.attempts)
            contacts_xyz.append((result.tapped_x_mm, result.tapped_y_mm, result.z_mm + session.options.z_offset_mm))
            progress(index + 1, len(points_xy_mm))
        toolhead.move_to(z=max(toolhead.get_position()[2], mesh_travel_height_mm(options, contacts_xyz, None)),
                         speed_mm_s=lift_speed)
    extra = sum(attempts) - len(attempts)
    report = f"{len(attempts)} points, {sum(attempts)} taps" + (f" ({extra} retried)" if extra else "")
    return MeshProbeRun(z_values, report, {"method": "tap", "taps": int(sum(attempts))})


def mesh_travel_height_mm(options: BedMeshOptions, contacts_xyz: Sequence[tuple[float, float, float]],
                          next_xy_mm: tuple[float, float] | None) -> float:
    """Toolhead Z to travel at toward the next point (None: the lift after the last point).

    `horizontal_move_z`, or with `horizontal_z_clearance` that much above the bed on the way,
    the next point's height predicted from the contacts so far (`tapcell.mesh.travel`).
    """
    clearance = options.horizontal_z_clearance_mm
    if clearance is None or not contacts_xyz:
        return options.horizontal_move_z_mm
    if next_xy_mm is None:
        return contacts_xyz[-1][2] + clearance
    return travel_height_mm(np.array(contacts_xyz), next_xy_mm, clearance, options.horizontal_move_z_mm)


def _method_function(method: str):
    if method == "tap":
        return probe_points_by_tapping
    if method == "two_pass":
        from tapcell.extras.bed_mesh.two_pass import probe_points_two_pass

        return probe_points_two_pass
    from tapcell.extras.prusa_probe import probe_points_prusa

    return probe_points_prusa


# -- the [bed_mesh] object --------------------------------------------------------------------

class BedMesh:
    """The active mesh, its profiles, the G-code commands and the move transform."""

    def __init__(self, section: ConfigSection, printer):
        self.printer = printer
        self.name = section.get_name()
        self.options = read_bed_mesh_options(section)
        self.mesh: ZMesh | None = None
        self.profiles: dict[str, ZMesh] = {}
        self.last_calibration: dict | None = None
        self.toolhead = printer.lookup_object("toolhead")
        # G-code moves come to us first, we pass the adjusted moves on.
        self.next_target = self.toolhead.set_move_transform(self)
        printer.register_event_handler("printer:ready", self._load_default_profile)
        gcode = printer.gcode
        gcode.register_command("BED_MESH_CALIBRATE", self.cmd_BED_MESH_CALIBRATE,
                               desc="Probe the bed and build a mesh: [PROFILE=] [METHOD=tap|two_pass|prusa] "
                                    "[BAD_PROBE_STRATEGY=] [HORIZONTAL_Z_CLEARANCE=]")
        gcode.register_command("BED_MESH_OUTPUT", self.cmd_BED_MESH_OUTPUT, desc="Show the active mesh [PGP=1]")
        gcode.register_command("BED_MESH_PROFILE", self.cmd_BED_MESH_PROFILE,
                               desc="Mesh profiles: SAVE=name | LOAD=name | REMOVE=name")
        gcode.register_command("BED_MESH_CLEAR", self.cmd_BED_MESH_CLEAR, desc="Stop following the mesh")

    # -- profiles -------------------------------------------------------------------------------
    def add_profile_section(self, section: ConfigSection) -> None:
        """A `[bed_mesh NAME]` section written by SAVE_CONFIG."""
        name = section.get_instance_name()
        try:
            self.profiles[name] = mesh_from_profile_options(name, section.config.section_options(section.get_name()))
        except MeshOptionError as exc:
            raise section.error(exc.option, exc.allowed) from None

    def _load_default_profile(self) -> None:
        if DEFAULT_PROFILE in self.profiles:
            self.set_mesh(self.profiles[DEFAULT_PROFILE])

    def set_mesh(self, mesh: ZMesh | None) -> None:
        """Make `mesh` the one moves follow (None: no mesh)."""
        if mesh is not None and self.options.fade.enabled:
            try:
                fade_target_mm(mesh, self.options.fade)
            except MeshOptionError as exc:
                raise GCodeError(f"[{self.name}] {exc.option} = {exc.value}: {exc.allowed}") from None
        self.mesh = mesh

    def save_profile(self, name: str) -> ZMesh:
        if self.mesh is None:
            raise GCodeError("BED_MESH_PROFILE: no active mesh to save; run BED_MESH_CALIBRATE or load a profile")
        mesh = replace(self.mesh, profile_name=name)
        self.mesh = mesh
        self.profiles[name] = mesh
        section = profile_section_name(name)
        for option, value in profile_options(mesh).items():
            self.printer.config.set(section, option, value)
        return mesh

    # -- the move transform ---------------------------------------------------------------------
    def get_position(self) -> tuple[float, float, float]:
        """The G-code position (without the mesh) of the toolhead."""
        x, y, z = self.next_target.get_position()
        if self.mesh is None:
            return (x, y, z)
        return (x, y, gcode_z_mm(self.mesh, self.options.fade, x, y, z))

    def move(self, position_xyz: Sequence[float], speed_mm_s: float) -> None:
        """Carry a G-code move over the mesh: split where the mesh changes, Z adjusted."""
        if self.mesh is None:
            self.next_target.move(tuple(position_xyz), speed_mm_s)
            return
        start = (*self.get_position(), 0.0)
        end = (*position_xyz, 0.0)
        for x, y, z, _ in split_move(start, end, self.mesh, self.options.fade, self.options.split):
            self.next_target.move((float(x), float(y), float(z)), speed_mm_s)

    # -- commands -------------------------------------------------------------------------------
    def cmd_BED_MESH_CALIBRATE(self, gcmd: GCodeCommand) -> None:
        options = command_options(self.options, gcmd)
        profile = gcmd.get("PROFILE", DEFAULT_PROFILE).strip()
        if not profile or " " in profile:
            raise gcmd.error(f"Error on '{gcmd.get_commandline()}': PROFILE must be one word")
        homed = self.toolhead.status()["homed_axes"]
        if homed != "xyz":
            raise gcmd.error("BED_MESH_CALIBRATE: home all axes first (G28)")
        if options.interpolation_note:
            gcmd.respond_info(options.interpolation_note)
        points = options.grid.probe_points_mm()
        # Probe without the old mesh: results are bed heights in the toolhead frame.
        self.set_mesh(None)
        total = len(points)
        gcmd.respond_info(f"Probing {total} points ({options.grid.x_count} x {options.grid.y_count}, "
                          f"method {options.method})")
        start_s = self.printer.get_time()

        def progress(done: int, count: int) -> None:
            self.printer.send_event(PROGRESS_EVENT, done, count)

        run = _method_function(options.method)(self.printer, options, gcmd, points, progress)
        elapsed_s = self.printer.get_time() - start_s
        matrix = matrix_from_probes(options.grid, run.z_mm)
        try:
            mesh = build_mesh(matrix, options.grid, options.interpolation, profile, options.zero_reference_xy_mm)
        except MeshError as exc:
            raise gcmd.error(f"BED_MESH_CALIBRATE: {exc}") from None
        self.set_mesh(mesh)
        self.save_profile(profile)
        low, high = mesh.z_range_mm()
        self.last_calibration = {"profile": profile, "points": total, "time_s": elapsed_s,
                                 "method": options.method, **(run.details or {})}
        if run.report:
            gcmd.respond_info(run.report)
        gcmd.respond_info(f"Mesh '{profile}' done in {elapsed_s:.1f} s: bed from {low:.4f} to {high:.4f} mm "
                          f"(range {high - low:.4f} mm). Moves now follow it; SAVE_CONFIG keeps the profile.")

    def cmd_BED_MESH_OUTPUT(self, gcmd: GCodeCommand) -> None:
        if gcmd.get_int("PGP", 0, minval=0, maxval=1):
            grid = self.options.grid if self.mesh is None else self.mesh.grid
            lines = ["Probe points (probing order):"]
            lines += [f"  {n}: X {x:.3f} Y {y:.3f}" for n, (x, y) in enumerate(grid.probe_points_mm())]
            gcmd.respond_info("\n".join(lines))
            return
        if self.mesh is None:
            gcmd.respond_info("Bed has not been probed (no active mesh)")
            return
        gcmd.respond_info(render_mesh(self.mesh))

    def cmd_BED_MESH_PROFILE(self, gcmd: GCodeCommand) -> None:
        given = [key for key in ("SAVE", "LOAD", "REMOVE") if gcmd.has(key)]
        if len(given) != 1:
            raise gcmd.error(f"Error on '{gcmd.get_commandline()}': give exactly one of SAVE=name, LOAD=name, REMOVE=name")
        action = given[0]
        name = gcmd.get(action).strip()
        if not name or " " in name:
            raise gcmd.error(f"Error on '{gcmd.get_commandline()}': {action} needs a one-word profile name")
        if action != "SAVE" and name not in self.profiles:
            raise gcmd.error(f"Error on '{gcmd.get_commandline()}': no bed mesh profile '{name}' "
                             f"(known: {', '.join(sorted(self.profiles)) or 'none'})")
        if action == "SAVE":
            self.save_profile(name)
            gcmd.respond_info(f"Bed mesh profile '{name}' saved; run SAVE_CONFIG to write it to the config file")
        elif action == "LOAD":
            self.set_mesh(self.profiles[name])
            gcmd.respond_info(f"Bed mesh profile '{name}' loaded: moves follow it")
        else:
            del self.profiles[name]
            self.printer.config.remove_section(profile_section_name(name))
            gcmd.respond_info(f"Bed mesh profile '{name}' removed; run SAVE_CONFIG to remove it from the config file")

    def cmd_BED_MESH_CLEAR(self, gcmd: GCodeCommand) -> None:
        self.set_mesh(None)
        gcmd.respond_info("Bed mesh cleared: moves no longer follow a mesh")

    # -- status -----------------------------------------------------------------------------------
    def get_status(self, eventtime=None) -> dict:
        status = empty_mesh_status() if self.mesh is None else self.mesh.to_status()
        status["profiles"] = {
            name: {"points": mesh.probed_matrix_mm.tolist(),
                   "mesh_params": {k: v for k, v in profile_options(mesh).items() if k != "points"}}
            for name, mesh in self.profiles.items()
        }
        status["last_calibration"] = self.last_calibration
        return status


def load_config(section: ConfigSection, printer) -> BedMesh:
    return BedMesh(section, printer)


def load_config_prefix(section: ConfigSection, printer) -> None:
    """`[bed_mesh NAME]`: a saved profile, kept by the `[bed_mesh]` object."""
    bed_mesh = printer.load_object(SECTION)
    if bed_mesh is None:
        raise section.error("version", "a saved bed mesh profile needs a [bed_mesh] section")
    bed_mesh.add_profile_section(section)
    return None
