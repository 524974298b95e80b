"""Probing safety rules: how hard a probing move can press, and whether a trigger was a contact.

The firmware stops Z on the first sample whose (filtered) force passes the trigger, or on a
raw force window (drift / force safety). Before that stop the nozzle keeps moving into the
bed: through the rest of the conversion window that saw the contact, the ADC's pipeline, the
MCU reading the sample, and the stop latency (the trigger to the steppers; through the host
when the sensor is on another MCU than the Z steppers). Filters add their own lag; a drift
(high-pass) filter can hide a slow tap altogether.

`predict_stop` runs the firmware trigger itself (the real C code, configured exactly
as for the move) on ideal contact ramps: the nozzle meets a bed of a given stiffness at a given
speed, at several instants within a conversion window. Every sample is the window average of
the ramp; the sample that stops the move (trigger or raw window) is read after the pipeline
and the read delay, the steppers stop after the stop latency, and the force there is the
peak. Nothing else decides when the move stops, so the prediction follows the firmware as it
is (a raw window added to it, a quarantine removed) without a second model of its rules.

Then for trigger-only results (G28 Z, METHOD=two_pass, METHOD=prusa), which have no tap
shape to judge: `contact_holds` (the force after the halt must stay pressed like a contact,
not vanish like a corrupted frame or swing negative like a transient that the tare took in)
and `agreement_tolerance_mm` (how far two trigger-only heights of one spot may differ).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tapcell import scale
from tapcell.mcu.trigger import FirmwareTrigger, TriggerError, TriggerParams

# The bed's stiffness (frame, load cell and sheet in series) assumed until taps measure it: a
# stiff frame with a stiff cell (toolheads we know measure Prusa ~1.5 g/um, the Kalico example
# ~4.6, the virtual printer 3.26, but a sensor stuck at contact on a 150 g/um bed pressed 7 kg
# under the old 10 g/um assumption). Until a tap measures the bed, moves toward it go at the
# speed that is safe on this bed (`SpeedGuard.check`), so the assumption costs one slow approach.
DEFAULT_STIFFNESS_G_UM = 100.0
# A measured stiffness is raised by this much: another spot of the bed may be stiffer.
MEASURED_STIFFNESS_MARGIN = 1.25
# The softest bed assumed when asking whether a filter can hide a slow tap (a slower force
# ramp is what a drift filter removes).
SOFTEST_STIFFNESS_G_UM = 1.0
# Trigger to steppers stopped: on the MCU that reads the sensor, a task switch and a step
# timer; through the host when the Z steppers are on another MCU (Klipper's multi-MCU
# homing budget, 25 ms).
ONE_MCU_STOP_LATENCY_S = 0.001
MULTI_MCU_STOP_LATENCY_S = 0.025
# The MCU polls data-ready ten times a period: a sample is read up to a tenth of a period late.
READ_DELAY_PERIODS = 0.1
# Extra delay from the end of a conversion window to data-ready, in periods: the ADS1220's
# sinc3 decimator centres its response about 1.5 periods back (one more than a plain window); the
# ADS131M0x's sinc3 filter is taken alike.
PIPELINE_PERIODS = {"hx711": 0.0, "hx717": 0.0, "ads1220": 1.0, "ads131m02": 1.0, "ads131m04": 1.0}
CONTACT_PHASES = (0.0, 0.25, 0.5, 0.75)   # where in a conversion window the nozzle meets the bed
PRE_CONTACT_SAMPLES = 2
# The prediction stops here when nothing has stopped the move: a hidden tap.
GIVE_UP_SHARE = 1.5                       # of force_safety_limit
GIVE_UP_WITHOUT_LIMIT_G = 10000.0         # when force_safety_limit is 0 (off)
MAX_RAMP_SAMPLES = 200_000
# Speeds offered as the safe one (the largest at or below the asked speed that passes).
SPEED_STEPS_MM_S = (50.0, 40.0, 30.0, 25.0, 20.0, 15.0, 12.0, 10.0, 8.0, 6.0, 5.0, 4.0, 3.0, 2.5, 2.0,
                    1.5, 1.0, 0.8, 0.5, 0.3, 0.2, 0.1)


@dataclass(frozen=True)
class StopTiming:
    """What delays the halt beyond the samples the trigger looks at."""

    sample_rate_sps: float
    pipeline_s: float       # conversion window end to data ready
    read_delay_s: float     # data ready to the MCU reading it
    stop_latency_s: float   # trigger to the steppers stopped

    @property
    def period_s(self) -> float:
        return 1.0 / self.sample_rate_sps


def stop_timing(sensor_type: str, sample_rate_sps: float, sensor_mcu: str, z_stepper_mcu: str) -> StopTiming:
    period_s = 1.0 / sample_rate_sps
    latency_s = ONE_MCU_STOP_LATENCY_S if sensor_mcu == z_stepper_mcu else MULTI_MCU_STOP_LATENCY_S
    return StopTiming(sample_rate_sps, PIPELINE_PERIODS[sensor_type] * period_s, READ_DELAY_PERIODS * period_s,
                      latency_s)


def _window_average_g(ramp_g_s: float, contact_s: float, start_s: np.ndarray, period_s: float) -> np.ndarray:
    """Mean over [start, start + period] of ramp * max(t - contact, 0) (an integrating ADC)."""
    before = np.maximum(start_s - contact_s, 0.0)
    after = np.maximum(start_s + period_s - contact_s, 0.0)
    return ramp_g_s * (after ** 2 - before ** 2) / (2.0 * period_s)


@dataclass(frozen=True)
class StopPrediction:
    """How a contact at a speed ends: the worst peak force over the contact instants, and
    what stopped the move there (TriggerError.NONE: the trigger; None: nothing did)."""

    peak_force_g: float
    stopped_by: TriggerError | None

    @property
    def hidden(self) -> bool:
        """The filtered force never reached the trigger: only a raw window (or nothing) stopped it."""
        return self.stopped_by not in (TriggerError.NONE, TriggerError.STUCK_SENSOR)


def predict_stop(params: TriggerParams, timing: StopTiming, speed_mm_s: float, stiffness_g_um: float) -> StopPrediction:
    """Run the firmware trigger on ideal contact ramps; the worst case over CONTACT_PHASES."""
    period_s = timing.period_s
    ramp_g_s = stiffness_g_um * speed_mm_s * 1000.0
    limit_g = params.force_safety_limit_g
    give_up_g = GIVE_UP_SHARE * limit_g if limit_g > 0 else GIVE_UP_WITHOUT_LIMIT_G
    count = min(MAX_RAMP_SAMPLES, PRE_CONTACT_SAMPLES + math.ceil(give_up_g / (ramp_g_s * period_s)) + 2)
    window_start_s = (np.arange(count) - PRE_CONTACT_SAMPLES) * period_s
    read_s = window_start_s + period_s + timing.pipeline_s + timing.read_delay_s
    sign = -1.0 if params.inverted else 1.0
    tare = int(params.reference_tare_counts)
    worst: StopPrediction | None = None
    for phase in CONTACT_PHASES:
        contact_s = phase * period_s
        force_g = _window_average_g(ramp_g_s, contact_s, window_start_s, period_s)
        # One count of dither every other sample: a real sensor's noise, so that the stuck-sensor
        # check never takes a slow ideal ramp (identical rounded samples) for a dead sensor.
        counts = np.round(tare + sign * params.counts_per_gram * force_g) + np.arange(count) % 2
        counts = np.clip(counts, -(1 << 31), (1 << 31) - 1).astype(np.int32)
        trigger = FirmwareTrigger(params)
        # Armed half a period before the first sample; the MCU clock starts a second earlier.
        offset_s = 1.0
        trigger.arm(tare, offset_s + read_s[0] - 0.5 * period_s)
        result = trigger.feed(read_s + offset_s, counts)
        index = result.trigger_index if result.trigger_index is not None else result.error_index
        if index is None:
            return StopPrediction(math.inf, None)
        halt_s = read_s[index] + timing.stop_latency_s
        prediction = StopPrediction(ramp_g_s * max(halt_s - contact_s, 0.0), result.error)
        if worst is None or prediction.peak_force_g > worst.peak_force_g:
            worst = prediction
    return worst


def stuck_at_contact_stop(params: TriggerParams, timing: StopTiming, speed_mm_s: float,
                          stiffness_g_um: float) -> StopPrediction | None:
    """A sensor that sticks as the nozzle meets the bed: no force is ever seen, and the firmware stops
    the move only after its run of identical samples (None when that check is off)."""
    run = params.effective_stuck_samples
    if not run:
        return None
    stop_s = run * timing.period_s + timing.pipeline_s + timing.read_delay_s + timing.stop_latency_s
    return StopPrediction(stiffness_g_um * speed_mm_s * 1000.0 * stop_s, TriggerError.STUCK_SENSOR)


def worst_stop(params: TriggerParams, timing: StopTiming, speed_mm_s: float, stiffness_g_um: float) -> StopPrediction:
    """The worst of a contact with a bed of `stiffness_g_um` (most overshoot), with the softest bed
    (where a drift filter is most likely to hide the tap), and with a sensor that sticks at contact."""
    cases = [predict_stop(params, timing, speed_mm_s, stiffness_g_um),
             predict_stop(params, timing, speed_mm_s, SOFTEST_STIFFNESS_G_UM),
             stuck_at_contact_stop(params, timing, speed_mm_s, stiffness_g_um)]
    return max((case for case in cases if case is not None), key=lambda p: p.peak_force_g)


# The pullback samples that measure a bad tap's stiffness: the force between these shares of its peak
# (clear of the contact's toe and of the halt's relaxation).
DECOMPRESSION_BAND = (0.2, 0.8)
MIN_DECOMPRESSION_SAMPLES = 3


def decompression_stiffness_g_um(time_s: np.ndarray, force_g: np.ndarray, z_at, pullback_start_s: float,
                                 pullback_end_s: float) -> float | None:
    """The bed's stiffness from a tap's pullback, whatever its analysis said: the force falling with
    the commanded Z (`z_at(t)`, mm) while between DECOMPRESSION_BAND of its peak, as the median of
    the slopes between all pairs of those samples (one corrupted frame cannot move it). None with
    fewer than MIN_DECOMPRESSION_SAMPLES such samples (a tap too fast or too stiff to read: the
    halt force alone says nothing reliable). The force guard only ever raises its assumption by it."""
    time_s = np.asarray(time_s, dtype=float)
    force_g = np.asarray(force_g, dtype=float)
    pullback = (time_s >= pullback_start_s) & (time_s <= pullback_end_s)
    t, f = time_s[pullback], force_g[pullback]
    if t.size < MIN_DECOMPRESSION_SAMPLES:
        return None
    peak_g = float(np.median(np.sort(f)[-3:]))  # the largest but one of the three: a flipped bit is not the peak
    if peak_g <= 0.0:
        return None
    low, high = (share * peak_g for share in DECOMPRESSION_BAND)
    band = (f >= low) & (f <= high)
    if np.count_nonzero(band) < MIN_DECOMPRESSION_SAMPLES:
        return None
    z_um = np.array([z_at(float(ti)) for ti in t[band]]) * 1000.0
    f = f[band]
    i, j = np.triu_indices(len(f), k=1)
    dz = z_um[j] - z_um[i]
    moved = np.abs(dz) > 1e-9
    if not np.any(moved):
        return None
    return float(abs(np.median((f[j] - f[i])[moved] / dz[moved])))


def exceeds_limit(prediction: StopPrediction, force_safety_limit_g: float) -> bool:
    """Unsafe: nothing stops the move, or it stops past force_safety_limit (when that is on)."""
    return prediction.stopped_by is None or (force_safety_limit_g > 0
                                              and prediction.peak_force_g > force_safety_limit_g)


def safe_speed_mm_s(params: TriggerParams, timing: StopTiming, below_mm_s: float, stiffness_g_um: float) -> float | None:
    """The largest of SPEED_STEPS_MM_S below `below_mm_s` that passes, None when none does."""
    for speed in SPEED_STEPS_MM_S:
        if speed < below_mm_s and not exceeds_limit(worst_stop(params, timing, speed, stiffness_g_um),
                                                    params.force_safety_limit_g):
            return speed
    return None


# Speeds tried for a watched move (the nozzle watch), fastest first.
WATCH_SPEED_STEPS_MM_S = (500.0, 400.0, 300.0, 250.0, 200.0, 150.0, 120.0, 100.0, 80.0, 60.0) + SPEED_STEPS_MM_S[1:]


def fastest_watched_speed_mm_s(params: TriggerParams, timing: StopTiming, stiffness_g_um: float,
                               limit_g: float) -> float:
    """The fastest of WATCH_SPEED_STEPS_MM_S at which the trigger stops the nozzle meeting a bed of
    `stiffness_g_um` head on at or below `limit_g` (the slowest step when none does).

    A sideways move meeting a blob's 45-degree flank loads the nozzle as fast as a Z move at the
    same speed meets the bed; the caller scales by the move's direction."""
    for speed in WATCH_SPEED_STEPS_MM_S:
        if predict_stop(params, timing, speed, stiffness_g_um).peak_force_g <= limit_g:
            return speed
    return WATCH_SPEED_STEPS_MM_S[-1]


