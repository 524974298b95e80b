"""`[load_cell_probe]` probing options and the small pure rules around one tap.

Kept apart from the device (`tapcell.extras.load_cell_probe.device`) so the option table and the rules
(tare length, pullback speed default, force safety check) are testable on their own.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from tapcell.mcu.trigger import TriggerError
from tapcell.extras.probe.options import OptionSpec
from tapcell.tap.angles import slope_angle_deg
from tapcell.tap.model import ANALYSIS_RANGES, AnalysisOptions
from tapcell.tap.robust import robust_sigma

# Every load-cell probing error starts with this (the spec's wording).
ERROR_PREFIX = "Load Cell Probe Error: "


def preload_refusal(beyond_g: float, force_safety_limit_g: float) -> str:
    """The spec's refusal when the force before the move is already past force_safety_limit."""
    return (ERROR_PREFIX + f"force of {abs(beyond_g):.0f}g exceeds force_safety_limit "
            f"({force_safety_limit_g:.0f}g) before probing!")


def trigger_error_message(error: TriggerError, force_safety_limit_g: float) -> str:
    """What the user reads when the firmware trigger stopped a probing move with `error`."""
    if error == TriggerError.DRIFT_SAFETY:
        return ERROR_PREFIX + "force exceeded drift_safety_limit before triggering!"
    if error == TriggerError.WATCHDOG_TIMEOUT:
        return ERROR_PREFIX + "timed out waiting for sensor data"
    if error == TriggerError.FORCE_SAFETY:
        return ERROR_PREFIX + f"force exceeded force_safety_limit ({force_safety_limit_g:.0f}g) while probing!"
    return ERROR_PREFIX + f"trigger error {error.name}"


# Defaults of the tap-analysis (classifier) options: the analysis's own.
ANALYSIS_DEFAULTS = AnalysisOptions()


@dataclass(frozen=True)
class TapOptions:
    """The load-cell-specific probing options (None = disabled / computed default)."""

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
    tap_classifier: str = ANALYSIS_DEFAULTS.tap_classifier
    min_tap_quality: float = ANALYSIS_DEFAULTS.min_tap_quality
    decompression_angle: float | None = ANALYSIS_DEFAULTS.decompression_angle
    max_approach_force: float = ANALYSIS_DEFAULTS.max_approach_force
    max_departure_force: float = ANALYSIS_DEFAULTS.max_departure_force
    max_baseline_force_delta: float = ANALYSIS_DEFAULTS.max_baseline_force_delta
    max_dwell_force_drop: float = ANALYSIS_DEFAULTS.max_dwell_force_drop
    contact_onset_um: float = 0.0  # 0: a sharp contact; LOAD_CELL_PROBE_CALIBRATE CALIBRATION=CONTACT_ONSET fits it


def analysis_option_spec(name: str, default=None) -> OptionSpec:
    """An option of the tap analysis: its range (and unless given, its default) from the analysis's table."""
    default = getattr(ANALYSIS_DEFAULTS, name) if default is None else default
    if name not in ANALYSIS_RANGES:
        return OptionSpec(name, name, "str", default)
    allowed = ANALYSIS_RANGES[name]
    limits = ({"above": allowed.low, "below": allowed.high} if allowed.exclusive
              else {"minval": allowed.low, "maxval": allowed.high})
    return OptionSpec(name, name, "optfloat" if default is None else "float", default, **limits)


PULLBACK_LIMITS_MM = (0.01, 2.0)  # pullback_distance's range (also the calibration's PULLBACK_DISTANCE)

