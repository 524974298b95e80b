"""Sensor and machine faults, each active from a time (or from a condition) for a duration.

Four places a fault can act: on the force the cell feels (weight, bowden tug), on the
counts the chip produces (chip reset offset jump, stuck value, saturation, corrupted
frames), on the stream itself (disconnected: no samples; chip reset: a short gap), or on
the whole MCU (mcu_reset: the steppers stop, the trigger is lost and the host link is down
for the fault's duration; the printer raises McuResetError once the link is back).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from tapcell.host.backend import DeviceError
from tapcell.sim.sensor import COUNTS_MAX, COUNTS_MIN

# name -> default parameters (every fault also takes duration_s)
FAULT_DEFAULTS: dict[str, dict[str, float | str | bool]] = {
    "disconnected": {},
    "stuck": {},
    "chip_reset": {"offset_jump_counts": 60000.0, "gap_s": 0.02},
    "corrupt_frame": {"count": 1, "spacing_s": 0.25, "detected": False},
    "saturation": {"level": "max"},
    "weight": {"grams": 500.0},
    "bowden_tug": {"force_g": 300.0},
    "mcu_reset": {},
}
FAULT_DEFAULT_DURATION_S = {"corrupt_frame": math.inf, "bowden_tug": 0.3, "mcu_reset": 0.5}
# When a fault may begin: a probing move starts, the nozzle meets the bed, the trigger fires, a
# probing move halts (the dwell), a move goes straight up (pullback, the lift between taps), a move
# travels in X/Y (mesh travel, nozzle wipes). With nth, on that occurrence of the condition.
CONDITIONS = ("probing_move", "contact", "trigger", "halt", "lift", "travel")


class FaultError(ValueError):
    """A fault was asked for by an unknown name, condition or parameter."""


class McuResetError(DeviceError):
    """The MCU reset during a command: its steppers stopped at `reset_s`, the host link came back at
    `restored_s`. Positions the host knew are no longer trusted (a real MCU loses them)."""

    positions_lost = True

    def __init__(self, reset_s: float, restored_s: float):
        super().__init__(f"the MCU reset at {reset_s:.3f} s (print time): the steppers stopped and the host link "
                         f"was lost until {restored_s:.3f} s")
        self.reset_s = reset_s
        self.restored_s = restored_s


@dataclass
class Fault:
    name: str
    start_s: float | None            # None until its condition happens
    when: str | None
    duration_s: float
    params: dict = field(default_factory=dict)
    stuck_counts: int | None = None
    first_index: int = 0             # first conversion not yet produced when the fault began
    done: bool = False               # an mcu_reset that has happened (each resets once)
    waits_for: int = 1               # occurrences of its condition still to come before it begins

    @property
    def end_s(self) -> float:
        return math.inf if self.start_s is None else self.start_s + self.duration_s

    def active_mask(self, t_s: np.ndarray) -> np.ndarray:
        if self.start_s is None:
            return np.zeros(t_s.shape, dtype=bool)
        return (t_s >= self.start_s) & (t_s < self.end_s)


def make_fault(name: str, at_s: float | None, when: str | None, now_s: float, params: dict, nth: int = 1) -> Fault:
    if name not in FAULT_DEFAULTS:
        raise FaultError(f"unknown fault '{name}'; allowed: {', '.join(FAULT_DEFAULTS)}")
    if when is not None and when not in CONDITIONS:
        raise FaultError(f"unknown fault condition '{when}'; allowed: {', '.join(CONDITIONS)}")
    if when is not None and at_s is not None:
        raise FaultError(f"fault '{name}': give either at_s or when, not both")
    allowed = {**FAULT_DEFAULTS[name], "duration_s": None}
    for key in params:
        if key not in allowed:
            raise FaultError(f"fault '{name}' has no parameter '{key}'; allowed: {', '.join(allowed)}")
    merged = {**FAULT_DEFAULTS[name], **{k: v for k, v in params.items() if k != "duration_s"}}
    if name == "saturation" and merged["level"] not in ("max", "min"):
        raise FaultError(f"fault 'saturation' level '{merged['level']}' is not one of: max, min")
    duration = float(params.get("duration_s", FAULT_DEFAULT_DURATION_S.get(name, math.inf)))
    if duration <= 0.0:
        raise FaultError(f"fault '{name}': duration_s must be above 0, got {duration}")
    if nth < 1 or nth != int(nth) or (nth > 1 and when is None):
        raise FaultError(f"fault '{name}': nth must be a whole number from 1, and only with a condition")
    start = None if when is not None else (now_s if at_s is None else float(at_s))
    return Fault(name, start, when, duration, merged, waits_for=int(nth))


def external_force_g(faults: list[Fault], t_s: np.ndarray) -> np.ndarray:
    """Force on the cell from a weight placed on it or a tug on the bowden tube."""
    force = np.zeros(t_s.shape)
    for f in faults:
        if f.start_s is None:        # waiting for its condition
            continue
        if f.name == "weight":
            force[f.active_mask(t_s)] += f.params["grams"]
        elif f.name == "bowden_tug":
            mask = f.active_mask(t_s)
            phase = (t_s[mask] - f.start_s) / f.duration_s
            force[mask] += f.params["force_g"] * np.sin(np.pi * phase) ** 2   # smooth pull and release
    return force


def apply_count_faults(faults: list[Fault], k0: int, t_ready_s: np.ndarray, counts: np.ndarray,
                       previous_counts: int | None, first_ready_s: float, period_s: float,
                       glitch_bits: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Counts as the chip reports them, and a mask of frames the MCU detects as bad.

    k0: conversion index of the first sample; previous_counts: the sample before it (None at start).
    glitch_bits: one random bit number per sample used to corrupt a frame.
    """
    counts = counts.copy()
    detected_bad = np.zeros(counts.shape, dtype=bool)
    for f in faults:
        if f.start_s is None:
            continue
        if f.name == "chip_reset":
            counts[t_ready_s >= f.start_s] += int(f.params["offset_jump_counts"])
    np.clip(counts, COUNTS_MIN, COUNTS_MAX, out=counts)
    for f in faults:
        if f.start_s is None:
            continue
        mask = f.active_mask(t_ready_s)
        if f.name == "stuck" and mask.any():
            if f.stuck_counts is None:
                first = int(np.argmax(mask))
                f.stuck_counts = int(counts[first - 1]) if first > 0 else (
                    previous_counts if previous_counts is not None else int(counts[first]))
            counts[mask] = f.stuck_counts
        elif f.name == "saturation":
            counts[mask] = COUNTS_MAX if f.params["level"] == "max" else COUNTS_MIN
        elif f.name == "corrupt_frame":
            for k_frame in corrupt_frame_indices(f, first_ready_s, period_s):
                idx = k_frame - k0
                if 0 <= idx < counts.size:
                    counts[idx] = counts[idx] ^ np.int32(1 << int(glitch_bits[idx]))
                    detected_bad[idx] = bool(f.params["detected"])
    return counts, detected_bad