# The config-load check needs no calibration: forces are in grams, any scale will do.
NOMINAL_COUNTS_PER_GRAM = 100.0
# The highest cutoff that no longer hides the tap is looked for in steps of this factor, down to this.
CUTOFF_SEARCH_STEP = 0.8
LOWEST_SUGGESTED_CUTOFF_HZ = 0.1


def unprotected_hiding_speeds(params: TriggerParams, timing: StopTiming, speeds_mm_s) -> list[float]:
    """Speeds at which the filtered force never reaches the trigger on the softest bed and no raw
    window stops the nozzle at or below force_safety_limit (the config-load check)."""
    hiding = []
    for speed in speeds_mm_s:
        prediction = predict_stop(params, timing, speed, SOFTEST_STIFFNESS_G_UM)
        if prediction.hidden and exceeds_limit(prediction, params.force_safety_limit_g):
            hiding.append(speed)
    return hiding


def hiding_filter_refusal(cutoff_hz: float, speed_mm_s: float, options, allowed_hz: float) -> str:
    """Why drift_filter_cutoff_frequency is refused at config load, and what is allowed."""
    return (f"{cutoff_hz:g} Hz hides a tap at {speed_mm_s:g} mm/s: on a soft bed ({SOFTEST_STIFFNESS_G_UM:g} g/um) "
            f"the filtered force never reaches trigger_force ({options.trigger_force_g:g}g), and no safety limit "
            f"stops the nozzle at or below force_safety_limit ({options.force_safety_limit_g:g}g; "
            f"drift_safety_limit is {options.drift_safety_limit_g:g}g); allowed: a cutoff of at most "
            f"{allowed_hz:.2g} Hz, or a drift_safety_limit that stops the move (e.g. 1000)")


