"""`[printer]` and `[stepper_x/y/z]`: the toolhead and its G-code commands.

The toolhead keeps the G-code state (absolute/relative, G92 offsets, feed rate) and
the homing state, checks every move against the axis limits and drives the virtual
printer (`printer.backend`). Z homes through the probe: G28 Z calls
`printer.lookup_object("probe").home_z(gcmd)`, and the probe re-bases Z with
`set_z_position` (the toolhead implements the probe's Motion protocol:
get_position, move_to, z_position_min, z_travel_mm, set_z_position, is_z_homed).

Coordinates: the virtual printer has its own machine coordinates; the toolhead's
coordinates are those plus a per-axis frame offset set by homing (X/Y endstops at
position_endstop, Z at the probed bed). G-code coordinates are the toolhead's minus
the G92 offsets.

Commands: G28, G0/G1 (F in mm/min), G90/G91, G92, M400, M114, M104/M109 (the
virtual nozzle heater). Status objects: `toolhead` and `extruder`.
"""

from __future__ import annotations

from dataclasses import dataclass

from tapcell.host.backend import MoveError
from tapcell.host.config import ConfigSection
from tapcell.host.gcode import GCodeCommand, GCodeError

AXES = "xyz"
KINEMATICS = ("cartesian",)
PROBE_ENDSTOP_PIN = "probe:z_virtual_endstop"
# M104/M109 range when there is no [extruder] section to say otherwise.
DEFAULT_MIN_TEMP_C = 0.0
DEFAULT_MAX_TEMP_C = 300.0
# The ranges every toolhead number is checked against: no printer is 10 m wide, and speeds,
# accelerations and temperatures have ceilings far above any real machine. The floor of
# the speeds keeps a move from lasting days (the virtual printer simulates every second).
MAX_COORDINATE_MM = 10_000.0
SPEED_MM_S = (0.1, 10_000.0)
# As getter keywords: getfloat("position_min", 0.0, **COORDINATE_RANGE).
COORDINATE_RANGE = {"minval": -MAX_COORDINATE_MM, "maxval": MAX_COORDINATE_MM}
SPEED_RANGE = {"minval": SPEED_MM_S[0], "maxval": SPEED_MM_S[1]}
ACCEL_MM_S2 = (1.0, 1_000_000.0)
MAX_TEMP_C = 1000.0
ABSOLUTE_ZERO_C = -273.15
MICROSTEPS = (1, 2, 4, 8, 16, 32, 64, 128, 256)
MAX_ROTATION_DISTANCE_MM = 1000.0
MAX_FULL_STEPS_PER_ROTATION = 10_000


@dataclass(frozen=True)
class AxisOptions:
    """One [stepper_?] section."""

    position_min_mm: float
    position_max_mm: float
    position_endstop_mm: float | None  # None when homed through the probe
    homing_speed_mm_s: float
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
    for pin in ("step_pin", "dir_pin"):
        section.get(pin)
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


class Extruder:
    """The virtual nozzle heater: M104/M109 targets and the `extruder` status."""

    def __init__(self, backend, min_temp_c: float, max_temp_c: float):
        self.backend = backend
        self.min_temp_c = min_temp_c
        self.max_temp_c = max_temp_c
        self.target_c = 0.0

    def set_target(self, target_c: float, wait: bool) -> None:
        self.target_c = target_c
        self.backend.set_nozzle_temperature(target_c, wait=wait)

    def get_status(self, eventtime=None) -> dict:
        return {"temperature": round(float(self.backend.nozzle_temperature_c), 2), "target": self.target_c,
                "min_temp": self.min_temp_c, "max_temp": self.max_temp_c}


# [extruder] options the virtual printer has no use for: read only to check them.
EXTRUDER_UNUSED_RANGES = {
    "rotation_distance": (0.001, MAX_ROTATION_DISTANCE_MM),
    "nozzle_diameter": (0.01, 10.0),
    "filament_diameter": (0.01, 10.0),
    "pid_kp": (0.0, 10_000.0),
    "pid_ki": (0.0, 10_000.0),
    "pid_kd": (0.0, 10_000.0),
    "pressure_advance": (0.0, 10.0),
    "min_extrude_temp": (ABSOLUTE_ZERO_C, MAX_TEMP_C),
    "max_extrude_only_distance": (0.0, MAX_COORDINATE_MM),
}