def corrupt_frame_indices(f: Fault, first_ready_s: float, period_s: float) -> list[int]:
    """The conversions a (started) corrupt_frame fault corrupts: for each frame time within the
    fault, the first conversion ready at or after it that was still to be produced when it began."""
    indices = []
    for i in range(int(f.params["count"])):
        frame_t = f.start_s + i * f.params["spacing_s"]
        if frame_t >= f.end_s:
            break
        indices.append(max(math.ceil((frame_t - first_ready_s) / period_s - 1e-9), f.first_index))
    return indices


def still_acting(faults: list[Fault], next_index: int, earliest_t_s: float, first_ready_s: float,
                 period_s: float) -> list[Fault]:
    """The faults that may still act on conversions from `next_index` on, none of which looks at
    anything before `earliest_t_s`; the others are finished and can be forgotten (so a long session
    does not pay for every fault it ever had on each chunk)."""
    def acting(f: Fault) -> bool:
        if f.start_s is None:                        # waiting for its condition
            return True
        if f.name == "chip_reset":                   # its offset jump lasts after the fault
            return True
        if f.name == "mcu_reset" and not f.done:     # one already due still resets (at once)
            return True
        if f.name == "corrupt_frame":
            return any(k >= next_index for k in corrupt_frame_indices(f, first_ready_s, period_s))
        return f.end_s >= earliest_t_s
    return [f for f in faults if acting(f)]


def stream_gap_mask(faults: list[Fault], t_ready_s: np.ndarray) -> np.ndarray:
    """True where the MCU gets no sample: the sensor is disconnected or restarting, or the MCU resets."""
    gone = np.zeros(t_ready_s.shape, dtype=bool)
    for f in faults:
        if f.start_s is None:
            continue
        if f.name in ("disconnected", "mcu_reset"):
            gone |= f.active_mask(t_ready_s)
        elif f.name == "chip_reset":
            gone |= (t_ready_s >= f.start_s) & (t_ready_s < f.start_s + f.params["gap_s"])
    return gone


def due_reset(faults: list[Fault], t_s: float) -> Fault | None:
    """The first mcu_reset that has not happened yet and is due by t_s."""
    due = [f for f in faults if f.name == "mcu_reset" and not f.done and f.start_s is not None and f.start_s <= t_s]
    return min(due, key=lambda f: f.start_s) if due else None
