"""Analysis of one tap: five lines and six points, Z at break contact, validation.

Steps (each a plain function; `analyze_tap` is the shell that runs them):
1. motion (phase times) from the moves or the z trace, sensor timing from options/meta;
2. polarity, then single corrupted frames repaired (robust spike test);
3. the globally optimal five-line split over windows the motion allows (segments.py);
4. points, chronology, shape and break-contact timing checks (validate.py);
5. Z: the contact model (contact.py) fitted to the pullback in Z space, with the sensor's
   conversion window and delay removed, and its 1 sigma; the line intersection P4 is kept as
   `z_line_mm` and used when the model cannot be fitted;
6. the sensor delay estimated from the tap: contact on the way down and break contact on the
   way up are shifted in opposite directions by a delay;
7. the configured classifier (classifiers.py).

The hot loops of every step run in small C kernels when they were built (tapcell.tap.native:
~5x faster a tap); each has its numpy twin beside its call site, the reference the tests compare
it with and what runs without a C compiler.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from tapcell.tap import contact, native, uncertainty, validate
from tapcell.tap.classifiers import get_classifier, run_classifier
from tapcell.tap.contact import (MIN_SPAN_UM, SEARCH_SAMPLES, ContactFit, fit_contact, fit_fixed_onset,
                                 fit_of_kernel, window_edges, window_mean_and_slope)
from tapcell.tap.context import AnalysisContext, SensorTiming, line_intersection
from tapcell.tap.lazy import cached_attribute
from tapcell.tap.model import (
    LOW_COMPRESSION_FORCE,
    LOW_DECOMPRESSION_FORCE,
    LOW_TAP_QUALITY,
    TAP_ADHESION,
    TAP_BREAK_CONTACT_TOO_EARLY,
    TAP_BREAK_CONTACT_TOO_LATE,
    TAP_CHRONOLOGY,
    TAP_CONTACT_MISMATCH,
    TAP_DATA_INSUFFICIENT,
    TAP_MOTION_INVALID,
    TAP_PULLBACK_TOO_SHORT,
    TAP_SENSOR_SATURATED,
    TAP_SHAPE_INVALID,
    TAP_TWO_STAGE_CONTACT,
    AnalysisOptions,
    PullbackFit,
    TapAnalysis,
    TapData,
)
from tapcell.tap.motion import Motion, MotionError, tap_motion
from tapcell.tap.robust import MAD_TO_SIGMA, grouped_median, lattice_step, median, robust_sigma
from tapcell.tap.validate import TapInvalid
from tapcell.tap.segments import (NO_DWELL_SAMPLES, TOO_FEW_AROUND, TOO_FEW_FOR_FIVE, PrefixSums, five_lines,
                                  segment_line, segment_stats)
from tapcell.tap.stage import (Ringing, SoftStage, TwoStageFit, departure_soft_stage, dwell_ringing,
                               shows_absorbed_stage, shows_soft_stage, shows_two_stage, two_stage_departure,
                               unnamed_stage_um)
from tapcell.tap.toe import (ADHESION_LEVEL_UM, ADHESION_REACH_UM, ADHESION_RUN_SAMPLES, THREAD_FAR_REACH_UM,
                             THREAD_REACH_UM, TOE_WIDTHS_UM, ToeFit, Wander, adhesion_measures, fit_toe, free_air_walks,
                             lag_from_halt_s, thread_pull_g, thread_pulls_g)

if TYPE_CHECKING:  # the hum's module is imported where a tap asks for hum removal (remove_mains_hum)
    from tapcell.tap.hum import HumFit

# The checks, robust statistics and window heights in C (c/analysis.c, tapcell.tap.native); None: numpy.
_C = native.load("analysis")

MIN_SAMPLES = 12
# Extra samples the force may keep changing after the motion stopped/started (ringing, filters).
LAG_MARGIN_SAMPLES = 3
# Lag allowed when the sensor delay is to be estimated (s).
UNKNOWN_DELAY_ALLOWANCE_S = 0.02
# An onset is modelled only when it lowers the residual by this many noise variances (~5 sigma).
ONSET_MIN_CHI2 = 25.0
ONSET_GRID_UM = (0.0, 2.0, 4.0, 6.0, 9.0, 12.0)
# A lead screw of 8 mm per turn, 200 full steps, 16 microsteps: the commonest Z resolution.
DEFAULT_Z_STEP_UM = 2.5
# The misfit looks at samples up to this many pullback steps past break contact.
MISFIT_REACH_SAMPLES = 10
# The compression stiffness is scored only from at least this many samples whose conversion
# window lies wholly in contact before the halt (fewer: onset, integration and the halt dominate).
MIN_COMPRESSION_SAMPLES = 2
# The force at the end of the pullback: the median of this many samples before it (did the nozzle leave the bed?).
END_SAMPLES = 3
# Break contact this many samples (and a sixth of the pullback) before the pullback's end, and a
# departure whose slope is under this share of the decompression's: the nozzle left inside it.
BREAK_MARGIN_SAMPLES = 3
DEPARTURE_FLAT_SHARE = 0.1
# The adhesion dip (toe model) that rejects a tap, in noise sigmas. The dip is measured below both
# free-air references, the departure's own level further up and the approach's line (`check_adhesion`).
# Over taplab seeds 1 and 2 and the reference set (1,960 taps), clean taps reach 4.03 (one reference
# bowden tap, under the floor below) and 2.6 otherwise, but for taplab's 10 sps taps (8.5, whose
# pullback lasts 16 s: the baseline's walk; under the floor but one, 1.05 % of the compression);
# mild ooze has a median of 4.0-5.8 and its deepest dips err most. The dip must also be deeper than
# the free air before contact dips by itself (`free_air_dip_g`, eleventh session): a fan's vibration
# or a heater's PWM the white noise does not measure (reference ADS1220 taps with a 1-4 g fan at
# 20-150 Hz, and with 10 Hz PWM: TAP_ADHESION on 6 of 240, and one of 400) dips the approach as deep
# as the departure; where nothing does, it dips 1-2 noise sigmas, under the limit (no tap of taplab
# seeds 1-100, every scenario, nor of the benchmark sets changed). Each of the two dips is one draw of
# the same interference's deepest trough plus the noise's, so the departure's must pass the free
# air's by FREE_AIR_DIP_MARGIN_NOISE noise sigmas (by 0.1-0.7 g, 0.2-1.3 sigmas, did the 7 fan and
# 1/f taps of the sweep's seeds 101-120 rejected at 1 x the free air's dip alone).
ADHESION_MAX_DIP_NOISE = 4.0
FREE_AIR_DIP_MARGIN_NOISE = 2.0
# The departure against the approach's free-air line (check_adhesion, tapcell.tap.toe.thread_pull_g):
# the limit in noise sigmas. Measured on 100 taps per
# scenario of the independent generator (seed 2), in noise sigmas: clean, soft, latency, hum and
# corrupt-frame taps -2.7..+2.6, cable drift -7.2 (its walk, allowed for separately), mild ooze
# down to -7.1, heavy ooze the generator's checks let through -10.6..-37.
THREAD_MAX_NOISE = 8.0
# ... and by more than this fraction of the compression force: a noise-free tap (noise 0) has no
# dip, only rounding. Below any real sensor's 4 sigmas (75 g x 1 % = 0.75 g; HX717 ~1 g noise).
ADHESION_MIN_DIP_FRACTION = 0.01
# A departure that lies below the approach's level by the same amount all the way up (a baseline
# shift: a cable or bowden pulling differently on the way up) does not move the toe's Z, which
# fits its own baseline over the departure. It is taken for a thread when it pulls at least
# THREAD_MIN_SHARE of the compression force, or when its pull changes along the departure (a thread
# stretches and lets go) by more than THREAD_LEVEL_CHANGE of itself between THREAD_REACH_UM and
# THREAD_FAR_REACH_UM, or when the dwell shows plastic under the nozzle (PLASTIC_DWELL_DROP_SHARE).
# Reference taps (issue 21): cable shifts up to 12.6 % of the compression (bowden drift, 80 taps),
# far/near 0.53-1.55; heavy-ooze threads that stay 18-38 %; mild ooze lets go (far/near 0-0.9);
# tap.synth's 10 g strand peaking 40 um up, +1.5..+3.9 um of Z, 0.7. A departure too short to show
# a change (under THREAD_FAR_MIN_UM above contact) with no plastic in the dwell shows no thread: a
# bowden shift of 7 % on a 43 um departure read Z within 0.04 um and was rejected as TAP_ADHESION.
THREAD_MIN_SHARE = 0.15
THREAD_LEVEL_CHANGE = 0.2
THREAD_FAR_MIN_UM = 100.0
# The departure's drift (g/µm) is fitted in the toe model instead of the approach's when the two
# lines' slopes differ by more than this many standard errors (`toe_drift_g_um`). On the reference
# taps' bowden drift (80 taps) 5 takes sigma from 0.84 to 0.76 um (8: 0.77) and leaves every other
# scenario of both sets within 0.02 um; 3 moves clean ones by up to 0.03 (hx711 slow 0.58 -> 0.60).
DRIFT_AGREEMENT_SIGMAS = 5.0
# The departure confirms the approach's free-air drift (`departure_drift_share`) from this high above
# contact on (past the toe and most of a thread), over at least this many samples, within this
# share of it: a walk of 1-4 g/sqrt(s) over a 0.2 mm departure moves its slope by 47-58 % of taplab's
# 10-40 g/mm cables (median; 36 % on the one tap the approach component rejected).
APPROACH_DRIFT_FROM_UM = 10.0
APPROACH_DRIFT_MATERIAL_SHARE = 0.05  # looked for only when the approach changes by this share of the compression
APPROACH_DRIFT_MIN_SAMPLES = 10
APPROACH_DRIFT_AGREEMENT = 0.6
# A film of plastic between nozzle and bed: the force falls during the dwell (the plastic flows out
# from under the nozzle; the spec's dwell drop) and after break contact the departure lies below
# the approach's free-air level (the film holds the nozzle): the contact the pullback finds is the
# film's, several um above the bed (reference mild ooze: +4..+25 um, 2 silent failures beyond 20).
# Either alone is no cause: a slow sensor's dwell has few samples (taplab 10 sps drops up to 13.5 %,
# no pull), a cable's shift has no dwell drop. Margins over both sets (1,560 taps): clean taps that
# pull >= 3 % of the compression drop <= 7.3 % in the dwell (bowden drift), clean taps dropping
# >= 10 % pull <= 1.2 %; the reference mild-ooze taps that read > 5 um high drop 15.9-32.3 % and
# pull 6.7-13.0 %. The pull must also stand PLASTIC_PULL_NOISE noise sigmas clear (a hum or noise
# swing on the median of a few samples is not a pull).
PLASTIC_DWELL_DROP_SHARE = 0.12
PLASTIC_PULL_SHARE = 0.03
PLASTIC_PULL_NOISE = 3.0
# ... or the film's other sign with the pull: the down contact above the up one by this share of the
# contact-mismatch tolerance (`_pressed_film`). Clean taps pulling >= 3 % of the compression reach 0.15
# (taplab seeds 1-12 cable drift; reference bowden drift -0.08, noisy mains 0.03, soft sheet -0.06);
# heavy ooze accepted 23-28 um high (taplab seeds 72 k 9, 114 k 7: films of 26 and 21 um, pulls of 8
# and 7 %, dwell drops of 11.5 and 5.6 %) 0.42 and 0.60; heavy and mild ooze up to 0.98 and 0.73.
PLASTIC_SQUEEZE_SHARE = 0.3
# ... or plastic met further up with the pull: the approach's force rose off its free air this far
# above break contact, less a sample's travel (`_film_met_above`). `python -m bench film_signs
# --seeds 1-30`: taplab's clean taps rise from at most 7.9 um (none of them pulling), those pulling
# >= 3 % (cable drift) from 21 um below contact at most, mild ooze from at most 12.7; the reference's
# bowden and soft-sheet approaches curve up from as high as 1,336 um, none of them pulling. The heavy
# ooze accepted 21 um high (seed 388 k 27: a pull of 7 %, the dwell dropping 3 %, the down contact
# 2 um above the up one) rose from 51; the one accepted 19.3 um high on seed 788 (k 0: a pull of
# 5.9 %, the dwell dropping 6.7 %, the down contact at 29 % of the mismatch allowed, a departure of
# 55 um) from 12.1. At 20 um that one passed; at 10 no tap of taplab seeds 1-100 (every scenario)
# or of the reference sets changes whether it is valid (a heavy-ooze tap of seed 14 is named
# TAP_ADHESION instead of TAP_TWO_STAGE_CONTACT).
PLASTIC_MET_ABOVE_UM = 10.0


def sensor_timing(tap: TapData, options: AnalysisOptions, sample_period_s: float) -> SensorTiming:
    """The sensor's delay and conversion window: the options, else the tap's meta."""
    delay = options.sensor_delay_s
    if delay is None:
        # A delay the recorder knew wins over the estimate from the halt (docs/tap-analysis.md).
        delay = _meta_seconds(tap, "sensor_delay_s", None)
    from_halt = delay is None or delay == "halt"
    integration = options.sensor_integration_s
    if integration is None:
        integration = _meta_seconds(tap, "sensor_integration_s", sample_period_s)
    z_step_um = options.z_step_um if options.z_step_um is not None else _meta_number(tap, "z_step_um",
                                                                                       DEFAULT_Z_STEP_UM)
    return SensorTiming(float(delay) if isinstance(delay, (float, int)) else 0.0, float(integration),
                        delay == "auto", from_halt, sample_period_s, float(z_step_um))


# A sensor's clock is off its nominal rate by a few per cent; a file's nominal rate further than this
# factor from the rate its samples' times show is not a rate (1e300 sps beside samples 3 ms apart).
NOMINAL_RATE_FACTOR = 2.0


def times_rate_sps(time_s: np.ndarray) -> float:
    """The samples' average rate from their first and last times (at least two, rising)."""
    return (len(time_s) - 1) / float(time_s[-1] - time_s[0])


def nominal_rate_agrees(nominal_rate_sps: float, time_s: np.ndarray) -> bool:
    """Is a nominal rate within NOMINAL_RATE_FACTOR of what the samples' times show?"""
    ratio = nominal_rate_sps / times_rate_sps(time_s)
    return 1.0 / NOMINAL_RATE_FACTOR < ratio < NOMINAL_RATE_FACTOR


def sample_period_s(nominal_rate_sps: float | None, time_s: np.ndarray) -> float:
    """The sample period: the nominal rate's when it agrees with the samples' times, else the median
    interval of the times (the reader refuses such a file; a tap made in memory lands here). A nominal
    rate of 1e300 sps would otherwise make every lag and step of the analysis zero or infinite."""
    if nominal_rate_sps and nominal_rate_agrees(nominal_rate_sps, time_s):
        return 1.0 / nominal_rate_sps
    return median(np.diff(time_s))


def _meta_seconds(tap: TapData, key: str, default: float | None) -> float | None:
    """A sensor time from the tap's meta: a number in [0, 1) s, else `default`."""
    value = _meta_number(tap, key, math.inf)
    return value if value < 1 else default


def _meta_number(tap: TapData, key: str, default: float) -> float:
    value = tap.meta.get(key)
    if value is None:  # not recorded, the common case
        return default
    if isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value) and value >= 0:
        return float(value)
    return default


def step_staircase_sigma_um(step_um: float, window_um: float) -> float:
    """Sigma of the Z-step staircase around a continuous move, as a sensor averaging over
    `window_um` of travel sees it.

    A stepper holds Z on whole steps: the true height differs from the commanded continuous
    one by a sawtooth of sigma step/√12. A window of w = m·step + r averages the whole periods
    out; what remains is (r/w)(1 - r/step)·step/√12 (for w < step: (1 - w/step)·step/√12).
    """
    if step_um <= 0:
        return 0.0
    sawtooth_um = step_um / math.sqrt(12.0)
    if window_um <= 0:
        return sawtooth_um
    remainder_um = math.fmod(window_um, step_um)
    return sawtooth_um * (remainder_um / window_um) * (1.0 - remainder_um / step_um)


def noise_sigma_g(force_g: np.ndarray) -> float:
    """White-noise sigma from the median absolute second difference (lines and spikes do not inflate it)."""
    if _C is not None:
        return _C.noise_sigma(force_g)
    if len(force_g) < 3:
        return 0.0
    return _noise_sigma_of(np.abs(force_g[1:-1] - 0.5 * (force_g[:-2] + force_g[2:])))


def _noise_sigma_of(abs_off_mid: np.ndarray) -> float:
    # off_mid of white noise has sigma sqrt(1.5) * noise sigma; coarse readings: robust.grouped_median.
    return MAD_TO_SIGMA * grouped_median(abs_off_mid, median(abs_off_mid)) / math.sqrt(1.5)


def rounding_noise_g(force_g: np.ndarray) -> float:
    """The noise a coarse converter's rounding alone leaves, step / sqrt(12), where the readings
    step by multiples of one step coarse against their steps' median (robust.lattice_step), else 0.
    With a hum taken out, readings in coarse steps leave their lattice, and the off-midpoints'
    median falls to what the hum fit leaves between two steps: a reference ADS1220 660 tap in 3 g
    steps with its 0.45 g hum fitted (`mains_hz=auto`) read 0.06 g of noise and TAP_ADHESION."""
    steps_g = np.abs(force_g[1:] - force_g[:-1])
    if len(steps_g) == 0:
        return 0.0
    step_g = lattice_step(steps_g, median(steps_g))
    return 0.0 if step_g is None else step_g / math.sqrt(12.0)


# Stale readings (issue 21's sweep, `ref_stale3`): a sensor read before its next conversion is done
# hands over the last value again, at a new time. A repeat inside a compression of 3-4 samples
# flattens its line: 1-3 of 40 reference clean taps with 3 % of their readings repeated were
# rejected on most seeds (TAP_CONTACT_MISMATCH, TAP_CHRONOLOGY, LOW_TAP_QUALITY). A reading equal to
# the one before it to the last digit, after which the force moves on by more than STALE_JUMP_NOISE
# noise sigmas, is no new conversion: a force that moving cannot read the same twice. Where equal
# readings are common (a sensor whose steps are coarser than its noise, a clipped or stuck one:
# more than STALE_MAX_SHARE of the samples) nothing is told from them. Measured: on the benchmark
# sets (2,360 taps at 1 µm a sample) one reading is dropped (reference session hx711_slow 84, its Z
# unchanged), at 4 noise sigmas 15 taps' (Z moved 0.11 µm at most).
STALE_JUMP_NOISE = 8.0
STALE_MAX_SHARE = 0.1


