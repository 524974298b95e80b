"""VirtualPrinter: the facade over clock, motion, bed, contact physics, sensor, nozzle and faults.

Time only moves forward through commands (move_to, dwell, probing_move, ...). Samples are
generated lazily, in chunks, for conversions whose integration window has closed by the
current time, so motion commanded later can never change a sample already produced.
"""

from __future__ import annotations

import copy
import json
import math
import threading
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.signal import lfilter

from tapcell.host.backend import EmergencyStopError, MoveError, ProbingMoveResult, SampleBatch
from tapcell.sim import faults as faultlib
from tapcell.sim.bed import BedError, bed_from_params
from tapcell.sim.contact import ContactModel, ContactState, contact_forces, elastic_force_g
from tapcell.sim.heaters import FirstOrderHeater, OutputLog
from tapcell.sim.mcu import SampleChunk, TriggerFeeder, VirtualMCU
from tapcell.sim.motion import (
    FORGET_BATCH,
    HISTORY_KEEP_S,
    MotionHistory,
    Segment,
    move_limits,
    plan_trapezoid,
    quantize_to_steps,
)
from tapcell.sim.nozzle import NozzleThermal
from tapcell.sim.params import SimParamError, SimParams, make_params, series_stiffness_g_um
from tapcell.sim.pin import pin_from_params
from tapcell.sim.scenarios import SCENARIOS
from tapcell.sim.sensor import IndexedNoise, chip_timing, counts_from_force, pink_block_maker, window_average_sine

# Chips whose samples travel in CRC-checked frames (tapcell.sim.ads131m0x_chip).
ADS131M0X_CHIPS = ("ads131m02", "ads131m04")

TAP_FORMAT = "tapcell.tap.v1"
CHUNK_S = 0.05            # probing chunk: the trigger is fed this much data per call
FREE_RUN_CHUNK = 4096     # samples per chunk when nothing listens to them
# Samples produced between two looks at the emergency stop while time runs under a command: the
# stop lands at the next sample either way; this bounds how long (wall time) it waits to be seen.
HALT_CHECK_SAMPLES = 256
NOISE_STREAMS = ("bed", "white", "pink", "poll", "jitter", "glitch_bit", "glitch_when", "hum")


@dataclass
class ResidueSpot:
    """Film a fouled tap left on the bed: met first by any later tap within the residue radius."""

    x_mm: float
    y_mm: float
    thickness_um: float


@dataclass
class _PhysicsState:
    contact: ContactState
    cell_warm_c: float = 0.0      # the load cell's temperature rise (low-passed nozzle heat)
    residue: list[ResidueSpot] = field(default_factory=list)   # ooze film left on the bed
    peak_contact_g: float = 0.0   # largest nozzle-bed force since Truth.take_peak_forces_g last read it
    peak_pin_g: float = 0.0       # largest sideways nozzle-pin force since then


@dataclass
class _ProbeRecord:
    start_s: float
    halt_time_s: float
    x_mm: float
    y_mm: float
    film_um: float


class Truth:
    """What only tests and benchmarks may read: the simulator's ground truth."""

    def __init__(self, vp: VirtualPrinter):
        self._vp = vp

    def surface_z(self, x_mm, y_mm):
        return self._vp._bed.surface_z(x_mm, y_mm)

    def contact_z_at(self, x_mm, y_mm, t_s: float | None = None):
        """Commanded Z at which the (hot, longer) nozzle just touches the bed surface."""
        vp = self._vp
        temp = vp._thermal.temps_at(vp.now_s if t_s is None else t_s)
        return vp._bed.surface_z(x_mm, y_mm) + float(vp._thermal.extension_mm(temp))

    @property
    def counts_per_gram(self) -> float:
        return self._vp._counts_per_gram

    @property
    def zero_offset_counts(self) -> float:
        return self._vp._zero_offset_counts

    @property
    def stiffness_g_um(self) -> float:
        return series_stiffness_g_um(self._vp.params)

    @property
    def film_um(self) -> float:
        return self._vp._state.contact.film_um

    @property
    def residue(self) -> list[ResidueSpot]:
        """Ooze residue spots on the bed (copies)."""
        return [copy.copy(spot) for spot in self._vp._state.residue]

    def force_g(self, t0_s: float, t1_s: float) -> tuple[np.ndarray, np.ndarray]:
        """Noise-free force on the cell (window average) for each delivered sample in [t0, t1]."""
        t, _, force = self._vp._mcu.log.between(t0_s, t1_s)
        return t, force

    @property
    def nozzle_clearance_mm(self) -> float:
        """Gap between the nozzle tip and the bed (or pin) under it now; negative = pressed in."""
        vp = self._vp
        return float(vp._gap_um_now() / 1000.0)

    def take_peak_forces_g(self) -> tuple[float, float]:
        """The largest nozzle-bed force (bed + ooze film, g) and the largest sideways nozzle-pin
        force (g, XY probing) since the last call, and start again.

        Forces are known for every conversion window produced so far; the nozzle's present
        press (the loading curve at today's gap, the pin's side at today's position) covers the
        window still open."""
        vp = self._vp
        vp._advance_to(vp.now_s)
        state = vp._state
        model = vp._contact_model
        gap_um, pin_now_g = vp._gap_and_pin_force_now()
        bed_now_g = float(elastic_force_g(-gap_um, model.stiffness_g_um, model.onset_um))
        peaks = (max(state.peak_contact_g, bed_now_g), max(state.peak_pin_g, pin_now_g))
        state.peak_contact_g = state.peak_pin_g = 0.0
        return peaks

    def take_peak_force_g(self) -> float:
        """The largest force the nozzle put on the bed or the pin since the last call (either
        reading starts both again): what must stay within force_safety_limit."""
        return max(self.take_peak_forces_g())