# -- the sensor itself ---------------------------------------------------------------------------

def sensor_fault(counts: np.ndarray, counts_range: scale.CountsRange, stuck_samples: int) -> str | None:
    """'saturated' when the newest sample sits at a limit of the ADC's range, 'stuck' when the
    newest `stuck_samples` raw samples are identical (the firmware's rule for this sensor, which a
    live sensor never meets: tapcell.mcu.sensors.stuck_sample_count), else None."""
    counts = np.asarray(counts)
    if counts.size == 0:
        return None
    if scale.saturated_mask(counts[-1:], counts_range)[0]:
        return "saturated"
    if counts.size >= stuck_samples and np.all(counts[-stuck_samples:] == counts[-1]):
        return "stuck"
    return None


def sensor_fault_message(fault: str, counts: np.ndarray, z_min_mm: float) -> str:
    """Why a probing move failed when the sensor itself did (stuck or saturated samples)."""
    last = int(np.asarray(counts)[-1])
    if fault == "saturated":
        return (f"the load cell reading is at the end of the ADC's range ({last} counts, saturated) during the "
                "probing move: the force cannot be measured; check the sensor wiring, its gain and the cell")
    run = int(np.argmax(np.asarray(counts)[::-1] != last)) or len(counts)
    return (f"the load cell reading stopped changing during the probing move ({run} samples in a row at {last} "
            f"counts): the sensor is stuck and no force could be seen (the move went on toward Z={z_min_mm:.3f}); "
            "check the sensor and its wiring")