# Filter options are range-checked by tapcell.filters (the limits depend on the sample rate).
TAP_OPTION_SPECS: tuple[OptionSpec, ...] = (
    OptionSpec("trigger_force", "trigger_force_g", "float", 75.0, minval=10.0, maxval=250.0),
    OptionSpec("force_safety_limit", "force_safety_limit_g", "float", 2000.0, minval=0.0, maxval=10000.0),
    OptionSpec("drift_safety_limit", "drift_safety_limit_g", "float", 1000.0, minval=0.0, maxval=10000.0),
    OptionSpec("tare_time", "tare_time_s", "float", 4.0 / 60.0, minval=0.01, maxval=1.0),
    OptionSpec("drift_filter_cutoff_frequency", "drift_filter_cutoff_frequency", "optfloat", None),
    OptionSpec("drift_filter_delay", "drift_filter_delay", "int", 2),
    OptionSpec("buzz_filter_cutoff_frequency", "buzz_filter_cutoff_frequency", "optfloat", None),
    OptionSpec("buzz_filter_delay", "buzz_filter_delay", "int", 2),
    OptionSpec("notch_filter_frequencies", "notch_filter_frequencies", "floatlist", None),
    OptionSpec("notch_filter_quality", "notch_filter_quality", "float", 2.0),
    OptionSpec("pullback_distance", "pullback_distance_mm", "float", 0.2,
               minval=PULLBACK_LIMITS_MM[0], maxval=PULLBACK_LIMITS_MM[1]),
    OptionSpec("pullback_speed", "pullback_speed_mm_s", "float", None, minval=0.01, maxval=2.0),
    analysis_option_spec("tap_classifier"),
    analysis_option_spec("min_tap_quality"),
    analysis_option_spec("decompression_angle"),
    analysis_option_spec("max_approach_force"),
    analysis_option_spec("max_departure_force"),
    analysis_option_spec("max_baseline_force_delta"),
    analysis_option_spec("max_dwell_force_drop"),
    analysis_option_spec("contact_onset_um", default=0.0),
)


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


def expected_peak_force_g(trigger_force_g: float, stiffness_g_um: float, speed_mm_s: float,
                          sample_rate_sps: float) -> float:
    """Worst-case force at the halt: the trigger force plus two samples of travel into the bed.

    The trigger acts on a sample averaged over one conversion window and stops the motor only
    after that sample was read, so the nozzle can press up to ~2 samples of travel further.
    """
    travel_um = speed_mm_s * 1000.0 / sample_rate_sps
    return trigger_force_g + 2.0 * travel_um * stiffness_g_um


def safe_speed_mm_s(trigger_force_g: float, stiffness_g_um: float, sample_rate_sps: float,
                    force_limit_g: float) -> float:
    """The speed whose expected peak force is 80 % of the limit."""
    return max(0.8 * force_limit_g - trigger_force_g, 0.0) / (2.0 * stiffness_g_um) * sample_rate_sps / 1000.0


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


# Onset widths tried by the pooled contact-onset calibration (µm): fine where sheets are
# (smooth PEI ~2, textured ~8), coarser up to soft sheets and beyond.
ONSET_GRID_UM = (0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 8.0, 10.0, 12.0, 15.0, 18.0, 22.0, 26.0, 30.0, 35.0, 40.0)
MIN_ONSET_TAPS = 3


@dataclass(frozen=True)
class OnsetCalibration:
    """Result of the pooled contact-onset fit."""

    onset_um: float
    taps: int  # valid taps pooled
    misfit_g2: tuple[float, ...]  # pooled misfit (Σ near-contact residual variance, g²) per grid onset
    z_shift_um: float  # mean change of Z between a sharp contact and the fitted onset


