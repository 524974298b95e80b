"""Mains hum in a tap's force: estimated as a nuisance and subtracted, without biasing Z.

Mains hum (50 or 60 Hz coupled into the load cell's wiring) reaches the analysis as a
sinusoid of fixed frequency riding on the tap. The firmware's notch filter only cleans the
trigger's input; the analysis sees the raw force, where a 10+ g hum drowns the short dwell
and the tap's corners.

The hum is fitted, not filtered. Over the tap the force is modelled as

    force(t) = spline(t) + Σ_f (a_f·sin(2πft) + b_f·cos(2πft))

where `spline` is a linear spline (hat functions) whose knots are the tap's corners (contact,
halt, release, break contact — where the force bends sharply) plus a uniform grid one hum
period apart (it follows relaxation, onset curvature and drift, but cannot follow the hum: a
sinusoid of that period takes the same value at every grid knot). Everything is linear, so one
least-squares solve gives a and b; the fitted sinusoid is then subtracted from the samples.
Nothing is delayed or smoothed: the samples keep their time, so Z is not biased (a causal
notch filter would delay the signal; a zero-phase one rings at every corner).

A sensor averaging over its conversion window turns each sinusoid into another of the same
frequency (smaller, phase-shifted), so the fit needs no sensor model. Frequencies above the
sample rate's Nyquist limit are fitted at the sample times as they are (aliasing is automatic);
a frequency that aliases to within a few cycles per tap of 0 Hz or of Nyquist cannot be told
apart from the baseline or is unobservable, and is left out (`resolvable_hz`).

All functions are pure (numpy arrays in, plain data out).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import numpy as np

from tapcell.tap import native
from tapcell.tap.robust import MAD_TO_SIGMA, median, robust_sigma

# The screen and the exact parts of the fit in C (tapcell.tap.native); None: the numpy twins beside each call.
_C = native.load("hum")

MAINS_LINES_HZ = (50.0, 60.0)
# `auto` also fits these multiples of the line it detected, when the screen sees them.
MAINS_HARMONICS = (2, 3)
# A line is resolvable when its alias lies this many cycles per tap away from 0 Hz and Nyquist.
MIN_ALIAS_CYCLES = 3.0
# `auto` keeps the stronger mains line only when it lowers the residual by this many noise
# variances (2 parameters: chance alone gives ~2; 30 is ~5 sigma of the amplitude).
DETECTION_MIN_CHI2 = 30.0
# Detection skips the outlier refit beyond this: no outlier moves a line this clear below the bar
# (the analysis refits the line it detected anyway, outliers and all, with better corners).
CLEAR_DETECTION_CHI2 = 4 * DETECTION_MIN_CHI2
# The screen before any fit (`screen_mains_hum`): a line is worth fitting when its power stands
# this far above the tap's own noise floor, in the units of the fit's chi2 (chance alone gives ~2,
# above 20 once in ~20000 lines). Below DETECTION_MIN_CHI2: the screen sees the force with the
# tap's ramps cut out, the fit sees them modelled, so the screen reads a weak hum lower. Measured on
# taplab and the reference taps (`auto` with screens at 10 / 20 / 30 / 60 against no screen): at 20
# no scenario's bias or sigma moved by more than 0.01 µm and 54 % of the taps were fitted (67 % at
# 10; both generators put a weak hum in most taps); at 30 some moved by 0.03 µm.
SCREEN_MIN_CHI2 = 20.0
# ... and only a line whose amplitude reaches this many noise sigmas (read from the same spectrum,
# `_screen`): a long record finds a weak line that cannot move Z. Measured against fitting every line
# that passes the screen (taplab seed 1 and the reference taps, the gate applied tap by tap): 0.3 /
# 0.35 / 0.4 / 0.45 / 0.5 moved the worst scenario's bias or sigma by 0.013 / 0.021 / 0.021 / 0.051 /
# 0.057 µm and fitted 599 / 554 / 496 / 439 / 381 of 1560 taps (628 with the screen alone); 0.35
# keeps a step below the edge. The screen's chi2 is no measure of amplitude: at 2000 sps the tap's own
# slow ramps raise its floor, and a 6 g line on 0.5 g noise read chi2 101-116 over 1626 steps. Gating
# by the samples in the toe fit's reach instead (30 µm of compression: 2 samples at 5 mm/s and 320 sps)
# moved taplab's bias by 0.5 µm: on a fast tap the hum still moves the lines around the corners.
FIT_MIN_HUM_TO_NOISE = 0.35
# A line dominates the tap's noise when the screen reads it at this many noise sigmas or more: a
# sinusoid that sets the steps' robust sigma itself still reads 0.67 (`_screen`). Such a hum, left
# in, is most of the noise every check of the tap was judged against (`dominant_mains_lines`).
HUM_DOMINATES_NOISE = 0.67
# ... over the tap's last this many samples: its contact, dwell and pullback, whose checks the hum
# misled (the benchmark sets' taps hold 300-3,000). A long approach before them adds FFT, not
# evidence: a 15,000-sample tap's screen cost 0.55 ms, more than its analysis (0.15 ms capped).
DOMINANCE_MAX_SAMPLES = 4096
# Sample-to-sample steps beyond this many robust sigmas are the tap's own corners and ramps
# (a compression rises tens of grams a sample), not hum or noise: cut, with this many neighbours.
SCREEN_STEP_SIGMAS = 6.0
SCREEN_STEP_NEIGHBOURS = 2
# The noise floor: the median power of the bins within ±30 % of the line's alias (at least 24 bins
# either side), leaving out 4 bins around every candidate line; fewer than 8 bins: no screen.
SCREEN_BAND = 0.3
SCREEN_MIN_HALF_BAND_BINS = 24
SCREEN_GUARD_BINS = 4
SCREEN_MIN_FLOOR_BINS = 8
# Samples the first fit cannot explain (a corner the knots missed, a burst) are dropped and the
# fit repeated: beyond this many robust sigmas.
OUTLIER_SIGMAS = 5.0


@dataclass
class HumFit:
    """The fitted hum: one amplitude and phase per frequency, and the hum at every sample."""

    frequencies_hz: tuple[float, ...]
    amplitudes_g: tuple[float, ...]  # sinusoid amplitude as the sensor saw it (after its averaging)
    phases_rad: tuple[float, ...]  # hum = A·sin(2πf(t - t0) + phase), t0 = first sample time
    hum_g: np.ndarray = field(repr=False)  # at every sample
    residual_sigma_g: float = 0.0  # of the whole model over the samples used
    chi2_improvement: float = 0.0  # residual lowered by the hum terms, in noise variances

    def to_json(self) -> dict:
        return {"frequencies_hz": list(self.frequencies_hz),
                "amplitudes_g": [round(a, 4) for a in self.amplitudes_g],
                "phases_rad": [round(p, 4) for p in self.phases_rad],
                "residual_sigma_g": round(self.residual_sigma_g, 4),
                "chi2_improvement": round(self.chi2_improvement, 1)}


def alias_hz(frequency_hz: float, sample_rate_sps: float) -> float:
    """Where a sinusoid of frequency_hz appears when sampled at sample_rate_sps (0..Nyquist)."""
    folded = math.fmod(frequency_hz, sample_rate_sps)
    return min(folded, sample_rate_sps - folded)


def resolvable_hz(frequencies_hz, sample_rate_sps: float, duration_s: float) -> tuple[float, ...]:
    """The frequencies whose alias is at least MIN_ALIAS_CYCLES per tap from 0 Hz and from Nyquist."""
    nyquist = 0.5 * sample_rate_sps
    kept = []
    for frequency in frequencies_hz:
        seen = alias_hz(frequency, sample_rate_sps)
        if min(seen, nyquist - seen) * duration_s >= MIN_ALIAS_CYCLES:
            kept.append(float(frequency))
    return tuple(kept)


@dataclass(frozen=True)
class HatSpline:
    """Linear-spline (hat) basis at the samples, sparse: sample i is `1 - share[i]` of knot
    `left[i]` plus `share[i]` of knot `left[i] + 1`; `count` knots in all."""

    left: np.ndarray
    share: np.ndarray
    count: int

    def at_samples(self, coefficients: np.ndarray) -> np.ndarray:
        """The spline with these knot values, at every sample."""
        return (1.0 - self.share) * coefficients[self.left] + self.share * coefficients[self.left + 1]

    def transpose_dot(self, values: np.ndarray) -> np.ndarray:
        """Basisᵀ · values (one sum per knot), without the dense basis."""
        return (np.bincount(self.left, (1.0 - self.share) * values, self.count)
                + np.bincount(self.left + 1, self.share * values, self.count))

    def gram(self, weight: np.ndarray) -> np.ndarray:
        """Basisᵀ · diag(weight) · Basis: tridiagonal (neighbouring knots only), returned dense."""
        low, high = 1.0 - self.share, self.share
        diagonal = (np.bincount(self.left, weight * low * low, self.count)
                    + np.bincount(self.left + 1, weight * high * high, self.count))
        beside = np.bincount(self.left, weight * low * high, self.count)[:-1]
        gram = np.diag(diagonal)
        rows = np.arange(self.count - 1)
        gram[rows, rows + 1] = beside
        gram[rows + 1, rows] = beside
        return gram

    def normal_equations(self, weight: np.ndarray, force_g: np.ndarray, waves: np.ndarray
                         ) -> tuple[np.ndarray, np.ndarray]:
        """The spline's part of the normal equations under the sample weights: its gram with a tiny
        ridge on the diagonal (1e-10 of its mean: a knot with no used sample gets coefficient 0, not
        a singular matrix) and Basisᵀ · (weight · column) for the force and every wave column.

        The kernel (c/hum.c) takes the same sums in the same order: bit for bit."""
        if _C is not None:
            columns = waves.shape[1]
            gram, per_knot = np.empty((self.count, self.count)), np.empty((self.count, columns + 1))
            _C.normal_equations(self.left, self.share, weight, force_g, np.ascontiguousarray(waves), self.count,
                                columns, gram, per_knot)
            return gram, per_knot
        gram = self.gram(weight)
        ridge = 1e-10 * max(float(np.trace(gram)) / self.count, 1e-300)
        gram[np.diag_indices_from(gram)] += ridge
        waves_used = waves * weight[:, None]
        per_knot = np.column_stack([self.transpose_dot(weight * force_g)]
                                   + [self.transpose_dot(column) for column in waves_used.T])
        return gram, per_knot


def hat_spline(time_s: np.ndarray, knots_s: np.ndarray) -> HatSpline:
    """The hat basis on `knots_s` (sorted, spanning the times, at least two) at `time_s`."""
    if _C is not None:  # the same searchsorted, division and clips: bit for bit
        left, share = np.empty(len(time_s), dtype=np.int64), np.empty(len(time_s))
        _C.hat_spline(np.ascontiguousarray(time_s, dtype=float), np.ascontiguousarray(knots_s, dtype=float), left, share)
        return HatSpline(left, share, len(knots_s))
    right = np.clip(np.searchsorted(knots_s, time_s, side="right"), 1, len(knots_s) - 1)
    left = right - 1
    share = np.clip((time_s - knots_s[left]) / (knots_s[right] - knots_s[left]), 0.0, 1.0)
    return HatSpline(left, share, len(knots_s))


def hat_basis(time_s: np.ndarray, knots_s: np.ndarray) -> np.ndarray:
    """Linear-spline basis, dense: column k is 1 at knot k, falling linearly to 0 at its neighbours.

    Knots must be sorted and span the times; any piecewise-linear function with corners at
    the knots is exactly a combination of the columns.
    """
    spline = hat_spline(time_s, knots_s)
    basis = np.zeros((len(time_s), spline.count))
    rows = np.arange(len(time_s))
    basis[rows, spline.left] = 1.0 - spline.share
    basis[rows, spline.left + 1] += spline.share
    return basis


def spline_knots(t_first_s: float, t_last_s: float, spacing_s: float, corners_s=()) -> np.ndarray:
    """A uniform grid `spacing_s` apart over [t_first, t_last] plus the corners inside it.

    A corner closer than a tenth of the spacing to a grid knot replaces that knot (two
    knots that close would make nearly identical columns).
    """
    count = max(int(math.ceil((t_last_s - t_first_s) / spacing_s)), 1)
    if _C is not None:  # the same grid, merge and sort: bit for bit
        corners = np.asarray(corners_s, dtype=float).reshape(-1)
        knots = np.empty(count + 1 + len(corners))
        return knots[:_C.spline_knots(t_first_s, t_last_s, spacing_s, corners, knots)]
    grid = t_first_s + (t_last_s - t_first_s) * np.arange(count + 1) / count
    corners = np.array([c for c in corners_s if t_first_s < c < t_last_s and math.isfinite(c)], dtype=float)
    if len(corners):
        near = np.min(np.abs(grid[:, None] - corners[None, :]), axis=1) < 0.1 * spacing_s
        near[[0, -1]] = False  # the ends stay
        grid = grid[~near]
    return np.unique(np.concatenate((grid, corners)))


def windows_holding(time_s: np.ndarray, corners_s, delay_s: float, integration_s: float,
                    margin_s: float) -> np.ndarray:
    """Samples whose conversion window, `margin_s` wider either side, holds one of the finite corners:
    the window of the sample at t spans [t - delay - integration, t - delay]."""
    time_s = np.ascontiguousarray(time_s, dtype=float)
    corners = np.asarray([c for c in corners_s if math.isfinite(c)], dtype=float)
    if _C is not None:  # the same sums and comparisons: bit for bit
        inside = np.empty(len(time_s), dtype=bool)
        _C.corner_windows(time_s, corners, delay_s, integration_s, margin_s, inside)
        return inside
    start_s = time_s - delay_s - integration_s - margin_s
    end_s = time_s - delay_s + margin_s
    return np.any((start_s[:, None] <= corners[None, :]) & (corners[None, :] <= end_s[:, None]), axis=1)


def sinusoid_basis(time_s: np.ndarray, frequencies_hz) -> np.ndarray:
    """Columns sin, cos for each frequency, with time measured from the first sample."""
    tau_s = time_s - time_s[0]
    basis = np.empty((len(time_s), 2 * len(frequencies_hz)))
    for index, frequency in enumerate(frequencies_hz):
        angle = 2.0 * np.pi * frequency * tau_s
        basis[:, 2 * index] = np.sin(angle)
        basis[:, 2 * index + 1] = np.cos(angle)
    return basis


@dataclass
class _LinesFit:
    """One group of hum lines fitted with the spline: coefficients and residual sums of squares."""

    spline_coefficients: np.ndarray
    wave_coefficients: np.ndarray
    rss_spline_alone: float  # the spline without the lines, over the same samples
    rss: float


def _fit_groups(spline: HatSpline, waves: np.ndarray, force_g: np.ndarray, use: np.ndarray,
                groups: list[list[int]]) -> list[_LinesFit]:
    """Least squares of the force on the spline plus each group of wave columns (alternatives).

    Normal equations in blocks: the spline's gram A (tridiagonal, from sums per knot), its
    cross terms B with the waves and the waves' own C. A is solved once for the force and for
    every wave column; each group then only needs its small Schur complement, and the residual
    of the spline alone comes free. A column with no used sample (a knot whose neighbourhood
    was excluded) would make A singular: a tiny ridge sets its coefficient to 0 instead.
    """
    weight = use.astype(float)
    weighted = weight * force_g
    gram, per_knot = spline.normal_equations(weight, force_g, waves)
    waves_used = waves * weight[:, None]
    to_spline, cross = per_knot[:, 0], per_knot[:, 1:]
    solved = np.linalg.solve(gram, per_knot)
    spline_alone, per_column = solved[:, 0], solved[:, 1:]
    rss_spline_alone = float(weighted @ force_g - to_spline @ spline_alone)
    # Every group's Schur complement and right-hand side are blocks of these (two products for all).
    schur_all = waves_used.T @ waves - cross.T @ per_column
    rhs_all = waves_used.T @ force_g - cross.T @ spline_alone
    fits = []
    for columns in groups:  # each group's columns are consecutive: its block is a slice (solve copies it anyway)
        rhs = rhs_all[columns]
        wave_coefficients = np.linalg.solve(schur_all[columns[0]:columns[-1] + 1, columns[0]:columns[-1] + 1], rhs)
        fits.append(_LinesFit(spline_alone - per_column[:, columns] @ wave_coefficients, wave_coefficients,
                              rss_spline_alone, max(rss_spline_alone - float(wave_coefficients @ rhs), 0.0)))
    return fits


def _hum_fit(frequencies_hz: tuple[float, ...], waves: np.ndarray, fit: _LinesFit, used: int) -> HumFit:
    dof = max(used - len(fit.spline_coefficients) - len(fit.wave_coefficients), 1)
    noise_var = fit.rss / dof
    sines, cosines = fit.wave_coefficients[0::2], fit.wave_coefficients[1::2]
    return HumFit(
        frequencies_hz=frequencies_hz,
        amplitudes_g=tuple(float(a) for a in np.hypot(sines, cosines)),
        phases_rad=tuple(float(p) for p in np.arctan2(cosines, sines)),
        hum_g=waves @ fit.wave_coefficients,
        residual_sigma_g=math.sqrt(noise_var),
        chi2_improvement=(fit.rss_spline_alone - fit.rss) / noise_var if noise_var > 0 else math.inf,
    )


def _fit_alternatives(time_s, force_g, alternatives: list[tuple[float, ...]], knots_s,
                      exclude: np.ndarray | None, refit_all: bool) -> list[HumFit | None]:
    """Each group of frequencies in `alternatives` fitted alone with the same spline.

    After the first fit, samples beyond OUTLIER_SIGMAS robust sigmas of a group's residual are
    dropped and that group refitted: every group (`refit_all`), or only the one that lowered the
    residual most (detection: the others are discarded anyway). None for a group when too few
    samples remain for its parameters.
    """
    time_s = np.asarray(time_s, dtype=float)
    force_g = np.asarray(force_g, dtype=float)
    force_g = force_g - median(force_g)  # the spline carries any offset; smaller sums, no cancellation (np.median's value)
    spline = hat_spline(time_s, np.asarray(knots_s, dtype=float))
    frequencies = [f for group in alternatives for f in group]
    waves = sinusoid_basis(time_s, frequencies)
    groups, column = [], 0
    for group in alternatives:
        groups.append(list(range(column, column + 2 * len(group))))
        column += 2 * len(group)
    use = np.ones(len(time_s), dtype=bool) if exclude is None else ~np.asarray(exclude, dtype=bool)
    used = int(np.count_nonzero(use))
    fits: list[HumFit | None] = [None] * len(alternatives)
    enough = [bool(group) and used >= spline.count + len(columns) + 4 for group, columns in zip(alternatives, groups)]
    if not any(enough):
        return fits
    first = _fit_groups(spline, waves, force_g, use, groups)
    order = [i for i in sorted(range(len(groups)), key=lambda i: first[i].rss) if enough[i]]
    for i in order if refit_all else order[:1]:
        columns = groups[i]
        fits[i] = _hum_fit(alternatives[i], waves[:, columns], first[i], used)
        if not refit_all and fits[i].chi2_improvement >= CLEAR_DETECTION_CHI2:
            break  # detected beyond doubt: the outliers cannot change the decision
        residual = force_g - spline.at_samples(first[i].spline_coefficients) - waves[:, columns] @ first[i].wave_coefficients
        inliers = use & (np.abs(residual) <= OUTLIER_SIGMAS * max(robust_sigma(residual[use]), 1e-12))
        kept = int(np.count_nonzero(inliers))
        if used > kept >= spline.count + len(columns) + 4:
            fits[i] = _hum_fit(alternatives[i], waves[:, columns], _fit_groups(spline, waves, force_g, inliers, [columns])[0], kept)
    return fits


def fit_hum(time_s: np.ndarray, force_g: np.ndarray, frequencies_hz, knots_s: np.ndarray,
            exclude: np.ndarray | None = None) -> HumFit | None:
    """Fit sinusoids at `frequencies_hz` jointly with a linear spline on `knots_s`.

    `exclude` marks samples to leave out of the fit (e.g. those whose conversion window holds
    a corner, which a linear spline cannot follow); the hum is still evaluated at every sample.
    After a first fit, samples beyond OUTLIER_SIGMAS robust sigmas are dropped and it is repeated.
    Returns None when too few samples remain for the parameters.
    """
    frequencies_hz = tuple(float(f) for f in frequencies_hz)
    return _fit_alternatives(time_s, force_g, [frequencies_hz], knots_s, exclude, refit_all=True)[0]


def detect_mains_hum(time_s: np.ndarray, force_g: np.ndarray, knots_s: np.ndarray,
                     exclude: np.ndarray | None = None, candidates_hz=MAINS_LINES_HZ) -> HumFit | None:
    """The stronger of the mains lines (50 or 60 Hz) when the tap clearly holds it, else None.

    Each candidate is fitted alone with the same spline (one solve serves all); the one that
    lowers the residual more is refitted without outliers and kept if it lowers it by at least
    DETECTION_MIN_CHI2 noise variances.
    """
    alternatives = [(float(frequency),) for frequency in candidates_hz]
    fits = [fit for fit in _fit_alternatives(time_s, force_g, alternatives, knots_s, exclude, refit_all=False) if fit]
    if not fits:
        return None
    best = max(fits, key=lambda fit: fit.chi2_improvement)
    return best if best.chi2_improvement >= DETECTION_MIN_CHI2 else None


def screen_mains_hum(time_s: np.ndarray, force_g: np.ndarray, sample_rate_sps: float,
                     candidates_hz) -> tuple[float, ...]:
    """Per candidate line, how clearly the tap holds it, before any fit: in the units of
    `fit_hum`'s chi2_improvement (chance alone gives ~2); inf when the floor cannot be measured."""
    return _screen(time_s, force_g, candidates_hz)[0]


