"""`[load_cell_probe]` probing options and the small pure rules around one tap.

Kept apart from the device (`tapcell.extras.load_cell_probe.device`) so the option table and the rules
(tare length, pullback speed default, force safety check) are testable on their own.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from tapcell.filters import (DRIFT_CUTOFF_MAX_HZ, DRIFT_CUTOFF_MIN_HZ, FILTER_ORDERS, NOTCH_QUALITY_MAX,
                             NOTCH_QUALITY_MIN)
from tapcell.mcu.trigger import MAX_STUCK_SAMPLES, TriggerError
from tapcell.extras.probe.options import OptionSpec, read_section_values, with_overrides
from tapcell.tap.model import ANALYSIS_RANGES, CONFIG_OPTIONS, CONTACT_MODELS, AnalysisOptions
from tapcell.tap.robust import robust_sigma

# Every load-cell probing error starts with this (the spec's wording).
ERROR_PREFIX = "Load Cell Probe Error: "
# The spec's "Load Cell not calibrated", and the command that fixes it.
NOT_CALIBRATED = "Load Cell not calibrated: run LOAD_CELL_CALIBRATE (then SAVE_CONFIG to keep it)"


def preload_refusal(beyond_g: float, force_safety_limit_g: float) -> str:
    """The spec's refusal when the force before the move is already past force_safety_limit."""
    return (ERROR_PREFIX + f"force of {abs(beyond_g):.0f}g exceeds force_safety_limit "
            f"({force_safety_limit_g:.0f}g) before probing!")


def trigger_error_message(error: TriggerError, force_safety_limit_g: float, stuck_samples: int = 0) -> str:
    """What the user reads when the firmware trigger stopped a probing move with `error`."""
    if error == TriggerError.STUCK_SENSOR:
        return (ERROR_PREFIX + f"load cell reads a constant value ({stuck_samples} identical samples in a row "
                "while probing): sensor stuck! Check the sensor's wiring and power (see stuck_sensor_samples)")
    if error == TriggerError.DRIFT_SAFETY:
        return ERROR_PREFIX + "force exceeded drift_safety_limit before triggering!"
    if error == TriggerError.WATCHDOG_TIMEOUT:
        return ERROR_PREFIX + "timed out waiting for sensor data"
    if error == TriggerError.FORCE_SAFETY:
        return ERROR_PREFIX + f"force exceeded force_safety_limit ({force_safety_limit_g:.0f}g) while probing!"
    return ERROR_PREFIX + f"trigger error {error.name}"


@dataclass(frozen=True)
class TapOptions:
    """The load-cell-specific probing options (None = disabled / computed default), the tap
    analysis's in `analysis`."""

    trigger_force_g: float = 75.0
    force_safety_limit_g: float = 2000.0
    drift_safety_limit_g: float = 1000.0
    tare_time_s: float = 4.0 / 60.0
    drift_filter_cutoff_frequency: float | None = None
    drift_filter_delay: int = 2
    buzz_filter_cutoff_frequency: float | None = None
    buzz_filter_delay: int = 2
    notch_filter_frequencies: tuple[float, ...] | None = None
    notch_filter_quality: float = 2.0
    pullback_distance_mm: float = 0.2
    pullback_speed_mm_s: float | None = None
    stuck_sensor_samples: int | None = None  # None: from the sensor's noise floor; 0: off
    # The tap-analysis options of the config (tapcell.tap.model.CONFIG_OPTIONS); the printer sets the
    # rest per command (`tap_analysis_options`: the trigger force, the mains hum).
    analysis: AnalysisOptions = field(default_factory=AnalysisOptions)


def analysis_option_spec(name: str) -> OptionSpec:
    """An option of the tap analysis: its default and range from the analysis's own table."""
    default = getattr(AnalysisOptions(), name)
    if name == "contact_model":
        return OptionSpec(name, name, "choice", default, choices=CONTACT_MODELS)
    if name not in ANALYSIS_RANGES:
        if not isinstance(default, str):  # a config option of another kind needs its reader here
            raise TypeError(f"analysis option {name}: no config reader for {type(default).__name__} values")
        return OptionSpec(name, name, "str", default)
    return OptionSpec(name, name, "optfloat" if default is None else "float", default, **ANALYSIS_RANGES[name].limits())