def stale_readings(force_g: np.ndarray) -> np.ndarray | None:
    """The indices of the stale readings among the samples (see STALE_JUMP_NOISE: each run of readings
    equal to the one before it, where the force then moves on by more than that), or None. In one
    kernel call when built (its noise sigma and comparisons are the twin's: the same indices); the
    twin's numpy calls and loop cost ~35 µs, on more than half of the reference taps (a repeat in free air)."""
    if _C is not None:
        stale = _C.stale_readings(force_g, STALE_JUMP_NOISE, STALE_MAX_SHARE)
        return None if stale is None else np.array(stale, dtype=np.intp)
    repeats = np.flatnonzero(force_g[1:] == force_g[:-1]) + 1  # each equal to the sample before it
    if len(repeats) == 0 or len(repeats) > STALE_MAX_SHARE * len(force_g):
        return None
    jump_g = STALE_JUMP_NOISE * noise_sigma_g(force_g)
    stale: list[int] = []
    run_start = 0
    for i, index in enumerate(repeats):
        run_ends = i + 1 == len(repeats) or repeats[i + 1] != index + 1
        if not run_ends:
            continue
        after = index + 1  # the first reading after the run
        if after < len(force_g) and abs(force_g[after] - force_g[index]) > jump_g:
            stale.extend(int(r) for r in repeats[run_start:i + 1])
        run_start = i + 1
    return np.array(stale, dtype=np.intp) if stale else None


def repair_spikes(force_g: np.ndarray, threshold_sigma: float) -> tuple[np.ndarray, int]:
    """Replace corrupted frames, alone or two in a row, by what their neighbours say.

    A sample is a spike when it stands off the midpoint of its neighbours by more than
    `threshold_sigma` noise sigmas while the neighbours agree with each other (a step or a
    steep ramp has neighbours far apart, so real edges are never touched), or when it stands that
    far outside everything a smooth curve through the samples around it could reach: both
    neighbours and the lines through the two samples on either side carried one step on (a frame
    corrupted on the ramp into the halt, whose neighbours are a compression apart). Two frames in
    a row are spikes when both stand that far outside the samples bracketing them and those lines
    carried on. A spike is replaced by the mean of its neighbours (at a corner, by the value
    both sides' lines carry on to: `_repaired_values`), a pair by the line between the
    samples bracketing it. The noise sigma comes from the median absolute second difference,
    which spikes cannot inflate.
    """
    if _C is not None:
        spikes, repaired_g = _C.spikes(force_g, threshold_sigma)
        if not spikes:
            return force_g, 0
        repaired = force_g.copy()
        repaired[spikes] = repaired_g
        return repaired, len(spikes)
    if len(force_g) < 5:
        return force_g, 0
    # Only the few samples that stand off their neighbours' midpoint (the corners, the spikes) and
    # the pairs between two steps are looked at. The one that stands out the most is repaired
    # first, and the rest judged again against it: a frame's garbage must not make its honest
    # neighbour look like one.
    suspects, threshold, weigh_neighbours = spike_suspects(force_g, threshold_sigma)
    step = np.abs(np.diff(force_g)) > threshold  # step[j]: from sample j to j + 1
    pairs = [k for k in (np.flatnonzero(step[:-2] & step[2:]) + 1).tolist() if 2 <= k <= len(force_g) - 4]
    f = force_g.tolist()
    spikes: set[int] = set()  # a set: with no credible noise (a frozen reading) hundreds of samples stand out
    while True:
        best_g, best_k, best_width = 0.0, 0, 0
        for width, candidates, stands_out in ((1, suspects, _lone_spike_g), (2, pairs, _spike_pair_g)):
            for k in candidates:
                if k in spikes or k + width - 1 in spikes:
                    continue
                out_g = stands_out(f, k, threshold)
                if out_g > best_g:
                    best_g, best_k, best_width = out_g, k, width
        if best_width == 0:
            break
        k = best_k
        if best_width == 1 and weigh_neighbours:
            k, best_width = _frame_among_neighbours(f, k, spikes, threshold)
        # A corner is told only against a credible noise estimate, as a neighbour is (weigh_neighbours).
        f[k:k + best_width] = _repaired_values(f, k, best_width, threshold if weigh_neighbours else math.inf)
        spikes.update(range(k, k + best_width))
    if not spikes:
        return force_g, 0
    ordered = sorted(spikes)
    repaired = force_g.copy()
    repaired[ordered] = [f[k] for k in ordered]
    return repaired, len(ordered)


def spike_suspects(force_g: np.ndarray, threshold_sigma: float) -> tuple[list[int], float, bool]:
    """The samples standing off their neighbours' midpoint by more than the spike threshold
    (`threshold_sigma` noise sigmas, at least a millionth of the force's span), the threshold, and
    whether smoothness may be weighed against the noise (`repair_spikes`: neighbours and corners
    told apart). It may where the tap shows noise: where it shows none (a reading frozen over half
    the tap, the threshold at its floor) every sample stands out, and where a reading frozen over
    part of it leaves too small a noise estimate, too many do (`CREDIBLE_NOISE_SHARE`)."""
    off_mid = np.abs(force_g[1:-1] - 0.5 * (force_g[:-2] + force_g[2:]))
    noise_sigma = _noise_sigma_of(off_mid)
    scale = float(force_g.max() - force_g.min())  # only sets a floor far below any real spike
    threshold = max(threshold_sigma * noise_sigma, 1e-6 * scale, 1e-9)
    suspects = (np.flatnonzero(off_mid > threshold) + 1).tolist()
    weigh_neighbours = (threshold_sigma * noise_sigma > 1e-6 * scale
                        and len(suspects) <= CREDIBLE_NOISE_SHARE * len(force_g))
    return suspects, threshold, weigh_neighbours


def _outside_g(value: float, reach: tuple[float, ...]) -> float:
    """How far value lies outside the span of the reach (negative inside it)."""
    return max(value - max(reach), min(reach) - value)


def _lone_spike_g(f: list[float], k: int, threshold: float) -> float:
    """How far sample k stands out when it is a lone spike, else 0."""
    before, after = f[k - 1], f[k + 1]
    off_mid = abs(f[k] - 0.5 * (before + after))  # again: a neighbour may have been repaired
    if off_mid <= threshold:
        return 0.0
    if off_mid > 2.0 * abs(after - before):
        return off_mid  # its neighbours agree with each other
    if k < 2 or k > len(f) - 3:
        return 0.0
    outside_g = _outside_g(f[k], (before, after, 2.0 * before - f[k - 2], 2.0 * after - f[k + 2]))
    return outside_g if outside_g > threshold else 0.0


def _repaired_values(f: list[float], k: int, width: int, threshold: float) -> list[float]:
    """What replaces a lone spike at k (its neighbours' mean, or at a corner the value both sides'
    lines carry on to) or a pair at k, k + 1 (the line between the samples bracketing it).

    At the halt the force turns a corner: a frame read there (taplab seed 350 corrupt frames k 23,
    the first sample after the halt) lies on both the ramp carried on (151 g) and the dwell carried
    back (150 g), while its neighbours' mean (115 g) lies on neither. A corner is where the two
    lines carried on agree with each other better than with the mean, which stands more than the
    spike threshold off them."""
    if width == 1:
        middle = 0.5 * (f[k - 1] + f[k + 1])
        if 2 <= k <= len(f) - 3:
            from_before, from_after = 2.0 * f[k - 1] - f[k - 2], 2.0 * f[k + 1] - f[k + 2]
            corner = 0.5 * (from_before + from_after)
            off_g = abs(middle - corner)
            if off_g > threshold and abs(from_before - from_after) < off_g:
                return [corner]
        return [middle]
    gap = f[k + 2] - f[k - 1]
    return [f[k - 1] + gap / 3.0, f[k - 1] + 2.0 * gap / 3.0]


def _frame_among_neighbours(f: list[float], k: int, spikes: set[int], threshold: float) -> tuple[int, int]:
    """Of the lone spike k that stands out most, a neighbour that stands out as a lone spike too, and
    the pair of the two when it stands out as a pair, the repair (first sample, width) that leaves
    the samples around smoother: the least sum of |second differences| over the five samples about k.

    A frame's garbage can make its honest neighbour stand out more than itself: taplab seed 17
    corrupt frames k 9, a frame at -152 g on the ramp into the halt between -1 and -108 g, beside the
    halt's -167 g, made the honest -108 g stand 51 g off its neighbours' midpoint, more than the
    frame's 44 g outside its own; repaired, the honest sample left the frame in place and the split
    read contact 151 um above break contact (TAP_CONTACT_MISMATCH). Repairing the frame leaves the ramp
    straight (roughness 110 g), the honest sample a 151 g step (296 g). And two frames in a row of
    opposite signs each stand out alone by more than the pair does against its wider reach (seed 51
    k 19: -165 and +164 g in free air; seed 53 k 19: -1317 and +3855 g in the dwell): repaired alone,
    the first took its mean with the second and left it on the line through the two (LOW_TAP_QUALITY
    misfit 85 %, TAP_CHRONOLOGY)."""
    lo, hi = max(1, k - 2), min(len(f) - 2, k + 2)
    best, best_width, best_roughness = k, 1, _roughness_repaired(f, k, 1, lo, hi, threshold)
    for j in (k - 1, k + 1):
        if j in spikes or not 1 <= j <= len(f) - 2:
            continue
        options = [(j, 1)] if _lone_spike_g(f, j, threshold) > 0.0 else []
        first = min(j, k)
        if 2 <= first <= len(f) - 4 and _spike_pair_g(f, first, threshold) > 0.0:
            options.append((first, 2))
        for start, width in options:
            roughness = _roughness_repaired(f, start, width, lo, hi, threshold)
            if roughness < best_roughness:
                best, best_width, best_roughness = start, width, roughness
    return best, best_width


def _roughness_repaired(f: list[float], k: int, width: int, lo: int, hi: int, threshold: float) -> float:
    """The sum of |second differences| at samples lo..hi with the spike at k (`width` samples) repaired."""
    window = f[lo - 1:hi + 2]
    window[k - lo + 1:k - lo + 1 + width] = _repaired_values(f, k, width, threshold)
    roughness = 0.0  # summed in order, as the kernel sums (sum() compensates from Python 3.12)
    for i in range(1, len(window) - 1):
        roughness += abs(window[i - 1] - 2.0 * window[i] + window[i + 1])
    return roughness


# The noise estimate is the tap's when at most this share of its samples stand off their neighbours'
# midpoint by the spike threshold (8 noise sigmas, which noise alone does not reach): a tap's corners
# and frames make up at most 6.5 % (`python -m bench film_signs --seeds 1-30`: taplab's corrupt
# frames; the reference taps and sessions 3.6 %); a synthetic tap frozen over its last 42 % 12 %, as
# the virtual printer's sensor stuck from the trigger on (150 of its 357 samples alike) is past it.
CREDIBLE_NOISE_SHARE = 0.1
PAIR_SPAN_SAMPLES = 4  # a pair of frames lies outside the samples this far on either side


def _spike_pair_g(f: list[float], k: int, threshold: float) -> float:
    """How far the farther of samples k and k + 1 stands out when both lie outside what the samples
    on either side reach, else 0. Two samples can swing together where one cannot: a real tap's
    dwell rings (the Voron capture: two samples 8-13 g below their neighbours' lines, with noise
    0.7 g), so a pair must also lie outside every value the four samples on either side take."""
    before, after = f[k - 1], f[k + 2]
    reach = (before, after, 2.0 * before - f[k - 2], 3.0 * before - 2.0 * f[k - 2],
             2.0 * after - f[k + 3], 3.0 * after - 2.0 * f[k + 3],
             *f[max(0, k - PAIR_SPAN_SAMPLES):k], *f[k + 2:k + 2 + PAIR_SPAN_SAMPLES])
    first_g, second_g = _outside_g(f[k], reach), _outside_g(f[k + 1], reach)
    if first_g > threshold and second_g > threshold:
        return max(first_g, second_g)
    return 0.0


def _indices(time_s: np.ndarray, *t: float) -> list[int]:
    """Index of the first sample at or after each time (the last sample for times past the end)."""
    if _C is not None:
        return _C.indices(time_s, t)
    return np.minimum(time_s.searchsorted(t), len(time_s) - 1).tolist()


# The five lines of a tap, in order, and the points they meet at (P0 starts the approach line, P5
# ends the departure line; P1..P4 are the intersections of consecutive lines).
APPROACH, COMPRESSION, DWELL, DECOMPRESSION, DEPARTURE = range(5)
P_START, P_CONTACT, P_DWELL_START, P_DWELL_END, P_BREAK, P_END = range(6)


@dataclass(eq=False, repr=False)
class Decomposition:
    """The five lines of a tap (`decompose`): the analysed window start..stop, the segments' bounds in it,
    the lines, the points where they meet and the angles between them."""

    start: int
    stop: int
    bounds: tuple[int, int, int, int]
    lines: list[tuple[float, float]]  # (slope g/s, intercept g) in positive polarity, APPROACH..DEPARTURE
    points: list[tuple[float, float]]  # (time s, force g), P_START..P_END
    angles_deg: list[float]  # the four angles between consecutive lines (line_angles_deg)

    @property
    def approach_line(self) -> tuple[float, float]:
        return self.lines[APPROACH]

    @property
    def compression_line(self) -> tuple[float, float]:
        return self.lines[COMPRESSION]

    @property
    def decompression_line(self) -> tuple[float, float]:
        return self.lines[DECOMPRESSION]

    @property
    def departure_line(self) -> tuple[float, float]:
        return self.lines[DEPARTURE]


def decompose(time_s: np.ndarray, force_g: np.ndarray, motion: Motion, lag_samples: int,
              period: float, from_s: float | None = None, approach_share: float = 0.0,
              release_lag_samples: int | None = None, dwell_from_halt: bool = False,
              compression_across_gap: bool = False) -> tuple[Decomposition, PrefixSums]:
    """Five lines and six points of a positive-polarity tap (`period`: the sample period, s), over
    the samples from `from_s` (default: a pullback's duration, at least 8 samples, before the halt);
    the approach line holds at least `approach_share` of the samples before the halt; the dwell
    ends at most `release_lag_samples` (default `lag_samples`) after the pullback reached its speed.
    `compression_across_gap`: frames were lost up to the halt (`frames_lost_at_the_halt`), and the
    compression is the chord from the last sample before their gap to the first after the halt."""
    n = len(time_s)
    duration = motion.pullback_duration_s
    window_start_s = motion.home_end_s - max(duration, 8 * period) if from_s is None else from_s
    start, last = _indices(time_s, window_start_s, motion.pullback_end_s + duration)
    stop = min(n, last + 1)
    t = time_s[start:stop]
    if compression_across_gap:  # the contact at the sample before the first after the halt, the peak at the next
        after_halt = int(t.searchsorted(motion.home_end_s))
        lag_samples, approach_share = 1, (after_halt - 0.5) / max(after_halt, 1)
    phases_s = (motion.home_end_s, motion.pullback_start_s, motion.pullback_cruise_s)
    if dwell_from_halt:
        phases_s = (_halt_read_s(t, motion.home_end_s), *phases_s[1:])
    release_lag = lag_samples if release_lag_samples is None else release_lag_samples
    ps, problem, bounds, lines, points, angles_deg = five_lines(t, force_g[start:stop], phases_s, lag_samples,
                                                                release_lag, approach_share)
    if problem == NO_DWELL_SAMPLES:
        raise TapInvalid(TAP_DATA_INSUFFICIENT, "no samples between the halt and the pullback")
    if problem == TOO_FEW_AROUND:
        raise TapInvalid(TAP_DATA_INSUFFICIENT, f"too few samples around the tap ({len(t)} in the analysis window)")
    if problem == TOO_FEW_FOR_FIVE:
        raise TapInvalid(TAP_DATA_INSUFFICIENT, "too few samples to fit five lines (each needs 2)")
    return Decomposition(start, stop, bounds, lines, points, angles_deg), ps


def _halt_read_s(t: np.ndarray, halt_s: float) -> float:
    """A halt time at which the five-line search lets the dwell begin no earlier than the first
    sample read at or after the halt (it searches from the sample before the halt given): the
    time of the sample after that one."""
    first = int(t.searchsorted(halt_s))
    return float(t[min(first + 1, len(t) - 1)])


# A retried split's approach holds at least this share of the samples before the halt: the approach
# crosses hundreds of um of free air, the compression tens (a contact found in the approach's first
# half would make the compression longer than the approach itself).
RETRY_APPROACH_SHARE = 0.5
# The dwell on the samples the motion gives it: from the first read after the halt to at most one
# after the pullback's cruise began (a dwell of a sample or two: the next sample is the pullback's).
DWELL_ON_THE_MOTION = {"dwell_from_halt": True, "release_lag_samples": 1}


def decompose_again(time_s: np.ndarray, force_g: np.ndarray, motion: Motion, lag_samples: int, period: float,
                    lost_at_halt: bool, first: tuple[Decomposition, PrefixSums]) -> tuple[Decomposition, PrefixSums]:
    """The five lines again when the first split fails the spec's checks on it (validate.split_checks_pass).

    Points out of time order: over the samples from the approach move's start on, when its window
    began before the approach moved, then with the approach line holding at least
    RETRY_APPROACH_SHARE of the samples before the halt, then with the dwell ending within
    LAG_MARGIN_SAMPLES of the pullback's cruise, then with the dwell on the samples the motion gives
    it (DWELL_ON_THE_MOTION); the first in order, else the first split. Points in order but the
    lines' angles not a tap's: only when the split began the dwell before the first sample read
    after the halt, or ran a dwell the motion gives one sample or none past the sample after the
    pullback's cruise (taplab seed 59 10 sps k 19: into a 0.01 mm/s pullback), the dwell on the
    motion's samples, kept when it passes both checks.

    Free air before the approach is flat in time, and a bowden or cable pulling in proportion to Z
    ramps during it: two lines, not one. When the compression lasts a sample or two (8.4 mm/s at
    320 sps), the best split then takes the ramp for the compression and its points fall out of
    order (reference bowden drift: one clean tap of 80 was TAP_CHRONOLOGY). A compression of three
    samples under a 20 g mains hum let the best split take the whole approach for the compression
    and leave 3 samples to the approach (reference noisy mains: one clean tap of 80). A sheet
    relaxing in the dwell as fast as a 0.08 mm/s pullback unloads let the dwell run 7 samples into
    the pullback and its line cross the decompression's before the compression's (reference sessions,
    HX711 80 sps: one clean tap of 200). At 10 sps a 0.1-0.35 s dwell lasts one to three samples and
    the compression two or three: a line of two samples fits any two exactly, so the best split
    ended the compression a sample before the halt and gave the dwell two compression samples (two
    steep lines meeting far off: out of order, or a compression flatter than the dwell:
    TAP_SHAPE_INVALID), or ran the dwell into the pullback (a dwell line as steep as the
    decompression's, meeting it far off): 21 of 440 clean 10 sps taps on taplab seeds 2-12. The
    force rises until the nozzle halts, so the dwell starts no earlier than the first sample read
    after it, and a dwell of a sample or two ends with the pullback's first sample. Taps whose
    split passes both checks are never split again, so their Z stays what it was.
    """
    dec = first[0]
    if validate.in_time_order(dec.points):
        halt, pullback = time_s.searchsorted((motion.home_end_s, motion.pullback_start_s)).tolist()
        began_after_halt = dec.start + dec.bounds[1] >= halt
        # A dwell the motion gives one sample or none (10 sps and a 0.1 s dwell) has no line of its own:
        # run into a pullback as slow as a dwell relaxes, its line meets the decompression's at no angle.
        ran_past_a_one_sample_dwell = (pullback - halt <= 1 and dec.start + dec.bounds[2]
                                       > int(time_s.searchsorted(motion.pullback_cruise_s)) + 1)
        if began_after_halt and not ran_past_a_one_sample_dwell:
            return first  # misshapen with the dwell where the motion puts it: the tap's own shape
        retries, shape_too = [DWELL_ON_THE_MOTION], True
    else:  # as before this retry existed: the first in order is kept, its shape checked next
        shape_too = False
        retries = [{"approach_share": RETRY_APPROACH_SHARE}, {"release_lag_samples": LAG_MARGIN_SAMPLES},
                   DWELL_ON_THE_MOTION]
        if motion.moves and time_s[dec.start] < motion.moves[-5].print_time < motion.home_end_s - 8 * period:
            retries.insert(0, {"from_s": motion.moves[-5].print_time})
    if lost_at_halt:  # frames_lost_at_the_halt
        retries.append({"compression_across_gap": True})
    for retry in retries:
        try:
            again = decompose(time_s, force_g, motion, lag_samples, period, **retry)
        except TapInvalid:  # a dwell of under two samples from the halt's to the cruise's: no such split
            continue
        points = again[0].points
        if validate.split_checks_pass(points, again[0].angles_deg) if shape_too else validate.in_time_order(points):
            return again
    return first