def _screen(time_s: np.ndarray, force_g: np.ndarray, candidates_hz) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """Per candidate line: the screen's chi2 (`screen_mains_hum`) and the line's amplitude in noise sigmas.

    The force's first differences remove its baseline and drift; the steps of the tap itself
    (contact, halt, release: far beyond the noise) are cut out, so what remains is noise and hum.
    The power at the line's alias is compared with the median power of the neighbouring bins:
    the noise floor at that frequency, whatever the sensor's noise colour. One FFT, zero-padded
    to twice the length (a line between two bins loses at most 19 % of its power), no fit.
    Samples with a gap (a period off the sample rate) are read with one DFT per line instead.

    The amplitude comes from the same power: a sinusoid of amplitude A steps by A·2·sin(π·f/rate)
    between samples, and n such steps give a power of (n·step/2)². The noise sigma is the steps'
    robust sigma over √2. A hum far above the noise sets that sigma itself, and still reads at
    least 0.67 sigmas (the steps of a sinusoid have a robust sigma of ~1.05 times their amplitude).

    The kernel (c/hum.c) computes the same, its powers by another FFT (c/fft.h's mixed radix): equal
    to rounding, the decisions the same unless a ratio lies within rounding of its bar.
    """
    time_s = np.ascontiguousarray(time_s, dtype=float)
    force_g = np.ascontiguousarray(force_g, dtype=float)
    if _C is not None:
        padded = _fast_length(2 * (len(force_g) - 1)) if len(force_g) > 2 else 0  # the twin's length below
        return _C.screen(time_s, force_g, np.asarray(candidates_hz, dtype=float), padded, SCREEN_STEP_SIGMAS,
                         SCREEN_STEP_NEIGHBOURS, SCREEN_BAND, SCREEN_MIN_HALF_BAND_BINS, SCREEN_GUARD_BINS,
                         SCREEN_MIN_FLOOR_BINS, MAD_TO_SIGMA)
    steps = force_g[1:] - force_g[:-1]  # np.diff's wrapper costs more than the subtraction here
    last = len(steps) - 1
    step_sigma_g = MAD_TO_SIGMA * median(np.abs(steps))
    limit = SCREEN_STEP_SIGMAS * max(step_sigma_g, 1e-12)
    for index in np.flatnonzero(np.abs(steps) > limit).tolist():  # a few ramps: slices beat a fancy index
        steps[max(index - SCREEN_STEP_NEIGHBOURS, 0):min(index + SCREEN_STEP_NEIGHBOURS, last) + 1] = 0.0
    kept = max(int(np.count_nonzero(steps)), 1)
    padded = _fast_length(2 * len(steps))
    spectrum = np.fft.rfft(steps, padded)
    power = spectrum.real ** 2 + spectrum.imag ** 2
    # The bins at the samples' own mean rate: a sensor clock a percent off moves a line by bins.
    mean_rate_sps = len(steps) / float(time_s[-1] - time_s[0])
    evenly = float((time_s[1:] - time_s[:-1]).max()) * mean_rate_sps < 1.5  # else a gap: one DFT per line
    bins_per_hz = padded / mean_rate_sps
    at_bins = [alias_hz(f, mean_rate_sps) * bins_per_hz for f in candidates_hz]
    # Left out of every floor: the bins around each candidate (the guard counts bins of the unpadded
    # length: twice as many padded ones), DC and Nyquist.
    guards = [(max(int(b) - 2 * SCREEN_GUARD_BINS, 0), int(b) + 2 * SCREEN_GUARD_BINS + 2) for b in at_bins]
    guards += [(0, 1), (len(power) - 1, len(power))]
    clear, hum_to_noise = [], []
    for frequency, at_bin in zip(candidates_hz, at_bins):
        half_band = max(SCREEN_BAND * at_bin, 2 * SCREEN_MIN_HALF_BAND_BINS)
        low, high = max(int(at_bin - half_band), 0), min(int(at_bin + half_band) + 1, len(power))
        keep = np.ones(max(high - low, 0), dtype=bool)
        for start, stop in guards:
            if start < high and stop > low:
                keep[max(start - low, 0):stop - low] = False
        band = power[low:high][keep]
        if len(band) < 2 * SCREEN_MIN_FLOOR_BINS:
            clear.append(math.inf)
            hum_to_noise.append(math.inf)
            continue
        mean_floor = median(band) / math.log(2.0)  # the median of exponential powers
        if evenly:
            line_power = float(max(power[int(at_bin)], power[min(int(at_bin) + 1, len(power) - 1)]))
        else:
            angle = 2.0 * np.pi * frequency * (time_s[1:] - time_s[1])
            line_power = float(steps @ np.cos(angle)) ** 2 + float(steps @ np.sin(angle)) ** 2
        clear.append(2.0 * line_power / mean_floor if mean_floor > 0 else math.inf)
        step_gain = 2.0 * math.sin(math.pi * at_bin / padded)  # the sinusoid's step per unit amplitude
        amplitude_g = 2.0 * math.sqrt(line_power) / kept / max(step_gain, 1e-12)
        noise_g = step_sigma_g / math.sqrt(2.0)
        hum_to_noise.append(amplitude_g / noise_g if noise_g > 0 else math.inf)
    return tuple(clear), tuple(hum_to_noise)


