"""The pure math of LOAD_CELL_PROBE_CALIBRATE: the pooled contact onset, the pullback distance
that centres break contact, and the decompression angle."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from tapcell.extras.load_cell_probe.options import PULLBACK_LIMITS_MM
from tapcell.tap.angles import slope_angle_deg


# Onset widths tried by the pooled contact-onset calibration (µm): fine where sheets are
# (smooth PEI ~2, textured ~8), coarser up to soft sheets and beyond.
ONSET_GRID_UM = (0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 8.0, 10.0, 12.0, 15.0, 18.0, 22.0, 26.0, 30.0, 35.0, 40.0)
MIN_ONSET_TAPS = 3
MAX_CALIBRATION_TAPS = 50  # a LOAD_CELL_PROBE_CALIBRATE taps at most this many times


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
    # The onset parabola belongs to the sharp model (a fixed onset selects it anyway; said here for the reader).
    base = dataclasses.replace(options, contact_model="sharp", fit_contact_onset=False, tap_classifier="empty")
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