def split_across_the_gap_if_flatter(time_s: np.ndarray, force_g: np.ndarray, motion: Motion, lag_samples: int,
                                    period: float, first: tuple[Decomposition, PrefixSums]
                                    ) -> tuple[Decomposition, PrefixSums]:
    """Frames lost up to the halt, and a first split that passed the checks: the compression as the
    chord across the gap instead (`decompose(compression_across_gap=True)`) where the first split's
    compression holds no sample read before the gap and rises less steeply than that chord. The
    force rises across the gap within some part of it, so a compression is at least as steep as the
    chord; a flatter one read wholly after the halt is the dwell's first samples, which the first
    split's lag allowance let it take. On the reference taps with the 2-5 samples before the halt
    lost (80 a scenario; `bench tap_sweep`'s `_burst_dropped(n, "halt")`) such a compression rose
    0.08-0.69 of the chord, met the approach up to 0.26 s before the halt and was up to 164 um above
    break contact: with the fit that found no contact (COMPRESSION_STIFFNESS_SHARE_MIN), 1-10
    TAP_CONTACT_MISMATCH of 80 clean taps a scenario before. A compression that kept samples before
    the gap (a 2000 sps tap, one frame lost) stays the first split's."""
    dec = first[0]
    first_after_halt = int(time_s.searchsorted(motion.home_end_s))
    if dec.start + dec.bounds[0] < first_after_halt:
        return first
    try:
        chord = decompose(time_s, force_g, motion, lag_samples, period, compression_across_gap=True)
    except TapInvalid:
        return first
    if (dec.lines[COMPRESSION][0] < chord[0].lines[COMPRESSION][0]
            and validate.split_checks_pass(chord[0].points, chord[0].angles_deg)):
        return chord
    return first


def frames_lost_at_the_halt(time_s: np.ndarray, halt_s: float, period_s: float) -> bool:
    """The first sample after the halt follows its predecessor by LOST_FRAME_PERIODS or more: frames
    lost over the compression left it no sample (a burst of 3 over a reference HX717 tap's 3-4
    sample compression). The five lines took the dwell's first samples for a compression, whose
    line met the approach's seconds before the halt (TAP_CHRONOLOGY, 3 of 40 taps)."""
    after = int(time_s.searchsorted(halt_s))
    return 0 < after < len(time_s) and time_s[after] - time_s[after - 1] >= LOST_FRAME_PERIODS * period_s



def break_time_sigma_s(ps: PrefixSums, dec: Decomposition, t_break: float) -> float:
    """1 sigma of the decompression ∩ departure time from the two line fits."""
    return corner_time_sigma_s(ps, dec, DECOMPRESSION, t_break)


def corner_time_sigma_s(ps: PrefixSums, dec: Decomposition, line: int, t_corner: float) -> float:
    """1 sigma of the time where line `line` meets the next (APPROACH..DWELL + 1) from the two line fits."""
    edges = [0, *dec.bounds, dec.stop - dec.start]
    var = 0.0
    for a, b in ((edges[line], edges[line + 1]), (edges[line + 1], edges[line + 2])):
        res_var, t_mean, sxx = segment_stats(ps, a, b)
        lever = (t_corner - ps.t_ref_s) - t_mean
        var += res_var * (1.0 / (b - a) + (lever * lever / sxx if sxx > 0 else 0.0))
    slope_gap = abs(dec.lines[line][0] - dec.lines[line + 1][0])
    return math.sqrt(var) / slope_gap if slope_gap > 0 else math.inf


@dataclass(eq=False, repr=False)
class ModelWindow:
    """The analysed samples in height space (µm above the halt), as the contact model sees them.

    Each sample covers heights [x_min, x_min + span] during its conversion window (read
    `delay_s` late). The line estimates of contact (P1) and break contact (P4) in the same
    space seed the model's search. One vectorised motion lookup serves both fits.
    """

    time_s: np.ndarray
    force_g: np.ndarray
    x_min_um: np.ndarray
    span_um: np.ndarray
    contact_line_um: float  # P1 mapped (approach)
    break_line_um: float  # P4 mapped (pullback)
    # `pullback_samples` by their first sample: the sharp fit, the toe fit and the Z uncertainty read the same.
    pullbacks: dict = field(default_factory=dict, repr=False, compare=False)
    # `pullback_first` by the time it searches for: asked four times a tap, for one or two delays.
    firsts: dict = field(default_factory=dict, repr=False, compare=False)


def model_window(time_s, force_g, motion: Motion, timing: SensorTiming, delay_s: float,
                 dec: Decomposition, contact_s: float | None = None) -> ModelWindow:
    """`contact_s`: when contact began as the lines read it, if not P1 (`SplitTap.contact_s`)."""
    t = time_s[dec.start:dec.stop]
    # A line point is read half a conversion window late, plus the delay.
    lag_s = delay_s + 0.5 * timing.integration_s
    lines_s = ((dec.points[P_CONTACT][0] if contact_s is None else contact_s) - lag_s, dec.points[P_BREAK][0] - lag_s)
    if _C is not None and motion.moves is not None:
        x_min, span = np.empty(len(t)), np.empty(len(t))
        # The kernel counts the samples read by the time the nozzle rose too: `pullback_first` at this delay.
        rising_s = pullback_rising_s(motion, timing, delay_s)
        contact_um, break_um, first = _C.window_heights(motion.move_rows, t, delay_s, timing.integration_s,
                                                        motion.z_halt_mm, MIN_SPAN_UM, *lines_s, rising_s, x_min,
                                                        span)
        return ModelWindow(t, force_g[dec.start:dec.stop], x_min, span, contact_um, break_um, {}, {rising_s: first})
    read_s = t - delay_s
    heights_um = (motion.z_at(np.concatenate((read_s - timing.integration_s, read_s, lines_s)))
                  - motion.z_halt_mm) * 1000.0
    n = len(t)
    x_min, span = window_edges(heights_um[:n], heights_um[n:2 * n])
    return ModelWindow(t, force_g[dec.start:dec.stop], x_min, span, float(heights_um[-2]), float(heights_um[-1]))


def fit_pullback(window: ModelWindow, samples: PullbackSamples, motion: Motion, timing: SensorTiming,
                 options: AnalysisOptions) -> tuple[ContactFit, float] | None:
    """The contact model over the pullback (`samples`: `pullback_samples`, those whose window starts
    after the nozzle began rising), and its residual sigma near contact (`near_contact_sigma_g`)."""
    x_min, _, y_fit = samples
    contact0 = window.break_line_um
    if not math.isfinite(contact0) or len(y_fit) < 2:
        return None
    span = window.span_um[len(window.span_um) - len(y_fit):]  # the samples' spans: they end the window
    spacing_um = max(motion.pullback_speed_mm_s * 1000.0 * timing.sample_period_s, 0.05)
    return pullback_fit(y_fit, x_min, span, contact0, spacing_um, options)


def pullback_fit(y_fit: np.ndarray, x_min: np.ndarray, span: np.ndarray, contact0: float, spacing_um: float,
                 options: AnalysisOptions) -> tuple[ContactFit, float] | None:
    """`fit_pullback` after its samples are chosen: the kernel _c_contact.fit_pullback when the onset is
    fixed (the whole of `pullback_fit_twin` in one call, its arithmetic in its order: the same to the
    last bit as the twin with the kernels it calls), else the twin."""
    if contact._C is None or _fits_onset(options):
        return pullback_fit_twin(y_fit, x_min, span, contact0, spacing_um, options)
    onset_um = options.contact_onset_um or 0.0
    found = contact._C.fit_pullback(y_fit, x_min, span, contact0, spacing_um, onset_um, SEARCH_SAMPLES,
                                    options.outlier_sigma, MISFIT_REACH_SAMPLES * spacing_um)
    return None if found is None else (fit_of_kernel(found, onset_um), found[6])


def pullback_fit_twin(y_fit: np.ndarray, x_min: np.ndarray, span: np.ndarray, contact0: float, spacing_um: float,
                      options: AnalysisOptions) -> tuple[ContactFit, float] | None:
    """The fit (`_fit_with_onset`), its robust pass and the near-contact sigma: _c_contact.fit_pullback's
    numpy twin, and the path of a fitted onset."""
    found = _fit_with_onset(y_fit, x_min, span, contact0, spacing_um, options)
    if found is None:
        return None
    fit, residual = found
    # Robust pass: drop samples the first fit cannot explain (ooze blobs, bursts), fit again.
    keep = _outliers_kept(residual, options.outlier_sigma, fit.residual_sigma_g)
    if keep is not None:
        refit = _fit_with_onset(y_fit[keep], x_min[keep], span[keep], fit.contact_um, spacing_um, options)
        if refit:
            fit = refit[0]
            residual = _residual(y_fit, x_min, span, fit)  # over every sample, dropped ones too
    return fit, near_contact_sigma_g(residual, x_min, fit, spacing_um)


def _outliers_kept(residual_g: np.ndarray, outlier_sigma: float, floor_g: float) -> np.ndarray | None:
    """The residuals within outlier_sigma × max(their robust sigma, floor_g) (a mask), or None when all are."""
    if _C is not None:
        keep = _C.outlier_mask(residual_g, outlier_sigma, floor_g)
        return None if keep is None else np.frombuffer(keep, dtype=bool)
    keep = np.abs(residual_g) <= outlier_sigma * max(robust_sigma(residual_g), floor_g)
    return None if keep.all() else keep


def near_contact_sigma_g(residual_g: np.ndarray, x_min_um: np.ndarray, fit: ContactFit, spacing_um: float) -> float:
    """Residual sigma of the fit over the samples that set Z: in contact, and up to
    MISFIT_REACH_SAMPLES past break contact (a soft ooze layer or a gradual release shows there).

    Samples further into the departure are left out: a strand pulling on the nozzle after it
    left the bed does not move Z, and the spec's departure component judges it.
    """
    below_um = fit.contact_um + MISFIT_REACH_SAMPLES * spacing_um
    if _C is not None:
        sigma_g = _C.near_sigma(residual_g, x_min_um, below_um)
        return fit.residual_sigma_g if math.isnan(sigma_g) else sigma_g
    near = residual_g[x_min_um < below_um]
    if len(near) <= 3:
        return fit.residual_sigma_g
    return math.sqrt(float(near @ near) / (len(near) - 3))


def _fit_with_onset(y, x_min, span, contact0_um: float, spacing_um: float, options: AnalysisOptions
                    ) -> tuple[ContactFit, np.ndarray] | None:
    """The contact model around the line estimate, with the onset calibrated, absent or fitted.

    The onset width is `contact_onset_um` when calibrated (no cost in spread). With
    `fit_contact_onset` it is fitted per tap and kept only when the data show one
    (likelihood-ratio test): onset width and contact height trade off against each other,
    so a per-tap onset costs several times the Z spread.
    """
    fixed_onset = options.contact_onset_um or 0.0
    # A line fit reads a soft contact onset/2 low.
    sharp = fit_fixed_onset(y, x_min, span, contact0_um + 0.5 * fixed_onset, spacing_um, fixed_onset)
    if not _fits_onset(options):
        return sharp
    # Best onset on a grid (each with its own global contact search), then all four parameters refined.
    trials = [fit_fixed_onset(y, x_min, span, contact0_um + 0.5 * onset, spacing_um, onset)
              for onset in ONSET_GRID_UM[1:]]
    trials = [trial for trial in trials if trial is not None]
    if not trials:
        return sharp
    start = min(trials, key=lambda trial: trial[0].rss_g2)[0]
    x_max = x_min + span
    soft = fit_contact(y, x_min, x_max, start.contact_um, start.stiffness_g_um, start.baseline_g, start.onset_um, True)
    if soft is None or sharp is None:
        return (soft, _residual(y, x_min, span, soft)) if soft else sharp
    # Keep the onset only when it explains the data clearly better (likelihood-ratio test).
    improvement = (sharp[0].rss_g2 - soft.rss_g2) / soft.residual_sigma_g ** 2 if soft.residual_sigma_g > 0 else np.inf
    return (soft, _residual(y, x_min, span, soft)) if improvement > ONSET_MIN_CHI2 else sharp


def _fits_onset(options: AnalysisOptions) -> bool:
    """Whether the onset width is fitted per tap (`fit_contact_onset`, none calibrated), not held fixed."""
    return options.fit_contact_onset and options.contact_onset_um is None


def _residual(y, x_min_um, span_um, fit: ContactFit) -> np.ndarray:
    mean, _ = window_mean_and_slope(fit.contact_um, fit.onset_um, x_min_um, span_um, slope=False)
    return y - (fit.baseline_g + fit.stiffness_g_um * mean)


def force_left_at_end_g(motion: Motion, dec: Decomposition, end_g: float) -> float:
    """The force at the pullback's end (`end_g`, `force_at_g` there) above the free-air level at that
    height: did the nozzle leave the bed (validate.check_left_the_bed)?

    The free-air level is the approach line at the halt carried up the pullback by the free-air
    drift (a cable pulling in proportion to Z moves the end's level by drift x pullback distance).
    """
    slope_g_s, intercept_g = dec.approach_line
    height_um = (motion.z_at_time_mm(motion.pullback_end_s) - motion.z_halt_mm) * 1000.0
    free_air_g = slope_g_s * motion.home_end_s + intercept_g + free_air_slope_g_um(dec, motion) * height_um
    return end_g - free_air_g


def force_at_g(time_s: np.ndarray, force_g: np.ndarray, t_s: float) -> float:
    """The force at t_s as the checks read it: the median over the first sample read at or after t_s
    (the last sample past the end) and the END_SAMPLES before it (one kernel call when built)."""
    if _C is not None:
        return _C.median_up_to(time_s, force_g, t_s, END_SAMPLES)
    end = _indices(time_s, t_s)[0]
    return median(force_g[max(end - END_SAMPLES, 0):end + 1])


def left_inside_pullback(motion: Motion, dec: Decomposition, period_s: float, end_g: float, scatter_g: float,
                         pressed_g: float) -> bool:
    """The tap shows the nozzle leaving the bed inside the pullback: break contact (P4) at least
    BREAK_MARGIN_SAMPLES and a sixth of the pullback before its end, a departure as flat as free
    air (its slope under DEPARTURE_FLAT_SHARE of the decompression's), and the force at the
    pullback's end (`end_g`) on the departure's level (within STILL_PRESSING_SCATTERS of its scatter
    `scatter_g` or the spec's share of the compression `pressed_g`). A cable pulling another way on
    the way up leaves such a departure offset from the approach's level; a nozzle still pressing
    keeps unloading to the end.
    """
    end_s = motion.pullback_end_s - max(motion.pullback_duration_s / 6.0, BREAK_MARGIN_SAMPLES * period_s)
    if not dec.points[P_BREAK][0] < end_s:
        return False
    (decompression_slope, _), (slope_g_s, intercept_g) = dec.lines[DECOMPRESSION:]
    if not abs(slope_g_s) <= DEPARTURE_FLAT_SHARE * abs(decompression_slope):
        return False
    off_g = end_g - (slope_g_s * motion.pullback_end_s + intercept_g)
    return abs(off_g) <= max(validate.STILL_PRESSING_SCATTERS * scatter_g, validate.STILL_PRESSING_SHARE * pressed_g)


def free_air_slope_g_um(dec: Decomposition, motion: Motion) -> float:
    """The force's slope against height in free air (g/µm; cable/bowden drift), from the approach line.

    The approach crosses hundreds of µm of free air, so its line pins the Z-proportional drift far
    better than the few tens of µm of departure after break contact can, and an adhesion thread
    pulling on the nozzle over the departure cannot tilt it (the height falls while the time runs).
    """
    return -dec.approach_line[0] / (motion.approach_speed_mm_s * 1000.0)


# The approach's free air is fitted for the adhesion checks over at least this many samples read
# before the contact (fewer: the split's approach line, as before).
FREE_AIR_MIN_SAMPLES = 3
# The approach's last samples rise off its line by more than this many noise sigmas: the force of
# something met before the contact, not free air (`approach_free_air_end`).
APPROACH_RISE_NOISE = 3.0


def free_air_samples(split: SplitTap, contact_um: float, delay_s: float) -> int:
    """How many of the approach's samples (from the split's start) were read before the nozzle came
    down to the contact height (`contact_um` above the halt, read `delay_s` late): its free air."""
    dec, motion = split.dec, split.motion
    touch_s = motion.home_end_s - contact_um / (motion.approach_speed_mm_s * 1000.0) + delay_s
    return min(int(split.time_s.searchsorted(touch_s, side="right")) - dec.start, dec.bounds[0])