def fit_pooled_contact_onset(taps, options, grid_um=ONSET_GRID_UM) -> OnsetCalibration:
    """The contact-onset width that best explains all the taps together.

    Each tap keeps its own contact height, stiffness and baseline; the onset width is shared.
    For each width on the grid every tap is analysed with that onset fixed (a global contact
    search each), and the near-contact residual variances are summed; the minimum is refined
    by the parabola through it and its neighbours. Per tap, onset and contact height trade off
    (fitting both costs several times the Z spread); pooled over taps the onset is stable.
    `taps`: TapData recorded by the probe; `options`: its AnalysisOptions. ValueError when
    fewer than MIN_ONSET_TAPS taps are valid at every grid width.
    """
    from tapcell.tap import analyze_tap  # the analysis is heavy to import; only this needs it

    grid = np.asarray(grid_um, dtype=float)
    base = dataclasses.replace(options, fit_contact_onset=False, tap_classifier="empty")
    variances = np.full((len(grid), len(taps)), np.nan)
    z_um = np.full((len(grid), len(taps)), np.nan)
    for g, onset_um in enumerate(grid):
        trial = dataclasses.replace(base, contact_onset_um=float(onset_um))
        for i, tap in enumerate(taps):
            result = analyze_tap(tap, trial)
            if result.valid and result.fit_residual_sigma_g is not None and result.z_mm is not None:
                variances[g, i] = result.fit_residual_sigma_g ** 2
                z_um[g, i] = result.z_mm * 1000.0
    usable = np.all(np.isfinite(variances), axis=0)
    if np.count_nonzero(usable) < MIN_ONSET_TAPS:
        raise ValueError(f"only {int(np.count_nonzero(usable))} taps could be analysed at every onset width; "
                         f"at least {MIN_ONSET_TAPS} are needed")
    misfit = variances[:, usable].sum(axis=1)
    best = int(np.argmin(misfit))
    onset_um = float(grid[best])
    if 0 < best < len(grid) - 1:
        onset_um = _parabola_minimum(grid[best - 1:best + 2], misfit[best - 1:best + 2])
    z_sharp = z_um[0, usable]
    z_best = z_um[best, usable]
    return OnsetCalibration(onset_um=round(onset_um, 2), taps=int(np.count_nonzero(usable)),
                            misfit_g2=tuple(float(m) for m in misfit),
                            z_shift_um=float(np.mean(z_best - z_sharp)))


def _parabola_minimum(x: np.ndarray, y: np.ndarray) -> float:
    """Vertex of the parabola through three points (x sorted), clamped to their range."""
    (x0, x1, x2), (y0, y1, y2) = x, y
    denominator = (x0 - x1) * (x0 - x2) * (x1 - x2)
    a = (x2 * (y1 - y0) + x1 * (y0 - y2) + x0 * (y2 - y1)) / denominator
    b = (x2 * x2 * (y0 - y1) + x1 * x1 * (y2 - y0) + x0 * x0 * (y1 - y2)) / denominator
    if a <= 0:
        return float(x1)
    return float(np.clip(-b / (2 * a), x0, x2))


# -- LOAD_CELL_PROBE_CALIBRATE CALIBRATION=PULLBACK_DISTANCE ---------------------------------
# The spec's break-contact rule: break contact must lie in the middle two thirds of the pullback.
BREAK_CONTACT_BAND = (1.0 / 6.0, 5.0 / 6.0)
# Kept clear of both band edges (share of the pullback) on top of 3 sigma of the taps' spread:
# the validator reads break contact to about a sample, and the bed differs a little from place to place.
BREAK_CONTACT_MARGIN = 0.03
# Where the mean break contact is put: the geometric middle of the band, sqrt(1/6 * 5/6) = 37 %.
# Break contact scales with speed and stiffness by factors, so this leaves the same factor
# (sqrt 5 = 2.24) of room for it to grow (faster probing, stiffer place) as to shrink.
BREAK_CONTACT_TARGET_SHARE = math.sqrt(BREAK_CONTACT_BAND[0] * BREAK_CONTACT_BAND[1])
# Taps with this pullback measure where break contact is; it is far longer than any bed needs.
CALIBRATION_PULLBACK_MM = 0.4
MIN_CALIBRATION_TAPS = 3
# This share of the taps must be usable, or the taps are not good enough to calibrate on.
MIN_USABLE_SHARE = 0.8


def min_usable_taps(samples: int) -> int:
    """Taps out of `samples` that a calibration needs (at least MIN_CALIBRATION_TAPS)."""
    return max(MIN_CALIBRATION_TAPS, math.ceil(MIN_USABLE_SHARE * samples - 1e-9))


def break_contact_height_um(break_contact_time_s: float, sensor_delay_s: float, integration_s: float,
                            motion) -> float:
    """Height of break contact above the halt (µm), at the time the validator judges it.

    The analysis reports break contact as the time of the sample that shows it; the motion
    there is the sensor delay and half a conversion window earlier (what the middle-two-thirds
    check uses). `motion`: the tap's `tapcell.tap.motion.Motion`.
    """
    t_s = break_contact_time_s - sensor_delay_s - 0.5 * integration_s
    return (float(motion.z_at(t_s)) - motion.z_halt_mm) * 1000.0