PULLBACK_LIMITS_MM = (0.01, 2.0)  # pullback_distance's range (also the calibration's PULLBACK_DISTANCE)

# The filter options' ranges here are the widest any sample rate allows (the fastest chip,
# an ADS1220 at 2000 sps, has its half rate at 1000 Hz); tapcell.filters then checks them
# against the configured sample rate and each other.
FILTER_HALF_RATE_MAX_HZ = 1000.0
TAP_OPTION_SPECS: tuple[OptionSpec, ...] = (
    OptionSpec("trigger_force", "trigger_force_g", "float", 75.0, minval=10.0, maxval=250.0),
    OptionSpec("force_safety_limit", "force_safety_limit_g", "float", 2000.0, minval=0.0, maxval=10000.0),
    OptionSpec("drift_safety_limit", "drift_safety_limit_g", "float", 1000.0, minval=0.0, maxval=10000.0),
    OptionSpec("tare_time", "tare_time_s", "float", 4.0 / 60.0, minval=0.01, maxval=1.0),
    OptionSpec("drift_filter_cutoff_frequency", "drift_filter_cutoff_frequency", "optfloat", None,
               minval=DRIFT_CUTOFF_MIN_HZ, maxval=DRIFT_CUTOFF_MAX_HZ),
    OptionSpec("drift_filter_delay", "drift_filter_delay", "int", 2, minval=min(FILTER_ORDERS),
               maxval=max(FILTER_ORDERS)),
    OptionSpec("buzz_filter_cutoff_frequency", "buzz_filter_cutoff_frequency", "optfloat", None,
               above=0.0, below=FILTER_HALF_RATE_MAX_HZ),
    OptionSpec("buzz_filter_delay", "buzz_filter_delay", "int", 2, minval=min(FILTER_ORDERS),
               maxval=max(FILTER_ORDERS)),
    OptionSpec("notch_filter_frequencies", "notch_filter_frequencies", "floatlist", None,
               above=0.0, below=FILTER_HALF_RATE_MAX_HZ),
    OptionSpec("notch_filter_quality", "notch_filter_quality", "float", 2.0, minval=NOTCH_QUALITY_MIN,
               maxval=NOTCH_QUALITY_MAX),
    OptionSpec("pullback_distance", "pullback_distance_mm", "float", 0.2,
               minval=PULLBACK_LIMITS_MM[0], maxval=PULLBACK_LIMITS_MM[1]),
    OptionSpec("pullback_speed", "pullback_speed_mm_s", "float", None, minval=0.01, maxval=2.0),
    # 1 is refused too (check_stuck_sensor_samples): a run of one sample is every sample.
    OptionSpec("stuck_sensor_samples", "stuck_sensor_samples", "int", None, minval=0, maxval=MAX_STUCK_SAMPLES),
)
# TapOptions.analysis's fields: read from the config and overridden by G-code like the rest, with the
# analysis's defaults and ranges (what `tapcell analyze --set` checks).
ANALYSIS_OPTION_SPECS: tuple[OptionSpec, ...] = tuple(analysis_option_spec(name) for name in CONFIG_OPTIONS)
# The load-cell guide names the classifier option `tap_classifier_module`; Kalico reads
# `tap_classifier`. A config may use either name, not both.
GUIDE_CLASSIFIER_OPTION = "tap_classifier_module"


def classifier_option(section) -> str:
    """The name this config gives the classifier option: the guide's, or Kalico's `tap_classifier`."""
    return GUIDE_CLASSIFIER_OPTION if section.has_option(GUIDE_CLASSIFIER_OPTION) else "tap_classifier"


def read_tap_options(section) -> TapOptions:
    """`[load_cell_probe]`'s tap options (TAP_OPTION_SPECS, ANALYSIS_OPTION_SPECS), the guide's classifier
    name included."""
    own = read_section_values(section, TAP_OPTION_SPECS)
    analysis = read_section_values(section, ANALYSIS_OPTION_SPECS)
    if classifier_option(section) == GUIDE_CLASSIFIER_OPTION:
        if section.has_option("tap_classifier"):
            raise section.error(GUIDE_CLASSIFIER_OPTION,
                                "the same option as tap_classifier (the guide's name for it): give one of them")
        analysis["tap_classifier"] = section.get(GUIDE_CLASSIFIER_OPTION).strip()
    return TapOptions(**own, analysis=AnalysisOptions(**analysis))


