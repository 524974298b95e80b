"""G-code coordinates on top of the toolhead (Klipper's `gcode_move`).

Three frames, as in Klipper:

* toolhead: where the nozzle is commanded to go (X, Y, Z and the extruder's E);
* gcode: what G-code talks about, `gcode = toolhead - base` per axis;
* base = the SET_GCODE_OFFSET part (`homing_origin`) + the G92 part.

Commands: G0/G1 (X Y Z E F), G90/G91, M82/M83, G92 (per axis; no axis: all four),
M114, M220/M221, SET_GCODE_OFFSET (X/Y/Z/E, *_ADJUST, MOVE=1, MOVE_SPEED), GET_POSITION,
SAVE_GCODE_STATE / RESTORE_GCODE_STATE. Status `gcode_move` with Klipper's fields
(`speed` in mm/min, factors as fractions).

Moves go to `toolhead.move_target` (the bed mesh and thermal transforms sit there) for
X/Y/Z, and to the toolhead for E; the toolhead checks limits and runs them.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field

from tapcell.host.gcode import GCodeCommand
from tapcell.host.limits import COORDINATE_RANGE, FEED_RANGE, SPEED_RANGE

AXES4 = "XYZE"
# M220 / M221 in percent: a factor must be positive and no slicer asks for 100x.
FACTOR_PERCENT_RANGE = {"above": 0.0, "maxval": 10_000.0}
DEFAULT_SPEED_MM_S = 25.0  # until the first F (Klipper's default feed rate)


@dataclass
class GCodeState:
    """Everything SAVE_GCODE_STATE keeps."""

    absolute_coordinates: bool = True
    absolute_extrude: bool = True
    base_position: list[float] = field(default_factory=lambda: [0.0] * 4)
    homing_position: list[float] = field(default_factory=lambda: [0.0] * 4)
    speed_mm_s: float = DEFAULT_SPEED_MM_S
    speed_factor: float = 1.0
    extrude_factor: float = 1.0
    last_position: list[float] | None = None  # the toolhead position when saved


class GCodeMove:
    def __init__(self, printer, toolhead):
        self.printer = printer
        self.toolhead = toolhead
        self.state = GCodeState()
        self.saved_states: dict[str, GCodeState] = {}
        # (position the transforms report after our last move, the position that move asked for):
        # the transforms' inverse (e.g. the bed mesh) is not exact, so while nothing else moved
        # the toolhead, the asked position is the position (Klipper's last_position).
        self._last_move: tuple[list[float], list[float]] | None = None
        printer.register_event_handler("toolhead:homed", self._after_homing)

    # -- positions ------------------------------------------------------------------------
    def toolhead_position(self) -> list[float]:
        """X, Y, Z as the move transforms see them, and E."""
        x, y, z = self.toolhead.move_target.get_position()
        now = [x, y, z, self.toolhead.e_position_mm]
        if self._last_move is not None and self._last_move[0] == now:
            return list(self._last_move[1])
        return now

    def _move(self, gcmd: GCodeCommand, current: list[float], target: list[float], speed_mm_s: float) -> None:
        self.toolhead.move_xyze(gcmd, current, target, speed_mm_s)
        x, y, z = self.toolhead.move_target.get_position()
        self._last_move = ([x, y, z, self.toolhead.e_position_mm], list(target))

    def gcode_position(self) -> list[float]:
        position = [p - b for p, b in zip(self.toolhead_position(), self.state.base_position)]
        position[3] /= self.state.extrude_factor  # G-code E counts before the extrude factor
        return position

    def _after_homing(self, axes: str) -> None:
        """A homed axis loses its G92 offset and keeps its SET_GCODE_OFFSET (Klipper's rule)."""
        for axis in axes:
            index = AXES4.index(axis.upper())
            self.state.base_position[index] = self.state.homing_position[index]

    # -- moves --------------------------------------------------------------------------
    def cmd_G1(self, gcmd: GCodeCommand) -> None:
        state = self.state
        feed_mm_min = gcmd.get_float("F", None, **FEED_RANGE)
        if feed_mm_min is not None:
            state.speed_mm_s = feed_mm_min / 60.0
        current = self.toolhead_position()
        target = list(current)
        for index, axis in enumerate("XYZ"):
            value = gcmd.get_float(axis, None, **COORDINATE_RANGE)
            if value is not None:
                target[index] = value + state.base_position[index] if state.absolute_coordinates else current[index] + value
        e_value = gcmd.get_float("E", None, **COORDINATE_RANGE)
        if e_value is not None:
            e_value *= state.extrude_factor
            absolute = state.absolute_coordinates and state.absolute_extrude
            target[3] = e_value + state.base_position[3] if absolute else current[3] + e_value
        self._move(gcmd, current, target, state.speed_mm_s * state.speed_factor)

    def cmd_G90(self, gcmd: GCodeCommand) -> None:
        self.state.absolute_coordinates = True

    def cmd_G91(self, gcmd: GCodeCommand) -> None:
        self.state.absolute_coordinates = False

    def cmd_M82(self, gcmd: GCodeCommand) -> None:
        self.state.absolute_extrude = True

    def cmd_M83(self, gcmd: GCodeCommand) -> None:
        self.state.absolute_extrude = False

    def cmd_G92(self, gcmd: GCodeCommand) -> None:
        position = self.toolhead_position()
        given = {index: gcmd.get_float(axis, None, **COORDINATE_RANGE) for index, axis in enumerate(AXES4)}
        if all(value is None for value in given.values()):
            self.state.base_position = list(position)
            return
        for index, value in given.items():
            if value is None:
                continue
            if index == 3:
                value *= self.state.extrude_factor
            self.state.base_position[index] = position[index] - value

    def cmd_M114(self, gcmd: GCodeCommand) -> None:
        x, y, z, e = self.gcode_position()
        gcmd.respond_raw(f"X:{x:.3f} Y:{y:.3f} Z:{z:.3f} E:{e:.3f}")

    def cmd_M220(self, gcmd: GCodeCommand) -> None:
        self.state.speed_factor = gcmd.get_float("S", 100.0, **FACTOR_PERCENT_RANGE) / 100.0

    def cmd_M221(self, gcmd: GCodeCommand) -> None:
        new_factor = gcmd.get_float("S", 100.0, **FACTOR_PERCENT_RANGE) / 100.0
        gcmd.get_int("T", None, minval=0, maxval=0)
        # Keep the G-code E where it is: the toolhead E does not jump.
        e_toolhead = self.toolhead.e_position_mm
        e_gcode = (e_toolhead - self.state.base_position[3]) / self.state.extrude_factor
        self.state.extrude_factor = new_factor
        self.state.base_position[3] = e_toolhead - e_gcode * new_factor

    # -- offsets ------------------------------------------------------------------------
    def cmd_SET_GCODE_OFFSET(self, gcmd: GCodeCommand) -> None:
        move_delta = [0.0] * 4
        for index, axis in enumerate(AXES4):
            offset = gcmd.get_float(axis, None, **COORDINATE_RANGE)
            adjust = gcmd.get_float(f"{axis}_ADJUST", None, **COORDINATE_RANGE)
            if offset is None and adjust is None:
                continue
            if offset is None:
                offset = self.state.homing_position[index] + adjust
            delta = offset - self.state.homing_position[index]
            move_delta[index] = delta
            self.state.base_position[index] += delta
            self.state.homing_position[index] = offset
        if gcmd.get_int("MOVE", 0, minval=0, maxval=1):
            speed = gcmd.get_float("MOVE_SPEED", self.state.speed_mm_s, **SPEED_RANGE)
            current = self.toolhead_position()
            target = [p + d for p, d in zip(current, move_delta)]
            if target != current:
                self._move(gcmd, current, target, speed)

    def z_offset_mm(self) -> float:
        """The SET_GCODE_OFFSET Z (what Z_OFFSET_APPLY_PROBE folds into the probe's z_offset)."""
        return self.state.homing_position[2]

    def cmd_SAVE_GCODE_STATE(self, gcmd: GCodeCommand) -> None:
        saved = copy.deepcopy(self.state)
        saved.last_position = self.toolhead_position()
        self.saved_states[gcmd.get("NAME", "default")] = saved

    def cmd_RESTORE_GCODE_STATE(self, gcmd: GCodeCommand) -> None:
        name = gcmd.get("NAME", "default")
        if name not in self.saved_states:
            raise gcmd.param_error(f"Unknown g-code state: {name}")
        saved = self.saved_states[name]
        e_now = self.toolhead.e_position_mm
        self.state = copy.deepcopy(saved)
        # The extruder does not go back: shift E's base so the G-code E continues from here.
        self.state.base_position[3] += e_now - saved.last_position[3]
        self.state.last_position = None
        if gcmd.get_int("MOVE", 0, minval=0, maxval=1):
            speed = gcmd.get_float("MOVE_SPEED", self.state.speed_mm_s, **SPEED_RANGE)
            current = self.toolhead_position()
            target = saved.last_position[:3] + [current[3]]
            self._move(gcmd, current, target, speed)

    def cmd_GET_POSITION(self, gcmd: GCodeCommand) -> None:
        toolhead = self.toolhead
        machine = toolhead.backend.position
        steps = [round(m / d) for m, d in zip(machine, toolhead.backend.step_distance_mm)]
        names = ("stepper_x", "stepper_y", "stepper_z")
        kinematic = toolhead.get_position()

        def axes(values, letters=AXES4):
            return " ".join(f"{letter}:{value:.6f}" for letter, value in zip(letters, values))

        gcmd.respond_info("\n".join((
            "mcu: " + " ".join(f"{n}:{s}" for n, s in zip(names, steps)),
            "stepper: " + " ".join(f"{n}:{m:.6f}" for n, m in zip(names, machine)),
            "kinematic: " + axes(kinematic, "XYZ"),
            "toolhead: " + axes([*kinematic, toolhead.e_position_mm]),
            "gcode: " + axes(self.gcode_position()),
            "gcode base: " + axes(self.state.base_position),
            "gcode homing: " + axes(self.state.homing_position[:3], "XYZ"),
        )))

    def get_status(self, eventtime=None) -> dict:
        state = self.state
        return {
            "speed_factor": state.speed_factor,
            "speed": state.speed_mm_s * 60.0,
            "extrude_factor": state.extrude_factor,
            "absolute_coordinates": state.absolute_coordinates,
            "absolute_extrude": state.absolute_extrude,
            "homing_origin": list(state.homing_position),
            "position": self.toolhead_position(),
            "gcode_position": self.gcode_position(),
        }


COMMANDS = (
    ("G0", "cmd_G1", "Move: G0 [X] [Y] [Z] [E] [F mm/min]"),
    ("G1", "cmd_G1", "Move: G1 [X] [Y] [Z] [E] [F mm/min]"),
    ("G90", "cmd_G90", "Absolute coordinates"),
    ("G91", "cmd_G91", "Relative coordinates"),
    ("M82", "cmd_M82", "Absolute extrusion (E)"),
    ("M83", "cmd_M83", "Relative extrusion (E)"),
    ("G92", "cmd_G92", "Set the G-code position: G92 [X] [Y] [Z] [E] (no axis: all)"),
    ("M114", "cmd_M114", "Report the G-code position"),
    ("M220", "cmd_M220", "Speed factor override: M220 S<percent>"),
    ("M221", "cmd_M221", "Extrude factor override: M221 S<percent>"),
    ("SET_GCODE_OFFSET", "cmd_SET_GCODE_OFFSET",
     "Set a G-code offset: [X|Y|Z|E=mm] [X|Y|Z|E_ADJUST=mm] [MOVE=1 [MOVE_SPEED=mm/s]]"),
    ("SAVE_GCODE_STATE", "cmd_SAVE_GCODE_STATE", "Save the G-code coordinate state: [NAME=]"),
    ("RESTORE_GCODE_STATE", "cmd_RESTORE_GCODE_STATE", "Restore a saved G-code state: [NAME=] [MOVE=1]"),
    ("GET_POSITION", "cmd_GET_POSITION", "Report the position in every frame (steps, stepper, toolhead, gcode)"),
)


def load_gcode_move(printer, toolhead) -> GCodeMove:
    gcode_move = GCodeMove(printer, toolhead)
    printer.add_object("gcode_move", gcode_move)
    for name, method, desc in COMMANDS:
        printer.gcode.register_command(name, getattr(gcode_move, method), desc=desc)
    return gcode_move
