"""Taps from the independent generator: scenarios, one tap, a labelled set of blinded files.

A tap is made the way a Klipper-family probe makes it: the approach cruises down at `speed`, the
MCU trigger fires on the (drift-filtered) force read from the sensor, the steppers halt a moment
later, the nozzle rests while the host schedules the pullback, then lifts at 1 µm per sample.
The motion is written as the five trapezoid moves of the tap format; the force as the sensor
stamped it. Each file holds only what a printer records; the truth (contact height, scenario,
every drawn parameter) goes to a separate `labels.jsonl` so the files are blinded.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np

from tapcell.taplab.physics import Contact, Ooze, contact_force_g
from tapcell.taplab.sensor import SUBSAMPLES, Adc, convert, corrupt_frames, pink_noise

FORMAT = "tapcell.tap.v1"
LABELS_FILE = "labels.jsonl"
TRIGGER_HIGHPASS_HZ = 0.8  # the MCU trigger sees the force through a drift filter, as users configure it


@dataclass(frozen=True)
class TapSpec:
    """Everything one tap is made from (all drawn per tap by a scenario)."""

    adc: Adc
    contact: Contact
    ooze: Ooze | None
    approach_speed_mm_s: float
    approach_mm: float  # cruise distance from the first sample to the bare bed
    z_contact_mm: float
    trigger_g: float
    trsync_s: float  # trigger read -> steppers halted
    dwell_s: float  # halt -> pullback start (host scheduling)
    pullback_over_travel: float  # pullback distance / overtravel at the halt
    pullback_accel_mm_s2: float
    tail_s: float  # samples kept after the pullback ends
    polarity: int
    offset_g: float
    drift_g_per_mm: float  # cable / bowden force per mm of Z
    walk_g_per_sqrt_s: float  # thermal random walk
    mains_hz: float
    hum_g: tuple[float, float, float]  # amplitudes of the fundamental, 2nd and 3rd harmonic
    corrupt_frames: int
    time_origin_s: float
    sample_phase: float  # where the conversion clock sits against the motion, 0..1 period
    # Gantry ringing: every change of Z speed rings the toolhead, this many g per mm/s of the
    # change, at ring_hz, decaying with ring_tau_s. 0: none.
    ring_g_per_mm_s: float = 0.0
    ring_hz: float = 40.0
    ring_tau_s: float = 0.05

    @property
    def pullback_speed_mm_s(self) -> float:
        return 0.001 * self.adc.nominal_sps  # the Klipper-family default: 1 µm per sample


@dataclass(frozen=True)
class Scenario:
    name: str
    title: str
    expect: str  # "accept": a good analysis accepts it; "reject": must reject; "either"
    draw: Callable[[np.random.Generator], TapSpec]


def _u(rng: np.random.Generator, low: float, high: float) -> float:
    return float(rng.uniform(low, high))


SENSORS = {
    # kind, nominal sps, white noise range (g): around the 0.72 g the real Voron HX717 capture shows
    "hx717": ("hx717", 320.0, (0.5, 1.0)),
    "hx711": ("hx711", 80.0, (0.3, 0.6)),
    "ads1220_660": ("ads1220", 660.0, (0.4, 0.8)),
    "ads1220_2000": ("ads1220", 2000.0, (0.7, 1.4)),
    "hx711_10": ("hx711", 10.0, (0.15, 0.3)),
}


def draw_adc(rng: np.random.Generator, sensor: str, latency: tuple[float, float] = (0.0, 0.25)) -> Adc:
    kind, sps, white = SENSORS[sensor]
    return Adc(kind=kind, nominal_sps=sps, clock_error=_u(rng, -0.04, 0.04), latency_periods=_u(rng, *latency),
               jitter_s=_u(rng, 5e-6, 30e-6), white_g=_u(rng, *white), pink_g=_u(rng, 0.1, 0.5),
               counts_per_gram=_u(rng, 200.0, 1000.0))


def draw_contact(rng: np.random.Generator, stiffness: tuple[float, float] = (2.0, 6.0),
                 onset: tuple[float, float] = (1.0, 8.0), relax: tuple[float, float] = (0.01, 0.04)) -> Contact:
    return Contact(stiffness_g_um=_u(rng, *stiffness), onset_um=_u(rng, *onset), onset_power=_u(rng, 0.35, 1.0),
                   onset_blend=_u(rng, 0.0, 0.5), unload_ratio=_u(rng, 0.9, 1.05),
                   relax_fraction=(_u(rng, *relax),), relax_tau_s=(_u(rng, 0.05, 0.3),))


def draw_ooze(rng: np.random.Generator, heavy: bool) -> Ooze:
    if heavy:
        return Ooze(bead_um=_u(rng, 60, 200), viscous_g_per_mm_s=_u(rng, 5, 20), film_um=_u(rng, 20, 60),
                    film_residual_um=_u(rng, 8, 30), squeeze_tau_s=_u(rng, 0.1, 0.5), thread_g=_u(rng, 10, 40),
                    thread_length_um=_u(rng, 20, 60))
    return Ooze(bead_um=_u(rng, 10, 40), viscous_g_per_mm_s=_u(rng, 0.5, 3), film_um=_u(rng, 2, 8),
                film_residual_um=_u(rng, 0.3, 3), squeeze_tau_s=_u(rng, 0.05, 0.3), thread_g=_u(rng, 1, 6),
                thread_length_um=_u(rng, 5, 20))


def draw_tap(rng: np.random.Generator, sensor: str = "hx717", **changes) -> TapSpec:
    """A clean tap on `sensor`; `changes` replace any field (after the draws, so seeds stay aligned)."""
    slow = sensor == "hx711"  # 80 sps needs <= 2 mm/s for a usable compression line
    slowest = sensor == "hx711_10"  # 10 sps: 0.2 mm/s, 20 um a sample
    spec = TapSpec(
        adc=draw_adc(rng, sensor), contact=draw_contact(rng), ooze=None,
        approach_speed_mm_s=0.2 if slowest else 2.0 if slow else 5.0,
        approach_mm=_u(rng, 0.1, 0.2) if slowest else _u(rng, 0.3, 0.8) if slow else _u(rng, 0.5, 1.5),
        z_contact_mm=_u(rng, -0.05, 0.15), trigger_g=75.0, trsync_s=_u(rng, 0.2e-3, 3e-3),
        dwell_s=_u(rng, 0.1, 0.35), pullback_over_travel=_u(rng, 2.2, 3.5),
        pullback_accel_mm_s2=_u(rng, 300, 1000), tail_s=_u(rng, 0.02, 0.25),
        polarity=int(rng.choice((-1, 1))), offset_g=_u(rng, -3, 3), drift_g_per_mm=_u(rng, -3, 3),
        walk_g_per_sqrt_s=_u(rng, 0.05, 0.5), mains_hz=float(rng.choice((50.0, 60.0))),
        hum_g=(_u(rng, 0, 0.8), _u(rng, 0, 0.4), _u(rng, 0, 0.3)), corrupt_frames=0,
        time_origin_s=_u(rng, 100, 5000), sample_phase=_u(rng, 0, 1))
    return replace(spec, **changes)


def _soft_sheet(rng):
    return draw_tap(rng, contact=draw_contact(rng, stiffness=(1.2, 3.0), onset=(8.0, 15.0), relax=(0.04, 0.08)))


def _cable_drift(rng):
    sign = float(rng.choice((-1.0, 1.0)))
    return draw_tap(rng, drift_g_per_mm=sign * _u(rng, 10, 40), walk_g_per_sqrt_s=_u(rng, 1.0, 4.0))


def _latency(rng):
    return draw_tap(rng, adc=draw_adc(rng, "hx717", latency=(1.0, 2.0)))


def _ringing(rng):
    return draw_tap(rng, ring_g_per_mm_s=_u(rng, 0.5, 2.0), ring_hz=_u(rng, 25.0, 70.0), ring_tau_s=_u(rng, 0.02, 0.08))


def _two_stage(rng):
    contact = draw_contact(rng)
    return draw_tap(rng, contact=replace(contact, stage_um=_u(rng, 8.0, 30.0),
                                         stage_stiffness_g_um=_u(rng, 0.1, 0.3) * contact.stiffness_g_um))


def _mains(rng):
    return draw_tap(rng, hum_g=(_u(rng, 2, 5), _u(rng, 0.3, 1.5), _u(rng, 0.3, 1.5)))


SCENARIOS: dict[str, Scenario] = {s.name: s for s in (
    Scenario("clean_hx717", "clean HX717 320 sps", "accept", lambda rng: draw_tap(rng, "hx717")),
    Scenario("clean_ads1220_660", "clean ADS1220 660 sps", "accept", lambda rng: draw_tap(rng, "ads1220_660")),
    Scenario("clean_ads1220_2000", "clean ADS1220 2000 sps", "accept", lambda rng: draw_tap(rng, "ads1220_2000")),
    Scenario("hx711_80", "HX711 80 sps, 2 mm/s", "accept", lambda rng: draw_tap(rng, "hx711")),
    Scenario("soft_sheet", "soft textured sheet", "accept", _soft_sheet),
    Scenario("cable_drift", "bowden / cable drift", "accept", _cable_drift),
    Scenario("latency", "ADC pipeline latency 1-2 samples", "accept", _latency),
    Scenario("mains_hum", "strong mains hum", "accept", _mains),
    Scenario("mild_ooze", "mild ooze", "either", lambda rng: draw_tap(rng, ooze=draw_ooze(rng, heavy=False))),
    Scenario("heavy_ooze", "heavy ooze", "reject", lambda rng: draw_tap(rng, ooze=draw_ooze(rng, heavy=True))),
    Scenario("corrupt_frames", "corrupt frames", "accept",
             lambda rng: draw_tap(rng, corrupt_frames=int(rng.integers(1, 4)))),
    Scenario("short_pullback", "short pullback", "reject",
             lambda rng: draw_tap(rng, pullback_over_travel=_u(rng, 0.6, 1.04))),
    Scenario("hx711_10", "HX711 10 sps, 0.2 mm/s", "accept", lambda rng: draw_tap(rng, "hx711_10")),
    Scenario("ringing", "gantry ringing", "accept", _ringing),
    Scenario("two_stage", "two-stage mount (sheet/springs)", "either", _two_stage),
)}


@dataclass
class _Timeline:
    """Fine grid and conversion times of one tap (t = 0 when the approach cruise starts)."""

    spec: TapSpec
    fine_s: np.ndarray = field(init=False)
    conversion_end_s: np.ndarray = field(init=False)

    def build(self, end_s: float) -> _Timeline:
        adc = self.spec.adc
        period = adc.period_s
        dt = period / SUBSAMPLES
        first_end = self.spec.sample_phase * period
        grid0 = first_end - adc.window_periods * period
        count = int(math.ceil((end_s - grid0) / dt)) + 1
        self.fine_s = grid0 + (np.arange(count) + 0.5) * dt
        samples = (count // SUBSAMPLES) - adc.window_periods + 1
        self.conversion_end_s = first_end + np.arange(samples) * period
        return self


def pullback_profile(spec: TapSpec, pullback_mm: float) -> tuple[float, float, float]:
    """The pullback's (top speed mm/s, each ramp's s, cruise s): a trapezoid at the spec's speed, or a
    triangle short of it where the distance is too short to reach it (as a printer's planner does)."""
    a_p = spec.pullback_accel_mm_s2
    v_p = min(spec.pullback_speed_mm_s, math.sqrt(a_p * max(pullback_mm, 0.0)))
    if v_p <= 0.0:  # no distance to lift: the speed's own ramps, never a division by a zero speed
        return spec.pullback_speed_mm_s, spec.pullback_speed_mm_s / a_p, 0.0
    ramp_s = v_p / a_p
    return v_p, ramp_s, max(pullback_mm / v_p - ramp_s, 0.0)


def _motion(spec: TapSpec, halt_s: float | None, pullback_mm: float) -> Callable[[np.ndarray], tuple]:
    """z(t) (mm) and closing speed (mm/s) of the approach (endless when halt_s is None) and the pullback."""
    z_start = spec.z_contact_mm + spec.approach_mm
    v_a = spec.approach_speed_mm_s
    v_p, ramp_s, cruise_s = pullback_profile(spec, pullback_mm)
    a_p = spec.pullback_accel_mm_s2

    def at(t: np.ndarray):
        if halt_s is None:
            return z_start - v_a * t, np.full_like(t, v_a), np.zeros(t.shape, dtype=bool)
        z_halt = z_start - v_a * halt_s
        start = halt_s + spec.dwell_s
        tau = np.clip(t - start, 0.0, None)
        # distance lifted: accel ramp, cruise, decel ramp
        rise = np.where(tau < ramp_s, 0.5 * a_p * tau ** 2,
                        np.where(tau < ramp_s + cruise_s, 0.5 * a_p * ramp_s ** 2 + v_p * (tau - ramp_s),
                                 pullback_mm - 0.5 * a_p * np.clip(2 * ramp_s + cruise_s - tau, 0.0, None) ** 2))
        speed_up = np.where(tau < ramp_s, a_p * tau, np.where(tau < ramp_s + cruise_s, v_p,
                                                             a_p * np.clip(2 * ramp_s + cruise_s - tau, 0.0, None)))
        approaching = t < halt_s
        z = np.where(approaching, z_start - v_a * t, z_halt + rise)
        closing = np.where(approaching, v_a, -speed_up)
        return z, closing, t >= start

    return at


def _input_g(spec: TapSpec, fine_s: np.ndarray, motion, walk: np.ndarray,
             touch_s: float | None = None) -> tuple[np.ndarray, dict]:
    """The force the sensor's input sees on the fine grid (before conversion), and truth facts."""
    z_mm, closing, pulling = motion(fine_s)
    overtravel_um = (spec.z_contact_mm - z_mm) * 1000.0
    force, facts = contact_force_g(fine_s, overtravel_um, closing, pulling, spec.contact, spec.ooze, touch_s)
    z_start = spec.z_contact_mm + spec.approach_mm
    mains_s = fine_s + spec.time_origin_s  # the mains phase is whatever the clock says
    hum = sum(a * np.sin(2 * np.pi * (k + 1) * spec.mains_hz * mains_s + 1.3 * k)
              for k, a in enumerate(spec.hum_g))
    signal = (spec.polarity * force + spec.offset_g + spec.drift_g_per_mm * (z_mm - z_start)
              + walk[:len(fine_s)] + hum)
    if spec.ring_g_per_mm_s > 0:
        signal = signal + _ringing_g(spec, fine_s, closing)
    return signal, facts


def _ringing_g(spec: TapSpec, fine_s: np.ndarray, closing_mm_s: np.ndarray) -> np.ndarray:
    """The toolhead ringing every change of Z speed excites: the changes on the fine grid
    convolved with a decaying sinusoid."""
    step_s = float(fine_s[1] - fine_s[0])
    kernel_s = np.arange(0.0, 6.0 * spec.ring_tau_s, step_s)
    kernel = np.exp(-kernel_s / spec.ring_tau_s) * np.sin(2.0 * np.pi * spec.ring_hz * kernel_s)
    changes = np.diff(closing_mm_s, prepend=closing_mm_s[0])
    # By FFT: a direct convolution costs len(changes) x len(kernel), seconds a tap at 4000 sps.
    n = len(changes) + len(kernel) - 1
    ringing = np.fft.irfft(np.fft.rfft(changes, n) * np.fft.rfft(kernel, n), n)
    return spec.ring_g_per_mm_s * ringing[:len(fine_s)]


def _converted_g(spec: TapSpec, timeline: _Timeline, motion, walk: np.ndarray,
                 touch_s: float | None = None) -> tuple[np.ndarray, dict]:
    """The sensor's samples of one tap before output noise (one per conversion of the timeline), and truth facts."""
    signal, facts = _input_g(spec, timeline.fine_s, motion, walk, touch_s)
    return convert(signal, spec.adc)[:len(timeline.conversion_end_s)], facts


@dataclass(frozen=True)
class RecordedMotion:
    """What a tap file fixes about the motion: when the approach halted, how far it pulled back,
    how many samples it kept."""

    halt_s: float  # from the start of the approach cruise
    pullback_mm: float
    sample_count: int

    @classmethod
    def of_tap(cls, tap: dict) -> RecordedMotion:
        return cls(halt_s=float(tap["moves"][0]["move_t"]), pullback_mm=float(tap["probe"]["pullback_distance"]),
                   sample_count=len(tap["time"]))


def noise_free_samples(spec: TapSpec, motion: RecordedMotion, touch_s: float | None = None) -> np.ndarray:
    """The samples `spec` makes along a recorded motion with no noise (white, 1/f, walk, jitter);
    hum as `spec.hum_g` says. touch_s: see `physics.contact_force_g` (None: as make_tap).

    The sample times stay the conversions `spec` implies (its clock and sample phase), so changing
    what the analysis cannot see (stiffness, onset, drift ...) changes only the values."""
    period = spec.adc.period_s
    timeline = _Timeline(spec).build(spec.sample_phase * period + (motion.sample_count + 1) * period)
    walk = np.zeros(len(timeline.fine_s))
    values, _ = _converted_g(spec, timeline, _motion(spec, motion.halt_s, motion.pullback_mm), walk, touch_s)
    return values[:motion.sample_count]


def _trigger_read_s(spec: TapSpec, samples_g: np.ndarray, read_s: np.ndarray) -> float:
    """When the MCU reads the first sample whose drift-filtered force reaches the trigger."""
    tare = float(np.mean(samples_g[:8]))
    alpha = 1.0 / (1.0 + 2 * math.pi * TRIGGER_HIGHPASS_HZ * spec.adc.period_s)
    filtered = 0.0
    previous = tare
    for value, read in zip(samples_g, read_s):
        filtered = alpha * (filtered + value - previous)
        previous = value
        if abs(filtered) >= spec.trigger_g:
            return float(read)
    raise ValueError("the approach never reached the trigger force")


def noise_record_length(spec: TapSpec) -> tuple[int, int]:
    """(fine steps, samples) of the noise drawn up front: enough for the longest tap `spec` can make.
    The 1/f noise is made over this many samples, so its spectrum depends on it."""
    period = spec.adc.period_s
    longest_s = (spec.approach_mm + 0.5) / spec.approach_speed_mm_s + spec.dwell_s + 1.0 / spec.pullback_speed_mm_s \
        + spec.tail_s + 4 * period
    most_fine = int(longest_s / period * SUBSAMPLES) + 8 * SUBSAMPLES
    return most_fine, most_fine // SUBSAMPLES


def make_tap(spec: TapSpec, rng: np.random.Generator) -> tuple[dict, dict]:
    """One tap: (tap-format object, truth). Deterministic from `rng`'s state."""
    adc = spec.adc
    period = adc.period_s
    # Everything random is drawn up front for the longest tap this spec can make.
    most_fine, most_samples = noise_record_length(spec)
    walk = np.cumsum(rng.normal(size=most_fine)) * spec.walk_g_per_sqrt_s * math.sqrt(period / SUBSAMPLES)
    noise = rng.normal(size=most_samples) * adc.white_g + pink_noise(most_samples, adc.pink_g, rng)
    jitter = rng.normal(size=most_samples) * adc.jitter_s

    def samples_on(timeline: _Timeline, motion, tap_spec: TapSpec = spec) -> tuple[np.ndarray, np.ndarray, dict]:
        values, facts = _converted_g(tap_spec, timeline, motion, walk)
        n = len(values)
        read = timeline.conversion_end_s[:n] + adc.latency_periods * period + jitter[:n]
        return values + noise[:n], read, facts

    # Pass 1: the endless approach, to find when the trigger halts it (later samples cannot change that).
    approach_end = (spec.approach_mm + 0.4) / spec.approach_speed_mm_s
    timeline = _Timeline(spec).build(approach_end)

    def halt_time(tap_spec: TapSpec) -> float:
        values, read, _ = samples_on(timeline, _motion(tap_spec, None, 0.0), tap_spec)
        return _trigger_read_s(tap_spec, values, read) + tap_spec.trsync_s

    halt_s = halt_time(spec)
    z_start = spec.z_contact_mm + spec.approach_mm
    z_halt = z_start - spec.approach_speed_mm_s * halt_s
    overtravel_mm = spec.z_contact_mm - z_halt
    # The pullback distance is set for this printer's clean taps (ooze does not change the setting).
    clean_halt_s = halt_s if spec.ooze is None else halt_time(replace(spec, ooze=None))
    clean_overtravel_mm = spec.z_contact_mm - (z_start - spec.approach_speed_mm_s * clean_halt_s)
    pullback_mm = round(clean_overtravel_mm * spec.pullback_over_travel, 4)
    v_p, ramp_s, cruise_s = pullback_profile(spec, pullback_mm)
    pullback_start = halt_s + spec.dwell_s
    pullback_end = pullback_start + pullback_mm / v_p + ramp_s
    # Pass 2: the whole tap.
    timeline = _Timeline(spec).build(pullback_end + spec.tail_s + 2 * period)
    motion = _motion(spec, halt_s, pullback_mm)
    values, read, facts = samples_on(timeline, motion)
    keep = read <= pullback_end + spec.tail_s
    values, read = values[keep], read[keep]
    frames = corrupt_frames(values, spec.corrupt_frames, adc, rng) if spec.corrupt_frames else []

    origin = spec.time_origin_s
    moves = [
        {"print_time": origin, "move_t": halt_s, "start_v": spec.approach_speed_mm_s, "accel": 0.0,
         "start_z": z_start, "z_r": -1},
        {"print_time": origin + halt_s, "move_t": 0.0, "start_v": 0.0, "accel": 0.0, "start_z": z_halt, "z_r": 0},
        {"print_time": origin + pullback_start, "move_t": ramp_s, "start_v": 0.0,
         "accel": spec.pullback_accel_mm_s2, "start_z": z_halt, "z_r": 1},
        {"print_time": origin + pullback_start + ramp_s, "move_t": cruise_s, "start_v": v_p, "accel": 0.0,
         "start_z": z_halt + 0.5 * v_p * ramp_s, "z_r": 1},
        {"print_time": origin + pullback_start + ramp_s + cruise_s, "move_t": ramp_s, "start_v": v_p,
         "accel": -spec.pullback_accel_mm_s2, "start_z": z_halt + pullback_mm - 0.5 * v_p * ramp_s, "z_r": 1},
    ]
    tap = {
        "format": FORMAT,
        "time": [round(origin + float(t), 7) for t in read],
        "force": [round(float(f), 5) for f in values],
        "moves": moves,
        "sample_rate": adc.nominal_sps,
        "events": {"home_end_time": origin + halt_s, "pullback_start_time": origin + pullback_start,
                   "pullback_end_time": origin + pullback_end},
        "probe": {"x": 150.0, "y": 150.0, "speed": spec.approach_speed_mm_s, "pullback_distance": pullback_mm,
                  "pullback_speed": spec.pullback_speed_mm_s, "trigger_force": spec.trigger_g},
        "meta": {"source": "tapcell.taplab"},
    }
    touched = math.isfinite(facts["touch_time_s"])
    truth = {
        "z_contact": spec.z_contact_mm,
        "overtravel_um": overtravel_mm * 1000.0,
        "touched": touched,
        "film_left_um": facts["film_left_um"] if spec.ooze else 0.0,
        # the nozzle ends above the bed (and above what film is left on it)
        "broke_contact": bool((overtravel_mm - pullback_mm) * 1000.0 + facts["film_left_um"] < 0.0),
        "corrupt_indices": frames,
        "spec": _plain(asdict(spec)),
    }
    return tap, truth


def _plain(value):
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    if isinstance(value, float):
        return round(value, 9)
    return value


def generate_set(out_dir: str | Path, seed: int = 1, taps_per_scenario: int = 40,
                 scenarios: list[str] | None = None) -> list[dict]:
    """Write a labelled, blinded tap set: tap-NNNN.json files (scenarios shuffled) + labels.jsonl.

    Returns the label records. Deterministic from `seed`: tap k of a scenario always comes from
    the same random stream, whatever else is generated.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    names = list(SCENARIOS) if scenarios is None else scenarios
    unknown = [n for n in names if n not in SCENARIOS]
    if unknown:
        raise ValueError(f"unknown scenario(s) {', '.join(unknown)}; known: {', '.join(SCENARIOS)}")
    jobs = [(name, k) for name in names for k in range(taps_per_scenario)]
    order = np.random.default_rng([seed, 0]).permutation(len(jobs))
    labels = []
    for number, job_index in enumerate(order, start=1):
        name, k = jobs[job_index]
        scenario = SCENARIOS[name]
        rng = np.random.default_rng([seed, list(SCENARIOS).index(name) + 1, k])
        tap, truth = make_tap(scenario.draw(rng), rng)
        file_name = f"tap-{number:04d}.json"
        (out / file_name).write_text(json.dumps(tap, separators=(",", ":")), encoding="utf-8")
        labels.append({"file": file_name, "scenario": name, "expect": scenario.expect, **truth})
    with open(out / LABELS_FILE, "w", encoding="utf-8") as handle:
        for record in sorted(labels, key=lambda r: r["file"]):
            handle.write(json.dumps(record, separators=(",", ":")) + "\n")
    return labels


SESSION_SCENARIOS = ("clean_hx717", "clean_ads1220_660", "hx711_80", "soft_sheet")


def session_tap_specs(name: str, seed: int, session: int, taps_per_session: int
                      ) -> list[tuple[TapSpec, np.random.Generator]]:
    """The tap specs of one session of `generate_sessions` (one drawn spec, per tap its own start
    height, sample phase and time), each with the random stream `make_tap` continues."""
    number = list(SCENARIOS).index(name) + 1
    spec = SCENARIOS[name].draw(np.random.default_rng([seed, 1000 + number, session]))
    specs = []
    for k in range(taps_per_session):
        rng = np.random.default_rng([seed, 1000 + number, session, k + 1])
        specs.append((replace(spec, approach_mm=spec.approach_mm * _u(rng, 0.8, 1.2), sample_phase=_u(rng, 0, 1),
                              time_origin_s=spec.time_origin_s + 10.0 * k), rng))
    return specs


def generate_sessions(out_dir: str | Path, seed: int = 1, sessions_per_scenario: int = 20, taps_per_session: int = 10,
                      scenarios: tuple[str, ...] | list[str] = SESSION_SCENARIOS) -> list[dict]:
    """Sessions of taps at one spot (PROBE_ACCURACY, `SAMPLES=`): per session one drawn tap spec (the
    bed, toe, sensor, noise levels and drift all shared), and per tap its own noise, start height
    and sample phase. Writes `<scenario>-<session>-<tap>.json` and labels.jsonl (with `session`)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    labels = []
    for name in scenarios:
        for session in range(sessions_per_scenario):
            for k, (tap_spec, rng) in enumerate(session_tap_specs(name, seed, session, taps_per_session)):
                tap, truth = make_tap(tap_spec, rng)
                file_name = f"{name}-{session:03d}-{k:02d}.json"
                (out / file_name).write_text(json.dumps(tap, separators=(",", ":")), encoding="utf-8")
                labels.append({"file": file_name, "scenario": name, "session": f"{name}-{session:03d}",
                               "expect": SCENARIOS[name].expect, **truth})
    with open(out / LABELS_FILE, "w", encoding="utf-8") as handle:
        for record in labels:
            handle.write(json.dumps(record, separators=(",", ":")) + "\n")
    return labels
