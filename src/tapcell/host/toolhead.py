"""`[printer]` and `[stepper_x/y/z]`: the toolhead and its G-code commands.

The toolhead keeps the homing state and the velocity limits, checks every move against the axis limits and drives the virtual
printer (`printer.backend`). Z homes through the probe: G28 Z calls
`printer.lookup_object("probe").home_z(gcmd)`, and the probe re-bases Z with
`set_z_position` (the toolhead implements the probe's Motion protocol:
get_position, move_to, z_position_min, z_travel_mm, set_z_position, is_z_homed).

Coordinates: the virtual printer has its own machine coordinates; the toolhead's
coordinates are those plus a per-axis frame offset set by homing (X/Y endstops at
position_endstop, Z at the probed bed). G-code coordinates are the toolhead's minus
the G92 offsets.

Commands: G28, G4, M400, M84/M18, M204, SET_VELOCITY_LIMIT; the G-code frame and G0/G1
live in `tapcell.host.gcode_move`, the nozzle heater and E axis in `tapcell.host.extruder`.
Status objects: `toolhead` (Klipper's fields), `gcode_move`, `extruder`.
"""

from __future__ import annotations

from dataclasses import dataclass

from tapcell.host.extruder import load_extruder
from tapcell.host.gcode_move import load_gcode_move
from tapcell.host.limits import (
    ACCEL_MM_S2,
    ACCEL_RANGE,
    COORDINATE_RANGE,
    MAX_COORDINATE_MM,
    MAX_FULL_STEPS_PER_ROTATION,
    MAX_ROTATION_DISTANCE_MM,
    MICROSTEPS,
    SPEED_MM_S,
    SPEED_RANGE,
)
from tapcell.host.backend import MoveError
from tapcell.host.config import ConfigSection
from tapcell.host.gcode import GCodeCommand, GCodeError

AXES = "xyz"
# CoreXY moves the toolhead in the same X/Y frame; only the motor mapping differs, which the
# virtual printer does not model (it moves X and Y directly).
KINEMATICS = ("cartesian", "corexy")
PROBE_ENDSTOP_PIN = "probe:z_virtual_endstop"
# Probes that tap the bed with the nozzle (they need Z below 0).
NOZZLE_PROBE_SECTIONS = ("load_cell_probe", "prusa_probe")
# G4 and M400 waits longer than this are refused (a typo in P= must not stall the printer for days).
MAX_DWELL_S = 3600.0


@dataclass(frozen=True)
class AxisOptions:
    """One [stepper_?] section."""

    position_min_mm: float
    position_max_mm: float
    position_endstop_mm: float | None  # None when homed through the probe
    homing_speed_mm_s: float
    step_pin: str  # names the MCU that drives the stepper (`toolboard:PA1`; no prefix: the main MCU)
    rotation_distance_mm: float
    microsteps: int
    full_steps_per_rotation: int
    homes_with_probe: bool

    @property
    def step_distance_mm(self) -> float:
        return self.rotation_distance_mm / (self.microsteps * self.full_steps_per_rotation)


@dataclass(frozen=True)
class ToolheadOptions:
    """The [printer] section and its steppers."""

    kinematics: str
    max_velocity_mm_s: float
    max_accel_mm_s2: float
    max_z_velocity_mm_s: float
    max_z_accel_mm_s2: float
    minimum_cruise_ratio: float
    square_corner_velocity_mm_s: float
    axes: dict[str, AxisOptions]


def read_axis_options(section: ConfigSection) -> AxisOptions:
    # Pins only need to be present on the virtual printer; read them so they are checked.
    step_pin = section.get("step_pin")
    section.get("dir_pin")
    section.get("enable_pin", None)
    section.get("gear_ratio", None)
    section.getfloat("step_pulse_duration", None, minval=0.0, maxval=0.001)
    endstop_pin = section.get("endstop_pin")
    homes_with_probe = endstop_pin.strip() == PROBE_ENDSTOP_PIN
    position_min = section.getfloat("position_min", 0.0, **COORDINATE_RANGE)
    position_max = section.getfloat("position_max", above=position_min, maxval=MAX_COORDINATE_MM)
    if homes_with_probe:
        position_endstop = None
    else:
        position_endstop = section.getfloat("position_endstop", minval=position_min, maxval=position_max)
    homing_speed = section.getfloat("homing_speed", 5.0, **SPEED_RANGE)
    section.getfloat("homing_retract_dist", 5.0, minval=0.0, maxval=MAX_COORDINATE_MM)
    section.getfloat("homing_retract_speed", homing_speed, **SPEED_RANGE)
    section.getfloat("second_homing_speed", homing_speed / 2.0, **SPEED_RANGE)
    section.getboolean("homing_positive_dir", None)
    return AxisOptions(
        position_min_mm=position_min,
        position_max_mm=position_max,
        position_endstop_mm=position_endstop,
        homing_speed_mm_s=homing_speed,
        step_pin=step_pin,
        rotation_distance_mm=section.getfloat("rotation_distance", above=0.0, maxval=MAX_ROTATION_DISTANCE_MM),
        microsteps=section.getchoice("microsteps", list(MICROSTEPS)),
        full_steps_per_rotation=section.getint("full_steps_per_rotation", 200, minval=1,
                                               maxval=MAX_FULL_STEPS_PER_ROTATION),
        homes_with_probe=homes_with_probe,
    )