def speed_refusal(params: TriggerParams, timing: StopTiming, speed_mm_s: float, prediction: StopPrediction,
                  stiffness_g_um: float, measured: bool, slower_mm_s: float | None) -> str:
    """Why a probing speed is refused, and the speed to use instead."""
    bed = (f"a bed of up to {stiffness_g_um:.1f} g/um ({'measured by the taps, with a margin' if measured else 'assumed until a tap measures it'})")
    latency_ms = timing.stop_latency_s * 1000.0
    if prediction.stopped_by is None:
        why = (f"probing at {speed_mm_s:g} mm/s refused: nothing would stop the nozzle, the filtered force stays below "
               f"trigger_force ({params.trigger_force_g:g}g) on a soft bed (the drift filter removes a slow "
               "tap) and no safety limit is on to stop it")
    else:
        travel_um = speed_mm_s * 1000.0 * timing.period_s
        why = (f"probing at {speed_mm_s:g} mm/s refused: it could press the bed with up to {prediction.peak_force_g:.0f}g, more "
               f"than force_safety_limit ({params.force_safety_limit_g:.0f}g): at {timing.sample_rate_sps:g} samples/s "
               f"the nozzle moves {travel_um:.1f} um per sample into {bed}, and {latency_ms:g} ms more before the "
               "steppers stop")
        if prediction.hidden:
            why += " (the drift filter hides the tap: only a safety limit stops the move)"
        elif prediction.stopped_by == TriggerError.STUCK_SENSOR:
            run = params.effective_stuck_samples
            why += (f" (should the sensor stick as the nozzle meets the bed, the firmware stops the move after "
                    f"{run} identical samples, {run * timing.period_s * 1000.0:g} ms: stuck_sensor_samples)")
    advice = (f"probe at {slower_mm_s:g} mm/s or slower" if slower_mm_s is not None
              else "no slower speed is safe: lower drift_filter_cutoff_frequency or set a drift_safety_limit")
    return f"{why}; {advice}"