# Lengths 2^a·3^b·5^c up to 2^24 samples: numpy's FFT is fast on these, slow on large primes.
def _smooth_lengths(limit: int) -> np.ndarray:
    """Every 2^a·3^b·5^c up to `limit`, ascending (each power grown only while it fits: a tenth of
    the import's cost of trying every exponent)."""
    lengths = []
    twos = 1
    while twos <= limit:
        threes = twos
        while threes <= limit:
            fives = threes
            while fives <= limit:
                lengths.append(fives)
                fives *= 5
            threes *= 3
        twos *= 2
    return np.array(sorted(lengths))


_FAST_LENGTHS = _smooth_lengths(1 << 24)


@functools.lru_cache(maxsize=256)
def _fast_length(at_least: int) -> int:
    """The smallest FFT-friendly length >= at_least (cached: a printer's taps have a few lengths)."""
    index = int(np.searchsorted(_FAST_LENGTHS, at_least))
    return int(_FAST_LENGTHS[index]) if index < len(_FAST_LENGTHS) else at_least


def lines_worth_fitting(time_s: np.ndarray, force_g: np.ndarray, sample_rate_sps: float,
                        candidates_hz) -> tuple[float, ...]:
    """The candidates `auto` fits: the screen reaches SCREEN_MIN_CHI2 (the line is there) and the
    line's amplitude FIT_MIN_HUM_TO_NOISE noise sigmas (it is strong enough to move Z)."""
    return _worth_fitting(time_s, force_g, candidates_hz)