def tap_options_with_overrides(options: TapOptions, gcmd) -> TapOptions:
    """A probing command's options: `options` with its G-code overrides (the same object when none)."""
    changed = with_overrides(options, TAP_OPTION_SPECS, gcmd)
    analysis = with_overrides(options.analysis, ANALYSIS_OPTION_SPECS, gcmd)
    return changed if analysis is options.analysis else dataclasses.replace(changed, analysis=analysis)


def replace_tap_options(options: TapOptions, **changes) -> TapOptions:
    """`options` with fields changed by name, a TapOptions field's or else its analysis's
    (`contact_onset_um=...`, `pullback_distance_mm=...`)."""
    own = {f.name for f in dataclasses.fields(TapOptions)}
    analysis = {k: v for k, v in changes.items() if k not in own}
    if analysis:
        changes = {k: v for k, v in changes.items() if k in own}
        changes["analysis"] = dataclasses.replace(options.analysis, **analysis)
    return dataclasses.replace(options, **changes)


@dataclass
class TapSettings:
    """Everything one command's taps use: options with overrides, designed filter, analysis options."""

    options: TapOptions
    sos: Any  # tapcell.filters.QuantizedSos | None
    pullback_speed_mm_s: float
    analysis: AnalysisOptions


def tap_analysis_options(options: TapOptions) -> AnalysisOptions:
    """What a tap is analysed with: the config's analysis options, the trigger force and the mains hum."""
    return dataclasses.replace(options.analysis, trigger_force_g=options.trigger_force_g,
                               mains_hz=mains_lines_hz(options))


def mains_lines_hz(options: TapOptions) -> tuple[float, ...] | str:
    """The hum the analysis removes: the notch filter's frequencies when configured (the user
    named the hum), else "auto" (50 or 60 Hz when the tap clearly holds it)."""
    return tuple(options.notch_filter_frequencies) if options.notch_filter_frequencies else "auto"


STUCK_SENSOR_SAMPLES_ALLOWED = f"0 (disabled) or 2 .. {MAX_STUCK_SAMPLES}"


def check_stuck_sensor_samples(value: int | None, make_error) -> None:
    """stuck_sensor_samples: 0 or 2 .. 65535 (the config/G-code range check lets 1 through)."""
    if value == 1:
        raise make_error(f"1 is not allowed; allowed: {STUCK_SENSOR_SAMPLES_ALLOWED}")


def default_pullback_speed_mm_s(sample_rate_sps: float) -> float:
    """1 µm of pullback per sample: the decompression is scanned at ~1 µm resolution."""
    return sample_rate_sps * 0.001


# Halt to pullback. At least the sample whose window holds the halt, two for the dwell line and
# one margin for read jitter (2 gives TAP_CHRONOLOGY on a stiff sheet). And at least
# DWELL_MIN_S: a soft sheet relaxes (8 %) and rounds the corners over its 25 µm onset, and a
# shorter dwell line lets the split swap P2/P3 (TAP_CHRONOLOGY). Measured at 320 sps
# (PROBE_ACCURACY SAMPLES=20): 12.5 ms fails every soft-sheet tap at 5-10 mm/s, 25 ms 15 % at
# 10 mm/s, 31 ms none at 2-10 mm/s. A time, not a sample count: at 80 sps ten samples (125 ms)
# would let a tap far too fast for the sensor pass as valid (-109 µm at 8 mm/s), while 4 samples
# reject it. Cost at 320 sps: 19 ms per tap (0.661 -> 0.680 s at 5 mm/s).
DWELL_MIN_SAMPLES = 4
DWELL_MIN_S = 0.031


def dwell_sample_count(sample_rate_sps: float) -> int:
    """Samples to dwell between the halt and the pullback (10 at 320 sps, 4 at 80 sps)."""
    return max(DWELL_MIN_SAMPLES, math.ceil(DWELL_MIN_S * sample_rate_sps - 1e-9))


def tare_sample_count(tare_time_s: float, sample_rate_sps: float) -> int:
    return max(2, math.ceil(tare_time_s * sample_rate_sps - 1e-9))