@dataclass(frozen=True)
class PullbackCalibration:
    """Result of the pullback-distance rule (heights in µm above the halt)."""

    pullback_distance_mm: float
    taps: int
    break_mean_um: float
    break_sigma_um: float
    break_min_um: float
    break_max_um: float

    def share(self, height_um: float) -> float:
        """Where a break-contact height lies in the proposed pullback (0..1)."""
        return height_um / (self.pullback_distance_mm * 1000.0)


def break_contact_spread_um(sigma_um: float, speed_mm_s: float, sample_rate_sps: float) -> float:
    """Half-width of the break-contact heights a pullback must hold: 3σ of the taps, and at least
    half a sample of approach travel (contact falls anywhere within a sample, so the halt, and
    break contact with it, scatters by up to one sample of travel: 16 µm at 10 mm/s, 320 sps)."""
    return max(3.0 * sigma_um, 0.5 * speed_mm_s * 1000.0 / sample_rate_sps)


def _break_band_um(pullback_um: float) -> tuple[float, float]:
    """The margined middle two thirds of a pullback, in µm above the halt."""
    return ((BREAK_CONTACT_BAND[0] + BREAK_CONTACT_MARGIN) * pullback_um,
            (BREAK_CONTACT_BAND[1] - BREAK_CONTACT_MARGIN) * pullback_um)


def propose_pullback_distance(break_heights_um, speed_mm_s: float, sample_rate_sps: float) -> PullbackCalibration:
    """The pullback_distance that puts break contact near the middle of the pullback.

    The mean break contact goes to BREAK_CONTACT_TARGET_SHARE of the pullback (37 %), unless
    mean ± spread (`break_contact_spread_um`: 3σ, at least half a sample of travel) would then
    leave the middle two thirds shrunk by BREAK_CONTACT_MARGIN on each side; then the nearest
    pullback that keeps them inside. With P the pullback:
    mean + spread ≤ (5/6 − margin)·P and mean − spread ≥ (1/6 + margin)·P. Rounded to 1 µm.
    ValueError (saying why and what to do) when fewer than MIN_CALIBRATION_TAPS heights are
    given, when no pullback satisfies both (the spread is too large), or when the result
    leaves the option's range.
    """
    heights = np.asarray(break_heights_um, dtype=float)
    if len(heights) < MIN_CALIBRATION_TAPS:
        raise ValueError(f"only {len(heights)} break-contact heights; at least {MIN_CALIBRATION_TAPS} are needed")
    mean_um, sigma_um = float(np.mean(heights)), float(np.std(heights))
    spread_um = break_contact_spread_um(sigma_um, speed_mm_s, sample_rate_sps)
    low_um, high_um = mean_um - spread_um, mean_um + spread_um
    low_share, high_share = (share / 1000.0 for share in _break_band_um(1000.0))
    shortest_um, longest_um = high_um / high_share, low_um / low_share
    if low_um <= 0 or shortest_um > longest_um:
        raise ValueError(
            f"break contact scatters too much: {mean_um:.1f} um +- {spread_um:.1f} um (3 sigma, at least half a "
            f"sample of travel) is {low_um:.1f}..{high_um:.1f} um above the halt, and no pullback keeps that range "
            f"inside {low_share:.0%}..{high_share:.0%} of it (the spec's middle two thirds less a "
            f"{BREAK_CONTACT_MARGIN:.0%} margin each side); clean the nozzle (NOZZLE_CLEANUP), check that the sheet "
            "lies flat and the toolhead is rigid, probe slower, and calibrate again")
    pullback_um = float(np.clip(mean_um / BREAK_CONTACT_TARGET_SHARE, shortest_um, longest_um))
    pullback_mm = round(pullback_um) / 1000.0
    lowest_mm, highest_mm = PULLBACK_LIMITS_MM
    if not lowest_mm <= pullback_mm <= highest_mm:
        raise ValueError(f"break contact {mean_um:.1f} um above the halt needs a pullback_distance of "
                         f"{pullback_mm:.3f} mm, outside the option's {lowest_mm:g}..{highest_mm:g} mm; check "
                         "trigger_force and the probing speed")
    return PullbackCalibration(pullback_distance_mm=pullback_mm, taps=len(heights), break_mean_um=mean_um,
                               break_sigma_um=sigma_um, break_min_um=float(heights.min()),
                               break_max_um=float(heights.max()))