def free_air_dip_g(time_s: np.ndarray, force_g: np.ndarray, line: tuple[float, float], run_samples: int) -> float:
    """How deep the free air dips by itself: the median of the samples' offsets from their line (slope
    g/s, intercept g) less the lowest mean of `run_samples` offsets in a row (0 with too few samples)."""
    if len(force_g) < run_samples + 2:
        return 0.0
    slope_g_s, intercept_g = line
    offsets_g = force_g - (slope_g_s * time_s + intercept_g)
    runs_g = np.convolve(offsets_g, np.full(run_samples, 1.0 / run_samples), mode="valid")
    return median(offsets_g) - float(runs_g.min())


def free_air_line(split: SplitTap, end: int) -> tuple[float, float]:
    """The approach's line (slope g/s, intercept g, as `Decomposition.lines`) over its first `end`
    samples, those read before the nozzle came down to the contact height (`free_air_samples`): the
    free air alone, never a sample the contact's toe already pushed.

    At 10 sps a sample spans 20 µm of the approach: the split's approach line can keep the first
    sample the toe pushed (6.5 g where the free air reads 0.4: taplab seed 2 hx711_10 k 22), which
    tilts its eight samples by 6 g/s, a "drift" of -0.03 g/µm where the cable pulls +0.002, and
    moves its level at the halt. Carried 60 µm up the departure, the adhesion checks read that
    tilt as a 2-3.5 g dip or pull.
    """
    dec = split.dec
    if end < FREE_AIR_MIN_SAMPLES:
        return dec.approach_line
    n, st, sf, stt, stf, _ = split.ps.sums[:, end].tolist()  # segment_sums(0, end): the first column is 0
    sxx = stt - st * st / n
    if not sxx > 0:
        return dec.approach_line
    slope = (stf - st * sf / n) / sxx
    # The sums are of t - t_ref and f - f_ref (`PrefixSums`).
    return slope, split.ps.f_ref_g + sf / n - slope * (split.ps.t_ref_s + st / n)