# The firmware stops a move on the first raw sample past force_safety_limit, with no quarantine,
# so a single corrupted frame stops it too; and a frame under drift_safety_limit (which the
# firmware quarantines) but past trigger_force triggers the probe. A stop by one sample whose
# neighbours both read near 0 is such a frame (a real force cannot come and go within two
# samples: after the halt the nozzle stays pressed): the move is tried again, going on down from
# where it stopped. A real over-limit press is never one: the sample after it still reads it.
#
# How many the move goes on after: more than CORRUPT_FRAME_RETRIES within CORRUPT_FRAME_WINDOW_S
# end it naming the sensor. The count is not a safety limit (each frame was shown to be alone);
# it names a sensor that corrupts frames often. At the `glitchy` cable's rate (0.5 frames/s at
# random) a third frame within 0.5 s comes once every 75 s of moving (the budget was 2: G28 Z's
# first tap on an unmeasured bed runs 12 s at 0.8 mm/s, and glitchy seed 6 failed so), a fifth
# once in about 4 h, while a sensor corrupting 20 frames/s is named after 0.26 s and one
# corrupting 5/s after 1.4 s (medians; tests/probe/test_glitchy_homing.py runs the budget on them).
CORRUPT_FRAME_RETRIES = 4
CORRUPT_FRAME_WINDOW_S = 0.5
# A trigger is a corrupted frame when the samples around it read under this part of trigger_force
# (in contact after the halt they read at least about trigger_force).
QUIET_PART_OF_TRIGGER = 0.5


def lone_frame(t_s: np.ndarray, force_g: np.ndarray, past: np.ndarray, armed_s: float, quiet_g: float,
               stop_time_s: float | None = None) -> int | None:
    """Index of the corrupted frame that stopped a move armed at `armed_s`, else None.

    It is the first sample read at or after `armed_s` (the firmware ignores older ones; a frame
    an earlier attempt moved on from is not this one) that is `past` the level that stopped the
    move, when it stands alone: the sample before it and every sample after it up to the one after
    `stop_time_s` (the triggering sample, filters delay a trigger; None: the frame itself)
    read under `quiet_g`. Without a sample on each side it is not judged alone.
    """
    seen = np.flatnonzero(past & (t_s >= armed_s))
    if seen.size == 0 or seen[0] == 0:
        return None
    first = int(seen[0])
    last = first + 1
    if stop_time_s is not None:
        last = max(last, int(np.searchsorted(t_s, stop_time_s)) + 1)
    if last >= len(force_g) or np.any(np.abs(force_g[[first - 1, *range(first + 1, last + 1)]]) >= quiet_g):
        return None
    return first


class CorruptFrameBudget:
    """When the corrupted frames that stopped one move were moved on from: allows another while
    at most CORRUPT_FRAME_RETRIES came within CORRUPT_FRAME_WINDOW_S."""

    def __init__(self):
        self.stops_s: list[float] = []

    def allows_another(self, now_s: float) -> bool:
        """Counts a frame at `now_s`; False when it is one too many."""
        self.stops_s = [t for t in self.stops_s if t > now_s - CORRUPT_FRAME_WINDOW_S] + [now_s]
        return len(self.stops_s) <= CORRUPT_FRAME_RETRIES


def force_beyond_safety_limit_g(tare_counts: float, reference_tare_counts: int, counts_per_gram: float,
                                limit_g: float) -> float | None:
    """The force (g, relative to the calibration zero) when it is beyond the limit, else None."""
    force_g = (tare_counts - reference_tare_counts) / counts_per_gram
    if limit_g > 0 and abs(force_g) >= limit_g:
        return force_g
    return None


# A tare sample further than this many robust sigmas from the median is a corrupted frame.
TARE_OUTLIER_SIGMAS = 8.0


def robust_tare_counts(counts: np.ndarray) -> float:
    """Mean of the tare samples after dropping corrupted frames (single flipped bits).

    One flipped high bit adds 2^16..2^22 counts (hundreds of grams or more): averaged in, it
    would shift the tare enough to trip the safety limit or trigger at once. Samples further
    than TARE_OUTLIER_SIGMAS robust sigmas (1.4826 x median absolute deviation, at least 1
    count) from the median are left out; honest noise never is.
    """
    counts = np.asarray(counts, dtype=float)
    median = float(np.median(counts))
    sigma = max(robust_sigma(counts - median), 1.0)
    kept = counts[np.abs(counts - median) <= TARE_OUTLIER_SIGMAS * sigma]
    return float(np.mean(kept))