def _worth_fitting(time_s: np.ndarray, force_g: np.ndarray, candidates_hz) -> tuple[float, ...]:
    """The candidates the screen sees (SCREEN_MIN_CHI2) with an amplitude that can move Z (FIT_MIN_HUM_TO_NOISE)."""
    clear, hum_to_noise = _screen(time_s, force_g, candidates_hz)
    return tuple(float(f) for f, c, r in zip(candidates_hz, clear, hum_to_noise)
                 if c >= SCREEN_MIN_CHI2 and r >= FIT_MIN_HUM_TO_NOISE)


def dominant_mains_lines(time_s: np.ndarray, force_g: np.ndarray) -> tuple[float, ...]:
    """The mains lines (MAINS_LINES_HZ) the screen sees (SCREEN_MIN_CHI2) at HUM_DOMINATES_NOISE
    noise sigmas or more over the last DOMINANCE_MAX_SAMPLES samples, at their own mean rate: a hum
    that set the tap's noise."""
    time_s = np.asarray(time_s, dtype=float)[-DOMINANCE_MAX_SAMPLES:]
    force_g = np.asarray(force_g, dtype=float)[-DOMINANCE_MAX_SAMPLES:]
    duration_s = float(time_s[-1] - time_s[0]) if len(time_s) > 2 else 0.0
    if not duration_s > 0.0:
        return ()
    candidates = resolvable_hz(MAINS_LINES_HZ, (len(time_s) - 1) / duration_s, duration_s)
    if not candidates:
        return ()
    clear, hum_to_noise = _screen(time_s, force_g, candidates)
    return tuple(f for f, c, r in zip(candidates, clear, hum_to_noise)
                 if c >= SCREEN_MIN_CHI2 and r >= HUM_DOMINATES_NOISE)