# -- trigger-only results ------------------------------------------------------------------------

# After the halt the force must stay at least this share of the trigger force, in compression,
# on every sample of the check: a real contact keeps pressing until the nozzle lifts.
CONTACT_HOLD_SHARE = 0.5
CONTACT_CHECK_SAMPLES = 4
# Two trigger-only heights of one spot agree within this, plus the lag of the faster move.
AGREEMENT_MM = 0.05


def contact_holds(force_after_halt_g: np.ndarray, threshold_g: float) -> bool:
    """Whether the force read in the CONTACT_CHECK_SAMPLES periods after a trigger-only halt is
    that of a nozzle pressing on the bed (one sample may be missing: read jitter)."""
    force = np.asarray(force_after_halt_g, dtype=float)
    return force.size >= CONTACT_CHECK_SAMPLES - 1 and bool(np.all(force >= CONTACT_HOLD_SHARE * threshold_g))


def trigger_lag_mm(timing: StopTiming, speed_mm_s: float) -> float:
    """How far a move travels between a contact and the halt, beyond the trigger depth: up to 1.5
    conversion windows, the pipeline, the read delay and the stop latency."""
    return speed_mm_s * (1.5 * timing.period_s + timing.pipeline_s + timing.read_delay_s + timing.stop_latency_s)


def agreement_tolerance_mm(timing: StopTiming, *speeds_mm_s: float) -> float:
    """How far two trigger-only heights of one spot, taken at these speeds, may differ."""
    return AGREEMENT_MM + trigger_lag_mm(timing, max(speeds_mm_s))
