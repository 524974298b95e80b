"""The backend: what the host needs from the machine under it, declared in one place.

The virtual printer (`tapcell.sim.VirtualPrinter`) implements `Backend`; a link to real MCUs
could implement the same. The host owns no clock of its own: time moves through the
backend's commands (moves, dwell, probing moves) and is read from `now_s`. Everything here
is plain data or a protocol; nothing imports the simulator.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from collections.abc import Sequence
from typing import Protocol

import numpy as np


class MoveError(ValueError):
    """A commanded move leaves the machine's limits."""


class DeviceError(RuntimeError):
    """The machine failed under a command (e.g. its MCU reset): the command ends with a G-code
    error saying what happened, as on a real printer; it is not a bug."""

    positions_lost = False  # True: the steppers' positions are no longer known (home again)


class EmergencyStopError(DeviceError):
    """An emergency stop halted the machine: its steppers stopped at `halt_s` (print time), at the
    next sample it produced after the stop was asked for, and every motion fails until a restart."""

    def __init__(self, halt_s: float):
        super().__init__(f"emergency stop: the steppers stopped at {halt_s:.3f} s (print time)")
        self.halt_s = halt_s


@dataclass
class SampleBatch:
    """Samples since the last take: read times (s), raw counts, and the counters since then."""

    t_s: np.ndarray
    counts: np.ndarray
    errors: int = 0
    overflows: int = 0


@dataclass
class ProbingMoveResult:
    triggered: bool
    trigger_time_s: float | None
    halt_time_s: float
    halt_z_mm: float
    error: object                  # TriggerError (NONE when the move ended normally or triggered)
    moves: list[dict] = field(default_factory=list)


class SampleSource(Protocol):
    """A load-cell sensor: the samples read since the last call."""

    def take_samples(self) -> SampleBatch: ...


class Backend(SampleSource, Protocol):
    """The machine under the host: motion, time, heaters, fans/pins and the probe's sensor.

    Positions are machine coordinates in mm; `trigger` is an armed
    `tapcell.mcu.trigger.FirmwareTrigger` that sees every sample of a probing move.
    """

    @property
    def now_s(self) -> float: ...

    @property
    def position(self) -> tuple[float, float, float]: ...

    @property
    def limits(self) -> dict[str, tuple[float, float]]: ...

    @property
    def nozzle_temperature_c(self) -> float: ...

    @property
    def step_distance_mm(self) -> Sequence[float]: ...

    @property
    def room_temperature_c(self) -> float: ...

    def move_to(self, x: float | None = None, y: float | None = None, z: float | None = None,
                speed_mm_s: float = 50.0, accel_mm_s2: float | None = None) -> None: ...

    def home_xy(self, axes: str = "xy") -> None: ...

    def watched_home_xy(self, axes: str, speed_mm_s: float, trigger) -> ProbingMoveResult: ...

    def position_at(self, t_s: float) -> tuple[float, float, float]: ...

    def speed_at(self, t_s: float) -> float: ...

    def endstop_triggered(self, axis: str) -> bool: ...

    def dwell(self, t_s: float) -> None: ...

    def set_nozzle_temperature(self, target_c: float, wait: bool = False) -> None: ...

    def heater_temperature_c(self, name: str) -> float: ...

    def set_heater_temperature(self, name: str, target_c: float) -> None: ...

    def wait_for_heater(self, name: str, within_c: float = 1.0) -> float: ...

    def set_output(self, name: str, value: float) -> None: ...

    def add_sensor(self, name: str, chip: str, sample_rate_sps: float) -> SampleSource: ...

    def probing_move(self, z_target_mm: float, speed_mm_s: float, trigger) -> ProbingMoveResult: ...

    def probing_move_xy(self, x_mm: float, y_mm: float, speed_mm_s: float, trigger) -> ProbingMoveResult: ...

    def watched_move(self, x: float | None, y: float | None, z: float | None, speed_mm_s: float,
                     accel_mm_s2: float | None, trigger) -> ProbingMoveResult: ...

    def wait_for_trigger(self, trigger, timeout_s: float) -> ProbingMoveResult: ...

    def recorded_moves(self, t0_s: float, t1_s: float) -> list[dict]: ...

    def emergency_stop(self) -> None:
        """From any thread: stop the steppers at the next sample; every motion after it raises
        EmergencyStopError (the command that moved fails) until release_emergency_stop."""

    def release_emergency_stop(self) -> None:
        """A restart: motion works again."""