SPEED_GRID_MM_S = np.round(np.arange(0.1, 50.0001, 0.1), 1)  # speeds the coverage estimate looks at


def covered_speed_range_mm_s(found: PullbackCalibration, speed_mm_s: float, sample_rate_sps: float,
                             trigger_depth_um: float) -> tuple[float, float]:
    """Probing speeds (mm/s, on a 0.1 mm/s grid up to 50) that this pullback suits.

    Break contact grows with speed: the nozzle presses trigger_depth_um (trigger force /
    stiffness) into the bed before the trigger fires, then travels on for the trigger's
    latency τ, read off the calibration: height(v) = trigger_depth + τ·v with
    τ = (break_mean − trigger_depth) / speed (0 when break contact is not deeper). A speed is
    suited when height(v) ± break_contact_spread_um stays in the margined middle two thirds.
    Returns the contiguous range around the calibration speed. An estimate from one speed.
    """
    low_um, high_um = _break_band_um(found.pullback_distance_mm * 1000.0)
    latency_s = max(0.0, (found.break_mean_um - trigger_depth_um) / (speed_mm_s * 1000.0))
    speeds = np.union1d(SPEED_GRID_MM_S, [speed_mm_s])
    heights = trigger_depth_um + latency_s * speeds * 1000.0
    spreads = np.array([break_contact_spread_um(found.break_sigma_um, v, sample_rate_sps) for v in speeds])
    suited = (heights - spreads >= low_um) & (heights + spreads <= high_um)
    at = int(np.searchsorted(speeds, speed_mm_s))
    first = last = at
    while first > 0 and suited[first - 1]:
        first -= 1
    while last < len(speeds) - 1 and suited[last + 1]:
        last += 1
    return float(speeds[first]), float(speeds[last])


# -- LOAD_CELL_PROBE_CALIBRATE CALIBRATION=DECOMPRESSION_ANGLE -------------------------------
# The calibration taps' angles may lie at most this far (share of the median) from their median:
# each such tap would already lose this much quality; ooze or a loose sheet moves it 7 % or more.
MAX_ANGLE_SPREAD = 0.03


def decompression_angle_deg(decompression_slope_g_s: float) -> float:
    """|atan(slope · 0.004 s/g)| in degrees, as the quality classifier measures it.

    The slope is the bed's stiffness times the pullback speed, so the angle holds only for the
    pullback_speed (default: 1 µm per sample, i.e. the sample rate) it was calibrated at.
    """
    return abs(slope_angle_deg(decompression_slope_g_s))


@dataclass(frozen=True)
class AngleCalibration:
    angle_deg: float  # the median
    taps: int
    min_deg: float
    max_deg: float
    spread: float  # largest |angle − median| / median


def calibrate_decompression_angle(angles_deg) -> AngleCalibration:
    """The median decompression angle of clean taps; ValueError (why, what to do) when there
    are fewer than MIN_CALIBRATION_TAPS or they scatter more than MAX_ANGLE_SPREAD."""
    angles = np.asarray(angles_deg, dtype=float)
    if len(angles) < MIN_CALIBRATION_TAPS:
        raise ValueError(f"only {len(angles)} decompression angles; at least {MIN_CALIBRATION_TAPS} are needed")
    median = float(np.median(angles))
    spread = float(np.max(np.abs(angles - median)) / median)
    if spread > MAX_ANGLE_SPREAD:
        raise ValueError(
            f"decompression angles scatter too much: {angles.min():.2f}..{angles.max():.2f} deg around "
            f"{median:.2f} deg ({spread:.1%} from the median, at most {MAX_ANGLE_SPREAD:.0%} allowed); some taps "
            "were fouled or the sheet moved: clean the nozzle (NOZZLE_CLEANUP), cool it below the ooze point, "
            "check the sheet, and calibrate again")
    return AngleCalibration(angle_deg=round(median, 2), taps=len(angles), min_deg=float(angles.min()),
                            max_deg=float(angles.max()), spread=spread)
