"""Threshold probing with the `[load_cell_probe]`'s sensor and firmware trigger: tares, and
probing moves in Z or XY that stop when the force passes a threshold (no tap analysis).

Used by `[prusa_probe]`, the two-pass ABL (`BED_MESH_CALIBRATE METHOD=two_pass`) and
`[xy_probe]`. A Z probe reports the toolhead Z at the triggering sample (what a stepper
position latched by an endstop gives) and where the filtered force crossed the threshold between
that sample and the one before (`trigger_crossing`; the height that does not move with the sample
phase), both from the probing move's own trapezoids. A Z probe goes through the load cell
probe's guarded probing move (speed cap, force guard, sensor faults) and then checks that the
force holds after the halt like a contact (`ThresholdHit.contact`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tapcell.extras.load_cell import sensor_error_note
from tapcell.extras.load_cell_probe.options import ERROR_PREFIX
from tapcell.extras.load_cell_probe.trigger_crossing import replay_filtered_g, threshold_crossing, window_middle_times_s
from tapcell.mcu.trigger import FirmwareTrigger, TriggerError
from tapcell.mesh.prusa import TARE_SAMPLE_COUNT, TARE_SETTLE_S
from tapcell.extras.probe.session import ProbeError
from tapcell.tap.model import Move


@dataclass(frozen=True)
class TareRecord:
    purpose: str
    counts: float
    force_g: float  # relative to the calibration's reference tare
    time_s: float


@dataclass(frozen=True)
class ThresholdHit:
    """One threshold probing move. Positions are in the toolhead frame."""

    triggered: bool
    trigger_time_s: float | None
    halt_time_s: float
    trigger_position_mm: tuple[float, float, float] | None  # where the triggering sample was taken
    halt_position_mm: tuple[float, float, float]  # where the steppers stopped (after the latency)
    contact: bool = True  # Z moves: the force held after the halt like a nozzle pressing on the bed
    # Z moves: the toolhead Z where the filtered force crossed the threshold, between two samples
    # (`trigger_crossing`): unlike the trigger's and the halt's, independent of the sample phase.
    crossing_z_mm: float | None = None


def commanded_z_mm(moves: list[Move], t_s: float) -> float:
    """Commanded Z at t_s: the last of `moves` started by then (the first, before any)."""
    started = [move for move in moves if move.print_time <= t_s] or moves[:1]
    return float(started[-1].z_at(t_s))


def z_at_time_mm(move_records: list[dict], t_s: float) -> float:
    """Commanded Z at t_s from the simulator's move records."""
    return commanded_z_mm([Move.from_record(record) for record in move_records], t_s)


