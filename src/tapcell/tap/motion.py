"""The motion of a tap: commanded Z at any time and the phase times (halt, pullback).

Built either from the trapezoid `moves` (exact) or from a commanded `z` per sample
(phases found from the Z trace itself). The analysis maps the break-contact time to a
height through `z_at`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tapcell.tap import native
from tapcell.tap.lazy import cached_attribute
from tapcell.tap.model import Move, TapData

# The move lookup in C (c/analysis.c, the window heights' kernel); None: numpy (`Motion.z_at`).
_C = native.load("analysis")

# Moves of one tap, counted from the end (tap-format / Klipper-family convention):
# [approach acceleration], approach cruise, halt marker, pullback accel, cruise, decel.
MIN_PROBING_MOVES = 5
MAX_PROBING_MOVES = 6


class MotionError(Exception):
    """The motion does not describe an approach, a halt and a pullback."""


@dataclass(eq=False, repr=False)
class Motion:
    """A tap's motion as the analysis reads it: when the approach halted, the pullback's times and
    speeds, and the heights (`tap_motion`)."""

    home_end_s: float  # the approach halted
    pullback_start_s: float
    pullback_cruise_s: float  # pullback reached its cruise speed
    pullback_end_s: float
    z_halt_mm: float
    approach_speed_mm_s: float
    pullback_speed_mm_s: float
    moves: list[Move] | None = None
    trace_time_s: np.ndarray | None = None
    trace_z_mm: np.ndarray | None = None

    @property
    def pullback_duration_s(self) -> float:
        return self.pullback_end_s - self.pullback_start_s

    def z_at(self, t_s: np.ndarray | float) -> np.ndarray:
        """Commanded Z (mm) at the given times."""
        t_s = np.asarray(t_s, dtype=float)
        if self.moves is None:
            return np.interp(t_s, self.trace_time_s, self.trace_z_mm)
        table = self.move_table
        index = np.maximum(table[0].searchsorted(t_s, side="right") - 1, 0)
        start, duration, start_v, accel, start_z, z_r = table.take(index, axis=1)
        tau_s = np.minimum(np.maximum(t_s - start, 0.0), duration)
        return start_z + z_r * (start_v + 0.5 * accel * tau_s) * tau_s

    def z_at_time_mm(self, t_s: float) -> float:
        """Commanded Z (mm) at one time: `z_at`'s move, clamp and arithmetic, bit for bit, in one kernel
        call when built (the numpy lookup costs ~15 µs a time inside the analysis)."""
        if _C is not None and self.moves is not None:
            return _C.z_at(self.move_rows, t_s)
        return float(self.z_at(t_s))

    @cached_attribute
    def move_table(self) -> np.ndarray:
        """Rows: start time, duration, start speed, acceleration, start Z, direction; one column per move."""
        # One flat list of floats laid out row by row (a list of tuples makes numpy discover the
        # nesting: twice the cost a tap; moves by columns needed a transposed copy).
        return np.array(self.move_rows, dtype=float).reshape(6, -1)

    @cached_attribute
    def move_rows(self) -> list[float]:
        """`move_table`'s six rows one after the other in one list: what the compiled window heights
        read (each tap's analysis builds no array for them)."""
        moves = self.moves
        flat = [m.print_time for m in moves]
        flat += [m.move_t for m in moves]
        flat += [m.start_v for m in moves]
        flat += [m.accel for m in moves]
        flat += [m.start_z for m in moves]
        flat += [m.z_r for m in moves]
        return flat


def motion_from_moves(moves: list[Move]) -> Motion:
    """Phase times from the last five moves (the approach acceleration may have aged out)."""
    cruise, halt, pull_start, pull_cruise, pull_end = moves[-5:]
    if cruise.start_v <= 0 or cruise.z_r >= 0:
        raise MotionError("the approach move (5th from last) does not move down")
    if pull_cruise.z_r <= 0 or pull_cruise.start_v <= 0:
        raise MotionError("the pullback cruise move (2nd from last) does not move up")
    # The halt marker carries the stop height; the cruise was cut short there.
    home_end_s = cruise.print_time + abs(halt.start_z - cruise.start_z) / cruise.start_v
    # Positional, in the fields' order (home_end_s .. pullback_speed_mm_s, moves): keywords cost more, once a tap.
    return Motion(home_end_s, pull_start.print_time, pull_cruise.print_time, pull_end.end_time, halt.start_z,
                  cruise.start_v, pull_cruise.start_v, list(moves))


def motion_from_z(time_s: np.ndarray, z_mm: np.ndarray) -> Motion:
    """Phase times from a commanded Z per sample: descent, rest at the lowest Z, rise."""
    z_low = float(z_mm.min())
    z_high_after = float(z_mm[np.argmin(z_mm):].max())
    travel_mm = z_high_after - z_low
    if travel_mm <= 0:
        raise MotionError("z never rises after its lowest point (no pullback)")
    tolerance_mm = max(1e-9, 1e-6 * travel_mm)
    at_bottom = np.flatnonzero(z_mm <= z_low + tolerance_mm)
    first, last = int(at_bottom[0]), int(at_bottom[-1])
    if first == 0:
        raise MotionError("z does not descend before its lowest point (no approach)")
    if last >= len(z_mm) - 2:
        raise MotionError("z does not rise after its lowest point (no pullback)")
    dt = np.diff(time_s)
    speed = np.diff(z_mm) / dt
    approach_speed = float(-speed[max(0, first - 3):first].mean())
    top = last + int(np.argmax(z_mm[last:] >= z_high_after - tolerance_mm))
    pullback_speed = float(np.median(speed[last:top])) if top > last + 1 else float(speed[last])
    if approach_speed <= 0 or pullback_speed <= 0:
        raise MotionError("could not measure the approach and pullback speeds from z")
    # Sub-sample phase times from the speeds on either side of the rest.
    home_end_s = float(time_s[first - 1] + (z_mm[first - 1] - z_low) / approach_speed)
    pullback_start_s = float(time_s[last + 1] - (z_mm[last + 1] - z_low) / pullback_speed)
    pullback_start_s = max(pullback_start_s, float(time_s[last]))
    pullback_end_s = float(time_s[top - 1] + (z_high_after - z_mm[top - 1]) / pullback_speed) if top > last + 1 else float(time_s[top])
    return Motion(
        home_end_s=min(home_end_s, float(time_s[first])),
        pullback_start_s=pullback_start_s,
        pullback_cruise_s=pullback_start_s,
        pullback_end_s=min(pullback_end_s, float(time_s[top])),
        z_halt_mm=z_low,
        approach_speed_mm_s=approach_speed,
        pullback_speed_mm_s=pullback_speed,
        trace_time_s=np.asarray(time_s, dtype=float),
        trace_z_mm=np.asarray(z_mm, dtype=float),
    )


def tap_motion(tap: TapData) -> Motion:
    if tap.moves:
        return motion_from_moves(tap.moves)
    if tap.z_mm is not None:
        return motion_from_z(tap.time_s, tap.z_mm)
    raise MotionError("the tap has neither moves nor z")