def read_toolhead_options(section: ConfigSection) -> ToolheadOptions:
    max_velocity = section.getfloat("max_velocity", **SPEED_RANGE)
    max_accel = section.getfloat("max_accel", minval=ACCEL_MM_S2[0], maxval=ACCEL_MM_S2[1])
    axes = {}
    for axis in AXES:
        stepper = section.getsection(f"stepper_{axis}")
        if not section.config.has_section(f"stepper_{axis}"):
            raise section.error("kinematics", f"cartesian kinematics needs a [stepper_{axis}] section")
        axes[axis] = read_axis_options(stepper)
    if axes["x"].homes_with_probe or axes["y"].homes_with_probe:
        axis = "x" if axes["x"].homes_with_probe else "y"
        raise section.getsection(f"stepper_{axis}").error(
            "endstop_pin", f"{PROBE_ENDSTOP_PIN} can only home Z")
    return ToolheadOptions(
        kinematics=section.getchoice("kinematics", list(KINEMATICS)),
        max_velocity_mm_s=max_velocity,
        max_accel_mm_s2=max_accel,
        max_z_velocity_mm_s=section.getfloat("max_z_velocity", max_velocity, minval=SPEED_MM_S[0],
                                             maxval=max_velocity),
        max_z_accel_mm_s2=section.getfloat("max_z_accel", max_accel, minval=ACCEL_MM_S2[0], maxval=max_accel),
        minimum_cruise_ratio=section.getfloat("minimum_cruise_ratio", 0.5, minval=0.0, below=1.0),
        square_corner_velocity_mm_s=section.getfloat("square_corner_velocity", 5.0, minval=0.0,
                                                     maxval=SPEED_MM_S[1]),
        axes=axes,
    )


