"""`[force_move]`: moving one stepper by hand, and SET_KINEMATIC_POSITION, as in Klipper.

Loaded on every printer, as Klipper loads it: STEPPER_BUZZ STEPPER= is always there. FORCE_MOVE
and SET_KINEMATIC_POSITION need `enable_force_move: True`.

SET_KINEMATIC_POSITION [X=] [Y=] [Z=] [SET_HOMED=XYZ] [CLEAR_HOMED=]: the toolhead takes the
given position without moving (an axis not given keeps its position) and the axes in SET_HOMED
(all of them by default, as in Klipper) count as homed; CLEAR_HOMED (or the older CLEAR) forgets
homing of the axes it names. Macros use it to lift Z before homing.

FORCE_MOVE STEPPER= DISTANCE= VELOCITY= [ACCEL=] drives one stepper, bypassing the kinematics'
checks: the toolhead keeps the position it had, as in Klipper. Unlike Klipper, the axes the stepper
moved are no longer homed: the toolhead no longer knows where they are, and the nozzle watch
decides on the toolhead's position, so a stale Z must not be trusted (home again; a FORCE_MOVE up
with Z not homed counts as the lift before homing X/Y, like [safe_z_home]'s z_hop).
STEPPER_BUZZ STEPPER= moves the stepper 1 mm forward and back ten times. Both run with the
load cell's nozzle watch when the move can reach the bed (extras/load_cell_probe/watch.py): a
FORCE_MOVE down is the move the guard must not assume away.
On the virtual printer the steppers are stepper_x, stepper_y and stepper_z (on corexy the first
two move both X and Y by half the distance) and the extruders, whose moves only take their time.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from tapcell.host.config import ConfigSection
from tapcell.host.gcode import GCodeCommand
from tapcell.host.limits import ACCEL_MM_S2, COORDINATE_RANGE, SPEED_MM_S

AXES = "xyz"
# STEPPER_BUZZ: forward and back by this much, this many times, each way in a quarter second,
# with a pause after each way (Klipper's figures, so a user hears the same buzz).
BUZZ_DISTANCE_MM = 1.0
BUZZ_REPEATS = 10
BUZZ_SPEED_MM_S = BUZZ_DISTANCE_MM / 0.25
BUZZ_PAUSES_S = (0.05, 0.45)
# A stepper back within this of where it started (a buzz's float sums) did not move its axis.
SAME_PLACE_MM = 1e-9


def _axes(gcmd: GCodeCommand, name: str, default: str) -> str:
    text = gcmd.get(name, default).strip().lower()
    if any(letter not in AXES for letter in text):
        raise gcmd.param_error(f"{name} must name axes from X, Y, Z (got '{text.upper()}')")
    return text


@dataclass(frozen=True)
class Stepper:
    name: str
    toolhead_mm_per_mm: tuple[float, float, float]  # how far X, Y, Z move per mm of the stepper


def steppers(kinematics: str, extruders: list[str]) -> dict[str, Stepper]:
    """The steppers FORCE_MOVE can drive on the virtual printer, by config name."""
    half = 0.5
    xy = ({"stepper_x": (half, half, 0.0), "stepper_y": (half, -half, 0.0)} if kinematics == "corexy"
          else {"stepper_x": (1.0, 0.0, 0.0), "stepper_y": (0.0, 1.0, 0.0)})
    table = {**xy, "stepper_z": (0.0, 0.0, 1.0)}
    table.update({name: (0.0, 0.0, 0.0) for name in extruders})
    return {name: Stepper(name, vector) for name, vector in table.items()}


class ForceMove:
    def __init__(self, printer, toolhead):
        self.printer = printer
        self.toolhead = toolhead

    def _stepper(self, gcmd: GCodeCommand) -> Stepper:
        config = self.printer.config
        extruders = [name for name in config.sections() if re.fullmatch(r"extruder\d*", name)]
        known = steppers(self.toolhead.options.kinematics, extruders)
        name = gcmd.get("STEPPER").strip()
        if name not in known:
            modelled = ", ".join(known)
            if config.has_section(name):
                raise gcmd.error(f"{gcmd.command}: [{name}] is accepted but not modelled by the virtual printer "
                                 f"(its motors move with their axis); STEPPER= one of {modelled}")
            raise gcmd.error(f"Unknown stepper {name}: STEPPER= one of {modelled}")
        return known[name]

    def _move_stepper(self, stepper: Stepper, distance_mm: float, speed_mm_s: float, accel_mm_s2: float) -> None:
        """Move one stepper by `distance_mm`, watched when the nozzle can reach the bed (the
        toolhead's frame follows; the caller restores the commanded position)."""
        toolhead = self.toolhead
        delta = [share * distance_mm for share in stepper.toolhead_mm_per_mm]
        if not any(delta):  # an extruder: no filament on the virtual printer, only the time
            toolhead.backend.dwell(abs(distance_mm) / speed_mm_s)
            return
        start = toolhead.get_position()
        end = tuple(begin + step for begin, step in zip(start, delta))
        target = tuple(None if step == 0.0 else float(machine) + step
                       for machine, step in zip(toolhead.backend.position, delta))
        toolhead.run_machine_move(start, end, target, speed_mm_s, accel_mm_s2 or toolhead.max_accel_mm_s2)

    def _keep_commanded_position(self, machine_before: list[float]) -> list[str]:
        """The toolhead keeps the position it had before the stepper moved, as in Klipper, and the
        axes that ended elsewhere lose their homing (returned, in order)."""
        toolhead = self.toolhead
        lost = []
        for index, axis in enumerate(AXES):
            moved_mm = float(toolhead.backend.position[index]) - machine_before[index]
            if abs(moved_mm) < SAME_PLACE_MM:
                continue
            toolhead.frame_offset_mm[axis] -= moved_mm
            if axis == "z" and not toolhead.is_z_homed():
                toolhead.z_lift_while_unhomed_mm = max(0.0, toolhead.z_lift_while_unhomed_mm + moved_mm)
            if axis in toolhead.homed_axes:
                toolhead.homed_axes.discard(axis)
                lost.append(axis.upper())
        return lost

    def _run_keeping_position(self, gcmd: GCodeCommand, stepper: Stepper, moves) -> None:
        """Run `moves()` (stepper moves); then the commanded position is restored and a lost homing said."""
        machine_before = [float(value) for value in self.toolhead.backend.position]
        try:
            moves()
        finally:
            lost = self._keep_commanded_position(machine_before)
            if lost:
                gcmd.respond_info(f"{gcmd.command} {stepper.name}: {' '.join(lost)} no longer homed (the toolhead "
                                  "kept its position; home before moving it again)")

    def cmd_FORCE_MOVE(self, gcmd: GCodeCommand) -> None:
        stepper = self._stepper(gcmd)
        distance_mm = gcmd.get_float("DISTANCE", **COORDINATE_RANGE)
        speed_mm_s = gcmd.get_float("VELOCITY", above=0.0, maxval=SPEED_MM_S[1])
        accel_mm_s2 = gcmd.get_float("ACCEL", 0.0, minval=0.0, maxval=ACCEL_MM_S2[1])  # 0: the toolhead's
        self._run_keeping_position(gcmd, stepper,
                                   lambda: self._move_stepper(stepper, distance_mm, speed_mm_s, accel_mm_s2))

    def cmd_STEPPER_BUZZ(self, gcmd: GCodeCommand) -> None:
        stepper = self._stepper(gcmd)
        gcmd.respond_info(f"Stepper buzz {stepper.name}")
        dwell = self.toolhead.backend.dwell

        def buzz() -> None:
            for _ in range(BUZZ_REPEATS):
                for direction, pause_s in zip((1.0, -1.0), BUZZ_PAUSES_S):
                    self._move_stepper(stepper, direction * BUZZ_DISTANCE_MM, BUZZ_SPEED_MM_S, 0.0)
                    dwell(pause_s)
        self._run_keeping_position(gcmd, stepper, buzz)

    def cmd_SET_KINEMATIC_POSITION(self, gcmd: GCodeCommand) -> None:
        toolhead = self.toolhead
        current = toolhead.get_position()
        machine = toolhead.backend.position
        wanted = [gcmd.get_float(axis.upper(), current[i], **COORDINATE_RANGE) for i, axis in enumerate(AXES)]
        set_homed = _axes(gcmd, "SET_HOMED", AXES)
        clear_homed = _axes(gcmd, "CLEAR_HOMED", _axes(gcmd, "CLEAR", ""))
        for i, axis in enumerate(AXES):
            toolhead.frame_offset_mm[axis] = wanted[i] - float(machine[i])
        toolhead.homed_axes.update(set_homed)
        toolhead.homed_axes.difference_update(clear_homed)
        gcmd.respond_info("SET_KINEMATIC_POSITION pos: " + " ".join(f"{a}={v:.3f}" for a, v in zip(AXES, wanted)))


def load_config(section: ConfigSection, printer) -> None:
    toolhead = printer.lookup_object("toolhead", None)
    if toolhead is None:  # a config without [printer] (macros only): no steppers to move
        section.getboolean("enable_force_move", False)  # read, so a [force_move] section is not "unused"
        return None
    force_move = ForceMove(printer, toolhead)
    register = printer.gcode.register_command
    register("STEPPER_BUZZ", force_move.cmd_STEPPER_BUZZ,
             desc="Oscillate a stepper 1 mm forward and back ten times: STEPPER=")
    if not section.getboolean("enable_force_move", False):
        return None
    register("FORCE_MOVE", force_move.cmd_FORCE_MOVE,
             desc="Move one stepper, bypassing the kinematics: STEPPER= DISTANCE= VELOCITY= [ACCEL=]")
    register("SET_KINEMATIC_POSITION", force_move.cmd_SET_KINEMATIC_POSITION,
             desc="Set the toolhead's position without moving: [X=] [Y=] [Z=] "
                  "[SET_HOMED=XYZ] [CLEAR_HOMED=]")
    return None