class ThresholdProber:
    """Tares and threshold probing moves with the `[load_cell_probe]`'s sensor and trigger."""

    def __init__(self, device):
        self.device = device  # tapcell.extras.load_cell_probe.device.LoadCellProbe
        self.backend = device.backend
        self.load_cell = device.load_cell
        self.toolhead = device.motion
        self.tares: list[TareRecord] = []

    def tare(self, purpose: str, settle_s: float = TARE_SETTLE_S, sample_count: int = TARE_SAMPLE_COUNT) -> TareRecord:
        """Wait settle_s for vibrations to die, then average sample_count samples."""
        self.device.require_calibrated()
        self.backend.dwell(settle_s)
        batch = self.load_cell.collect(sample_count / self.device.sample_rate_sps)
        if batch.errors:
            raise ProbeError(ERROR_PREFIX + f"sensor reported {batch.errors} errors while taring"
                             f"{sensor_error_note(self.device.backend)}")
        if len(batch.counts) == 0:
            raise ProbeError(ERROR_PREFIX + "timed out waiting for sensor data")
        counts = float(np.mean(batch.counts[-sample_count:]))
        force_g = self.device.grams(counts, self.load_cell.reference_tare_counts)
        record = TareRecord(purpose, counts, float(force_g), self.backend.now_s)
        self.load_cell.set_tare(counts)
        self.tares.append(record)
        return record

    def _arm(self, tare: TareRecord, threshold_g: float, release_g: float,
             drift_safety_limit_g: float | None = None) -> FirmwareTrigger:
        device = self.device
        # Refused before the move, with the force (the firmware would only say "too much").
        device.refuse_preload(tare.counts, device.options)
        return device.trigger.arm(device.config_settings, tare.counts, trigger_force_g=threshold_g,
                          release_force_g=release_g, drift_safety_limit_g=drift_safety_limit_g)

    def _frame_mm(self) -> np.ndarray:
        return np.array([self.toolhead.frame_offset_mm[axis] for axis in "xyz"])

    def probe_z(self, tare: TareRecord, threshold_g: float, release_g: float, z_min_mm: float,
                speed_mm_s: float, drift_safety_limit_g: float | None = None) -> ThresholdHit:
        """Move down toward z_min_mm until the force passes threshold_g (triggered False: no contact),
        through the load cell probe's guarded probing move; after a trigger, check that the force
        holds like a contact (`contact`). `drift_safety_limit_g`: the load cell probe's unless
        given (0 disables the drift check)."""
        device = self.device
        # Refused before the move, with the force (the firmware would only say "too much").
        device.refuse_preload(tare.counts, device.options)
        trigger = {"trigger_force_g": threshold_g, "release_force_g": release_g,
                   "drift_safety_limit_g": drift_safety_limit_g}
        history = device.history
        kept_from_s = history.keep_from_s
        # The move's samples stay until the crossing is found.
        history.keep_from_s = self.backend.now_s if kept_from_s is None else min(kept_from_s, self.backend.now_s)
        try:
            result, _, t_start_s = device.probing_move(device.config_settings, tare.counts, z_min_mm, speed_mm_s,
                                                       **trigger)
            frame = self._frame_mm()
            halt = tuple(np.array(self.backend.position) + frame)
            if not result.triggered:
                return ThresholdHit(False, None, result.halt_time_s, None, halt)
            z_mm = z_at_time_mm(result.moves, result.trigger_time_s) + frame[2]
            crossing_z_mm = self._crossing_z_mm(result, tare, t_start_s, trigger) + frame[2]
        finally:
            history.keep_from_s = kept_from_s
        contact = device.contact_holds_after_halt(tare.counts, threshold_g)
        return ThresholdHit(True, result.trigger_time_s, result.halt_time_s, (halt[0], halt[1], float(z_mm)), halt,
                            contact, float(crossing_z_mm))

    def _crossing_z_mm(self, result, tare: TareRecord, arm_time_s: float, trigger: dict) -> float:
        """Z of the move's trapezoids (machine frame) where the filtered force crossed the threshold
        (`trigger_crossing`); at the trigger's window middle when the host lacks the samples."""
        device = self.device
        t_s, counts, _ = device.history.between(arm_time_s, result.trigger_time_s)
        params = device.trigger.move_params(device.config_settings, **trigger)
        replay = replay_filtered_g(params, tare.counts, arm_time_s, t_s, counts, result.trigger_time_s)
        if replay is None:
            crossing_s = float(window_middle_times_s(result.trigger_time_s, device.stop_timing))
        else:
            crossing_s = threshold_crossing(*replay, params.trigger_force_g, device.stop_timing).time_s
        return z_at_time_mm(result.moves, crossing_s)

    def probe_xy(self, tare: TareRecord, threshold_g: float, release_g: float, x_mm: float, y_mm: float,
                 speed_mm_s: float) -> ThresholdHit:
        """Move horizontally toward (x, y) until the force passes threshold_g."""
        trigger = self._arm(tare, threshold_g, release_g)
        frame = self._frame_mm()
        start = np.array(self.backend.position)
        result = self.backend.probing_move_xy(x_mm - frame[0], y_mm - frame[1], speed_mm_s, trigger)
        self.load_cell.pump()
        if result.error != TriggerError.NONE:
            # The move stopped on an error, maybe pressed against the pin: back away to where it
            # started before the error goes on (the XY counterpart of lifting after a Z error).
            travelled_mm = float(np.linalg.norm(np.array(self.backend.position) - start))
            self.backend.move_to(x=float(start[0]), y=float(start[1]), speed_mm_s=speed_mm_s)
            self.device.printer.gcode.respond_info(
                f"Backed the nozzle off {travelled_mm:.3f} mm to where the XY probing move started, after the error")
            raise ProbeError(self.device.trigger.error_message(result.error, self.device.options))
        halt = np.array(self.backend.position)
        trigger_position = None
        if result.triggered:
            # The move cruises at speed when it meets the pin: step back along it by the latency.
            direction = (halt - start) / max(float(np.linalg.norm(halt - start)), 1e-12)
            trigger_position = tuple(halt - direction * speed_mm_s * (result.halt_time_s - result.trigger_time_s)
                                     + frame)
        return ThresholdHit(result.triggered, result.trigger_time_s, result.halt_time_s, trigger_position,
                            tuple(halt + frame))
