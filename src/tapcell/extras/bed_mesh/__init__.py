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

from collections.abc import Sequence
from dataclasses import replace

from tapcell.extras.bed_mesh.methods import METHODS
from tapcell.extras.bed_mesh.options import SECTION, command_options, read_bed_mesh_options
from tapcell.host.config import ConfigSection
from tapcell.host.gcode import GCodeCommand, GCodeError
from tapcell.mesh.errors import MeshError, MeshOptionError
from tapcell.mesh.grid import matrix_from_probes
from tapcell.mesh.profiles import mesh_from_profile_options, profile_options, profile_section_name
from tapcell.mesh.faulty_regions import probing_plan
from tapcell.mesh.report import render_generated_points, render_mesh, render_mesh_map, render_probed_matrix
from tapcell.mesh.split import split_move
from tapcell.mesh.zero_reference import zero_reference_warning
from tapcell.mesh.zmesh import ZMesh, build_mesh, empty_mesh_status, fade_target_mm, gcode_z_mm

DEFAULT_PROFILE = "default"
PROGRESS_EVENT = "bed_mesh:progress"


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
        # Where Z was homed (the toolhead X/Y at G28 Z): the datum a zero reference must agree with.
        self.z_datum_xy_mm: tuple[float, float] | None = None
        printer.register_event_handler("toolhead:z_homed", self._note_z_datum)
        gcode = printer.gcode
        gcode.register_command("BED_MESH_CALIBRATE", self.cmd_BED_MESH_CALIBRATE,
                               desc="Probe the bed and build a mesh: [PROFILE=] [METHOD=tap|two_pass|prusa] "
                                    "[STRATEGY=CIRCLE] [ADAPTIVE=1 [ADAPTIVE_MARGIN=]] [HORIZONTAL_Z_CLEARANCE=]")
        gcode.register_command("BED_MESH_OUTPUT", self.cmd_BED_MESH_OUTPUT,
                               desc="Show the active mesh as Klipper does [PGP=1: the probe points]")
        gcode.register_command("BED_MESH_MAP", self.cmd_BED_MESH_MAP,
                               desc="The active mesh as one JSON line (mesh_map_output) for tools")
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

    def _note_z_datum(self) -> None:
        x_mm, y_mm, _ = self.toolhead.get_position()
        self.z_datum_xy_mm = (x_mm, y_mm)

    def _warn_zero_reference(self, gcmd: GCodeCommand) -> None:
        warning = zero_reference_warning(self.mesh, self.options.zero_reference_xy_mm, self.z_datum_xy_mm)
        if warning:
            gcmd.respond_info(f"Warning: {warning}")

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
        options = command_options(self.options, gcmd, self._print_objects())
        profile = gcmd.get("PROFILE", DEFAULT_PROFILE).strip()
        if not profile or " " in profile:
            raise gcmd.param_error("PROFILE must be one word")
        homed = self.toolhead.status()["homed_axes"]
        if homed != "xyz":
            raise gcmd.error("BED_MESH_CALIBRATE: home all axes first (G28)")
        for note in (options.adaptive_note, options.interpolation_note):
            if note:
                gcmd.respond_info(note)
        plan = self._probing_plan(options.grid, gcmd)
        places = plan.flat_places_mm()
        # Probe without the old mesh: results are bed heights in the toolhead frame.
        self.set_mesh(None)
        total = len(plan.points_mm)
        substituted = plan.substituted
        faulty = (f"; {len(substituted)} in faulty regions, probed at "
                  f"{sum(len(around) for around in substituted.values())} places around them" if substituted else "")
        gcmd.respond_info(f"Probing {total} points ({options.grid.x_count} x {options.grid.y_count}, "
                          f"method {options.method}{faulty})")
        start_s = self.printer.get_time()

        def progress(done: int, count: int) -> None:
            self.printer.send_event(PROGRESS_EVENT, done, count)

        try:
            run = METHODS[options.method](self.printer, options, gcmd, places, progress)
        except MeshError as exc:  # e.g. a point whose probes keep disagreeing (tapcell.mesh.outliers)
            raise gcmd.error(f"BED_MESH_CALIBRATE: {exc}") from None
        elapsed_s = self.printer.get_time() - start_s
        matrix = matrix_from_probes(options.grid, plan.fold(run.z_mm))
        try:
            mesh = build_mesh(matrix, options.grid, options.interpolation, profile, options.zero_reference_xy_mm)
        except MeshError as exc:
            raise gcmd.error(f"BED_MESH_CALIBRATE: {exc}") from None
        self.set_mesh(mesh)
        self.save_profile(profile)
        self._warn_zero_reference(gcmd)
        low, high = mesh.z_range_mm()
        self.last_calibration = {"profile": profile, "points": total, "time_s": elapsed_s,
                                 "method": options.method, **(run.details or {})}
        if run.report:
            gcmd.respond_info(run.report)
        gcmd.respond_info(f"Mesh '{profile}' done in {elapsed_s:.1f} s: Mesh Range: min={low:.4f} max={high:.4f} "
                          f"({high - low:.4f} mm). Moves now follow it; SAVE_CONFIG keeps the profile.")

    def _print_objects(self) -> list | None:
        """The print's objects (`exclude_object` status `objects`), None without [exclude_object]."""
        exclude_object = self.printer.lookup_object("exclude_object", None)
        if exclude_object is None:
            return None
        return list(exclude_object.get_status(self.printer.get_time()).get("objects") or [])

    def _probing_plan(self, grid, gcmd: GCodeCommand):
        """Where `grid`'s points are probed around the configured faulty regions."""
        try:
            return probing_plan(grid, self.options.faulty_regions)
        except MeshOptionError as exc:  # a MESH_MIN/MAX, ADAPTIVE=1 or loaded mesh with no way around a region
            raise gcmd.error(f"{gcmd.command}: [{SECTION}] {exc.option}: {exc.allowed}") from None

    def _probe_offsets_mm(self) -> tuple[float, float]:
        probe = self.printer.lookup_object("probe", None)
        return (0.0, 0.0) if probe is None else (probe.options.x_offset_mm, probe.options.y_offset_mm)

    def cmd_BED_MESH_OUTPUT(self, gcmd: GCodeCommand) -> None:
        """Klipper's output: the probed matrix (as `//` info) then the mesh (raw lines)."""
        if gcmd.get_int("PGP", 0, minval=0, maxval=1):
            grid = self.options.grid if self.mesh is None else self.mesh.grid
            gcmd.respond_info(render_generated_points(self._probing_plan(grid, gcmd),
                                                      self._probe_offsets_mm(), self.options.zero_reference_xy_mm))
            return
        if self.mesh is None:
            gcmd.respond_info("Bed has not been probed")
            return
        gcmd.respond_info(render_probed_matrix(self.mesh))
        gcmd.respond_raw(render_mesh(self.mesh, self.options.horizontal_move_z_mm, self._probe_offsets_mm()))

    def cmd_BED_MESH_MAP(self, gcmd: GCodeCommand) -> None:
        if self.mesh is None:
            gcmd.respond_info("Bed has not been probed")
            return
        gcmd.respond_raw(render_mesh_map(self.mesh))

    def cmd_BED_MESH_PROFILE(self, gcmd: GCodeCommand) -> None:
        given = [key for key in ("SAVE", "LOAD", "REMOVE") if gcmd.has(key)]
        if len(given) != 1:
            raise gcmd.param_error("give exactly one of SAVE=name, LOAD=name, REMOVE=name")
        action = given[0]
        name = gcmd.get(action).strip()
        if not name or " " in name:
            raise gcmd.param_error(f"{action} needs a one-word profile name")
        if action != "SAVE" and name not in self.profiles:
            raise gcmd.param_error(f"no bed mesh profile '{name}' "
                                   f"(known: {', '.join(sorted(self.profiles)) or 'none'})")
        if action == "SAVE":
            self.save_profile(name)
            gcmd.respond_info(f"Bed mesh profile '{name}' saved; run SAVE_CONFIG to write it to the config file")
        elif action == "LOAD":
            self.set_mesh(self.profiles[name])
            gcmd.respond_info(f"Bed mesh profile '{name}' loaded: moves follow it")
            self._warn_zero_reference(gcmd)
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