def approach_free_air_end(split: SplitTap) -> int:
    """How many of the approach's samples (from the split's start) lie in free air: its last samples
    are dropped while the last one stands more than APPROACH_RISE_NOISE noise sigmas above the line
    over those before it (at most half of them).

    Ooze met above the bed pushes the approach's end up before the nozzle touches (taplab seed 388
    heavy ooze k 27: 1.5 to 18 g over its last five samples, from 51 um above break contact)."""
    dec, ps, time_s, force_g = split.dec, split.ps, split.time_s, split.force_g
    end = dec.bounds[0]
    least = max(end // 2, FREE_AIR_MIN_SAMPLES)
    rise_g = APPROACH_RISE_NOISE * split.noise_g
    while end > least:
        slope, intercept = segment_line(ps, 0, end - 1)  # the sums count from the split's start
        last = dec.start + end - 1
        if force_g[last] - (slope * time_s[last] + intercept) <= rise_g:
            break
        end -= 1
    return end


def approach_rise_above_um(split: SplitTap, contact_um: float, delay_s: float) -> float | None:
    """How high above the contact height (`contact_um` above the halt, samples read `delay_s` late)
    the approach's force rose off its free air (`approach_free_air_end`), less the height a sample's
    travel spans; None when it did not rise before the end of its line."""
    dec, motion = split.dec, split.motion
    end = approach_free_air_end(split)
    if end == dec.bounds[0]:
        return None
    speed_um_s = motion.approach_speed_mm_s * 1000.0
    read_at_um = (motion.home_end_s - (float(split.time_s[dec.start + end]) - delay_s)) * speed_um_s
    return read_at_um - contact_um - speed_um_s * split.timing.sample_period_s


def toe_drift_g_um(dec: Decomposition, ps: PrefixSums, motion: Motion, period_s: float,
                   walk_var_g2: float = 0.0) -> float | None:
    """The free-air drift the toe fit takes as known: the approach's (`free_air_slope_g_um`), unless
    the departure line's own slope disagrees with it by more than DRIFT_AGREEMENT_SIGMAS standard
    errors; then None, and the toe fit finds the drift over the departure with the rest. Each
    line's error: its residual scatter, plus the baseline's random walk (walk_var_g2 per sample,
    `free_air_wanders`), which tilts a line over n samples by 6 q / (5 n) per sample² in variance.

    A bowden tube or cable can pull differently on the way up than on the way down: the approach's
    drift then tilts the departure's baseline under the toe, and a wrong tilt moves the contact by
    tilt x reach / stiffness. Where the two agree, the approach's many hundred µm pin the drift far
    better than the departure's few tens (and an adhesion thread cannot tilt it).
    """
    approach_speed_um_s = motion.approach_speed_mm_s * 1000.0
    pullback_speed_um_s = motion.pullback_speed_mm_s * 1000.0
    approach_g_um = free_air_slope_g_um(dec, motion)
    departure_g_um = dec.departure_line[0] / pullback_speed_um_s
    variance = 0.0
    for (first, end), speed_um_s in (((0, dec.bounds[0]), approach_speed_um_s),
                                     ((dec.bounds[3], dec.stop - dec.start), pullback_speed_um_s)):
        residual_var, _, sxx = segment_stats(ps, first, end)
        samples = end - first
        if not (sxx > 0 and samples > 0):
            return approach_g_um
        step_um = speed_um_s * period_s
        variance += (residual_var / sxx / (speed_um_s * speed_um_s)
                     + 1.2 * walk_var_g2 / samples / (step_um * step_um))
    agrees = abs(departure_g_um - approach_g_um) <= DRIFT_AGREEMENT_SIGMAS * math.sqrt(variance)
    return approach_g_um if agrees else None


PullbackSamples = tuple[np.ndarray, np.ndarray, np.ndarray]  # window low edge µm, high edge µm, force g


def pullback_rising_s(motion: Motion, timing: SensorTiming, delay_s: float) -> float:
    """The last time a sample can be read whose conversion window began before the nozzle rose."""
    return motion.pullback_start_s + delay_s + timing.integration_s


def pullback_first(window: ModelWindow, motion: Motion, timing: SensorTiming, delay_s: float) -> int:
    """The first sample whose conversion window starts after the nozzle began rising."""
    rising_s = pullback_rising_s(motion, timing, delay_s)
    first = window.firsts.get(rising_s)
    if first is None:
        first = window.firsts[rising_s] = int(window.time_s.searchsorted(rising_s, side="right"))
    return first


def pullback_samples(window: ModelWindow, motion: Motion, timing: SensorTiming, delay_s: float) -> PullbackSamples:
    """(window low edge µm, high edge µm, force g) of the samples read after the pullback began."""
    first = pullback_first(window, motion, timing, delay_s)
    found = window.pullbacks.get(first)
    if found is None:
        x_lo = window.x_min_um[first:]
        found = window.pullbacks[first] = (x_lo, x_lo + window.span_um[first:], window.force_g[first:])
    return found


def read_while_rising(samples: PullbackSamples, split: SplitTap, window: ModelWindow, delay_s: float
                      ) -> PullbackSamples:
    """The pullback samples (`pullback_samples`, read `delay_s` late) read before the pullback ended.
    Those read after it all lie at its top height while the baseline goes on walking: as the
    adhesion checks' free-air level they turned a cable's walk into a "dip" (taplab seed 2 cable
    drift: 4 of 100 clean taps TAP_ADHESION, 82 of one tap's 100 level samples read after the
    motion stopped)."""
    if delay_s == split.timing.delay_s:  # the split's own stop (the window is its samples start..stop)
        rising = min(split.rising_stop, split.dec.stop) - split.dec.start
    else:
        rising = int(window.time_s.searchsorted(split.motion.pullback_end_s + delay_s, side="right"))
    kept = max(rising - (len(window.time_s) - len(samples[2])), 0)
    return samples[0][:kept], samples[1][:kept], samples[2][:kept]


def free_air_wanders(force_g: np.ndarray, dec: Decomposition, steps_um: tuple[float, float],
                     rising_stop: int) -> tuple[Wander | None, Wander | None]:
    """The baseline's white noise and random walk in time from the approach line's samples and the
    departure line's read while the nozzle rose (before `rising_stop`, an index into force_g), with
    a pull curved in height told apart from the walk (`walk_beside_height_pull`; steps_um: the
    height crossed per sample on the approach and on the pullback), for the toe fit; and from the
    approach's alone, which no ooze thread after the tap can pull (for the thread check), in one
    call (`toe.free_air_walks`)."""
    bounds = dec.bounds
    approach_force = force_g[dec.start:dec.start + bounds[0]]
    departure_force = force_g[dec.start + bounds[3]:min(dec.stop, rising_stop)]
    return free_air_walks(approach_force, departure_force, steps_um)


def fit_pullback_toe(samples: PullbackSamples, motion: Motion, timing: SensorTiming, contact0_um: float,
                     drift_g_um: float | None, wander: Wander | None = None) -> ToeFit | None:
    """The toe model (tapcell.tap.toe) over the pullback's samples (`pullback_samples`)."""
    if not math.isfinite(contact0_um):
        return None
    spacing_um = max(motion.pullback_speed_mm_s * 1000.0 * timing.sample_period_s, 0.05)
    return fit_toe(*samples, contact0_um, spacing_um, drift_g_um, wander)


def check_adhesion(samples: PullbackSamples, motion: Motion, timing: SensorTiming, dec: Decomposition,
                   approach_line: tuple[float, float], free_air: tuple[np.ndarray, np.ndarray], contact_um: float,
                   noise_g: float, approach_wander: Wander | None, compression_force_g: float,
                   down_above_up_um: tuple[float, float] | None = None,
                   approach_rise_um: float | None = None, ringing: Ringing | None = None) -> float:
    """TAP_ADHESION when ooze or adhesion pulls the nozzle after break contact, seen either way:
    the force dips below the departure's own free-air level just above break contact by more than
    ADHESION_MAX_DIP_NOISE noise sigmas, and more than the free air before contact dips by itself
    (`free_air_dip_g` over `free_air`, its times and forces, about approach_line) by
    FREE_AIR_DIP_MARGIN_NOISE of them; or the departure lies below the approach's free-air line at the same heights by more than THREAD_MAX_NOISE noise sigmas plus
    what the baseline's walk can move it between the two, 3 sigma (`thread_pull_g`: a thread
    pulling the whole departure pulls the dip's own reference too), unless the tap shows it to be a
    baseline shift (`_baseline_shift`). The walk is the approach's own: a thread pulling over the
    departure would pass for a walk there. Either must also exceed ADHESION_MIN_DIP_FRACTION of the
    compression force (a noise-free tap has no noise to compare with). The dip is a run's mean over
    half the period of a ringing the dwell shows (`adhesion_run_samples`). A film of plastic (a
    departure pulled below the approach's level together with a dwell drop, `_plastic_film`, a down
    contact above the up one, `_pressed_film`, or an approach that rose off its free air well above
    break contact, `_film_met_above`, approach_rise_um) is named before the thread.

    Returns the larger of the dip and the pull it let pass (g, 0 when the force neither dipped nor
    lay below): `analyze_tap` asks whether a hum had hidden a film in them.
    """
    floor_g = ADHESION_MIN_DIP_FRACTION * compression_force_g
    # The approach line's force where the approach passed the halt's height (its time is the halt).
    slope_g_s, intercept_g = approach_line
    drift_g_um = -slope_g_s / (motion.approach_speed_mm_s * 1000.0)  # as free_air_slope_g_um
    approach_at_halt_g = slope_g_s * motion.home_end_s + intercept_g
    run_samples = adhesion_run_samples(ringing)
    dip_g, pull_g = adhesion_measures(*samples, drift_g_um, contact_um, approach_at_halt_g, run_samples)
    dip_limit_g = max(ADHESION_MAX_DIP_NOISE * noise_g, floor_g)
    if dip_g is not None and dip_g > dip_limit_g:  # the second reference only when the first would reject
        dip_g = dip_below_both_references_g(samples, drift_g_um, contact_um, approach_at_halt_g, dip_g)
    if dip_g is not None and dip_g > dip_limit_g:
        # A fan's vibration or a heater's PWM dips the free air by itself, where no ooze is yet.
        own_dip_g = free_air_dip_g(*free_air, approach_line, run_samples)
        if dip_g > own_dip_g + FREE_AIR_DIP_MARGIN_NOISE * noise_g:
            raise TapInvalid(TAP_ADHESION, f"the force dips {dip_g:.1f} g below free air just above break contact "
                                           f"(more than {ADHESION_MAX_DIP_NOISE:g} x the {noise_g:.2f} g noise, and "
                                           f"than the {own_dip_g:.1f} g the free air before contact dips by itself "
                                           f"by {FREE_AIR_DIP_MARGIN_NOISE:g} x the noise): ooze or adhesion pulling "
                                           "the nozzle")
    passed_g = max(dip_g or 0.0, 0.0)
    if pull_g is None:
        return passed_g
    apart_samples = (motion.pullback_start_s - motion.home_end_s) / timing.sample_period_s + 2 * THREAD_REACH_UM[1]
    walk_g = 3.0 * math.sqrt(approach_wander.walk_var_g2 * max(apart_samples, 0.0)) if approach_wander else 0.0
    limit_g = thread_limit_g(noise_g, walk_g, compression_force_g)
    dwell_drop_share = abs(dec.points[P_DWELL_START][1] - dec.points[P_DWELL_END][1]) / compression_force_g
    if _plastic_film(pull_g, dwell_drop_share, compression_force_g, noise_g):
        raise TapInvalid(TAP_ADHESION, f"the force fell {dwell_drop_share:.0%} of the compression during the dwell "
                                       f"and after break contact lies {pull_g:.1f} g ({pull_g / compression_force_g:.0%}) "
                                       "below the approach's free-air level: plastic flowed from under the nozzle and "
                                       "holds it, so the contact the pullback finds is the film's, above the bed")
    if _pressed_film(pull_g, down_above_up_um, compression_force_g, noise_g):
        above_um, allowed_um = down_above_up_um
        raise TapInvalid(TAP_ADHESION, f"contact on the way down lies {above_um:.1f} um above break contact on the "
                                       f"way up ({above_um / allowed_um:.0%} of the {allowed_um:.1f} um allowed), and "
                                       f"after break contact the force lies {pull_g:.1f} g ({pull_g / compression_force_g:.0%}) "
                                       "below the approach's free-air level: a film of plastic the nozzle pressed "
                                       "holds it, so the contact the pullback finds is the film's, above the bed")
    if _film_met_above(pull_g, approach_rise_um, compression_force_g, noise_g):
        raise TapInvalid(TAP_ADHESION, f"the force on the way down rose off free air {approach_rise_um:.0f} um above "
                                       f"break contact, and after break contact lies {pull_g:.1f} g "
                                       f"({pull_g / compression_force_g:.0%}) below the approach's free-air level: "
                                       "plastic the nozzle met above the bed holds it, so the contact the pullback "
                                       "finds is the plastic's, above the bed")
    if pull_g > limit_g and not _baseline_shift(samples, drift_g_um, contact_um, approach_at_halt_g, pull_g,
                                                compression_force_g, dwell_drop_share):
        raise TapInvalid(TAP_ADHESION, f"the force after break contact lies {pull_g:.1f} g below the approach's "
                                       f"free-air level at the same heights (more than {limit_g:.1f} g): "
                                       "ooze or adhesion pulling the nozzle")
    return max(passed_g, pull_g)


def thread_limit_g(noise_g: float, walk_g: float, compression_force_g: float) -> float:
    """How far the departure may lie below the approach's free-air level (`check_adhesion`):
    THREAD_MAX_NOISE noise sigmas plus the walk between the two (walk_g), and at least
    ADHESION_MIN_DIP_FRACTION of the compression. The walk may excuse a pull up to THREAD_MIN_SHARE
    of the compression, no more: past it a pull is a thread (taplab seed 180 heavy ooze k 26: 29.4
    g, 20 %, let through by a walk allowance of 78 g)."""
    noise_limit_g = THREAD_MAX_NOISE * noise_g
    return max(min(noise_limit_g + walk_g, THREAD_MIN_SHARE * compression_force_g), noise_limit_g,
               ADHESION_MIN_DIP_FRACTION * compression_force_g)


def adhesion_run_samples(ringing: Ringing | None) -> int:
    """The samples the adhesion dip averages over: ADHESION_RUN_SAMPLES, or half the period of a
    ringing the dwell shows when that is longer. A ringing the pullback's start excites swings the
    departure about its level, and a short run reads its trough as a dip (2000 sps: 1-6 of 80 clean
    taps TAP_ADHESION under the sweep's ringing, the dwell ringing at 25-70 Hz, 29-80 samples); over
    half a period the trough averages out, while a thread's pull, tens of µm long, does not (taplab's
    and the reference's ooze: the dwell "rings" on a third to half of their taps, at 2-33 samples,
    and about one mild-ooze tap in 400 of taplab's is accepted for it, within 1.5 of its z_sigma_um)."""
    if ringing is None:
        return ADHESION_RUN_SAMPLES
    return max(ADHESION_RUN_SAMPLES, int(round(0.5 * ringing.period_samples)))


def dip_below_both_references_g(samples: PullbackSamples, drift_g_um: float, contact_um: float,
                                approach_at_halt_g: float, dip_g: float) -> float:
    """The adhesion dip (below the departure's level further up, `adhesion_dip`) reduced to what also
    lies below the approach's free-air line when that level stands above the line.

    A thread pulls the force below free air by either reference. A baseline that walks up over the
    departure (a cable's walk: taplab seed 2 cable drift, 3 to 5 g in 0.3 s) raises the level
    further up above the approach's line and leaves a "dip" below it near contact that lies no
    lower than the approach's free air (3 of 100 clean taps were TAP_ADHESION); a bowden shift on the
    way up moves the approach's line instead, and the departure's own level is the reference then.
    """
    x_um = 0.5 * (samples[0] + samples[1])
    level_pull_g = thread_pull_g(x_um, samples[2], drift_g_um, approach_at_halt_g, contact_um,
                                 (ADHESION_REACH_UM, ADHESION_LEVEL_UM))
    return dip_g + min(level_pull_g, 0.0) if level_pull_g is not None else dip_g


def departure_drift_share(samples: PullbackSamples, contact_um: float, drift_g_um: float) -> float:
    """How much of the approach's free-air drift (g per µm of height, from its line) the departure
    shows too: min(k_departure / k_approach, 1) when the departure's own slope against height, from
    APPROACH_DRIFT_FROM_UM above contact on, has the approach's sign and lies within APPROACH_DRIFT_AGREEMENT of it;
    else 0 (molten plastic met before the bed tilts the approach alone).

    A cable or bowden pulling in proportion to Z tilts both; the spec's approach component, meant
    for plastic under the nozzle, read taplab's 37 g/mm cable as 60 % (LOW_TAP_QUALITY).
    """
    x_lo_um, x_hi_um, force_g = samples
    first = int(x_lo_um.searchsorted(contact_um + APPROACH_DRIFT_FROM_UM))  # rising while the pullback moves
    if len(force_g) - first < APPROACH_DRIFT_MIN_SAMPLES or drift_g_um == 0.0:
        return 0.0
    x_um = x_lo_um[first:] + x_hi_um[first:]
    x_um -= x_um.mean()
    departure_g_um = 2.0 * float(x_um @ force_g[first:]) / float(x_um @ x_um)
    if departure_g_um / drift_g_um <= 0.0 or abs(departure_g_um - drift_g_um) > APPROACH_DRIFT_AGREEMENT * abs(drift_g_um):
        return 0.0
    return min(departure_g_um / drift_g_um, 1.0)


def _plastic_film(pull_g: float, dwell_drop_share: float, compression_force_g: float, noise_g: float) -> bool:
    """A film of plastic under the nozzle: the dwell drops PLASTIC_DWELL_DROP_SHARE of the compression
    and the departure lies PLASTIC_PULL_SHARE of it (and PLASTIC_PULL_NOISE noise sigmas) below the
    approach's level."""
    return dwell_drop_share >= PLASTIC_DWELL_DROP_SHARE and _film_holds(pull_g, compression_force_g, noise_g)


def _film_holds(pull_g: float, compression_force_g: float, noise_g: float) -> bool:
    """The departure lies PLASTIC_PULL_SHARE of the compression (and PLASTIC_PULL_NOISE noise sigmas)
    below the approach's level: the pull that, with a sign of plastic under the nozzle, is a film."""
    return pull_g >= max(PLASTIC_PULL_SHARE * compression_force_g, PLASTIC_PULL_NOISE * noise_g)


def _pressed_film(pull_g: float, down_above_up_um: tuple[float, float] | None, compression_force_g: float,
                  noise_g: float) -> bool:
    """A film of plastic under the nozzle seen the other way: the approach met it above the bed (the
    down contact PLASTIC_SQUEEZE_SHARE or more of the way to TAP_CONTACT_MISMATCH above the up one)
    and it holds the nozzle after break contact (the departure PLASTIC_PULL_SHARE of the compression
    and PLASTIC_PULL_NOISE noise sigmas below the approach's level)."""
    if down_above_up_um is None:
        return False
    above_um, allowed_um = down_above_up_um
    return above_um >= PLASTIC_SQUEEZE_SHARE * allowed_um and _film_holds(pull_g, compression_force_g, noise_g)


def _film_met_above(pull_g: float, approach_rise_um: float | None, compression_force_g: float,
                    noise_g: float) -> bool:
    """Plastic met above the bed: the approach rose off its free air PLASTIC_MET_ABOVE_UM or more
    above break contact (`approach_rise_above_um`) and the departure lies PLASTIC_PULL_SHARE of the
    compression (and PLASTIC_PULL_NOISE noise sigmas) below the approach's level."""
    return (approach_rise_um is not None and approach_rise_um >= PLASTIC_MET_ABOVE_UM
            and _film_holds(pull_g, compression_force_g, noise_g))


def _baseline_shift(samples: PullbackSamples, drift_g_um: float, contact_um: float, approach_at_halt_g: float,
                    pull_g: float, compression_force_g: float, dwell_drop_share: float) -> bool:
    """A departure below the approach's level that is a baseline shift, not a thread: small
    (under THREAD_MIN_SHARE of the compression), no plastic in the dwell (under
    PLASTIC_DWELL_DROP_SHARE), and as deep further up (THREAD_FAR_REACH_UM) within
    THREAD_LEVEL_CHANGE of itself when the departure reaches that far (THREAD_FAR_MIN_UM)."""
    if pull_g >= THREAD_MIN_SHARE * compression_force_g or dwell_drop_share >= PLASTIC_DWELL_DROP_SHARE:
        return False
    x_um = 0.5 * (samples[0] + samples[1])
    if x_um.max() - contact_um < THREAD_FAR_MIN_UM:
        return True  # too short to show a thread letting go, and nothing else shows one
    far_g = thread_pull_g(x_um, samples[2], drift_g_um, approach_at_halt_g, contact_um, THREAD_FAR_REACH_UM)
    return far_g is not None and abs(far_g - pull_g) <= THREAD_LEVEL_CHANGE * pull_g


def fit_compression(window: ModelWindow, motion: Motion, timing: SensorTiming, delay_s: float,
                    onset_um: float, drift_g_um: float = 0.0) -> ContactFit | None:
    """The contact model over the approach up to the halt (onset fixed to the pullback's), the
    free-air drift (g per µm of height, from the approach line) taken out first: a cable pulling
    40 g/mm ramps the approach like a soft contact, and the model has a constant baseline (taplab's
    cable drift: the down contact read ~190 µm above break contact, TAP_CONTACT_MISMATCH)."""
    spacing_um = max(motion.approach_speed_mm_s * 1000.0 * timing.sample_period_s, 0.05)
    return compression_fit(window, motion.home_end_s + delay_s, spacing_um, onset_um, drift_g_um)


def compression_fit(window: ModelWindow, read_until_s: float, spacing_um: float, onset_um: float,
                    drift_g_um: float) -> ContactFit | None:
    """`fit_compression` over the samples read up to `read_until_s`: the kernel _c_contact.fit_compression
    (the whole of `compression_fit_twin` in one call, its arithmetic in its order: the same to the last
    bit as the twin with the fit_fixed_onset kernel), or the twin."""
    if contact._C is None:
        return compression_fit_twin(window, read_until_s, spacing_um, onset_um, drift_g_um)
    found = contact._C.fit_compression(window.time_s, window.force_g, window.x_min_um, window.span_um, read_until_s,
                                       window.contact_line_um, spacing_um, onset_um, drift_g_um, SEARCH_SAMPLES)
    return None if found is None else fit_of_kernel(found, onset_um)


def compression_fit_twin(window: ModelWindow, read_until_s: float, spacing_um: float, onset_um: float,
                         drift_g_um: float) -> ContactFit | None:
    """The compression's fit without the kernel: _c_contact.fit_compression's numpy twin."""
    last = int(window.time_s.searchsorted(read_until_s, side="right"))
    if last < 6 or not math.isfinite(window.contact_line_um):
        return None
    x_min, span = window.x_min_um[:last], window.span_um[:last]
    force_g = window.force_g[:last]
    if drift_g_um:
        force_g = force_g - drift_g_um * (x_min + 0.5 * span)
    # fit_contact_at only answers with at least 2 samples in contact.
    found = fit_fixed_onset(force_g, x_min, span, window.contact_line_um + 0.5 * onset_um, spacing_um, onset_um)
    return found[0] if found else None


def check_contact_heights(window: ModelWindow, pullback: ContactFit | None, compression: ContactFit | None,
                          motion: Motion, timing: SensorTiming, compression_placed: bool) -> tuple[float, float] | None:
    """Contact on the way down against break contact on the way up, both at the same delay
    (validate.check_contact_consistency): the model fits when they exist, else the line points
    P1 and P4 mapped through the motion, the way down's within the approach's travel over a period,
    or where that would not do, over the gap frames lost about the touch left (`approach_interval_s`).
    Not judged unless `compression_placed`
    (`compression_places_the_halt`, and a compression fit that found a contact:
    COMPRESSION_STIFFNESS_SHARE_MIN): where no sample's window lies wholly between the touch and the
    halt, the way down holds no contact to place (issue 21's sweep: a reference tap averaged to 80
    sps, 1.3 periods from P1 to P2, put the down contact 754 um above the halt, TAP_CONTACT_MISMATCH;
    reference HX711 taps averaged to 10 sps, 0.2-0.5 samples from contact to the halt, 231-512 um).
    Returns how far the down contact lies above the up one and how far the check allows (µm; a film's
    first sign, `_pressed_film`), None where it is not judged."""
    if not compression_placed:
        return None
    down_um, down_sigma_um = ((compression.contact_um, compression.contact_sigma_um) if compression
                              else (window.contact_line_um, 0.0))
    up_um, up_sigma_um = (pullback.contact_um, pullback.contact_sigma_um) if pullback else (window.break_line_um, 0.0)
    period_s = timing.sample_period_s

    def tolerance_um_over(approach_s: float) -> float:
        return validate.contact_mismatch_tolerance_um(motion.approach_speed_mm_s * approach_s * 1000.0,
                                                      motion.pullback_speed_mm_s * period_s * 1000.0,
                                                      down_sigma_um, up_sigma_um)
    tolerance_um = tolerance_um_over(period_s)
    in_a_gap = False
    if down_um - up_um > PLASTIC_SQUEEZE_SHARE * tolerance_um:  # the gaps are looked for only where they matter
        approach_s = approach_interval_s(window.time_s, motion.home_end_s, down_um, motion.approach_speed_mm_s,
                                         period_s)
        in_a_gap = approach_s > period_s
        tolerance_um = tolerance_um_over(approach_s)
    validate.check_contact_consistency(down_um, up_um, tolerance_um)
    if in_a_gap:
        # The way down's contact lies anywhere in the frames lost about the touch: no film to read off
        # it (`_pressed_film`; reference bowden taps with the 1-5 samples before the halt lost: 1-7 of
        # 80 clean taps TAP_ADHESION, their down contacts 31-56 um above the up ones, 32-90 % of the way).
        return None
    return (down_um - up_um, tolerance_um) if math.isfinite(down_um - up_um) else None


# Frames lost in transport leave a gap in the samples' times; one this many periods long or longer
# (a jittered clock stays well under it) is a lost frame, not a late one.
LOST_FRAME_PERIODS = 1.5


def approach_interval_s(time_s: np.ndarray, halt_s: float, down_um: float, approach_speed_mm_s: float,
                        period_s: float) -> float:
    """The time between the approach's samples around its contact, down_um above the halt: one
    period, or where frames were lost between a period before the touch and the halt, the widest
    gap there. The way down knows its contact only to within that travel: a burst of 3 frames lost
    over a 3-4 sample compression (reference HX717 taps, 10 mm/s) put it 33-70 um above break
    contact, past the one sample allowed (31 um), TAP_CONTACT_MISMATCH on 6 of 40 clean taps."""
    if not (math.isfinite(down_um) and approach_speed_mm_s > 0):
        return period_s
    touch_s = halt_s - down_um / (approach_speed_mm_s * 1000.0)
    first = max(int(time_s.searchsorted(touch_s - period_s)) - 1, 0)
    times = time_s[first:int(time_s.searchsorted(halt_s)) + 1].tolist()  # a few samples: plain floats
    if len(times) < 2:
        return period_s
    widest_s = max(later - earlier for earlier, later in zip(times, times[1:]))
    return widest_s if widest_s >= LOST_FRAME_PERIODS * period_s else period_s


def compression_sample_count(window: ModelWindow, motion: Motion, delay_s: float, onset_um: float,
                             contact_um: float) -> int:
    """Samples read before the halt whose whole conversion window was at least an onset into contact."""
    if _C is not None:
        return _C.compression_samples(window.time_s, window.x_min_um, window.span_um, delay_s, motion.home_end_s,
                                      contact_um - onset_um)
    before_halt = window.time_s - delay_s <= motion.home_end_s
    pressed = window.x_min_um + window.span_um <= contact_um - onset_um
    return int(np.count_nonzero(before_halt & pressed))


def analyze_tap(tap: TapData, options: AnalysisOptions | None = None) -> TapAnalysis:
    """Analyse one tap. Never raises on data: what cannot be analysed is an invalid tap with a code."""
    # Wall time is what a printer waits (Klipper's `elapsed`); the process's CPU time is what the
    # analysis costs whatever else the machine runs (the speed benchmarks compare it).
    started, cpu_started = time.perf_counter(), time.process_time()
    options = options or AnalysisOptions()
    classifier = get_classifier(options.tap_classifier, options)  # a wrong name is a config error: raise
    result = _analyze_and_classify(tap, options, classifier)
    if hum_not_asked(tap, options) and hum_may_have_misled(tap, result):
        # Analysed again as `auto` would (its screen finds the hum or leaves the force as it was). A
        # rejection is replaced only when the tap then passes: the hum was the cause, and the
        # analysis without it is the better one; otherwise the first answer names what the tap
        # shows. An accepted tap takes the second answer whatever it is: its noise was a hum.
        again = _second_look_without_hum(tap, options.with_mains_hz("auto"), classifier)
        if again is not None and (again.valid or result.valid):
            result = again
    result.elapsed_ms = (time.perf_counter() - started) * 1000.0
    result.cpu_ms = (time.process_time() - cpu_started) * 1000.0
    return result


# The rejections a mains hum left in the force can cause, looked at again with the hum removed where
# a mains line dominates the tap's noise (`hum_may_have_misled`). A strong hum nobody asked to remove
# can part the two contacts by more than their white-noise fits allow (TAP_CONTACT_MISMATCH: bench
# tap_sweep's hum4000, 4 g at 50 or 60 Hz in a 4000 sps tap, 3 of 480 taps on seeds 1-12), or put the
# five lines' break in the pullback's first sixth (TAP_BREAK_CONTACT_TOO_EARLY: the reference
# noisy-mains taps with 5/2/2 g more hum, 2 of 240 clean taps on seeds 1-3, read -0.25 and -0.21 um
# off with it removed). Stronger, it bends every line and check: the reference's clean ADS1220 2000
# sps taps with 20/5/5 g more hum, 21 of 80 rejected (TAP_ADHESION 8, LOW_TAP_QUALITY 12,
# TAP_CHRONOLOGY 1), every one valid with the hum removed; on the other clean reference scenarios
# with 20/5/5 g, TAP_BREAK_CONTACT_TOO_LATE and LOW_TAP_QUALITY too. Not the sampling's, the motion's
# or the sensor's codes (too few samples, no dwell, a saturated ADC), which no hum causes; nor a
# pullback that never broke contact or a soft stage, whose tests a hum only makes harder to meet
# (its noise raises their bars): taplab seed 1's three short-pullback and two two-stage taps under a
# dominant line were rejected again with the same codes. A second look that rejects again leaves
# the first answer, so fouled taps keep theirs. Gated by the dominant line, hum4000 (seeds 1-12 and
# 126-140, 1,080 taps) and the noisy-mains taps above (240) lose no tap, as without the gate.
HUM_MAY_CAUSE = frozenset({TAP_CONTACT_MISMATCH, TAP_BREAK_CONTACT_TOO_EARLY, TAP_BREAK_CONTACT_TOO_LATE,
                           TAP_CHRONOLOGY, TAP_SHAPE_INVALID, LOW_COMPRESSION_FORCE, LOW_DECOMPRESSION_FORCE,
                           LOW_TAP_QUALITY, TAP_ADHESION})


def hum_may_have_misled(tap: TapData, result: TapAnalysis) -> bool:
    """Whether a hum left in the force may have misled the analysis of this tap: a rejection it can
    cause (HUM_MAY_CAUSE) under a mains line that dominates the noise, or an accepted tap whose film
    check a hum may have blinded (`film_judged_against_a_hum`)."""
    if result.valid:
        return film_judged_against_a_hum(tap, result)
    return result.error in HUM_MAY_CAUSE and hum_dominates(tap)


# A dip or pull the adhesion check let pass this many noise sigmas deep (and above the compression
# floor) is one a quieter noise could fail: with a hum removed that was most of the noise, the noise
# falls 2-4x (the reference HX717 taps with 5 / 10 g of hum: 3.8 / 5.7 g of noise, 1.6 g without),
# and the hum's own swing leaves the dip too. Measured on the reference's mild ooze with 3 / 5 / 10 g
# of hum at 50 or 60 Hz, 80 taps each (seed 1; accepted without a second look: 6 / 26 / 44, and 4
# with no hum added): a second look from 0, 0.5 or 1 noise sigma leaves 4 / 4 / 4 accepted, from 2
# 4 / 5 / 23. From 1, this look screens 178 of the 1,260 taps of both benchmark sets (from 0.5: 293)
# and the one tap that changed validity is a taplab mild-ooze one, now TAP_ADHESION.
FILM_HUM_LOOK_MIN_NOISE = 1.0


def film_judged_against_a_hum(tap: TapData, result: TapAnalysis) -> bool:
    """The adhesion check let a dip or pull pass that a quieter noise could fail (FILM_HUM_LOOK_MIN_NOISE
    noise sigmas deep, above ADHESION_MIN_DIP_FRACTION of the compression), and a mains line
    dominates the tap's noise (`hum_dominates`: its FFT is paid only past the dip's bar)."""
    floor_g = ADHESION_MIN_DIP_FRACTION * (result.compression_force_g or 0.0)
    noise_g = result.noise_sigma_g or 0.0
    return (result.passed_film_g > floor_g and result.passed_film_g >= FILM_HUM_LOOK_MIN_NOISE * noise_g
            and hum_dominates(tap))


def hum_dominates(tap: TapData) -> bool:
    """A mains line dominates the tap's noise (`tapcell.tap.hum.dominant_mains_lines`: one FFT)."""
    from tapcell.tap.hum import dominant_mains_lines  # as remove_mains_hum: a run without hum never imports it

    return bool(dominant_mains_lines(tap.time_s, tap.force_g))


def hum_not_asked(tap: TapData, options: AnalysisOptions) -> bool:
    """Neither the options nor the tap's meta say what to do about mains hum (a tap from elsewhere):
    an explicit `mains_hz` (a list, `none`, `auto`) is the user's or the printer's answer, kept."""
    return options.mains_hz is None and tap.meta.get("mains_hz") is None


def _second_look_without_hum(tap: TapData, auto: AnalysisOptions, classifier) -> TapAnalysis | None:
    """The tap analysed again with `auto`'s hum removal, or None where its screen finds no hum to
    remove (the force is left as it was, and the analysis would repeat the first look's answer: on
    taplab's 300 taps of seed 1, 6 of the 14 second looks) or the split fails with it."""
    try:
        split_made = split_tap(tap, auto)
    except TapInvalid:
        return None
    _, _, _, hum = split_made
    if hum is None:
        return None
    return _analyze_and_classify(tap, auto, classifier, split_made)


def _analyze_and_classify(tap: TapData, options: AnalysisOptions, classifier,
                          split_made: SplitMade | None = None) -> TapAnalysis:
    """The tap analysed (from `split_tap`'s answer, when made already) and its quality classified,
    or an invalid answer with the code that stopped it."""
    try:
        result, context = _analyze(tap, options, split_made)
        return run_classifier(result, context, classifier, options.tap_classifier)
    except TapInvalid as invalid:
        return TapAnalysis(valid=False, error=invalid.code, message=invalid.message)


# What the sample check finds (the kernel's `sample_problem` answers with these numbers, 0: nothing;
# SAMPLES_REPEATING: nothing wrong, but some reading equals the one before it, for `stale_readings`).
SAMPLES_NOT_FINITE, SAMPLES_NOT_INCREASING, SAMPLES_SATURATED, SAMPLES_REPEATING = 1, 2, 3, 4
_SAMPLE_PROBLEMS = {SAMPLES_NOT_FINITE: "time or force holds NaN or infinity",
                    SAMPLES_NOT_INCREASING: "sample times are not strictly increasing"}
# A saturated sensor (an ADC at its limit records the force clipped flat): at least SATURATED_RUN
# samples in a row exactly at the tap's extreme force, the force leaving it before the tap ends
# (a reading frozen to the end is a stuck sensor, which the live probe names itself), where the rest of the tap repeats a value
# from one sample to the next in at most one step in SATURATED_REPEATS_OTHER. Measured (bench
# tap_sweep's clipped cases, docs/tap-analysis.md): no clean tap of taplab (seeds 1, new), the
# reference taps and sessions or the real tap holds more than 2 equal samples at its extreme, and
# none of them rounded to 0.1-30 g steps is flagged once the repeat rule applies (rounded to 1 g a
# tap holds up to 11 at its extreme; rounded to 10 g one holds 63 there, its other steps 64 %
# repeats, 0.4 % on clean taps at most); the same taps clipped at 90 % of their peak are flagged
# in 77-100 % of each set (those left: a spike the peak, a run too short).
SATURATED_RUN, SATURATED_REPEATS_OTHER = 8, 4


def saturated_run(force_g: np.ndarray) -> tuple[int, int]:
    """Where a saturated sensor held the force: (first sample, samples) of the longest run exactly at
    the tap's extreme force, on the side away from its first sample (its max, or its min for a
    negative polarity) and left before the last sample, when that run is SATURATED_RUN samples or longer and the other samples
    repeat a value in at most one step in SATURATED_REPEATS_OTHER; else (0, 0). The kernel's
    `sample_problem` twin (finite samples): a sensor whose steps are coarser than its noise repeats
    values everywhere, and a long run proves nothing there."""
    f = force_g
    high, low = f.max(), f.min()
    extreme = high if high - f[0] >= f[0] - low else low
    at = np.concatenate(([False], f == extreme, [False]))
    edges = np.flatnonzero(at[1:] != at[:-1])  # starts and ends of the runs, in pairs
    # A run held to the last sample is a sensor that stopped changing (or a nozzle still pressing),
    # not a limit the force went past and came back from.
    left = edges[1::2] < len(f)
    starts, lengths = edges[::2][left], (edges[1::2] - edges[::2])[left]
    if len(lengths) == 0 or lengths.max() < SATURATED_RUN:
        return 0, 0
    longest = int(lengths.argmax())
    off = f[1:] != extreme
    repeats = np.count_nonzero(off & (f[1:] == f[:-1]))
    if SATURATED_REPEATS_OTHER * repeats > np.count_nonzero(off):
        return 0, 0
    return int(starts[longest]), int(lengths[longest])


def _saturated(t: np.ndarray, f: np.ndarray) -> TapInvalid:
    start, count = saturated_run(f)
    held_ms = (t[start + count - 1] - t[start]) * 1000.0
    side = "highest" if f[start] >= f[0] else "lowest"
    return TapInvalid(TAP_SENSOR_SATURATED,
                      f"the force holds at {f[start]:.1f} g, the tap's {side}, for {count} samples in a row "
                      f"({held_ms:.0f} ms): the load cell's sensor saturated and the force past its limit is "
                      "lost; lower the probing speed (PROBE_SPEED=) or the trigger force, or the sensor's "
                      "gain, or fit a larger load cell")


def _check_samples(tap: TapData) -> tuple[np.ndarray, np.ndarray, bool]:
    """The tap's times and forces, checked (TapInvalid when not finite, not increasing, too few,
    saturated), and whether any reading may equal the one before it (the kernel says; the twins
    leave it to `stale_readings`)."""
    # Contiguous (a caller's strided view is copied): the compiled kernels read them as plain arrays.
    t = np.ascontiguousarray(tap.time_s, dtype=float)
    f = np.ascontiguousarray(tap.force_g, dtype=float)
    if t.ndim != 1 or f.shape != t.shape:
        raise TapInvalid(TAP_DATA_INSUFFICIENT, f"time and force differ in shape ({t.shape} vs {f.shape})")
    if len(t) < MIN_SAMPLES:
        raise TapInvalid(TAP_DATA_INSUFFICIENT, f"{len(t)} samples, at least {MIN_SAMPLES} needed")
    repeating = True
    if _C is not None:
        code = _C.sample_problem(t, f)
        if code == SAMPLES_SATURATED:
            raise _saturated(t, f)
        problem, repeating = _SAMPLE_PROBLEMS.get(code), code == SAMPLES_REPEATING
    elif not (np.isfinite(t).all() and np.isfinite(f).all()):
        problem = _SAMPLE_PROBLEMS[SAMPLES_NOT_FINITE]
    elif (t[1:] <= t[:-1]).any():
        problem = _SAMPLE_PROBLEMS[SAMPLES_NOT_INCREASING]
    elif saturated_run(f)[1]:
        raise _saturated(t, f)
    else:
        problem = None
    if problem:
        raise TapInvalid(TAP_DATA_INSUFFICIENT, problem)
    return t, f, repeating


@dataclass(eq=False, repr=False)
class SplitTap:
    """A tap after its first steps: samples checked, motion and sensor timing read, polarity and
    corrupted frames and hum handled, the five lines found."""

    time_s: np.ndarray
    force_g: np.ndarray  # positive polarity, spikes repaired, hum removed
    motion: Motion
    timing: SensorTiming
    dec: Decomposition
    ps: PrefixSums
    noise_g: float
    # The points in time order and the angles a tap's (validate.split_checks_pass): check_split
    # need not check them again.
    points_pass: bool = False
    stale_readings: int = 0  # readings dropped as stale (`stale_readings`)
    frames_lost_at_halt: bool = False  # `frames_lost_at_the_halt`

    @cached_attribute
    def rising_stop(self) -> int:
        """The first sample read after the pullback ended (at the timing's delay): where the free-air
        walk's departure and the adhesion checks' samples end (`read_while_rising`)."""
        return int(self.time_s.searchsorted(self.motion.pullback_end_s + self.timing.delay_s, side="right"))

    @cached_attribute
    def wanders(self) -> tuple[Wander | None, Wander | None]:
        """`free_air_wanders` of the tap, measured once for the toe fit and its uncertainty."""
        motion, period_s = self.motion, self.timing.sample_period_s
        steps_um = (motion.approach_speed_mm_s * 1000.0 * period_s, motion.pullback_speed_mm_s * 1000.0 * period_s)
        return free_air_wanders(self.force_g, self.dec, steps_um, self.rising_stop)

    @cached_attribute
    def compression_placed(self) -> bool:
        """`compression_places_the_halt` for this tap: asked by the lag, the contact check and z_sigma_um."""
        return compression_places_the_halt(self.dec, self.motion, self.timing)

    @cached_attribute
    def steep_rise(self) -> tuple[float, float] | None:
        """The line of the compression's steep rise alone, where the split's compression segment ran on
        into a ringing dwell (`steep_rise_line`), else None: the compression line the lag and the
        stiffness the lines show take instead of the split's."""
        return steep_rise_line(self)

    @property
    def contact_s(self) -> float:
        """When contact began as the lines read it: P1, or where the steep rise's line meets the
        approach line when the split's compression segment ran on (`steep_rise`): there P1 lies where
        a line through the ringing meets the approach, too early."""
        p1_s = self.dec.points[P_CONTACT][0]
        return p1_s if self.steep_rise is None else line_intersection(self.steep_rise, self.dec.approach_line, p1_s)[0]

    @cached_attribute
    def ringing(self) -> Ringing | None:
        """The ringing the dwell shows (tapcell.tap.stage.dwell_ringing), against the white noise:
        measured once for the stage checks and z_sigma_um's ringing part."""
        start, (_, peak, release, _) = self.dec.start, self.dec.bounds
        dwell_start, dwell_end = start + peak, start + release
        return dwell_ringing(self.time_s[dwell_start:dwell_end], self.force_g[dwell_start:dwell_end],
                             self.noise_g * self.noise_g)


@dataclass(eq=False, repr=False)
class ContactFits:
    """The sharp contact model over the pullback (with its near-contact residual sigma) and over the
    approach; either may be missing. With what the steps after them read again: the pullback's
    samples at the window's delay (`pullback_samples`) and the free-air drift (`free_air_slope_g_um`)."""

    pullback: ContactFit | None
    near_sigma_g: float | None
    compression: ContactFit | None
    samples: PullbackSamples
    drift_g_um: float
    no_contact_down: bool = False  # the compression's fit found no contact (COMPRESSION_STIFFNESS_SHARE_MIN)


# What `split_tap` answers: the split, the polarity, the frames repaired and the hum removed.
SplitMade = tuple[SplitTap, int, int, "HumFit | None"]


def _analyze(tap: TapData, options: AnalysisOptions,
             split_made: SplitMade | None = None
             ) -> tuple[TapAnalysis, AnalysisContext]:
    split, polarity, outliers, hum = split_made or split_tap(tap, options)
    result = result_of_split(split, polarity, outliers, hum)
    context = AnalysisContext(tap, split.motion, split.timing)
    try:
        delay_s = lag_before_the_fits(split, result)
        check_split(split, delay_s)
        window = model_window(split.time_s, split.force_g, split.motion, split.timing, delay_s, split.dec,
                              split.contact_s)
        fits = fit_contact_models(split, window, delay_s, options, result)
        result.z_line_mm = split.motion.z_halt_mm + window.break_line_um / 1000.0  # P4 mapped, delay-corrected
        down_above_up_um = check_contact_heights(window, fits.pullback, fits.compression, split.motion, split.timing,
                                                 split.compression_placed and not fits.no_contact_down)
        window_delay_s = delay_s  # the delay the window's heights were read with ("auto": 0, estimated now)
        delay_s = apply_delay_estimate(split, fits, delay_s, result)
        z_from_sharp_model_or_lines(split, fits, result)
        if options.uses_toe_model:
            z_from_toe_model(split, window, fits, delay_s, window_delay_s, result, down_above_up_um)
        check_decompression_samples(split, window, delay_s, window_delay_s, result)
        z_uncertainty(split, window, fits, delay_s, window_delay_s, result)
        compression_stiffness(split, window, fits, delay_s, result)
    except TapInvalid as invalid:
        # Keep the lines, points and what was measured: they show what went wrong (plots, tap logs).
        result.valid, result.error, result.message = False, invalid.code, invalid.message
        return result, context
    result.message = "ok"
    return result, context


def split_tap(tap: TapData, options: AnalysisOptions) -> SplitMade:
    """Steps 1-3: samples and motion checked, sensor timing, polarity, corrupted frames repaired,
    mains hum removed, the five lines; with the polarity, the frames repaired and the hum."""
    time_s, force_raw, repeating = _check_samples(tap)
    stale = stale_readings(force_raw) if repeating else None
    if stale is not None:  # dropped, as a lost reading is: its time is not its conversion's
        time_s, force_raw = np.delete(time_s, stale), np.delete(force_raw, stale)
    validate.check_moves(tap.moves)
    try:
        motion = tap_motion(tap)
    except MotionError as problem:
        raise TapInvalid(TAP_MOTION_INVALID, str(problem)) from None
    period_s = sample_period_s(tap.sample_rate_sps, time_s)
    timing = sensor_timing(tap, options, period_s)
    validate.check_motion(motion, time_s)
    polarity, force, outliers, all_noise_g = polarity_and_repaired(time_s, force_raw, motion, options.outlier_sigma)
    allowance = UNKNOWN_DELAY_ALLOWANCE_S if timing.estimate_delay or timing.delay_from_halt else timing.delay_s
    lag_samples = math.ceil((allowance + timing.integration_s) / period_s) + LAG_MARGIN_SAMPLES
    force_read = force  # as read (repaired): their steps bound the noise where a hum is taken out
    force, hum = remove_mains_hum(tap, options, time_s, force, motion, timing, lag_samples, period_s)
    dec, ps = decompose(time_s, force, motion, lag_samples, period_s)
    checks_pass = validate.split_checks_pass(dec.points, dec.angles_deg)
    lost_at_halt = frames_lost_at_the_halt(time_s, motion.home_end_s, period_s)
    if not checks_pass:
        dec, ps = decompose_again(time_s, force, motion, lag_samples, period_s, lost_at_halt, (dec, ps))
        checks_pass = validate.split_checks_pass(dec.points, dec.angles_deg)
    elif lost_at_halt:
        dec, ps = split_across_the_gap_if_flatter(time_s, force, motion, lag_samples, period_s, (dec, ps))
    # Second differences of the whole analysed window: hundreds of samples even when the
    # approach holds a dozen; the four kinks of a tap cannot move their median. A window of every
    # sample, which no repair and no hum removal changed, is what the spike repair measured.
    if all_noise_g is not None and hum is None and dec.start == 0 and dec.stop == len(force):
        noise_g = all_noise_g
    else:
        noise_g = noise_sigma_g(force[dec.start:dec.stop])
        if hum is not None:
            noise_g = max(noise_g, rounding_noise_g(force_read[dec.start:dec.stop]))
    split = SplitTap(time_s, force, motion, timing, dec, ps, noise_g, checks_pass,
                     0 if stale is None else len(stale), lost_at_halt)
    return split, polarity, outliers, hum


def result_of_split(split: SplitTap, polarity: int, outliers: int, hum: HumFit | None) -> TapAnalysis:
    """The result as far as the five lines go, in the tap's own polarity."""
    dec = split.dec
    if polarity == 1:  # x 1 changes no bit: copies of the split's own lists
        points, lines, angles_deg = list(dec.points), list(dec.lines), list(dec.angles_deg)
    else:
        sign = float(polarity)  # what int x float multiplies by; float x float takes the interpreter's fast path
        points = [(t, sign * f) for t, f in dec.points]
        lines = [(sign * slope, sign * intercept) for slope, intercept in dec.lines]
        angles_deg = [sign * a for a in dec.angles_deg]
    return TapAnalysis(
        valid=True,
        polarity=polarity,
        points=points,
        lines=lines,
        angles_deg=angles_deg,
        outliers=outliers,
        stale_readings=split.stale_readings,
        sensor_integration_s=split.timing.integration_s,
        noise_sigma_g=split.noise_g,
        hum=hum.to_json() if hum else None,
        compression_force_g=abs(dec.points[P_DWELL_START][1] - dec.points[P_CONTACT][1]),
        break_contact_time_s=dec.points[P_BREAK][0],
    )


def lag_before_the_fits(split: SplitTap, result: TapAnalysis) -> float:
    """The sensor delay the heights are read with: from the halt (P2 against the motion's halt),
    the option or meta's, or 0 while it is to be estimated from the fits ("auto")."""
    timing = split.timing
    if timing.delay_from_halt:
        halt_lag_s = (lag_from_halt_s(compression_end_s(split), split.motion.home_end_s,
                                      timing.sample_period_s, UNKNOWN_DELAY_ALLOWANCE_S)
                      if split.compression_placed else None)
        timing.delay_s = max(halt_lag_s - 0.5 * timing.integration_s, 0.0) if halt_lag_s is not None else 0.0
    delay_s = 0.0 if timing.estimate_delay else timing.delay_s
    result.sensor_delay_s = delay_s
    return delay_s


# A compression segment that runs this many samples past its steep rise, one of them this many noise
# sigmas above the dwell line, ran on into a ringing dwell; steep: a step of this many noise sigmas
# (noise cannot halve it). Without the overshoot, 13 reference taps (clean, glitch, soft sheet, mild
# ooze) read 0.03-0.55 um higher; with it the rule fires on no clean reference tap and on 17 heavy-ooze
# ones, rejected as before (tests/tap/test_ringing_lag.py), and changes no code or Z of taplab seeds 1-40.
RISE_OVERRUN_SAMPLES = 3
STEEP_RISE_NOISE = 8.0
OVERSHOOT_NOISE = 6.0


def compression_end_s(split: SplitTap) -> float:
    """When the force reached the dwell, as the sensor read it: P2, but no later than the dwell's first
    sample, which already reads the dwell's force. A compression of one sample (taplab at 20 g/µm and 5
    mm/s: one sample between free air and the dwell) gives the split a compression line through a
    free-air sample and that one, a third as steep as the real one, which meets the dwell 6 ms after
    the halt, past the dwell's first sample at 3 ms; the lag read off it, 4.5 ms, put the down contact
    22 µm high at 5 mm/s (TAP_CONTACT_MISMATCH, the sweep's k20 on seed 3). Only a compression line
    drawn through two samples is bounded so; a line fitted to three or more keeps its P2 (bounded
    there too, the reference's noisy mains read +0.13 µm higher, and a heavy-ooze tap of taplab seed 1
    pressing a film for 17 periods passed its contact check), unless it ran on into a ringing dwell
    (`steep_rise_line`: a gantry rung by the halt carried the force past the dwell's level and the split
    ended the compression 4-7 samples late, P2 8-13 ms after the halt, the down contact 20-85 µm
    above the up one; the sweep's ring320x3 and ref_ring)."""
    dec = split.dec
    contact, peak = dec.bounds[0], dec.bounds[1]
    if peak - contact > 2:
        p2_s = dec.points[P_DWELL_START][0]
        if split.steep_rise is None:
            return p2_s
        # Where the steep rise's own line meets the dwell line.
        return min(p2_s, line_intersection(split.steep_rise, dec.lines[2], p2_s)[0])
    return min(dec.points[P_DWELL_START][0], float(split.time_s[dec.start + peak]))


def steep_rise_line(split: SplitTap) -> tuple[float, float] | None:
    """The line (slope g/s, intercept g) of the compression's steep rise alone, when the split's
    compression segment ran on into the dwell: RISE_OVERRUN_SAMPLES or more samples after the rise fell
    to under half its steepest step (a step of STEEP_RISE_NOISE noise sigmas or more), one of them
    OVERSHOOT_NOISE noise sigmas above the dwell line, and the steep line steeper than the dwell's.
    Else None."""
    dec, time_s, force_g = split.dec, split.time_s, split.force_g
    first, stop = dec.start + dec.bounds[0], dec.start + dec.bounds[1]
    if stop - first < RISE_OVERRUN_SAMPLES + 2:
        return None
    dwell_slope, dwell_intercept = dec.lines[2]
    # First the cheap test most taps fail: no sample of the segment stands that far above the dwell
    # line's lowest point over the segment (a compression rises towards the dwell from below).
    lowest_dwell_g = dwell_slope * float(time_s[stop - 1] if dwell_slope < 0.0 else time_s[first]) + dwell_intercept
    segment = force_g[first:stop]
    if float(segment.max()) < lowest_dwell_g + OVERSHOOT_NOISE * split.noise_g:
        return None
    steps = np.diff(segment)
    steepest = int(np.argmax(steps))
    if steps[steepest] < STEEP_RISE_NOISE * split.noise_g:
        return None
    slowed = np.flatnonzero(steps[steepest + 1:] < 0.5 * steps[steepest])
    if len(slowed) == 0:
        return None
    rise_stop = first + steepest + 2 + int(slowed[0])  # the first sample past the steep rise
    if stop - rise_stop < RISE_OVERRUN_SAMPLES:
        return None
    overshoot_g = force_g[rise_stop:stop] - (dwell_slope * time_s[rise_stop:stop] + dwell_intercept)
    if float(overshoot_g.max()) < OVERSHOOT_NOISE * split.noise_g:
        return None
    line = segment_line(split.ps, dec.bounds[0], rise_stop - dec.start)
    return line if line[0] > dwell_slope else None


def compression_places_the_halt(dec: Decomposition, motion: Motion, timing: SensorTiming) -> bool:
    """Does the compression (P1 to P2) last one conversion window and one period, so that at least
    one sample's window lies wholly between the touch and the halt? Shorter, the compression line
    runs through samples the windows smear across both kinks, and P2 lands anywhere in a window:
    the lag read off it is no lag, and the delay falls back to 0 as for an implausible lag
    (issue 21's sweep: a reference tap averaged to 10 sps read a lag of 46 ms, its contact 15 um
    low at z_sigma 0.7). The clean reference taps press 1.8-3.7 periods, all but one >= 2.3;
    those averaged to 80 sps 1.3-1.5.

    An approach faster than the guide allows must also have taken a sample to come down from
    break contact's height (P4) to the halt (`validate.compression_too_fast`): else P1 lies where no
    sample put it, however long before P2 (the sweep's reference HX717 taps averaged to 80 sps, 66 um
    a sample, 0.9 samples from contact to the halt and 2.9 periods from P1 to P2: a lag of 9 ms read
    off the halt put Z 3.1 um low, and a down contact above the up one a squeeze of 36 um in z_sigma_um)."""
    period_s = timing.sample_period_s
    pressing_s = dec.points[P_DWELL_START][0] - dec.points[P_CONTACT][0]
    if pressing_s < period_s + timing.integration_s:
        return False
    step_um = motion.approach_speed_mm_s * period_s * 1000.0
    if step_um <= validate.FAST_APPROACH_GUIDE_STEPS * validate.GUIDE_APPROACH_STEP_UM:
        return True  # within the guide's speed: no motion lookup
    return not validate.compression_too_fast(break_line_height_um(dec, motion, timing, 0.0), step_um)


def break_line_height_um(dec: Decomposition, motion: Motion, timing: SensorTiming, delay_s: float) -> float:
    """Break contact's line point P4 mapped through the motion (µm above the halt; read half a
    conversion window late, plus the delay)."""
    return (motion.z_at_time_mm(dec.points[P_BREAK][0] - delay_s - 0.5 * timing.integration_s)
            - motion.z_halt_mm) * 1000.0


def check_split(split: SplitTap, delay_s: float) -> None:
    """The spec's checks on the lines: the nozzle left the bed (unless the tap shows it leaving
    inside the pullback), the points' order and the lines' shape, break contact's place in the pullback."""
    dec, motion, timing = split.dec, split.motion, split.timing
    period_s = timing.sample_period_s
    try:
        # What both ways of asking "did the nozzle leave the bed" read: the compression force, the
        # force at the pullback's end and the departure's scatter about its line.
        pressed_g = dec.points[P_DWELL_START][1] - dec.points[P_CONTACT][1]
        end_g = force_at_g(split.time_s, split.force_g, motion.pullback_end_s)
        scatter_g = math.sqrt(segment_stats(split.ps, dec.bounds[3], dec.stop - dec.start)[0])
        if not left_inside_pullback(motion, dec, period_s, end_g, scatter_g, pressed_g):
            validate.check_left_the_bed(pressed_g, force_left_at_end_g(motion, dec, end_g), scatter_g)
        if not split.points_pass:
            validate.check_points(dec.points, dec.angles_deg)
        validate.check_break_contact(dec.points[P_BREAK][0] - delay_s - 0.5 * timing.integration_s, motion, period_s)
    except TapInvalid as invalid:
        # "Lengthen pullback_distance" on a pullback of a few samples: its rules count samples the
        # pullback does not hold (issue 21's sweep: 10 mm/s at 320 sps); say so instead.
        if invalid.code in (TAP_PULLBACK_TOO_SHORT, TAP_BREAK_CONTACT_TOO_LATE):
            validate.check_pullback_samples(motion, period_s)
        # Lines out of order or misshapen where the approach crossed the compression in less than a
        # sample: no sample placed them (issue 21's sweep, reference HX711 taps averaged to 10 sps).
        if invalid.code in (TAP_CHRONOLOGY, TAP_SHAPE_INVALID):
            check_compression_samples(motion, period_s, break_line_height_um(dec, motion, timing, delay_s))
        raise


def check_compression_samples(motion: Motion, period_s: float, contact_um: float) -> None:
    """TAP_DATA_INSUFFICIENT where the approach went from contact (`contact_um` above the halt, as
    the way up reads it) to the halt in less than a sample, faster than the guide's probing speed
    (`validate.check_compression_samples`)."""
    step_um = motion.approach_speed_mm_s * period_s * 1000.0
    validate.check_compression_samples(contact_um, step_um, motion.approach_speed_mm_s)


def fit_contact_models(split: SplitTap, window: ModelWindow, delay_s: float, options: AnalysisOptions,
                       result: TapAnalysis) -> ContactFits:
    """The sharp contact model over the pullback and over the approach (the onset the pullback's)."""
    motion, timing = split.motion, split.timing
    samples = pullback_samples(window, motion, timing, delay_s)
    found = fit_pullback(window, samples, motion, timing, options)
    pullback, near_sigma_g = found if found else (None, None)
    if pullback:
        # For pooling taps at one spot (tapcell.tap.pool): the samples the sharp fit read, and its answer.
        x_lo, x_hi, force_up = samples
        result.pullback_fit = PullbackFit(x_lo, x_hi - x_lo, force_up, pullback.contact_um, pullback.stiffness_g_um,
                                          pullback.onset_um, motion.pullback_speed_mm_s, delay_s)
    drift_g_um = free_air_slope_g_um(split.dec, motion)
    compression = fit_compression(window, motion, timing, delay_s, pullback.onset_um if pullback else 0.0, drift_g_um)
    no_contact_down = bool(compression and pullback
                           and compression.stiffness_g_um < COMPRESSION_STIFFNESS_SHARE_MIN * pullback.stiffness_g_um)
    if no_contact_down:
        compression = None
    return ContactFits(pullback, near_sigma_g, compression, samples, drift_g_um, no_contact_down)


# A compression fit softer than this share of the pullback's stiffness found no contact, and the
# way down then holds none to judge (`check_contact_heights`): with the frames between the touch
# and the halt lost, one sample was left pressed, and the fit took the approach's slow rise for a
# contact of 0.02 g/um 485 um above the halt (the pullback's: 1.9 g/um; a reference HX717 tap with
# the 2 samples before the halt lost, TAP_CONTACT_MISMATCH), where the line point P1, from the
# same lone sample, lay as far off on ADS1220 660 taps with 4-5 lost. Every valid tap of taplab
# seed 1, the reference taps and the sessions reads 0.55 or more (the loading and unloading
# stiffness of one bed), every tap at all 0.16 or more.
COMPRESSION_STIFFNESS_SHARE_MIN = 0.1


def apply_delay_estimate(split: SplitTap, fits: ContactFits, delay_s: float, result: TapAnalysis) -> float:
    """The delay estimated from the tap (contact down against break contact up), reported; with
    `sensor_delay_s=auto` applied to the pullback's contact and the line estimate. Returns the delay."""
    motion, timing = split.motion, split.timing
    pullback, compression = fits.pullback, fits.compression
    if timing.delay_from_halt:
        result.sensor_delay_estimate_s = delay_s
    elif pullback and compression:
        speeds_um_s = (motion.approach_speed_mm_s + motion.pullback_speed_mm_s) * 1000.0
        result.sensor_delay_estimate_s = delay_s + (pullback.contact_um - compression.contact_um) / speeds_um_s
    if timing.estimate_delay:
        delay_s = result.sensor_delay_estimate_s if result.sensor_delay_estimate_s is not None else 0.0
        if pullback:
            # Break contact moves down by v_pullback × delay; the sigma gains the down/up share of both fits.
            share = motion.pullback_speed_mm_s / (motion.approach_speed_mm_s + motion.pullback_speed_mm_s)
            pullback.contact_um -= delay_s * motion.pullback_speed_mm_s * 1000.0
            if compression:
                pullback.contact_sigma_um = math.hypot(pullback.contact_sigma_um * (1 - share),
                                                       share * compression.contact_sigma_um)
        result.z_line_mm = motion.z_at_time_mm(split.dec.points[P_BREAK][0] - delay_s - 0.5 * timing.integration_s)
    result.sensor_delay_s = delay_s
    return delay_s


def z_from_sharp_model_or_lines(split: SplitTap, fits: ContactFits, result: TapAnalysis) -> None:
    """Z from the sharp contact model, or from the line intersection P4 when it could not be fitted."""
    motion, timing, pullback = split.motion, split.timing, fits.pullback
    if pullback:
        result.z_mm = motion.z_halt_mm + pullback.contact_um / 1000.0
        result.z_sigma_um = pullback.contact_sigma_um
        result.z_sharp_mm, result.z_sharp_sigma_um = result.z_mm, result.z_sigma_um
        result.z_method = "contact_model"
        result.contact_onset_um = pullback.onset_um
        result.stiffness_decompression_g_um = pullback.stiffness_g_um
        result.fit_residual_sigma_g = fits.near_sigma_g
        window_um = motion.pullback_speed_mm_s * timing.integration_s * 1000.0
        result.step_sigma_g = pullback.stiffness_g_um * step_staircase_sigma_um(timing.z_step_um, window_um)
    else:
        dec = split.dec
        result.z_mm = result.z_line_mm
        result.z_sigma_um = break_time_sigma_s(split.ps, dec, dec.points[P_BREAK][0]) * motion.pullback_speed_mm_s * 1000.0
        result.z_method = "lines"
        result.stiffness_decompression_g_um = abs(dec.decompression_line[0]) / (motion.pullback_speed_mm_s * 1000.0)


def z_from_toe_model(split: SplitTap, window: ModelWindow, fits: ContactFits, delay_s: float, window_delay_s: float,
                     result: TapAnalysis, down_above_up_um: tuple[float, float] | None = None) -> None:
    """Z from the toe model (tapcell.tap.toe), started at the sharp model's contact; then the
    adhesion checks that belong to it (TAP_ADHESION raised). down_above_up_um: what
    `check_contact_heights` measured and allowed."""
    motion, timing, dec, pullback = split.motion, split.timing, split.dec, fits.pullback
    # The toe is fitted in the window's heights; a delay estimated since ("auto") moves its
    # contact down by pullback speed x delay, as it moved the sharp fit's above.
    lag_shift_um = (delay_s - window_delay_s) * motion.pullback_speed_mm_s * 1000.0
    start = pullback.contact_um + lag_shift_um if pullback else window.break_line_um
    drift_g_um, samples = fits.drift_g_um, fits.samples  # the samples: for the toe fit and the adhesion check
    wander, approach_wander = split.wanders
    fit_drift_g_um = toe_drift_g_um(dec, split.ps, motion, timing.sample_period_s,
                                    wander.walk_var_g2 if wander else 0.0)
    toe = fit_pullback_toe(samples, motion, timing, start, fit_drift_g_um, wander)
    if not toe:
        # No toe has its least residual inside the grid's reach of the sharp contact (of 2,060 taps
        # of both sets, 11 heavy-ooze ones). The adhesion checks hold at the sharp contact all the
        # same: a heavy-ooze reference tap read in 3 g steps passed the classifier (quality 54) and
        # was accepted 43 µm high, its film unchecked.
        if math.isfinite(start):
            rising = read_while_rising(samples, split, window, window_delay_s)
            result.passed_film_g = check_adhesion_at(split, rising, start, lag_shift_um, delay_s,
                                                     approach_wander or wander, result.compression_force_g,
                                                     down_above_up_um)
        return
    result.z_mm = motion.z_halt_mm + (toe.contact_um - lag_shift_um) / 1000.0
    result.toe_grid, result.toe_z_origin_mm = toe.grid, motion.z_halt_mm - lag_shift_um / 1000.0
    result.z_sigma_um = toe.sigma_um
    result.z_method = "toe"
    result.contact_onset_um = toe.width_um
    result.stiffness_decompression_g_um = toe.stiffness_g_um
    rising = read_while_rising(samples, split, window, window_delay_s)
    result.passed_film_g = check_adhesion_at(split, rising, toe.contact_um, lag_shift_um, delay_s,
                                             approach_wander or wander, result.compression_force_g, down_above_up_um)
    walk_var_g2 = approach_walk_var_g2(split)  # the two-stage fits' walk
    ramp, stages = check_stages(split, samples, drift_g_um, toe, lag_shift_um, wander, walk_var_g2,
                                drift_held=fit_drift_g_um is not None)
    result.unnamed_stage_um = unnamed_stage_um(*samples, drift_g_um, toe.contact_um, toe.width_um, split.noise_g,
                                               walk_var_g2, ramp, fit_drift_g_um is not None, split.ringing)
    # A stage the toe took in at its widest (tapcell.tap.stage.shows_absorbed_stage): its first touch
    # is the stage part. A ringing over the departure scores a far first touch too (the sweep's 4000
    # sps: 3 of 20 taps, read 3-6 um off): there the part covers what the ringing moves.
    if shows_absorbed_stage(stages, toe.contact_um, toe.width_um >= TOE_WIDTHS_UM[-1]):
        result.unnamed_stage_um = stages.top_um - toe.contact_um
    approach_change_g = abs(dec.points[P_CONTACT][1] - dec.points[P_START][1])
    if approach_change_g > APPROACH_DRIFT_MATERIAL_SHARE * result.compression_force_g:  # else it costs the score little
        result.approach_drift_share = departure_drift_share(rising, toe.contact_um, drift_g_um)
    # The quality classifier's misfit judges the model that set Z: a soft sheet's toe misfits the
    # sharp model by up to 3.7 x the noise (reference soft sheet, 2 of 80 taps LOW_TAP_QUALITY),
    # while the toe explains it to 1.2 x at most (tapcell.tap.classifiers.MISFIT_TOLERANCE 1.25);
    # clean taps of both sets 1.74 x at most (a hum nobody removed), where the misfit is 28 % (cutoff 50).
    result.fit_residual_sigma_g = toe.residual_sigma_g


def check_adhesion_at(split: SplitTap, rising: PullbackSamples, contact_um: float, lag_shift_um: float,
                      delay_s: float, wander: Wander | None, compression_force_g: float,
                      down_above_up_um: tuple[float, float] | None) -> float:
    """`check_adhesion` at a contact `contact_um` high in the window's heights (TAP_ADHESION raised;
    else the dip or pull it let pass, g).
    The free air before the contact (`free_air_line`); the walk the approach shows, or where it is
    too short to show one (10 sps: 8 samples), the one the free air on both sides shows (`wander`)."""
    dec = split.dec
    tap_contact_um = contact_um - lag_shift_um
    free_air_end = free_air_samples(split, tap_contact_um, delay_s)
    free_air = slice(dec.start, dec.start + free_air_end)
    return check_adhesion(rising, split.motion, split.timing, dec, free_air_line(split, free_air_end),
                          (split.time_s[free_air], split.force_g[free_air]), contact_um, split.noise_g,
                          wander, compression_force_g, down_above_up_um,
                          approach_rise_above_um(split, tap_contact_um, delay_s), split.ringing)


def check_decompression_samples(split: SplitTap, window: ModelWindow, delay_s: float, window_delay_s: float,
                                result: TapAnalysis) -> None:
    """TAP_DATA_INSUFFICIENT when the pullback is too fast to leave the decompression line two
    samples wholly pressed below break contact (`validate.check_decompression_samples`)."""
    motion, timing = split.motion, split.timing
    if result.z_mm is None:
        return
    contact_um = _break_contact_in_window_um(motion, delay_s, window_delay_s, result.z_mm)
    step_um = motion.pullback_speed_mm_s * 1000.0 * timing.sample_period_s
    if not validate.decompression_may_fall_short(contact_um, step_um):
        return  # no faster than the guide allows, or a contact too low to ask: nothing to count
    _, x_high_um, _ = pullback_samples(window, motion, timing, window_delay_s)
    pressed = int(np.count_nonzero(x_high_um <= contact_um))
    validate.check_decompression_samples(pressed, contact_um, step_um)


def _break_contact_in_window_um(motion: Motion, delay_s: float, window_delay_s: float, z_mm: float) -> float:
    """Break contact in the window's heights (µm above the halt): a delay estimated since the window
    was read moved Z down by pullback speed x the change."""
    return (z_mm - motion.z_halt_mm) * 1000.0 + (delay_s - window_delay_s) * motion.pullback_speed_mm_s * 1000.0


# How far apart the thread's near and far reaches' middles lie (µm): z_uncertainty's walk between them.
THREAD_REACHES_APART_UM = (sum(THREAD_FAR_REACH_UM) - sum(THREAD_REACH_UM)) / 2.0


def z_uncertainty(split: SplitTap, window: ModelWindow, fits: ContactFits, delay_s: float, window_delay_s: float,
                  result: TapAnalysis) -> None:
    """`z_sigma_um` from the parts the tap shows (tapcell.tap.uncertainty): the sharp fit's noise
    and the toe's shape spread (when the toe set Z; else the sharp fit's or the lines' sigma),
    a departure thread letting go, the misfit near contact, the Z staircase, the halt's delay."""
    motion, timing, dec = split.motion, split.timing, split.dec
    if result.z_mm is None or result.z_sigma_um is None:
        return
    stiffness = result.stiffness_decompression_g_um or 0.0
    speed_um_s = motion.pullback_speed_mm_s * 1000.0
    contact_um = _break_contact_in_window_um(motion, delay_s, window_delay_s, result.z_mm)
    slope_g_s, intercept_g = dec.approach_line
    samples = fits.samples
    near_pull_g, far_pull_g = thread_pulls_g(*samples, fits.drift_g_um, slope_g_s * motion.home_end_s + intercept_g,
                                             contact_um, THREAD_FAR_MIN_UM)
    # The walk between the near and far reaches' middles, in samples of the pullback.
    _, approach_wander = split.wanders
    apart_samples = THREAD_REACHES_APART_UM / max(speed_um_s * timing.sample_period_s, 1e-9)
    walk_var_g2 = approach_wander.walk_var_g2 * apart_samples if approach_wander else 0.0
    # The scatter away from contact: the departure line's residual, or the white noise when larger.
    departure_g = math.sqrt(segment_stats(split.ps, dec.bounds[3], dec.stop - dec.start)[0])
    window_um = speed_um_s * timing.integration_s
    halt_sigma_s = (corner_time_sigma_s(split.ps, dec, COMPRESSION, dec.points[P_DWELL_START][0])
                    if timing.delay_from_halt else 0.0)
    compression_placed = split.compression_placed
    if timing.delay_from_halt and not compression_placed:
        # No lag read off the halt (lag_before_the_fits): P2 lies anywhere in a conversion window.
        halt_sigma_s = math.hypot(halt_sigma_s if math.isfinite(halt_sigma_s) else 0.0,
                                  timing.integration_s / math.sqrt(12.0))
    down_um, up_um, allowance_um = _contact_down_and_up(fits, motion.approach_speed_mm_s * 1000.0
                                                       * timing.sample_period_s, compression_placed)
    if (down_um is not None and up_um is not None and down_um - up_um > allowance_um
            and approach_interval_s(window.time_s, motion.home_end_s, down_um, motion.approach_speed_mm_s,
                                    timing.sample_period_s) > timing.sample_period_s):
        # Frames lost about the touch leave the way down's contact anywhere in their gap: no squeeze to
        # read off it (a burst of 3 over a reference tap's compression: z_sigma 45-62 µm, its error 0.4).
        down_um, up_um, allowance_um = None, None, 0.0
    if result.z_method == "toe" and result.toe_grid is not None:
        # The noise: the sharp fit's over the same samples (the toe fit's own when there is none).
        noise_um = result.z_sharp_sigma_um if result.z_sharp_sigma_um is not None else result.z_sigma_um
        shape_um = uncertainty.toe_shape_um(result.toe_grid)
    else:
        noise_um, shape_um = result.z_sigma_um, 0.0
    # The quality classifier's misfit allows for the same ringing (TapAnalysis.dwell_ringing_var_g2).
    result.dwell_ringing_var_g2 = split.ringing.var_g2 if split.ringing is not None else 0.0
    result.z_sigma_parts, result.z_sigma_um = uncertainty.tap_sigma_parts(
        samples[0], samples[1], contact_um, stiffness, noise_um, shape_um, walk_var_g2, near_pull_g, far_pull_g,
        max(split.noise_g, departure_g), result.fit_residual_sigma_g, result.step_sigma_g, down_um, up_um,
        allowance_um, _toe_lift_um(result), step_staircase_sigma_um(timing.z_step_um, window_um), timing.z_step_um,
        speed_um_s * halt_sigma_s if math.isfinite(halt_sigma_s) else 0.0, split.ringing, result.unnamed_stage_um)


def _contact_down_and_up(fits: ContactFits, approach_travel_um: float,
                         compression_placed: bool) -> tuple[float | None, float | None, float]:
    """(contact on the way down, break contact on the way up, µm, from the sharp fits at the same
    delay; None where a fit is missing, or where the compression is too short to place a contact:
    `compression_places_the_halt`) and what their noise and the approach's sample grid allow
    between them (`uncertainty.squeeze_allowance_um`; not TAP_CONTACT_MISMATCH's hysteresis and
    whole sample of travel, which on taplab's mild ooze hide every film the pullback reads high by)."""
    down, up = fits.compression, fits.pullback
    if down is None or up is None or not compression_placed:
        return None, None, 0.0
    return down.contact_um, up.contact_um, uncertainty.squeeze_allowance_um(down.contact_sigma_um, up.contact_sigma_um,
                                                                         approach_travel_um)


def _toe_lift_um(result: TapAnalysis) -> float:
    """How far the toe model's Z lies from the sharp model's (µm; 0 when the toe did not set Z)."""
    if result.z_method != "toe" or result.z_sharp_mm is None or result.z_mm is None:
        return 0.0
    return (result.z_mm - result.z_sharp_mm) * 1000.0


def check_stages(split: SplitTap, samples: PullbackSamples, drift_g_um: float, toe: ToeFit, lag_shift_um: float,
                 wander: Wander | None, walk_var_g2: float,
                 drift_held: bool) -> tuple[SoftStage | None, TwoStageFit | None]:
    """The two-stage checks (TAP_TWO_STAGE_CONTACT raised); where they name a stage and the dwell
    rings (tapcell.tap.stage.dwell_ringing), again with the ringing in their noise: a gantry's
    ringing over a fast pullback's departure is no stage (issue 21). Returns the soft-stage ramp
    they weighed (tapcell.tap.stage.unnamed_stage_um looks further where it shows one) and the
    two-stage fit (None where the toe was too narrow to run it). wander: the
    tap's (`SplitTap.wanders`); walk_var_g2: the approach's walk (`approach_walk_var_g2`)."""
    motion, noise_g = split.motion, split.noise_g
    # The ramp's noise: the walk the free air on both sides shows, as the toe fit weighs it. The
    # approach's alone (32-96 samples at 320 sps) read no walk under a 2.4 g/sqrt(s) cable (taplab
    # seed 4 cable drift k 20): its level wandering over the departure's 61 samples scored a
    # 13 um "stage" at 39.7 noise variances (limit 36), TAP_TWO_STAGE_CONTACT.
    try:
        ramp = check_soft_stage(samples, motion, drift_g_um, toe.contact_um, lag_shift_um, noise_g, wander,
                                toe.stiffness_g_um)
        return ramp, check_two_stage(samples, motion, drift_g_um, toe, lag_shift_um, noise_g, walk_var_g2, drift_held)
    except TapInvalid:
        ringing = split.ringing
        if ringing is None:
            raise
        ramp = check_soft_stage(samples, motion, drift_g_um, toe.contact_um, lag_shift_um, noise_g, wander,
                                toe.stiffness_g_um, ringing)
        return ramp, check_two_stage(samples, motion, drift_g_um, toe, lag_shift_um, noise_g, walk_var_g2, drift_held,
                                     ringing)


def check_soft_stage(samples: PullbackSamples, motion: Motion, drift_g_um: float, contact_um: float,
                     lag_shift_um: float, noise_g: float, wander: Wander | None, stiffness_g_um: float,
                     ringing: Ringing | None = None) -> SoftStage | None:
    """TAP_TWO_STAGE_CONTACT when the force keeps a soft stage's ramp above the contact found
    (tapcell.tap.stage): the stiff stage let go there, the first touch is higher (weighed against
    the noise, the walk and the ringing the dwell shows). Returns the ramp when it names nothing."""
    walk_var_g2 = wander.walk_var_g2 if wander else 0.0
    stage = departure_soft_stage(*samples, drift_g_um, contact_um, noise_g * noise_g, walk_var_g2, ringing)
    if shows_soft_stage(stage, stiffness_g_um, contact_um):
        first_touch_mm = motion.z_halt_mm + (stage.top_um - lag_shift_um) / 1000.0
        raise TapInvalid(TAP_TWO_STAGE_CONTACT,
                         f"after break contact the force falls along a soft stage ({stage.slope_g_um:.2f} g/um, "
                         f"{stage.top_um - contact_um:.0f} um up to Z {first_touch_mm:.4f}): a soft layer pressed "
                         "before the contact, a two-stage mount (a magnetic sheet, a sprung bed) or a film of ooze; "
                         "its stiff stage would read low")
    return stage


def approach_walk_var_g2(split: SplitTap) -> float:
    """The walk the approach shows (g^2 a sample), 0 where it shows none: the two-stage fit's walk."""
    _, approach_wander = split.wanders
    return approach_wander.walk_var_g2 if approach_wander else 0.0


def check_two_stage(samples: PullbackSamples, motion: Motion, drift_g_um: float, toe: ToeFit, lag_shift_um: float,
                    noise_g: float, walk_var_g2: float, drift_held: bool = False,
                    ringing: Ringing | None = None) -> TwoStageFit | None:
    """TAP_TWO_STAGE_CONTACT when the departure is two stages rather than the wide toe fitted
    (tapcell.tap.stage.two_stage_departure): the toe absorbed a soft first stage and reads low.
    drift_held: the toe fit held drift_g_um (the departure agrees with the approach), the stages are
    weighed on it too; walk_var_g2: the walk the approach shows (approach_walk_var_g2). Returns the
    fit when it names nothing (None where the toe is too narrow to run it)."""
    fit = two_stage_departure(*samples, drift_g_um, toe.contact_um, toe.width_um, noise_g, walk_var_g2, drift_held,
                              ringing)
    if shows_two_stage(fit, toe.contact_um):
        first_touch_mm = motion.z_halt_mm + (fit.top_um - lag_shift_um) / 1000.0
        raise TapInvalid(TAP_TWO_STAGE_CONTACT,
                         f"the departure is two stages, not one contact: a stiff stage, then a soft one "
                         f"({100.0 * fit.soft_share:.0f} % of its stiffness) over {fit.span_um:.0f} um up to "
                         f"Z {first_touch_mm:.4f}, {fit.evidence_chi2:.0f} noise variances better than any "
                         f"one-stage toe: a two-stage mount (a magnetic sheet, a sprung bed) or a film of "
                         f"ooze; the contact found would read {fit.top_um - toe.contact_um:.1f} um low")
    return fit


def compression_stiffness(split: SplitTap, window: ModelWindow, fits: ContactFits, delay_s: float,
                          result: TapAnalysis) -> None:
    """The compression stiffness, when enough samples were pressed wholly in contact before the halt
    and no frames were lost up to it: the gap then holds the compression's deepest part, and the
    samples before it its shallowest, where the onset lowers the slope (reference noisy-mains taps
    with the 2-5 samples before the halt lost: 1.45 g/um read against the pullback's 6.06, a
    mismatch of 197 %; LOW_TAP_QUALITY on 1-5 of 80 clean taps)."""
    pullback, motion = fits.pullback, split.motion
    onset_um = pullback.onset_um if pullback else 0.0
    result.compression_samples = compression_sample_count(window, motion, delay_s, onset_um,
                                                          pullback.contact_um if pullback else window.break_line_um)
    if (result.compression_samples >= MIN_COMPRESSION_SAMPLES
            and not split.frames_lost_at_halt):
        compression_line = split.steep_rise or split.dec.compression_line
        result.stiffness_compression_g_um = (fits.compression.stiffness_g_um if fits.compression else
                                             abs(compression_line[0]) / (motion.approach_speed_mm_s * 1000.0))
        result.line_stiffness_ratio = line_stiffness_ratio(compression_line, split.dec.decompression_line, motion)


def line_stiffness_ratio(compression_line: tuple[float, float], decompression_line: tuple[float, float],
                         motion: Motion) -> float | None:
    """The decompression line's stiffness over the compression line's (each slope over its speed, g/um).

    The quality classifier's stiffness component compares the two sides with one estimator: the
    models' stiffnesses come from different spans (the compression fit over the whole over-travel,
    the toe within 30 um of contact) and parted by 55-70 % on clean taps under a mains hum the
    analysis was not told of, where the lines agreed within 13 % (reference noisy mains: 2 of 80
    clean taps LOW_TAP_QUALITY for stiffness). The classifier takes the smaller mismatch of the two
    (tapcell.tap.classifiers.stiffness_ratio): over taplab seeds 1 and 2 and the reference set clean
    taps reach 34 %; ooze that halves the decompression's stiffness shows in both.
    """
    compression_g_um = abs(compression_line[0]) / motion.approach_speed_mm_s
    decompression_g_um = abs(decompression_line[0]) / motion.pullback_speed_mm_s
    return decompression_g_um / compression_g_um if compression_g_um > 0 else None


def mains_frequencies_hz(tap: TapData, options: AnalysisOptions) -> tuple[float, ...] | str:
    """The hum lines to remove: the option, else tap meta `mains_hz` (a number, a list, "auto"; an
    empty list: none), else none. The printer records what it used (its default "auto") in every
    tap's meta, so its taps get the same answer here; a tap from elsewhere is analysed without hum
    removal unless asked: `auto` moved no reference scenario by more than 0.04 µm (taplab's strong
    hum 0.3 µm, our own generator's) and costs ~0.15-0.3 ms a tap
    more (docs/tap-analysis.md, "Mains hum"). `analyze_tap` looks again with `auto` where a hum
    may have caused the rejection (HUM_MAY_CAUSE) or hidden a film (`film_judged_against_a_hum`)."""
    if options.mains_hz is not None:
        return options.mains_hz
    value = tap.meta.get("mains_hz")
    if value is None:  # the common case (a tap from elsewhere): no hum asked for
        return ()
    values = value if isinstance(value, list | tuple) else [value]
    if value == "auto":
        return "auto"
    if all(isinstance(v, int | float) and not isinstance(v, bool) and 0 < v < 10000 for v in values):
        return tuple(float(v) for v in values)
    return ()


def remove_mains_hum(tap: TapData, options: AnalysisOptions, time_s: np.ndarray, force_g: np.ndarray,
                     motion: Motion, timing: SensorTiming, lag_samples: int, period_s: float
                     ) -> tuple[np.ndarray, HumFit | None]:
    """The force with the mains hum fitted and subtracted (tapcell.tap.hum), and the fit.

    The spline under the hum needs knots at the tap's corners. They come from the five-line
    split: first of the force with the hum still in it, then (once) of the cleaned force, and
    the hum is refitted from the original force with the better corners; a hum within 3 noise
    sigmas skips the second round (measured: no Z on taplab or the reference taps moved). "auto"
    first screens the lines (`lines_worth_fitting`, one FFT): a tap without hum pays for no split
    and no fit. Samples whose conversion window holds a corner are left out of the fit (the
    sensor rounds a corner over one window, which a linear spline cannot follow); the hum is
    subtracted from every sample.
    """
    wanted = mains_frequencies_hz(tap, options)
    if not wanted:  # none asked for: the hum's module is not even imported (a run without it starts faster)
        return force_g, None
    from tapcell.tap.hum import (MAINS_LINES_HZ, alias_hz, detect_mains_hum, fit_hum, harmonics_worth_fitting,
                                 lines_worth_fitting, resolvable_hz, spline_knots)

    duration_s = float(time_s[-1] - time_s[0])
    candidates = resolvable_hz(MAINS_LINES_HZ if wanted == "auto" else wanted, 1.0 / period_s, duration_s)
    if wanted == "auto":  # the cheap screen first: a tap without hum pays for no split and no fit
        candidates = lines_worth_fitting(time_s, force_g, 1.0 / period_s, candidates)
    if not candidates:
        return force_g, None
    # One period of the lowest line as the sensor sees it: the grid cannot follow that line.
    spacing_s = max(1.0 / min(alias_hz(f, 1.0 / period_s) for f in candidates), 2.0 * period_s)
    cleaned, hum, lines = force_g, None, candidates
    for _ in range(2):
        dec, _ = decompose(time_s, cleaned, motion, lag_samples, period_s)
        corners_s = [p[0] for p in dec.points[1:5]] + [motion.home_end_s, motion.pullback_start_s,
                                                       motion.pullback_cruise_s, motion.pullback_end_s]
        knots_s = spline_knots(float(time_s[0]), float(time_s[-1]), spacing_s, corners_s)
        exclude = _corner_windows(time_s, corners_s, timing)
        if wanted == "auto" and hum is None:
            hum = detect_mains_hum(time_s, force_g, knots_s, exclude, candidates)
            if hum is None:
                return force_g, None
            # Its harmonics too, when the screen sees them (one more FFT): fitted in the second round.
            lines = hum.frequencies_hz + harmonics_worth_fitting(time_s, force_g, 1.0 / period_s, hum.frequencies_hz[0])
        else:
            # Refitted with the corners found on the cleaned force (auto: the line it detected, and
            # the harmonics the screen sees).
            hum = fit_hum(time_s, force_g, lines, knots_s, exclude)
            if hum is None:
                return force_g, None
        cleaned = force_g - hum.hum_g
        if lines == hum.frequencies_hz and sum(hum.amplitudes_g) < 3.0 * hum.residual_sigma_g:
            break  # a hum within 3 noise sigmas moves the corners no more than the noise: no second split and fit
    return cleaned, hum


def _corner_windows(time_s: np.ndarray, corners_s: list[float], timing: SensorTiming) -> np.ndarray:
    """Samples whose conversion window (one sample of margin either side) holds a corner."""
    from tapcell.tap.hum import windows_holding  # imported with the hum's module, as remove_mains_hum does

    return windows_holding(time_s, corners_s, timing.delay_s, timing.integration_s, timing.sample_period_s)


def polarity_and_repaired(time_s: np.ndarray, force_raw: np.ndarray, motion: Motion, outlier_sigma: float
                          ) -> tuple[int, np.ndarray, int, float | None]:
    """(polarity (`_polarity`), the force in positive polarity with its corrupted frames repaired
    (`repair_spikes`), how many were repaired, and that force's `noise_sigma_g` over all its samples
    where the repair measured it and repaired nothing, else None): one kernel call when built
    (polar_spikes: the twins' arithmetic in their order, bit for bit), else the twins (no noise sigma)."""
    baseline_from_s = motion.home_end_s - max(motion.pullback_duration_s, POLARITY_BASELINE_MIN_S)
    if _C is None:
        polarity = _polarity(time_s, force_raw, motion.home_end_s, motion.pullback_start_s, baseline_from_s)
        force, outliers = repair_spikes(polarity * force_raw, outlier_sigma)
        return polarity, force, outliers, None
    force = np.empty(len(force_raw))
    polarity, outliers, noise_g = _C.polar_spikes(time_s, force_raw, motion.home_end_s, motion.pullback_start_s,
                                                  baseline_from_s, outlier_sigma, force)
    if polarity == 0:
        raise TapInvalid(TAP_SHAPE_INVALID, NO_FORCE_CHANGE)
    return polarity, force, outliers, noise_g if outliers == 0 else None


# The polarity's baseline: the force read over a pullback's duration (at least this long) before the halt.
POLARITY_BASELINE_MIN_S = 0.05
NO_FORCE_CHANGE = "the force does not change between approach and dwell"


def _polarity(time_s: np.ndarray, force_g: np.ndarray, halt_s: float, pullback_start_s: float,
              baseline_from_s: float) -> int:
    """+1 when contact pushes the force up, -1 when down (dwell force vs the baseline read from
    baseline_from_s to the halt)."""
    home_end, pull_start, start = _indices(time_s, halt_s, pullback_start_s, baseline_from_s)
    baseline = median(force_g[start:max(home_end - 1, start + 1)])
    dwell = force_g[home_end:pull_start + 1]
    change = median(dwell) - baseline if len(dwell) else float(force_g[home_end]) - baseline
    if change == 0 or not math.isfinite(change):
        raise TapInvalid(TAP_SHAPE_INVALID, NO_FORCE_CHANGE)
    return 1 if change > 0 else -1