def too_fast_explanation(force_before_g: float, force_at_error_g: float, trigger_force_g: float,
                         drift_safety_limit_g: float, speed_mm_s: float, sample_rate_sps: float) -> str | None:
    """Why drift_safety_limit tripped, when the cause is probing too fast for the sensor.

    The trigger can only act on a sample. When the sample before the error was still below
    the trigger force and the step was at least half the limit, the force jumped past
    drift_safety_limit within one sample period: the nozzle travels too far per sample.
    Returns None for a real drift (a slow rise).
    """
    jump_g = abs(force_at_error_g - force_before_g)
    if abs(force_before_g) >= trigger_force_g or jump_g < 0.5 * drift_safety_limit_g:
        return None
    travel_um = speed_mm_s * 1000.0 / sample_rate_sps
    # Half the speed that would keep one sample's jump at the limit: room for the trigger's own latency.
    suggested_mm_s = 0.5 * speed_mm_s * drift_safety_limit_g / jump_g if jump_g > 0 else speed_mm_s
    return (f"the force jumped from {force_before_g:.0f}g to {force_at_error_g:.0f}g within one sample: "
            f"at {speed_mm_s:g} mm/s and {sample_rate_sps:g} samples/s the nozzle moves {travel_um:.1f} um "
            f"per sample, too far for the trigger to stop it; probe at {suggested_mm_s:.1f} mm/s or slower "
            "(or use a faster sensor)")


def too_fast_for_analysis(force_before_trigger_g: float, force_at_trigger_g: float, peak_force_g: float,
                          trigger_force_g: float, speed_mm_s: float, sample_rate_sps: float,
                          pullback_distance_mm: float, stiffness_g_um: float | None = None) -> str | None:
    """Why a bad tap may be the speed's fault: the compression happened between two samples.

    The trigger sample is the first at or above the trigger force. When the force rose by
    more than the trigger force within that one sample, the whole compression up to the
    trigger fell between two samples: the analysis has no samples on the compression line to
    find where contact began, and the nozzle goes on pressing until the halt (over-travel).
    The bed's stiffness comes from earlier taps when known, else from that one-sample jump
    (a full sample in contact rises by stiffness x travel per sample; a partial one by less,
    so the estimate is low and the over-travel estimate high). Returns None otherwise.
    """
    jump_g = force_at_trigger_g - force_before_trigger_g
    if jump_g < trigger_force_g or speed_mm_s <= 0:
        return None
    travel_um = speed_mm_s * 1000.0 / sample_rate_sps
    k_g_um = stiffness_g_um if stiffness_g_um else jump_g / travel_um
    contact_to_trigger_um = trigger_force_g / k_g_um
    over_travel_um = peak_force_g / k_g_um
    pullback_um = pullback_distance_mm * 1000.0
    # The speed at which the force takes one full sample to reach the trigger force.
    suggested_mm_s = contact_to_trigger_um * sample_rate_sps / 1000.0
    why = (f"probing too fast for this sensor: at {speed_mm_s:g} mm/s and {sample_rate_sps:g} samples/s the nozzle "
           f"moves {travel_um:.1f} um per sample, but on this bed (about {k_g_um:.1f} g/um) the force reaches the "
           f"{trigger_force_g:.0f}g trigger {contact_to_trigger_um:.0f} um after first contact: it jumped from "
           f"{force_before_trigger_g:.0f}g to {force_at_trigger_g:.0f}g within one sample, so no sample shows the "
           f"compression and the tap cannot be analysed; the nozzle stopped about {over_travel_um:.0f} um past "
           f"first contact, pressing {peak_force_g:.0f}g")
    if over_travel_um >= 0.75 * pullback_um:
        why += (f", more than 3/4 of the {pullback_distance_mm:g} mm pullback, so it leaves the bed late in the "
                "pullback or not at all")
    return why + f"; probe at {suggested_mm_s:.1f} mm/s or slower (or use a faster sensor)"
