"""Synthetic taps with known truth, for tests and benchmarks.

The physics, kept independent of the analysis code on purpose (the truth must not
share the analysis' assumptions by construction):
- approach at `approach_speed_mm_s`; the sensor's measured force (not the true one)
  triggers at `trigger_force_g`, the steppers halt `trigger_latency_s` later, instantly;
- contact: force = stiffness × compression, with a gradual onset over the first
  `contact_onset_um` (a soft or textured sheet: parabola, then linear);
- dwell: stress relaxation, the contact force relaxes by `relaxation_fraction` with
  time constant `relaxation_time_s` (the break-contact height does not change);
- pullback: `pullback_distance_mm` at `pullback_speed_mm_s` (default 1 µm per sample),
  with acceleration and deceleration;
- ooze: a soft film `film_um` thick on the nozzle (touches before the nozzle, lifts off
  after it), and a string pulling the nozzle back while it departs (`pull_force_g`);
- sensor: each sample is the mean force over its conversion window (one sample period
  when `sensor_integration`), read `sensor_delay_s` late, plus white noise, and
  `corrupted_frames` single frames replaced by garbage.
Truth: `z_contact` = the commanded Z at which the nozzle (not the film) touches the bed.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from tapcell.tap.model import Move, TapData

SUBSTEPS = 16  # midpoint rule over a conversion window


@dataclass
class SynthTap:
    sample_rate_sps: float = 660.0
    noise_g: float = 1.0
    approach_speed_mm_s: float = 5.0
    pullback_speed_mm_s: float | None = None  # None: 1 µm per sample
    pullback_distance_mm: float = 0.1  # break contact (~20-40 µm at 4.6 g/µm) in the middle two thirds
    accel_mm_s2: float = 500.0
    stiffness_g_um: float = 4.6
    contact_onset_um: float = 0.0
    trigger_force_g: float = 75.0
    trigger_latency_s: float = 0.0005
    z_contact_mm: float = 0.0
    approach_time_s: float = 0.4  # of approach cruise recorded before contact
    dwell_s: float = 0.3
    tail_s: float = 0.05
    relaxation_fraction: float = 0.03
    relaxation_time_s: float = 0.08
    film_um: float = 0.0
    film_stiffness_g_um: float = 0.3
    pull_force_g: float = 0.0
    pull_length_um: float = 15.0
    sensor_integration: bool = True
    sensor_delay_s: float = 0.0
    corrupted_frames: int = 0
    polarity: int = 1
    baseline_g: float = 0.0
    time_origin_s: float = 1000.0
    seed: int = 0
    label: str = "clean"

    @property
    def pullback_speed(self) -> float:
        return self.pullback_speed_mm_s or self.sample_rate_sps * 0.001

    @property
    def integration_s(self) -> float:
        return 1.0 / self.sample_rate_sps if self.sensor_integration else 0.0


@dataclass
class Phases:
    """The commanded motion of one synthetic tap (times in s, heights in mm)."""

    t_cruise: float  # approach cruise starts (first sample time)
    z_cruise: float
    t_halt: float
    z_halt: float
    t_pull: float  # pullback starts
    t_accel: float  # duration of pullback acceleration (= deceleration)
    t_cruise_pull: float  # duration of pullback cruise
    approach_speed: float
    pullback_speed: float
    accel: float

    def z_at(self, t: np.ndarray) -> np.ndarray:
        t = np.asarray(t, dtype=float)
        approach = self.z_cruise - self.approach_speed * (np.minimum(t, self.t_halt) - self.t_cruise)
        tau = t - self.t_pull
        ta, tc, a, v = self.t_accel, self.t_cruise_pull, self.accel, self.pullback_speed
        with np.errstate(invalid="ignore", over="ignore"):  # the trigger search has no pullback yet
            rise = np.where(tau < ta, 0.5 * a * tau ** 2,
                            np.where(tau < ta + tc, 0.5 * a * ta ** 2 + v * (tau - ta),
                                     0.5 * a * ta ** 2 + v * tc + v * np.minimum(tau - ta - tc, ta)
                                     - 0.5 * a * np.minimum(tau - ta - tc, ta) ** 2))
            return np.where(t < self.t_halt, approach, np.where(tau <= 0, self.z_halt, self.z_halt + rise))

    @property
    def t_pull_end(self) -> float:
        return self.t_pull + 2 * self.t_accel + self.t_cruise_pull


def true_force(spec: SynthTap, phases: Phases, t: np.ndarray, z_contact_mm: float) -> np.ndarray:
    """The force on the nozzle (positive polarity, no sensor effects) at times t."""
    z = phases.z_at(t)
    depth_um = (z_contact_mm - z) * 1000.0
    w = spec.contact_onset_um
    if w > 0:
        contact = np.where(depth_um >= w, depth_um - 0.5 * w, np.where(depth_um > 0, depth_um ** 2 / (2 * w), 0.0))
    else:
        contact = np.maximum(depth_um, 0.0)
    since_halt = np.maximum(t - phases.t_halt, 0.0)
    relaxed = 1.0 - spec.relaxation_fraction * (1.0 - np.exp(-since_halt / spec.relaxation_time_s))
    force = spec.stiffness_g_um * contact * relaxed
    if spec.film_um > 0:
        force = force + spec.film_stiffness_g_um * np.maximum(depth_um + spec.film_um, 0.0)
    if spec.pull_force_g > 0:
        stretch = np.where((t > phases.t_pull) & (depth_um < 0), -depth_um / spec.pull_length_um, 0.0)
        force = force - spec.pull_force_g * stretch * np.exp(1.0 - stretch)
    return force


def sensed_force(spec: SynthTap, phases: Phases, times: np.ndarray, z_contact_mm: float) -> np.ndarray:
    """Noise-free sensor output: mean over each conversion window, read late by the delay."""
    window = spec.integration_s
    if window == 0:
        return true_force(spec, phases, times - spec.sensor_delay_s, z_contact_mm)
    offsets = (np.arange(SUBSTEPS) + 0.5) / SUBSTEPS * window
    grid = times[:, None] - spec.sensor_delay_s - window + offsets[None, :]
    return true_force(spec, phases, grid.ravel(), z_contact_mm).reshape(grid.shape).mean(axis=1)


def plan_motion(spec: SynthTap, times: np.ndarray, noise: np.ndarray) -> Phases:
    """Approach until the measured force triggers, halt, dwell, pullback."""
    v = spec.approach_speed_mm_s
    t0 = float(times[0])
    z_cruise = spec.z_contact_mm + v * spec.approach_time_s
    v_pull, a = spec.pullback_speed, spec.accel_mm_s2
    t_accel = min(v_pull / a, 0.5 * spec.pullback_distance_mm / v_pull)
    cruise_mm = spec.pullback_distance_mm - a * t_accel ** 2
    endless = Phases(t0, z_cruise, np.inf, -np.inf, np.inf, t_accel, cruise_mm / v_pull, v, v_pull, a)
    measured = sensed_force(spec, endless, times, spec.z_contact_mm) + noise
    over = np.flatnonzero(np.abs(measured) >= spec.trigger_force_g)
    if len(over) == 0:
        raise ValueError("the synthetic approach never reaches the trigger force; lengthen the record")
    t_halt = float(times[over[0]]) + spec.trigger_latency_s
    z_halt = z_cruise - v * (t_halt - t0)
    return Phases(t0, z_cruise, t_halt, z_halt, t_halt + spec.dwell_s, t_accel, cruise_mm / v_pull, v, v_pull, a)


def moves_of(spec: SynthTap, phases: Phases) -> list[Move]:
    v, a = phases.approach_speed, phases.accel
    t_up = v / a
    approach_accel = Move(phases.t_cruise - t_up, t_up, 0.0, a, phases.z_cruise + 0.5 * a * t_up ** 2, -1)
    cruise = Move(phases.t_cruise, phases.t_halt - phases.t_cruise, v, 0.0, phases.z_cruise, -1)
    halt = Move(phases.t_halt, 0.0, 0.0, 0.0, phases.z_halt, 0)
    ta, vp = phases.t_accel, phases.pullback_speed
    rise_accel = 0.5 * a * ta ** 2
    up_accel = Move(phases.t_pull, ta, 0.0, a, phases.z_halt, 1)
    up_cruise = Move(phases.t_pull + ta, phases.t_cruise_pull, vp, 0.0, phases.z_halt + rise_accel, 1)
    up_decel = Move(phases.t_pull + ta + phases.t_cruise_pull, ta, vp, -a,
                    phases.z_halt + rise_accel + vp * phases.t_cruise_pull, 1)
    return [approach_accel, cruise, halt, up_accel, up_cruise, up_decel]


def synth_tap(spec: SynthTap | None = None, **changes) -> TapData:
    """One synthetic tap; keyword arguments override fields of `spec`."""
    spec = dataclasses.replace(spec or SynthTap(), **changes)
    rng = np.random.default_rng(spec.seed)
    period = 1.0 / spec.sample_rate_sps
    # Long enough for approach, any over-travel, dwell, pullback and tail.
    span = spec.approach_time_s + 0.2 + spec.dwell_s + spec.pullback_distance_mm / spec.pullback_speed + 0.1
    times = spec.time_origin_s + np.arange(int(span / period) + 1) * period
    noise = rng.normal(0.0, spec.noise_g, len(times))
    phases = plan_motion(spec, times, noise)
    keep = times <= phases.t_pull_end + spec.tail_s
    times, noise = times[keep], noise[keep]
    force = spec.polarity * sensed_force(spec, phases, times, spec.z_contact_mm) + spec.baseline_g + noise
    if spec.corrupted_frames:
        where = rng.choice(np.arange(5, len(times) - 5), size=spec.corrupted_frames, replace=False)
        force[where] = rng.choice([-1.0, 1.0], size=len(where)) * rng.uniform(2000, 8000, size=len(where))
    return TapData(
        time_s=times,
        force_g=force,
        z_mm=phases.z_at(times),
        moves=moves_of(spec, phases),
        sample_rate_sps=spec.sample_rate_sps,
        events={"home_end_time": phases.t_halt, "pullback_start_time": phases.t_pull,
                "pullback_end_time": phases.t_pull_end},
        probe={"speed": spec.approach_speed_mm_s, "pullback_distance": spec.pullback_distance_mm,
               "pullback_speed": phases.pullback_speed, "trigger_force": spec.trigger_force_g},
        truth={"z_contact": spec.z_contact_mm, "label": spec.label},
        meta={"source": "tapcell.tap.synth", "seed": spec.seed, "sensor_delay_s": spec.sensor_delay_s,
              "sensor_integration_s": spec.integration_s},
    )


def best_achievable_z(spec: SynthTap, tap: TapData) -> float:
    """Z from the exact noise-free model with only the contact height free (the accuracy limit).

    The motion is held as recorded; the contact height is solved by Gauss-Newton with a
    numerical derivative (the model is smooth in it away from sample-exact kinks).
    """
    phases = _phases_from_moves(tap.moves, spec)
    data = spec.polarity * (tap.force_g - spec.baseline_g)
    z = spec.z_contact_mm + 0.0
    step_mm = 1e-5
    for _ in range(6):
        model = sensed_force(spec, phases, tap.time_s, z)
        slope = (sensed_force(spec, phases, tap.time_s, z + step_mm) - model) / step_mm
        denominator = float(slope @ slope)
        if denominator == 0:
            break
        change = float(slope @ (data - model)) / denominator
        z += change
        if abs(change) < 1e-9:
            break
    return z


def _phases_from_moves(moves: list[Move], spec: SynthTap) -> Phases:
    _, cruise, halt, up_accel, up_cruise, _ = moves
    return Phases(cruise.print_time, cruise.start_z, halt.print_time, halt.start_z, up_accel.print_time,
                  up_accel.move_t, up_cruise.move_t, cruise.start_v, up_cruise.start_v, spec.accel_mm_s2)


# Parameters an analysis of a real tap cannot know and must fit alongside the contact height.
NUISANCE_FIELDS = ("stiffness_g_um", "baseline_g", "relaxation_fraction", "relaxation_time_s")


def contact_sigma_limit_um(spec: SynthTap, tap: TapData, free: tuple[str, ...] = ()) -> float:
    """Cramér-Rao bound (1σ, µm) of the contact height from all samples of `tap` under the exact model.

    Noise is white with sigma `spec.noise_g`; the motion is held as recorded. With `free` empty
    only the contact height is unknown (the spread `best_achievable_z` reaches); naming fields of
    `spec` (e.g. NUISANCE_FIELDS) makes them unknown too, which is the honest limit for an
    estimator that must fit them. Derivatives are central differences of the noise-free signal.
    """
    phases = _phases_from_moves(tap.moves, spec)

    def signal(changed: SynthTap, z_mm: float) -> np.ndarray:
        return sensed_force(changed, phases, tap.time_s, z_mm) + changed.baseline_g

    columns = []
    step_um = 1e-3
    columns.append((signal(spec, spec.z_contact_mm + step_um * 1e-3) - signal(spec, spec.z_contact_mm - step_um * 1e-3))
                   / (2 * step_um))
    for name in free:
        value = getattr(spec, name)
        step = 1e-4 * max(abs(value), 1e-3)
        up = signal(dataclasses.replace(spec, **{name: value + step}), spec.z_contact_mm)
        down = signal(dataclasses.replace(spec, **{name: value - step}), spec.z_contact_mm)
        columns.append((up - down) / (2 * step))
    jacobian = np.column_stack(columns)
    covariance = np.linalg.inv(jacobian.T @ jacobian) * spec.noise_g ** 2
    return float(np.sqrt(covariance[0, 0]))