class VirtualPrinter:
    def __init__(self, params: SimParams, seed: int = 1, scenario: str = "custom"):
        self.params = params
        self.seed = int(seed)
        self.scenario = scenario
        streams = np.random.SeedSequence(self.seed).spawn(len(NOISE_STREAMS))
        rng = {name: np.random.Generator(np.random.PCG64(s)) for name, s in zip(NOISE_STREAMS, streams)}
        self._bed = bed_from_params(params, rng["bed"])
        self._pin = pin_from_params(params)
        xy_step = params.rotation_distance_xy_mm / (params.full_steps_per_rotation * params.microsteps)
        z_step = params.rotation_distance_z_mm / (params.full_steps_per_rotation * params.microsteps)
        self.step_distance_mm = np.array([xy_step, xy_step, z_step])
        start = (params.bed_x_mm / 2.0, params.bed_y_mm / 2.0, params.start_z_mm)
        self._motion = MotionHistory(tuple(quantize_to_steps(start, self.step_distance_mm)))
        self._timing = chip_timing(params)
        rate = params.sample_rate_sps
        self._white = IndexedNoise(rng["white"], lambda g, n: g.standard_normal(n) * params.white_noise_counts)
        self._pink = IndexedNoise(rng["pink"], pink_block_maker(params.pink_noise_counts, rate))
        self._glitch_bits = IndexedNoise(rng["glitch_bit"], lambda g, n: g.integers(16, 23, n).astype(float))
        self._glitch_draw = IndexedNoise(rng["glitch_when"], lambda g, n: g.uniform(0.0, 1.0, n))
        self._hum_phase = float(rng["hum"].uniform(0.0, 2.0 * np.pi))
        self._mcu = VirtualMCU(self._timing.period_s, params.read_jitter_s, params.stop_delay_s,
                               params.multi_mcu_delay_s, rng["poll"], rng["jitter"])
        gain_scale = params.gain / 128.0
        self._counts_per_gram = params.cell_polarity * params.counts_per_gram * gain_scale
        self._zero_offset_counts = params.zero_offset_counts * gain_scale
        self._contact_model = ContactModel(
            series_stiffness_g_um(params), params.contact_onset_um, params.relax_fraction, params.relax_tau_s,
            params.hysteresis_fraction, params.hysteresis_travel_um, params.ooze_stiffness_g_um,
            params.ooze_squeeze_tau_s, params.ooze_pull_g, params.ooze_pull_full_um, params.ooze_break_um, params.ooze_clear_fraction,
            params.ooze_max_um)
        self._state = _PhysicsState(ContactState(film_um=params.ooze_film_um))
        self._thermal = NozzleThermal(params.ambient_c, params.heater_tau_s, params.start_nozzle_c,
                                      expansion_um_per_c=params.nozzle_expansion_um_per_c)
        # Heaters by the host's name: the nozzle is "extruder"; others ([heater_bed], ...) come with add_heater.
        self._heaters: dict[str, FirstOrderHeater] = {"extruder": self._thermal}
        self.outputs = OutputLog()
        self._faults: list[faultlib.Fault] = []
        if params.disconnect_at_s >= 0.0:
            self._faults.append(faultlib.make_fault("disconnected", params.disconnect_at_s, None, 0.0, {}))
        self._hand_taps: list[tuple[float, float, float]] = []   # (start_s, duration_s, peak_g)
        self._probes: list[_ProbeRecord] = []
        self._tap_xy_mm: tuple[float, float] | None = None   # where the last probing move went down
        self._next_k = 0
        self._chunk_samples = max(4, round(CHUNK_S * params.sample_rate_sps))
        self._now_s = 0.0
        self._aux_sensors: list = []
        self._frame_chip = None
        if params.chip in ADS131M0X_CHIPS:  # frames with a CRC, read by the firmware's reader
            from tapcell.sim.ads131m0x_chip import VirtualADS131M0x
            self._frame_chip = VirtualADS131M0x(params.chip)
        # Set from any thread (an API connection, a console's Ctrl-C); read where motion is produced.
        self._halt = threading.Event()
        self.halted_at_s: float | None = None   # when an emergency stop stopped the steppers
        self.truth = Truth(self)
        self.world_notice: str | None = None  # set by from_config: the scenario and what it changes

    # -- construction ------------------------------------------------------------------
    @classmethod
    def from_scenario(cls, name: str = "clean", seed: int = 1, **overrides) -> VirtualPrinter:
        if name not in SCENARIOS:
            raise SimParamError(f"unknown scenario '{name}'; allowed: {', '.join(SCENARIOS)}")
        return cls(make_params({**SCENARIOS[name].overrides, **overrides}), seed=seed, scenario=name)

    @classmethod
    def from_config(cls, section, machine: dict | None = None) -> VirtualPrinter:
        """`[virtual_printer]`: scenario, seed and physics overrides, on the machine the printer's own
        config describes (`machine`: tapcell.sim.machine.machine_params). The world is
        [virtual_printer]'s; a machine value there that the printer config contradicts is an error."""
        from tapcell.sim.config import read_virtual_printer_section

        name, seed, overrides = read_virtual_printer_section(section)
        machine = dict(machine or {})
        for param, (value, where) in machine.items():
            if param in overrides and overrides[param] != value:
                raise section.error(param, f"the printer's own config sets this ({where} = {value}); "
                                           "[virtual_printer] describes only the world (bed, noise, faults, scenario)")
        while True:
            try:
                vp = cls.from_scenario(name, seed, **{**SCENARIOS[name].overrides,
                                                      **{k: v for k, (v, _) in machine.items()}, **overrides})
                break
            except BedError as exc:
                raise section.error("bed_csv", str(exc)) from None
            except SimParamError as exc:
                if exc.option in machine and exc.option not in overrides:
                    # The module owning that section reports the bad value; the machine keeps its default.
                    del machine[exc.option]
                    continue
                raise section.error(exc.option or "scenario", str(exc)) from None
        vp.world_notice = describe_world(vp, overrides, machine)
        return vp

    # -- what the host may know ------------------------------------------------------------
    @property
    def now_s(self) -> float:
        return self._now_s

    def sensor_error_note(self) -> str:
        """Why the sensor's samples were refused, when the chip can tell ('' otherwise): an
        ADS131M0x's CRC failures or its reset."""
        return self._frame_chip.error_note() if self._frame_chip is not None else ""

    @property
    def sensor_info(self) -> dict:
        p = self.params
        return {"chip": p.chip, "sample_rate_sps": p.sample_rate_sps, "gain": p.gain, "counts_bits": 24,
                "counts_min": -(1 << 23), "counts_max": (1 << 23) - 1,
                "analysis_meta": {"scenario": self.scenario, "seed": self.seed, "source": "tapcell.sim"}}

    @property
    def position(self) -> tuple[float, float, float]:
        return tuple(float(v) for v in quantize_to_steps(self._motion.end_position, self.step_distance_mm))

    @property
    def nozzle_temperature_c(self) -> float:
        return float(self._thermal.temps_at(self._now_s))

    @property
    def limits(self) -> dict:
        p = self.params
        return {"x": (p.x_position_min_mm, p.x_position_max_mm), "y": (p.y_position_min_mm, p.y_position_max_mm),
                "z": (p.z_position_min_mm, p.z_position_max_mm)}

    # -- commands ---------------------------------------------------------------------------
    def move_to(self, x: float | None = None, y: float | None = None, z: float | None = None,
                speed_mm_s: float = 50.0, accel_mm_s2: float | None = None) -> None:
        """Trapezoidal move (rest to rest) within the axis limits; time advances to its end.
        `accel_mm_s2` (the host's current limit) is capped by the machine's own."""
        start, target = self._begin_move(x, y, z, speed_mm_s)
        self._plan_and_run(start, target, speed_mm_s, accel_mm_s2)

    def home_xy(self, axes: str = "xy") -> None:
        """Move the axes named in `axes` ("x", "y" or "xy") to their endstops at the homing speed
        (x_endstop_mm, y_endstop_mm); an axis not named stays where it is."""
        start = self._motion.end_position
        p = self.params
        target = (p.x_endstop_mm if "x" in axes else start[0], p.y_endstop_mm if "y" in axes else start[1], start[2])
        self._plan_and_run(start, target, p.homing_speed_mm_s)

    def watched_home_xy(self, axes: str, speed_mm_s: float, trigger) -> ProbingMoveResult:
        """home_xy with the armed firmware trigger seeing every sample (the host's nozzle watch):
        at the homing speed, or `speed_mm_s` when slower; it halts like a watched move."""
        start = self._motion.end_position
        p = self.params
        target = (p.x_endstop_mm if "x" in axes else start[0], p.y_endstop_mm if "y" in axes else start[1], start[2])
        return self._probing_move_to(target, min(speed_mm_s, p.homing_speed_mm_s), trigger, probe=False)

    def endstop_triggered(self, axis: str) -> bool:
        """Whether the X or Y endstop switch is pressed: the carriage sits at it (within half a step)."""
        index = "xy".index(axis)
        endstop_mm = (self.params.x_endstop_mm, self.params.y_endstop_mm)[index]
        return abs(self.position[index] - endstop_mm) <= self.step_distance_mm[index] / 2.0

    def position_at(self, t_s: float) -> tuple[float, float, float]:
        """Where the toolhead was (or will be, for a move already planned) at `t_s`."""
        return tuple(float(v) for v in self._motion.positions_at(np.array([t_s]))[0])

    def speed_at(self, t_s: float) -> float:
        """The toolhead's speed along its path at `t_s` (mm/s; 0 at rest)."""
        return self._motion.speed_at(t_s)

    def dwell(self, t_s: float) -> None:
        if t_s < 0.0:
            raise MoveError(f"dwell time must not be negative, got {t_s}")
        self._advance_to(self._now_s + t_s)

    def take_samples(self) -> SampleBatch:
        self._advance_to(self._now_s)
        return self._mcu.take(self._now_s)

    def set_nozzle_temperature(self, target_c: float, wait: bool = False) -> None:
        self.set_heater_temperature("extruder", target_c)
        if wait:
            self.wait_for_heater("extruder")

    def heater(self, name: str) -> FirstOrderHeater:
        """The thermal model of the host's heater `name` ("extruder" is the nozzle); others are
        made on first use, at room temperature, with the bed heater's time constant."""
        if name not in self._heaters:
            p = self.params
            self._heaters[name] = FirstOrderHeater(p.ambient_c, p.bed_heater_tau_s, p.ambient_c, self._now_s)
        return self._heaters[name]

    def heater_temperature_c(self, name: str) -> float:
        return float(self.heater(name).temps_at(self._now_s))

    def set_heater_temperature(self, name: str, target_c: float) -> None:
        self.heater(name).set_target(self._now_s, float(target_c))

    def wait_for_heater(self, name: str, within_c: float = 1.0) -> float:
        """Let time pass until the heater is within `within_c` of its set point; returns the seconds waited."""
        waited_s = self.heater(name).time_to_settle_s(self._now_s, within_c)
        self.dwell(waited_s)
        return waited_s

    @property
    def room_temperature_c(self) -> float:
        return float(self.params.ambient_c)

    def set_output(self, name: str, value: float) -> None:
        """Record a fan speed or pin value (0..1) set now."""
        self.outputs.set(name, self._now_s, value)

    def place_weight(self, grams: float, add: bool = False) -> float:
        """A weight now rests on the cell: it replaces what rested there, or with `add` joins it.
        Returns the total weight on the cell."""
        if not add:
            self.remove_weight()
        self.inject_fault("weight", grams=float(grams))
        return self.weight_on_cell_g()

    def remove_weight(self) -> None:
        for f in self._weights_on_cell():
            f.duration_s = self._now_s - f.start_s

    def weight_on_cell_g(self) -> float:
        return float(sum(f.params["grams"] for f in self._weights_on_cell()))

    def _weights_on_cell(self) -> list:
        return [f for f in self._faults
                if f.name == "weight" and f.start_s is not None and f.start_s <= self._now_s < f.end_s]

    def tap_nozzle(self, peak_force_g: float, duration_s: float = 0.15, delay_s: float = 0.0) -> None:
        """A finger tap on the nozzle starting `delay_s` from now (half-sine force pulse); time does not advance."""
        if duration_s <= 0.0:
            raise MoveError(f"tap duration must be above 0 s, got {duration_s}")
        if delay_s < 0.0:
            raise MoveError(f"tap delay must not be negative, got {delay_s}")
        self._hand_taps.append((self._now_s + float(delay_s), float(duration_s), float(peak_force_g)))

    def inject_fault(self, name: str, at_s: float | None = None, when: str | None = None, nth: int = 1,
                     **params) -> None:
        """Start a fault now, at `at_s`, or when a condition happens (faults.CONDITIONS), on its
        `nth` occurrence."""
        fault = faultlib.make_fault(name, at_s, when, self._now_s, params, nth)
        fault.first_index = self._next_k
        self._faults.append(fault)

    def emergency_stop(self) -> None:
        """From any thread: the steppers stop at the next sample the machine produces (inside a move,
        a probing move, a dwell or a wait), and every command that lets time run from then on raises
        EmergencyStopError at once. Sampling goes on (take_samples), nothing moves."""
        self._halt.set()

    def release_emergency_stop(self) -> None:
        """A restart that keeps this machine: motion works again."""
        self._halt.clear()

    def add_sensor(self, name: str, chip: str, sample_rate_sps: float):
        """An extra scale (no contact physics) sharing this printer's clock, e.g. a spool scale."""
        from tapcell.sim.scale_sensor import ScaleSensor

        sensor = ScaleSensor(self, name, chip, sample_rate_sps, seed=self.seed + 1 + len(self._aux_sensors))
        self._aux_sensors.append(sensor)
        return sensor

    def probing_move(self, z_target_mm: float, speed_mm_s: float, trigger) -> ProbingMoveResult:
        """Move Z down toward z_target feeding every sample to the (armed) firmware trigger;
        halt without deceleration `stop latency` after it triggers or reports an error."""
        start = self._motion.end_position
        if not self.params.z_position_min_mm <= z_target_mm <= start[2]:
            raise MoveError(f"probing move target z={z_target_mm:.3f} must be between position_min "
                            f"{self.params.z_position_min_mm:.3f} and the current z={start[2]:.3f}")
        return self._probing_move_to((start[0], start[1], float(z_target_mm)), speed_mm_s, trigger)

    def probing_move_xy(self, x_mm: float, y_mm: float, speed_mm_s: float, trigger) -> ProbingMoveResult:
        """Like probing_move, but horizontally toward (x, y) at the current Z (XY probing on a pin);
        the halt position is `position` afterwards."""
        start = self._motion.end_position
        target = (float(x_mm), float(y_mm), start[2])
        self._check_target(target)
        return self._probing_move_to(target, speed_mm_s, trigger)

    def watched_move(self, x: float | None, y: float | None, z: float | None, speed_mm_s: float,
                     accel_mm_s2: float | None, trigger) -> ProbingMoveResult:
        """An ordinary move (any direction, like move_to) with the armed firmware trigger seeing
        every sample: it halts like a probing move when the trigger fires or reports an error
        (the host's nozzle watch). Not a probe: no probing_move/contact fault conditions fire."""
        _, target = self._begin_move(x, y, z, speed_mm_s)
        return self._probing_move_to(target, speed_mm_s, trigger, accel_mm_s2, probe=False)

    def _probing_move_to(self, target, speed_mm_s: float, trigger, accel_mm_s2: float | None = None,
                         probe: bool = True) -> ProbingMoveResult:
        start = self._motion.end_position
        self._advance_to(self._now_s)
        if probe:
            self._tap_xy_mm = (float(start[0]), float(start[1]))
            self._meet_residue(start[0], start[1])
            self._fire_condition("probing_move", self._now_s)
        film_at_start_um = self._state.contact.film_um
        segments = self._plan(start, target, speed_mm_s, accel_mm_s2)
        t_start = self._now_s
        contact_t = self._crossing_time(segments, float(self.truth.contact_z_at(start[0], start[1])))
        if contact_t is not None and probe:
            self._fire_condition("contact", contact_t)
        self._motion.append(segments)
        end_s = segments[-1].end_time if segments else t_start
        reset = faultlib.due_reset(self._faults, end_s)
        if reset is not None:
            end_s = max(reset.start_s, t_start)      # a resetting MCU stops the move at once
        feeder = TriggerFeeder(trigger, self._timing.period_s, t_start, _trigger_error_none())
        pending_t, pending_c = self._mcu.pending(t_start)
        event = feeder.feed(pending_t, pending_c, t_start) if pending_t.size else None
        halt_s = end_s
        k_move_end = self._last_index_closed_by(end_s)
        undelivered_state = None       # physics state before a chunk that was fed but not delivered
        while event is None:
            k0 = self._next_k
            if self._halt.is_set():
                self._advance_to(end_s)   # stops the steppers at the next sample and raises
            if k0 >= k_move_end:
                event = feeder.feed(np.zeros(0), np.zeros(0, dtype=np.int32), end_s)   # watchdog to the end
                break
            k1 = min(k_move_end, k0 + self._chunk_samples)
            saved = copy.deepcopy(self._state)
            chunk = self._compute(k0, k1)
            event = feeder.feed(chunk.t_s, chunk.counts, min(end_s, float(self._timing.ready_times(k1 - 1, k1)[0])))
            if event is None:
                self._mcu.deliver(chunk)
                self._next_k = k1
            else:
                undelivered_state = saved
        if event is not None or reset is not None:
            halt_s = end_s if event is None else min(event.time_s + self._mcu.stop_latency_s, end_s)
            self._truncate_probing_move(len(segments), halt_s)
        if undelivered_state is not None:
            # That chunk was made with the untruncated move: make it again. Conversions closed
            # by the halt come out identical; later ones now see the nozzle stopped.
            self._state = undelivered_state
        self._advance_to(halt_s)
        if event is not None and event.triggered:
            self._fire_condition("trigger", event.time_s)
        if probe:
            self._fire_condition("halt", halt_s)
        probe_moves = [s.as_tap_move() for s in self._motion.segments_between(t_start, halt_s)
                       if s.print_time >= t_start]
        if probe:
            self._probes.append(_ProbeRecord(t_start, halt_s, start[0], start[1], film_at_start_um))
        if len(self._probes) > FORGET_BATCH and self._probes[0].halt_time_s < halt_s - HISTORY_KEEP_S:
            self._probes = [r for r in self._probes if r.halt_time_s >= halt_s - HISTORY_KEEP_S]
        halt_z = float(self._motion.end_position[2])
        no_error = _trigger_error_none()
        return ProbingMoveResult(
            triggered=bool(event is not None and event.triggered),
            trigger_time_s=event.time_s if event is not None and event.triggered else None,
            halt_time_s=halt_s, halt_z_mm=halt_z,
            error=event.error if event is not None else no_error, moves=probe_moves)

    def wait_for_trigger(self, trigger, timeout_s: float) -> ProbingMoveResult:
        """Feed samples to the armed trigger with no motion (LOAD_CELL_TEST_TAP) until it fires,
        reports an error, or the timeout passes."""
        self._advance_to(self._now_s)
        t_start = self._now_s
        end_s = t_start + timeout_s
        feeder = TriggerFeeder(trigger, self._timing.period_s, t_start, _trigger_error_none())
        pending_t, pending_c = self._mcu.pending(t_start)
        event = feeder.feed(pending_t, pending_c, t_start) if pending_t.size else None
        while event is None and self._now_s < end_s:
            step_end = min(self._now_s + CHUNK_S, end_s)
            previous = self._now_s
            self._advance_to(step_end)
            t, c = self._mcu.pending(previous)
            event = feeder.feed(t[t <= step_end], c[t <= step_end], step_end)
        halt_s = self._now_s if event is None else max(event.time_s, t_start)
        z = float(self._motion.end_position[2])
        return ProbingMoveResult(bool(event is not None and event.triggered),
                                 event.time_s if event is not None and event.triggered else None,
                                 halt_s, z, event.error if event is not None else _trigger_error_none(), [])

    # -- records ----------------------------------------------------------------------------
    def recorded_moves(self, t0_s: float, t1_s: float) -> list[dict]:
        """Motion covering [t0, t1] in the tapcell.tap.v1 `moves` form, oldest first."""
        return [s.as_tap_move() for s in self._motion.segments_between(t0_s, t1_s)]

    def write_tap_file(self, path, t0_s: float, t1_s: float, probe: dict, analysis_meta: dict | None = None,
                       counts_per_gram: float | None = None, tare_counts: float | None = None) -> dict:
        """Write one tap as tapcell.tap.v1 JSON (or append a line to a .jsonl file); returns the object.

        Force is tared with `tare_counts` (default: the mean of the first 10 samples) and scaled
        with `counts_per_gram` (default: the true one)."""
        t, counts, _ = self._mcu.log.between(t0_s, t1_s)
        if t.size < 2:
            raise ValueError(f"tap file {path}: fewer than 2 samples between {t0_s:.3f} s and {t1_s:.3f} s")
        cpg = self._counts_per_gram if counts_per_gram is None else counts_per_gram
        tare = float(np.mean(counts[:10])) if tare_counts is None else tare_counts
        x = float(probe.get("x", self.position[0]))
        y = float(probe.get("y", self.position[1]))
        tap = {"format": TAP_FORMAT, "time": t.tolist(), "force": ((counts - tare) / cpg).tolist(),
               "moves": self.recorded_moves(t0_s, t1_s), "sample_rate": self.params.sample_rate_sps,
               "events": self._tap_events(t0_s, t1_s), "probe": dict(probe),
               "truth": {"z_contact": float(self.truth.contact_z_at(x, y, t0_s)),
                         "label": "fouled" if self._film_at_start(t0_s, t1_s) > 1.0 else "clean"},
               "meta": {"scenario": self.scenario, "seed": self.seed, "sensor_type": self.params.chip,
                        "source": "tapcell.sim", **(analysis_meta or {})}}
        path = Path(path)
        if path.suffix == ".jsonl":
            with open(path, "a", encoding="utf-8") as out:
                out.write(json.dumps(tap) + "\n")
        else:
            path.write_text(json.dumps(tap), encoding="utf-8")
        return tap

    # -- internals: motion --------------------------------------------------------------------
    def _check_target(self, target) -> None:
        for axis, value in zip("xyz", target):
            low, high = self.limits[axis]
            if not low - 1e-9 <= value <= high + 1e-9:
                raise MoveError(f"move out of range: {axis}={value:.3f} (allowed {low:.3f} .. {high:.3f})")

    def _plan(self, start, target, speed_mm_s: float, accel_mm_s2: float | None = None) -> list[Segment]:
        delta = np.subtract(target, start)
        distance = float(np.linalg.norm(delta))
        if distance <= 0.0:
            return []
        p = self.params
        max_accel = p.max_accel_mm_s2 if accel_mm_s2 is None else min(accel_mm_s2, p.max_accel_mm_s2)
        speed, accel = move_limits(delta / distance, p.max_velocity_mm_s, max_accel,
                                   p.max_z_velocity_mm_s, p.max_z_accel_mm_s2, speed_mm_s)
        return plan_trapezoid(start, target, self._now_s, speed, accel)

    def _plan_and_run(self, start, target, speed_mm_s: float, accel_mm_s2: float | None = None) -> None:
        segments = self._plan(start, target, speed_mm_s, accel_mm_s2)
        if not segments:
            return
        self._motion.append(segments)
        self._advance_to(segments[-1].end_time)

    def _truncate_probing_move(self, count: int, halt_s: float) -> None:
        """Cut the last `count` segments (a probing move, or whatever moves when the MCU resets) at the
        halt and add a zero-length marker at the stepper position."""
        segments = self._motion.segments[-count:]
        kept = [s.truncated(halt_s) for s in segments if s.print_time < halt_s]
        last = kept[-1] if kept else segments[0]
        halt_pos = tuple(float(v) for v in quantize_to_steps(last.position_at(halt_s), self.step_distance_mm))
        marker = Segment(halt_s, 0.0, 0.0, 0.0, halt_pos, (0.0, 0.0, 0.0))
        self._motion.replace_last(count, [s for s in kept if s.move_t > 0.0] + [marker])

    @staticmethod
    def _crossing_time(segments: list[Segment], z_mm: float) -> float | None:
        """When a downward move first reaches z_mm (None if it never does)."""
        for s in segments:
            z0, z1 = s.start[2], s.end[2]
            if z1 <= z_mm <= z0 and s.direction[2] < 0:
                dist = (z0 - z_mm) / -s.direction[2]
                a, v = 0.5 * s.accel, s.start_v
                tau = dist / v if abs(a) < 1e-12 else (-v + math.sqrt(max(v * v + 4 * a * dist, 0.0))) / (2 * a)
                return s.print_time + tau
        return None

    # -- internals: samples ---------------------------------------------------------------------
    def _last_index_closed_by(self, t_s: float) -> int:
        """One past the last conversion whose integration window has closed by t_s."""
        return self._timing.first_index_after(t_s + self._timing.pipeline_s)

    def _advance_to(self, t_s: float) -> None:
        """Produce the samples up to t_s. An MCU reset due by then stops the steppers where they
        are, time runs on until the host link is back, and McuResetError is raised. An emergency
        stop asked for while time runs here stops the steppers at the next sample not yet produced,
        time ends there, and EmergencyStopError is raised."""
        reset = faultlib.due_reset(self._faults, t_s)
        if reset is not None:
            reset.start_s = max(reset.start_s, self._now_s)   # a condition already past: now
            reset.done = True
            self._stop_steppers_at(reset.start_s)
            t_s = reset.end_s                                    # the command ends there
        entry_s = self._now_s
        halt_s = None
        if self._halt.is_set() and t_s > entry_s:
            halt_s = t_s = self._halt_steppers(entry_s)
        self._now_s = max(self._now_s, t_s)
        k_end = self._last_index_closed_by(self._now_s)
        while self._next_k < k_end:
            if halt_s is None and self._halt.is_set():
                halt_s = self._now_s = self._halt_steppers(entry_s)
                k_end = self._last_index_closed_by(halt_s)
                continue
            k1 = min(k_end, self._next_k + (HALT_CHECK_SAMPLES if self._now_s > entry_s else FREE_RUN_CHUNK))
            self._mcu.deliver(self._compute(self._next_k, k1))
            self._next_k = k1
        timing = self._timing
        earliest_s = min(self._now_s, timing.window_start_s(self._next_k))  # nothing later looks before this
        self._faults = faultlib.still_acting(self._faults, self._next_k, earliest_s, timing.first_ready_s,
                                             timing.period_s)
        # Hand taps over before then can no longer press on the cell: forget them too.
        self._hand_taps = [tap for tap in self._hand_taps if tap[0] + tap[1] >= earliest_s]
        for sensor in self._aux_sensors:
            sensor.advance_to(self._now_s)
        if reset is not None:
            raise faultlib.McuResetError(reset.start_s, reset.end_s)
        if halt_s is not None:
            self.halted_at_s = halt_s
            raise EmergencyStopError(halt_s)

    def _halt_steppers(self, entry_s: float) -> float:
        """An emergency stop: the steppers stop where the next sample to be produced starts (the
        samples made so far saw the motion before it; time never goes back), returns that time."""
        return self._stop_steppers_at(max(entry_s, self._timing.window_start_s(self._next_k)))

    def _stop_steppers_at(self, t_s: float) -> float:
        """Cut whatever moves after t_s there (no deceleration: a reset or an emergency stop)."""
        moving = sum(1 for segment in self._motion.segments if segment.end_time > t_s)
        if moving:
            self._truncate_probing_move(moving, t_s)
        return t_s

    def _fire_condition(self, condition: str, t_s: float) -> None:
        for f in self._faults:
            if f.when == condition and f.start_s is None:
                f.waits_for -= 1
                if f.waits_for <= 0:
                    f.start_s = t_s
                    f.first_index = self._next_k

    def _begin_move(self, x, y, z, speed_mm_s: float):
        """A move that is not a probe, checked (limits, speed) and announced to the faults waiting
        for it: (start, target)."""
        start = self._motion.end_position
        target = tuple(float(v) if v is not None else s for v, s in zip((x, y, z), start))
        self._check_target(target)
        if speed_mm_s <= 0.0:
            raise MoveError(f"move speed must be above 0 mm/s, got {speed_mm_s}")
        self._fire_move_conditions(start, target)
        return start, target

    def _fire_move_conditions(self, start, target) -> None:
        """A move that is not a probe: 'travel' when it moves in X/Y, else 'lift' when it goes up."""
        travel = math.hypot(target[0] - start[0], target[1] - start[1]) > 0.0
        if travel or target[2] > start[2]:
            self._advance_to(self._now_s)
            self._fire_condition("travel" if travel else "lift", self._now_s)

    def _film_at_start(self, t0_s: float, t1_s: float) -> float:
        """Ooze film when the tap in [t0, t1] started (now, if no probing move is in the span)."""
        probes = [r for r in self._probes if t0_s <= r.halt_time_s <= t1_s]
        return probes[-1].film_um if probes else self._state.contact.film_um

    def _meet_residue(self, x_mm: float, y_mm: float) -> None:
        """A tap within the residue radius of film left on the bed meets that film first.

        For a vertical tap a layer on the bed and one on the nozzle squeeze, pull and tear alike,
        so the residue simply joins the nozzle's film (and the next strand break splits it again).
        """
        radius = self.params.ooze_residue_radius_mm
        residue = self._state.residue
        met = [s for s in residue if math.hypot(s.x_mm - x_mm, s.y_mm - y_mm) <= radius]
        if met:
            self._state.residue = [s for s in residue if s not in met]
            self._state.contact.film_um += sum(s.thickness_um for s in met)

    def _place_residue(self) -> None:
        """Film that left the nozzle (flowed out, or torn off with the strand) stays where the tap is."""
        deposited = self._state.contact.deposited_um
        if deposited <= 0.0 or self._tap_xy_mm is None:
            return
        self._state.contact.deposited_um = 0.0
        x_mm, y_mm = self._tap_xy_mm
        for spot in self._state.residue:
            if spot.x_mm == x_mm and spot.y_mm == y_mm:
                spot.thickness_um += deposited
                return
        self._state.residue.append(ResidueSpot(x_mm, y_mm, deposited))

    def _compute(self, k0: int, k1: int) -> SampleChunk:
        """Conversions k0..k1-1 as the MCU reads them; advances the physics state."""
        p, timing = self.params, self._timing
        n, sub = k1 - k0, timing.substeps
        grid_t = timing.grid_times(k0, k1)
        pos = quantize_to_steps(self._motion.positions_at(grid_t), self.step_distance_mm)
        temps = self._thermal.temps_at(grid_t)
        gap_um, pin_side_g = self._gaps_um(pos, temps)
        pin_g = 0.0 if self._pin is None else self._pin.side_coupling * pin_side_g  # what the cell reads
        growth_um = p.ooze_growth_um_per_s_per_c * np.maximum(temps - p.ooze_temp_c, 0.0) * timing.grid_dt_s
        bed_g, film_g = contact_forces(gap_um, timing.grid_dt_s, growth_um, self._contact_model,
                                       self._state.contact)
        contact_g = bed_g + film_g   # the true nozzle-bed force (SIM_TRUTH's peak_force_g)
        if n:
            self._state.peak_contact_g = max(self._state.peak_contact_g, float(np.max(contact_g)))
            self._state.peak_pin_g = max(self._state.peak_pin_g, float(np.max(pin_side_g)))
        self._place_residue()
        centre = (p.bed_x_mm / 2.0, p.bed_y_mm / 2.0)
        drag_g = (p.bowden_g_per_mm_x * (pos[:, 0] - centre[0]) + p.bowden_g_per_mm_y * (pos[:, 1] - centre[1])
                  + p.bowden_g_per_mm_z * pos[:, 2])
        grid_force = (contact_g + drag_g + pin_g + faultlib.external_force_g(self._faults, grid_t)
                      + self._hand_force(grid_t))
        force_g = grid_force.reshape(n, sub).mean(axis=1)
        t_ready = timing.ready_times(k0, k1)
        force_g = force_g + p.thermal_drift_g_per_c * self._cell_warming(t_ready)
        window_end = t_ready - timing.pipeline_s
        electrical = self._white.values(k0, k1) + self._pink.values(k0, k1)
        if p.hum_counts > 0.0:
            electrical = electrical + window_average_sine(p.hum_counts, p.hum_hz, window_end, timing.period_s,
                                                          self._hum_phase)
        counts = counts_from_force(force_g, self._counts_per_gram, self._zero_offset_counts, electrical)
        crc_refused = np.zeros(n, dtype=bool)
        if p.glitch_rate_per_s > 0.0:
            hit = self._glitch_draw.values(k0, k1) < p.glitch_rate_per_s * timing.period_s
            bits = self._glitch_bits.values(k0, k1).astype(np.int64)
            if self._frame_chip is not None:  # the frame's CRC catches the flipped bit
                crc_refused = self._frame_chip.corrupted_frames(counts, hit, bits)
            else:
                counts[hit] ^= (np.int64(1) << bits[hit]).astype(np.int32)
        delays = self._mcu.read_delays(k0, k1)
        t_read = t_ready + delays
        counts, bad = faultlib.apply_count_faults(self._faults, k0, t_ready, counts, self._mcu.last_counts,
                                                  timing.first_ready_s, timing.period_s,
                                                  self._glitch_bits.values(k0, k1).astype(int))
        bad = bad | crc_refused
        if self._frame_chip is not None:
            # A corrupt_frame fault's flipped bit fails that frame's CRC; a reset chip says so in its
            # next frame and is refused from then on.
            corrupt = np.zeros(n, dtype=bool)
            for f in self._faults:
                if f.name == "corrupt_frame" and f.start_s is not None:
                    for k in faultlib.corrupt_frame_indices(f, timing.first_ready_s, timing.period_s):
                        if k0 <= k < k1:
                            corrupt[k - k0] = True
            bad = bad | self._frame_chip.corrupted_frames(counts, corrupt, self._glitch_bits.values(k0, k1))
            resets = [f.start_s + f.params["gap_s"] for f in self._faults
                      if f.name == "chip_reset" and f.start_s is not None]
            bad = bad | self._frame_chip.after_reset(counts, t_ready, resets)
        missing = faultlib.stream_gap_mask(self._faults, t_ready)
        late = delays > timing.period_s
        keep = ~(bad | missing | late)
        return SampleChunk(t_read[keep], counts[keep], force_g[keep], int(np.count_nonzero(bad & ~missing)),
                           int(np.count_nonzero(late & ~missing & ~bad)))

    def _gaps_um(self, pos: np.ndarray, temps) -> tuple[np.ndarray, np.ndarray | float]:
        """Per (n, 3) position: how far the commanded nozzle tip is above its first touch of the bed
        or the pin (µm, negative = pressed in), and the sideways nozzle-pin force (g)."""
        bed_z = self._bed.surface_z(pos[:, 0], pos[:, 1])
        extension_mm = self._thermal.extension_mm(temps)
        pin_g = 0.0
        if self._pin is not None:
            pin_base_mm = float(self._bed.surface_z(self._pin.x_mm, self._pin.y_mm))
            pin_g = self._pin.side_force_g(pos[:, 0], pos[:, 1], pos[:, 2] - extension_mm, pin_base_mm)
            bed_z = self._pin.surface_z(pos[:, 0], pos[:, 1], bed_z, pin_base_mm)
        return (pos[:, 2] - (bed_z + extension_mm)) * 1000.0, pin_g

    def _gap_um_now(self) -> float:
        return self._gap_and_pin_force_now()[0]

    def _gap_and_pin_force_now(self) -> tuple[float, float]:
        pos = quantize_to_steps(self._motion.positions_at(np.array([self._now_s])), self.step_distance_mm)
        gap_um, pin_g = self._gaps_um(pos, self._thermal.temps_at(np.array([self._now_s])))
        return float(gap_um[0]), float(np.max(pin_g))

    def _hand_force(self, t_s: np.ndarray) -> np.ndarray:
        force = np.zeros(t_s.shape)
        for start, duration, peak in self._hand_taps:
            inside = (t_s >= start) & (t_s < start + duration)
            force[inside] += peak * np.sin(np.pi * (t_s[inside] - start) / duration)
        return force

    def _cell_warming(self, t_s: np.ndarray) -> np.ndarray:
        """The cell's temperature rise: a slow low-pass of the nozzle's rise (state carried over)."""
        p = self.params
        drive = p.cell_heat_coupling * (self._thermal.temps_at(t_s) - p.ambient_c)
        keep = math.exp(-self._timing.period_s / p.cell_heat_tau_s)
        # first-order filter, one step per sample: y[n] = keep*y[n-1] + (1-keep)*x[n]
        warm, _ = lfilter([1.0 - keep], [1.0, -keep], drive, zi=[keep * self._state.cell_warm_c])
        self._state.cell_warm_c = float(warm[-1])
        return warm

    def _tap_events(self, t0_s: float, t1_s: float) -> dict:
        events = {}
        probes = [r for r in self._probes if t0_s <= r.halt_time_s <= t1_s]
        if not probes:
            return events
        halt = probes[-1].halt_time_s
        events["home_end_time"] = halt
        after = [s for s in self._motion.segments_between(halt, t1_s) if s.print_time > halt and s.direction[2] > 0]
        if after:
            # the pullback is the first run of back-to-back upward segments
            end = after[0].print_time
            for s in after:
                if abs(s.print_time - end) > 1e-9:
                    break
                end = s.end_time
            events["pullback_start_time"] = after[0].print_time
            events["pullback_end_time"] = end
        return events