def read_extruder(config, backend) -> Extruder:
    """[extruder] is optional on the virtual printer: only its temperature range matters."""
    if not config.has_section("extruder"):
        return Extruder(backend, DEFAULT_MIN_TEMP_C, DEFAULT_MAX_TEMP_C)
    section = config.getsection("extruder")
    for option in ("step_pin", "dir_pin", "heater_pin", "sensor_type", "sensor_pin"):
        section.get(option, None)
    for option in ("enable_pin", "control", "gear_ratio"):
        section.get(option, None)
    section.getchoice("microsteps", list(MICROSTEPS), None)
    for option, (low, high) in EXTRUDER_UNUSED_RANGES.items():
        section.getfloat(option, None, minval=low, maxval=high)
    min_temp = section.getfloat("min_temp", DEFAULT_MIN_TEMP_C, minval=ABSOLUTE_ZERO_C, maxval=MAX_TEMP_C)
    max_temp = section.getfloat("max_temp", DEFAULT_MAX_TEMP_C, above=min_temp, maxval=MAX_TEMP_C)
    return Extruder(backend, min_temp, max_temp)


class Toolhead:
    """Moves and homing on the virtual printer, in the toolhead's coordinates."""

    def __init__(self, printer, options: ToolheadOptions):
        self.printer = printer
        self.options = options
        self.backend = printer.backend
        self.homed_axes: set[str] = set()
        # toolhead coordinate = virtual printer coordinate + frame offset (set by homing)
        self.frame_offset_mm = {axis: 0.0 for axis in AXES}
        # G-code coordinate = toolhead coordinate - G92 offset
        self.gcode_offset_mm = {axis: 0.0 for axis in AXES}
        self.absolute_coordinates = True
        self.speed_mm_s = 25.0  # until a G1 F sets it (Klipper's default feed rate)
        # Where G-code moves go: the toolhead itself, or a transform wrapping it (bed mesh,
        # thermal adjust). A transform has move(position_xyz, speed_mm_s) and get_position().
        self.move_target = self

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
        try:
            self.backend.move_to(**machine, speed_mm_s=speed_mm_s)
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
        self.printer.send_event("toolhead:z_homed")

    def is_z_homed(self) -> bool:
        return "z" in self.homed_axes

    # -- commands --------------------------------------------------------------

    def cmd_G28(self, gcmd: GCodeCommand) -> None:
        asked = [axis for axis in AXES if gcmd.has(axis)]
        axes = asked or list(AXES)
        xy = [axis for axis in axes if axis in "xy"]
        if xy:
            self.backend.home_xy()
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

    def _gcode_position(self) -> dict[str, float]:
        toolhead = self.move_target.get_position()
        return {axis: toolhead[i] - self.gcode_offset_mm[axis] for i, axis in enumerate(AXES)}

    def cmd_G1(self, gcmd: GCodeCommand) -> None:
        if gcmd.has("E"):
            raise gcmd.param_error("the virtual printer has no extruder motor,"
                                   " E moves are not supported")
        feed_mm_min = gcmd.get_float("F", None, minval=SPEED_MM_S[0] * 60.0, maxval=SPEED_MM_S[1] * 60.0)
        if feed_mm_min is not None:
            self.speed_mm_s = feed_mm_min / 60.0
        current = self._gcode_position()
        target = dict(current)
        moved = []
        for axis in AXES:
            value = gcmd.get_float(axis, None, **COORDINATE_RANGE)
            if value is None:
                continue
            target[axis] = value if self.absolute_coordinates else current[axis] + value
            moved.append(axis)
        if not moved:
            return
        unhomed = [axis.upper() for axis in moved if axis not in self.homed_axes]
        if unhomed:
            raise gcmd.error(f"Must home axis first: {' '.join(unhomed)} (run G28)")
        toolhead_target = {axis: target[axis] + self.gcode_offset_mm[axis] for axis in AXES}
        self._check_in_range(toolhead_target, moved)
        speed = min(self.speed_mm_s, self.options.max_velocity_mm_s)
        if moved == ["z"]:
            speed = min(speed, self.options.max_z_velocity_mm_s)
        self.move_target.move(tuple(toolhead_target[axis] for axis in AXES), speed)

    def cmd_G90(self, gcmd: GCodeCommand) -> None:
        self.absolute_coordinates = True

    def cmd_G91(self, gcmd: GCodeCommand) -> None:
        self.absolute_coordinates = False

    def cmd_G92(self, gcmd: GCodeCommand) -> None:
        toolhead = self.move_target.get_position()
        given = {axis: gcmd.get_float(axis, None, **COORDINATE_RANGE)
                 for axis in AXES}
        if all(value is None for value in given.values()):
            given = {axis: 0.0 for axis in AXES}
        for i, axis in enumerate(AXES):
            if given[axis] is not None:
                self.gcode_offset_mm[axis] = toolhead[i] - given[axis]

    def cmd_M400(self, gcmd: GCodeCommand) -> None:
        """Wait for moves to finish: the virtual printer runs every move to its end at once."""

    def cmd_M114(self, gcmd: GCodeCommand) -> None:
        position = self._gcode_position()
        gcmd.respond_raw("X:{x:.3f} Y:{y:.3f} Z:{z:.3f} E:0.000".format(**position))

    def status(self) -> dict:
        axes = self.options.axes
        return {
            "position": [*self.get_position(), 0.0],
            "gcode_position": [*self._gcode_position().values(), 0.0],
            "homed_axes": "".join(axis for axis in AXES if axis in self.homed_axes),
            "axis_minimum": [axes[a].position_min_mm for a in AXES] + [0.0],
            "axis_maximum": [axes[a].position_max_mm for a in AXES] + [0.0],
            "absolute_coordinates": self.absolute_coordinates,
            "speed": self.speed_mm_s,
            "max_velocity": self.options.max_velocity_mm_s,
            "max_accel": self.options.max_accel_mm_s2,
            "max_z_velocity": self.options.max_z_velocity_mm_s,
            "max_z_accel": self.options.max_z_accel_mm_s2,
            "print_time": float(self.backend.now_s),
        }

    def get_status(self, eventtime=None) -> dict:
        return self.status()