def harmonics_worth_fitting(time_s: np.ndarray, force_g: np.ndarray, sample_rate_sps: float,
                            line_hz: float) -> tuple[float, ...]:
    """The harmonics of a detected line (MAINS_HARMONICS) that pass the screen too.

    Mains hum is rarely a pure sine (rectifiers, transformer saturation): a strong line carries
    a second and third harmonic that, left in, can still break a short compression. A harmonic
    whose alias lies within MIN_ALIAS_CYCLES per tap of 0 Hz, Nyquist, the line's alias or an
    earlier harmonic's cannot be told apart from them and is left out.
    """
    duration_s = float(time_s[-1] - time_s[0])
    seen = [alias_hz(line_hz, sample_rate_sps)]
    harmonics = []
    for multiple in MAINS_HARMONICS:
        frequency = multiple * line_hz
        alias = alias_hz(frequency, sample_rate_sps)
        if resolvable_hz((frequency,), sample_rate_sps, duration_s) and all(
                abs(alias - other) * duration_s >= MIN_ALIAS_CYCLES for other in seen):
            harmonics.append(frequency)
            seen.append(alias)
    if not harmonics:
        return ()
    # The screen's chi2 alone: under a strong line the steps' sigma is the line's, which would read
    # a harmonic low against the noise (taplab mains hum: bias -0.27 -> -0.31 µm with the amplitude bar).
    clear = screen_mains_hum(time_s, force_g, sample_rate_sps, harmonics)
    return tuple(h for h, c in zip(harmonics, clear) if c >= SCREEN_MIN_CHI2)


def notch_zero_phase(force_g: np.ndarray, sample_rate_sps: float, frequencies_hz, quality: float) -> np.ndarray:
    """The force through forward-backward (zero-phase) IIR notches: the alternative to `fit_hum`.

    No delay, but each notch rings for about quality/frequency seconds around every corner of
    the tap; `bench tap_accuracy` compares the two. Frequencies at or above Nyquist are folded.
    """
    from scipy import signal  # only this comparison needs scipy: the analysis imports with numpy alone

    filtered = np.asarray(force_g, dtype=float)
    for frequency in frequencies_hz:
        seen = alias_hz(frequency, sample_rate_sps)
        if not 0.0 < seen < 0.5 * sample_rate_sps:
            continue
        b, a = signal.iirnotch(seen, quality, fs=sample_rate_sps)
        filtered = signal.filtfilt(b, a, filtered)
    return filtered