def describe_world(vp: VirtualPrinter, overrides: dict, machine: dict) -> str:
    """One line: the scenario, what it changes, and what the printer's config decides instead."""
    scenario = SCENARIOS[vp.scenario]
    changed = [f"{k}={getattr(vp.params, k):g}" if isinstance(getattr(vp.params, k), float)
               else f"{k}={getattr(vp.params, k)}" for k in scenario.overrides if k not in machine]
    taken = [f"{k}={v}" for k, v in scenario.overrides.items() if k in machine]
    line = f"Virtual printer: scenario '{vp.scenario}' ({scenario.description}), seed {vp.seed}: "
    line += ("changes " + ", ".join(changed)) if changed else "no changes to the default world"
    if taken:
        p = vp.params
        line += (f"; {', '.join(taken)} are for the printer config to say (it has {p.chip} at "
                 f"{p.sample_rate_sps:g} sps)")
    own = [f"{k}={v}" for k, v in overrides.items()]
    if own:
        line += "; [virtual_printer] sets " + ", ".join(own)
    if "chip" in machine:
        p = vp.params
        line += (f". The machine is the printer config's: load cell {p.chip} at {p.sample_rate_sps:g} sps, gain "
                 f"{p.gain}; X {p.x_position_min_mm:g}..{p.x_position_max_mm:g}, Y {p.y_position_min_mm:g}.."
                 f"{p.y_position_max_mm:g}, Z down to {p.z_position_min_mm:g} mm")
    return line


def _trigger_error_none():
    from tapcell.mcu.trigger import TriggerError

    return TriggerError.NONE
