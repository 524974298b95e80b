"""Toolhead motion: trapezoidal moves, limits, step quantization and the move history.

Moves are stored as constant-acceleration segments (the shape of a Klipper trapq entry):
position(t) = start + direction * (start_v + accel*τ/2) * τ for τ in [0, move_t].
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

# Simulated time of motion (and samples, see mcu.SampleLog) the virtual printer remembers: far
# more than one command looks back over (a tap file, a whole mesh's truth), and bounded, so the
# cost per tap stays flat over a session of thousands of taps.
HISTORY_KEEP_S = 600.0
FORGET_BATCH = 256


@dataclass(frozen=True)
class Segment:
    print_time: float                  # s, when the segment starts
    move_t: float                      # s
    start_v: float                     # mm/s along the direction, >= 0
    accel: float                       # mm/s², signed
    start: tuple[float, float, float]  # mm
    direction: tuple[float, float, float]  # unit vector (all zero for a marker)

    @property
    def end_time(self) -> float:
        return self.print_time + self.move_t

    def distance_at(self, tau_s):
        return (self.start_v + 0.5 * self.accel * tau_s) * tau_s

    def position_at(self, t_s: float) -> tuple[float, float, float]:
        d = self.distance_at(min(max(t_s - self.print_time, 0.0), self.move_t))
        return tuple(s + u * d for s, u in zip(self.start, self.direction))

    @property
    def end(self) -> tuple[float, float, float]:
        return self.position_at(self.end_time)

    def truncated(self, t_s: float) -> Segment:
        """The same segment ending at t_s (a halt without deceleration)."""
        return Segment(self.print_time, max(0.0, min(t_s, self.end_time) - self.print_time),
                       self.start_v, self.accel, self.start, self.direction)

    def as_tap_move(self) -> dict:
        """The tapcell.tap.v1 `moves` form (Z only)."""
        z_r = self.direction[2]
        return {"print_time": float(self.print_time), "move_t": float(self.move_t),
                "start_v": float(self.start_v), "accel": float(self.accel), "start_z": float(self.start[2]),
                "z_r": 0 if abs(z_r) < 1e-12 else (1 if z_r > 0 else -1)}


def plan_trapezoid(start, end, t0_s: float, speed_mm_s: float, accel_mm_s2: float) -> list[Segment]:
    """Accelerate, cruise, decelerate from start to end (rest to rest); short moves become triangles."""
    delta = np.subtract(end, start, dtype=float)
    distance = float(np.linalg.norm(delta))
    if distance <= 0.0:
        return []
    direction = tuple(float(v) for v in delta / distance)
    cruise_v = min(speed_mm_s, math.sqrt(accel_mm_s2 * distance))
    accel_t = cruise_v / accel_mm_s2
    accel_d = 0.5 * cruise_v * accel_t
    cruise_d = max(0.0, distance - 2.0 * accel_d)
    segments = []
    t = float(t0_s)
    pos = tuple(float(v) for v in start)

    def add(move_t, start_v, accel, length):
        nonlocal t, pos
        if move_t <= 0.0:
            return
        segments.append(Segment(t, float(move_t), float(start_v), float(accel), pos, direction))
        t += move_t
        pos = tuple(p + u * length for p, u in zip(pos, direction))

    add(accel_t, 0.0, accel_mm_s2, accel_d)
    add(cruise_d / cruise_v, cruise_v, 0.0, cruise_d)
    add(accel_t, cruise_v, -accel_mm_s2, accel_d)
    return segments


def move_limits(direction, max_velocity_mm_s: float, max_accel_mm_s2: float,
                max_z_velocity_mm_s: float, max_z_accel_mm_s2: float, speed_mm_s: float) -> tuple[float, float]:
    """Speed and acceleration along a move direction, capped like Klipper's cartesian kinematics:
    the toolhead limits apply to the whole move, the Z limits scale with the Z share of the move."""
    speed = min(speed_mm_s, max_velocity_mm_s)
    accel = max_accel_mm_s2
    z_ratio = abs(direction[2])
    if z_ratio > 0.0:
        speed = min(speed, max_z_velocity_mm_s / z_ratio)
        accel = min(accel, max_z_accel_mm_s2 / z_ratio)
    return speed, accel


def quantize_to_steps(position_mm, step_distance_mm):
    """Where the steppers really are: the nearest whole (micro)step."""
    return np.round(np.asarray(position_mm, dtype=float) / step_distance_mm) * step_distance_mm


class MotionHistory:
    """The executed segments of the last HISTORY_KEEP_S, oldest first, with vectorised lookup.

    Older segments are dropped as new ones come, so a long session costs the same per move as
    a short one (the lookups bisect arrays of start and end times instead of scanning a list).
    Positions before the oldest kept segment read as its start.
    """

    def __init__(self, start_position):
        self.rest_position = tuple(float(v) for v in start_position)
        self.segments: list[Segment] = []
        self._starts = np.zeros(0)
        self._ends = np.zeros(0)

    def append(self, segments: list[Segment]) -> None:
        self.segments.extend(segments)
        self._starts = np.concatenate([self._starts, [s.print_time for s in segments]])
        self._ends = np.concatenate([self._ends, [s.end_time for s in segments]])
        self._forget_before(self._ends[-1] - HISTORY_KEEP_S if len(self._ends) else 0.0)

    def replace_last(self, count: int, segments: list[Segment]) -> None:
        keep = len(self.segments) - count
        del self.segments[keep:]
        self._starts, self._ends = self._starts[:keep], self._ends[:keep]
        self.append(segments)

    def _forget_before(self, t_s: float) -> None:
        old = int(np.searchsorted(self._ends, t_s, side="left"))
        if old > FORGET_BATCH:  # in batches: the slices copy the arrays
            del self.segments[:old]
            self._starts, self._ends = self._starts[old:], self._ends[old:]

    @property
    def end_time(self) -> float:
        return self.segments[-1].end_time if self.segments else 0.0

    @property
    def end_position(self) -> tuple[float, float, float]:
        return self.segments[-1].end if self.segments else self.rest_position

    def positions_at(self, t_s: np.ndarray) -> np.ndarray:
        """(n, 3) commanded positions; between and after segments the toolhead rests."""
        t_s = np.asarray(t_s, dtype=float)
        out = np.empty((t_s.size, 3))
        if not self.segments:
            out[:] = self.rest_position
            return out
        index = np.searchsorted(self._starts, t_s, side="right") - 1
        before = index < 0
        out[before] = self.segments[0].start
        for i in np.unique(index[~before]):
            seg = self.segments[i]
            sel = index == i
            tau = np.clip(t_s[sel] - seg.print_time, 0.0, seg.move_t)
            d = seg.distance_at(tau)
            out[sel] = np.asarray(seg.start) + np.outer(d, seg.direction)
        return out

    def speed_at(self, t_s: float) -> float:
        """The speed along the path at t_s (0 between and after segments)."""
        index = int(np.searchsorted(self._starts, t_s, side="right")) - 1
        if index < 0:
            return 0.0
        seg = self.segments[index]
        tau = t_s - seg.print_time
        if tau >= seg.move_t or not any(seg.direction):
            return 0.0
        return float(seg.start_v + seg.accel * tau)

    def segments_between(self, t0_s: float, t1_s: float) -> list[Segment]:
        """Segments that end at or after t0 and start at or before t1."""
        first = int(np.searchsorted(self._ends, t0_s, side="left"))
        last = int(np.searchsorted(self._starts, t1_s, side="right"))
        return self.segments[first:last]