def _temperature_commands(extruder: Extruder):
    def set_temperature(gcmd: GCodeCommand, wait: bool) -> None:
        target = gcmd.get_float("S", 0.0, minval=0.0, maxval=MAX_TEMP_C)
        if target and not extruder.min_temp_c <= target <= extruder.max_temp_c:
            raise gcmd.param_error(f"S={target:g} is outside the nozzle's range "
                                   f"{extruder.min_temp_c:g} to {extruder.max_temp_c:g} (min_temp / max_temp)")
        extruder.set_target(target, wait)
        if wait:
            gcmd.respond_info(f"Nozzle at {extruder.backend.nozzle_temperature_c:.1f}C (target {target:g}C)")

    return (lambda gcmd: set_temperature(gcmd, wait=False)), (lambda gcmd: set_temperature(gcmd, wait=True))


def load_config(section: ConfigSection, printer) -> None:
    """[printer]: builds the toolhead and extruder objects and their commands."""
    if printer.backend is None:
        raise section.error("kinematics", "the toolhead needs the virtual printer ([virtual_printer])")
    toolhead = Toolhead(printer, read_toolhead_options(section))
    extruder = read_extruder(section.config, printer.backend)
    printer.add_object("toolhead", toolhead)
    printer.add_object("extruder", extruder)
    gcode = printer.gcode
    for name, handler, desc in (
        ("G28", toolhead.cmd_G28, "Home axes: G28 [X] [Y] [Z] (Z through the probe)"),
        ("G0", toolhead.cmd_G1, "Move: G0 [X] [Y] [Z] [F mm/min]"),
        ("G1", toolhead.cmd_G1, "Move: G1 [X] [Y] [Z] [F mm/min]"),
        ("G90", toolhead.cmd_G90, "Absolute coordinates"),
        ("G91", toolhead.cmd_G91, "Relative coordinates"),
        ("G92", toolhead.cmd_G92, "Set the G-code position: G92 [X] [Y] [Z]"),
        ("M400", toolhead.cmd_M400, "Wait for the moves to finish"),
        ("M114", toolhead.cmd_M114, "Report the G-code position"),
    ):
        gcode.register_command(name, handler, desc=desc)
    set_nozzle, set_nozzle_and_wait = _temperature_commands(extruder)
    gcode.register_command("M104", set_nozzle, desc="Set the nozzle temperature: M104 S<celsius>")
    gcode.register_command("M109", set_nozzle_and_wait, desc="Set the nozzle temperature and wait: M109 S<celsius>")
    return None