class Toolhead:
    """Moves and homing on the virtual printer, in the toolhead's coordinates."""

    def __init__(self, printer, options: ToolheadOptions):
        self.printer = printer
        self.options = options
        self.backend = printer.backend
        self.homed_axes: set[str] = set()
        # toolhead coordinate = virtual printer coordinate + frame offset (set by homing)
        self.frame_offset_mm = {axis: 0.0 for axis in AXES}
        self.e_position_mm = 0.0  # the commanded extruder position (no filament on the virtual printer)
        # Limits SET_VELOCITY_LIMIT / M204 change at run time.
        self.max_velocity_mm_s = options.max_velocity_mm_s
        self.max_accel_mm_s2 = options.max_accel_mm_s2
        self.square_corner_velocity_mm_s = options.square_corner_velocity_mm_s
        self.minimum_cruise_ratio = options.minimum_cruise_ratio
        self.extruder = None  # set by load_config
        # Where G-code moves go: the toolhead itself, or a transform wrapping it (bed mesh,
        # thermal adjust). A transform has move(position_xyz, speed_mm_s) and get_position().
        self.move_target = self
        # The nozzle watch of a load-cell probe (extras/load_cell_probe/watch.py), None without:
        # wants(start, target) says whether a move runs watched, move(machine_xyz, speed, accel) runs it.
        self.nozzle_watch = None
        # How far Z was lifted (relative) since it lost its homing: [safe_z_home] z_hop on an unhomed
        # Z. The nozzle watch trusts a lift of nozzle_watch_height to clear the bed for G28 X/Y.
        self.z_lift_while_unhomed_mm = 0.0

    def forget_homing(self) -> None:
        """Motors off or positions lost: every axis must be homed again, and no lift is known."""
        self.homed_axes.clear()
        self.z_lift_while_unhomed_mm = 0.0

    def set_move_transform(self, transform):
        """Route G-code moves (G0/G1, M114) through `transform`; returns the previous target,
        to which the transform passes its (adjusted) moves."""
        previous = self.move_target
        self.move_target = transform
        return previous

    def move(self, position_xyz, speed_mm_s: float) -> None:
        """The end of the transform chain: a move in toolhead coordinates."""
        x, y, z = position_xyz
        self.move_to(x=x, y=y, z=z, speed_mm_s=speed_mm_s)

    # -- the probe's Motion protocol -------------------------------------------

    def get_position(self) -> tuple[float, float, float]:
        machine = self.backend.position
        return tuple(float(machine[i]) + self.frame_offset_mm[axis] for i, axis in enumerate(AXES))

    def move_to(self, x: float | None = None, y: float | None = None, z: float | None = None,
                speed_mm_s: float = 5.0) -> None:
        """A move in toolhead coordinates; outside the configured axis ranges it is refused
        (GCodeError) before anything moves, wherever the target came from."""
        target = {"x": x, "y": y, "z": z}
        moved = [axis for axis in AXES if target[axis] is not None]
        current = self.get_position()
        self._check_in_range({axis: current[i] if target[axis] is None else target[axis]
                              for i, axis in enumerate(AXES)}, moved)
        machine = {axis: None if value is None else value - self.frame_offset_mm[axis]
                   for axis, value in target.items()}
        end = tuple(current[i] if target[axis] is None else target[axis] for i, axis in enumerate(AXES))
        if not self.is_z_homed():
            self.z_lift_while_unhomed_mm = max(0.0, self.z_lift_while_unhomed_mm + end[2] - current[2])
        self.run_machine_move(current, end, (machine["x"], machine["y"], machine["z"]), speed_mm_s,
                              self.max_accel_mm_s2)

    def run_machine_move(self, start_xyz, end_xyz, machine_xyz, speed_mm_s: float, accel_mm_s2: float) -> None:
        """Move the machine to `machine_xyz` (None: the axis stays), the nozzle going from `start_xyz`
        to `end_xyz` in toolhead coordinates: with the nozzle watch armed when that can reach the
        bed. No range check: move_to checks first; FORCE_MOVE bypasses the kinematics on purpose."""
        try:
            if self.nozzle_watch is not None and self.nozzle_watch.wants(start_xyz, end_xyz):
                self.nozzle_watch.move(machine_xyz, speed_mm_s, accel_mm_s2)
            else:
                x, y, z = machine_xyz
                self.backend.move_to(x=x, y=y, z=z, speed_mm_s=speed_mm_s, accel_mm_s2=accel_mm_s2)
        except MoveError as exc:  # the virtual machine is smaller than the config says
            raise GCodeError(f"Move refused by the virtual printer: {exc}") from None

    def _check_in_range(self, position: dict[str, float], moved: list[str]) -> None:
        for axis in moved:
            limits = self.options.axes[axis]
            if not limits.position_min_mm <= position[axis] <= limits.position_max_mm:
                shown = " ".join(f"{position[a]:.3f}" for a in AXES)
                raise GCodeError(f"Move out of range: {shown} ({axis.upper()} must be within "
                                 f"{limits.position_min_mm:g} to {limits.position_max_mm:g})")

    def z_position_min(self) -> float:
        return self.options.axes["z"].position_min_mm

    def z_travel_mm(self) -> float:
        z = self.options.axes["z"]
        return z.position_max_mm - z.position_min_mm

    def set_z_position(self, z_mm: float) -> None:
        self.frame_offset_mm["z"] = z_mm - float(self.backend.position[2])
        self.homed_axes.add("z")
        self.z_lift_while_unhomed_mm = 0.0
        self.printer.send_event("toolhead:z_homed")

    def is_z_homed(self) -> bool:
        return "z" in self.homed_axes

    # -- commands --------------------------------------------------------------

    def cmd_G28(self, gcmd: GCodeCommand) -> None:
        asked = [axis for axis in AXES if gcmd.has(axis)]
        axes = asked or list(AXES)
        xy = [axis for axis in axes if axis in "xy"]
        if xy:
            self._home_xy("".join(xy))
            machine = self.backend.position
            for axis in xy:
                index = AXES.index(axis)
                self.frame_offset_mm[axis] = self.options.axes[axis].position_endstop_mm - float(machine[index])
                self.homed_axes.add(axis)
        if "z" in axes:
            z_axis = self.options.axes["z"]
            if not z_axis.homes_with_probe:
                raise gcmd.error(
                    "G28 Z: only homing through the load cell is simulated; set [stepper_z] "
                    f"endstop_pin: {PROBE_ENDSTOP_PIN}")
            probe = self.printer.lookup_object("probe", None)
            if probe is None:
                raise gcmd.error(
                    f"G28 Z: [stepper_z] endstop_pin is {PROBE_ENDSTOP_PIN} but there is no probe; "
                    "add a [load_cell_probe] section")
            probe.home_z(gcmd)
            self.homed_axes.add("z")
        self.printer.send_event("toolhead:homed", "".join(axes))

    def _home_xy(self, axes: str) -> None:
        """The endstop move of G28 X/Y: watched by the load cell when the nozzle may be low
        (extras/load_cell_probe/watch.py). An axis whose homing a collision stopped is not homed."""
        watch = self.nozzle_watch
        if watch is None or not watch.wants_homing():
            self.backend.home_xy(axes)
            return
        speed_mm_s = min(self.options.axes[axis].homing_speed_mm_s for axis in axes)
        try:
            watch.home_xy(axes, speed_mm_s)
        except GCodeError:
            self.homed_axes.difference_update(axes)
            raise

    def move_xyze(self, gcmd: GCodeCommand, current: list[float], target: list[float], speed_mm_s: float) -> None:
        """A G-code move from `current` to `target` (toolhead X, Y, Z, E): homing, limits and the
        extruder's checks, then X/Y/Z through the move transforms; an E-only move takes its time."""
        moved = [axis for index, axis in enumerate(AXES) if target[index] != current[index]]
        unhomed = [axis.upper() for axis in moved if axis not in self.homed_axes]
        if unhomed:
            raise gcmd.error(f"Must home axis first: {' '.join(unhomed)} (run G28)")
        self._check_in_range(dict(zip(AXES, target)), moved)
        xyz_distance = sum((t - c) ** 2 for t, c in zip(target[:3], current[:3])) ** 0.5
        e_distance = target[3] - current[3]
        try:
            self.extruder.check_move(xyz_distance, e_distance)
        except GCodeError as exc:
            raise gcmd.param_error(f"{exc}") from None
        self.e_position_mm = target[3]
        if not moved and e_distance:
            speed = min(speed_mm_s, self.extruder.max_extrude_only_velocity_mm_s)
            self.backend.dwell(abs(e_distance) / speed)
            return
        # Nothing moved in G-code terms still goes through the transforms, as in Klipper: one that
        # changed since (thermal adjust switched off, a new mesh) places the nozzle anew.
        speed = min(speed_mm_s, self.max_velocity_mm_s)
        if moved == ["z"]:
            speed = min(speed, self.options.max_z_velocity_mm_s)
        self.move_target.move(tuple(target[:3]), speed)

    def cmd_G4(self, gcmd: GCodeCommand) -> None:
        """Dwell: P milliseconds (S seconds, as some slicers write it)."""
        seconds = gcmd.get_float("S", None, minval=0.0, maxval=MAX_DWELL_S)
        if seconds is None:
            seconds = gcmd.get_float("P", 0.0, minval=0.0, maxval=MAX_DWELL_S * 1000.0) / 1000.0
        self.backend.dwell(seconds)

    def cmd_M400(self, gcmd: GCodeCommand) -> None:
        """Wait for moves to finish: the virtual printer runs every move to its end at once."""

    def cmd_M84(self, gcmd: GCodeCommand) -> None:
        """Motors off: every axis must be homed again (the steppers may be moved by hand).
        As in Klipper every motor goes off; axis letters (Cura's `M84 X Y E`) are taken and ignored."""
        for axis in "XYZE":
            gcmd.has(axis)
        self.forget_homing()
        self.printer.send_event("toolhead:motors_off")

    def cmd_M204(self, gcmd: GCodeCommand) -> None:
        accel = gcmd.get_float("S", None, **ACCEL_RANGE)
        if accel is None:
            # P (printing) and T (travel): the smaller one; R (retract) does not apply (as in Klipper).
            printing = gcmd.get_float("P", None, **ACCEL_RANGE)
            travel = gcmd.get_float("T", None, **ACCEL_RANGE)
            gcmd.get_float("R", None, **ACCEL_RANGE)
            if printing is None or travel is None:
                gcmd.respond_info(f'Invalid M204 command "{gcmd.get_commandline()}"')
                return
            accel = min(printing, travel)
        self.max_accel_mm_s2 = accel

    def cmd_SET_VELOCITY_LIMIT(self, gcmd: GCodeCommand) -> None:
        velocity = gcmd.get_float("VELOCITY", None, **SPEED_RANGE)
        accel = gcmd.get_float("ACCEL", None, **ACCEL_RANGE)
        corner = gcmd.get_float("SQUARE_CORNER_VELOCITY", None, minval=0.0, maxval=SPEED_MM_S[1])
        cruise_ratio = gcmd.get_float("MINIMUM_CRUISE_RATIO", None, minval=0.0, below=1.0)
        accel_to_decel = gcmd.get_float("ACCEL_TO_DECEL", None, **ACCEL_RANGE)  # the older spelling (OrcaSlicer)
        self.max_velocity_mm_s = velocity or self.max_velocity_mm_s
        self.max_accel_mm_s2 = accel or self.max_accel_mm_s2
        self.square_corner_velocity_mm_s = corner if corner is not None else self.square_corner_velocity_mm_s
        if cruise_ratio is None and accel_to_decel is not None:
            cruise_ratio = 1.0 - min(1.0, accel_to_decel / self.max_accel_mm_s2)
        self.minimum_cruise_ratio = cruise_ratio if cruise_ratio is not None else self.minimum_cruise_ratio
        if all(value is None for value in (velocity, accel, corner, cruise_ratio)):
            gcmd.respond_info(f"max_velocity: {self.max_velocity_mm_s:.6f}\nmax_accel: {self.max_accel_mm_s2:.6f}\n"
                              f"minimum_cruise_ratio: {self.minimum_cruise_ratio:.6f}\n"
                              f"square_corner_velocity: {self.square_corner_velocity_mm_s:.6f}")

    def status(self) -> dict:
        """Klipper's toolhead fields (positions in the toolhead frame, E last)."""
        axes = self.options.axes
        now_s = float(self.backend.now_s)
        return {
            "homed_axes": "".join(axis for axis in AXES if axis in self.homed_axes),
            "axis_minimum": [axes[a].position_min_mm for a in AXES] + [0.0],
            "axis_maximum": [axes[a].position_max_mm for a in AXES] + [0.0],
            "position": [*self.get_position(), self.e_position_mm],
            "extruder": "extruder",
            "print_time": now_s,
            "estimated_print_time": float(self.printer.estimated_print_time()),
            "stalls": 0,
            "max_velocity": self.max_velocity_mm_s,
            "max_accel": self.max_accel_mm_s2,
            "minimum_cruise_ratio": self.minimum_cruise_ratio,
            "square_corner_velocity": self.square_corner_velocity_mm_s,
        }

    def get_status(self, eventtime=None) -> dict:
        return self.status()


def load_config(section: ConfigSection, printer) -> None:
    """[printer]: builds the toolhead, the G-code frame and the extruder, with their commands."""
    if printer.backend is None:
        raise section.error("kinematics", "the toolhead needs the virtual printer ([virtual_printer])")
    toolhead = Toolhead(printer, read_toolhead_options(section))
    # A machine that lost the stepper positions (its MCU reset): every axis must be homed again.
    printer.register_event_handler("printer:positions_lost", toolhead.forget_homing)
    printer.add_object("toolhead", toolhead)
    z_min_mm = toolhead.options.axes["z"].position_min_mm
    if z_min_mm >= 0.0 and any(section.config.has_section(name) for name in NOZZLE_PROBE_SECTIONS):
        printer.warnings.append(
            f"[stepper_z] position_min = {z_min_mm:g}: taps need room below zero. The nozzle presses a little "
            "past the bed before the probe triggers, so a probing move that ends at Z=0 slows down first and every "
            "tap fails with COASTING_MOVE_ACCELERATION; set a negative position_min, e.g. position_min: -5")
    toolhead.extruder = load_extruder(section.config, printer, toolhead.options.max_velocity_mm_s)
    load_gcode_move(printer, toolhead)
    gcode = printer.gcode
    for name, handler, desc in (
        ("G28", toolhead.cmd_G28, "Home axes: G28 [X] [Y] [Z] (Z through the probe)"),
        ("G4", toolhead.cmd_G4, "Dwell: G4 P<milliseconds>"),
        ("M400", toolhead.cmd_M400, "Wait for the moves to finish"),
        ("M84", toolhead.cmd_M84, "Motors off (the axes must be homed again)"),
        ("M18", toolhead.cmd_M84, "Motors off (the axes must be homed again)"),
        ("M204", toolhead.cmd_M204, "Set the acceleration: M204 S<mm/s^2> (or P and T)"),
        ("SET_VELOCITY_LIMIT", toolhead.cmd_SET_VELOCITY_LIMIT,
         "Change the velocity limits: [VELOCITY=] [ACCEL=] [SQUARE_CORNER_VELOCITY=] [MINIMUM_CRUISE_RATIO=]"),
    ):
        gcode.register_command(name, handler, desc=desc)
    return None
