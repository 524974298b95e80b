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

import math
from dataclasses import dataclass, field

import numpy as np

from tapcell.tap.robust import robust_sigma

MAINS_LINES_HZ = (50.0, 60.0)
# A line is resolvable when its alias lies this many cycles per tap away from 0 Hz and Nyquist.
MIN_ALIAS_CYCLES = 3.0
# `auto` keeps the stronger mains line only when it lowers the residual by this many noise
# variances (2 parameters: chance alone gives ~2; 30 is ~5 sigma of the amplitude).
DETECTION_MIN_CHI2 = 30.0
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


def hat_basis(time_s: np.ndarray, knots_s: np.ndarray) -> np.ndarray:
    """Linear-spline basis: column k is 1 at knot k, falling linearly to 0 at its neighbours.

    Knots must be sorted and span the times; any piecewise-linear function with corners at
    the knots is exactly a combination of the columns.
    """
    basis = np.zeros((len(time_s), len(knots_s)))
    right = np.clip(np.searchsorted(knots_s, time_s, side="right"), 1, len(knots_s) - 1)
    left = right - 1
    width = knots_s[right] - knots_s[left]
    share = np.clip((time_s - knots_s[left]) / width, 0.0, 1.0)
    rows = np.arange(len(time_s))
    basis[rows, left] = 1.0 - share
    basis[rows, right] += share
    return basis


def spline_knots(t_first_s: float, t_last_s: float, spacing_s: float, corners_s=()) -> np.ndarray:
    """A uniform grid `spacing_s` apart over [t_first, t_last] plus the corners inside it.

    A corner closer than a tenth of the spacing to a grid knot replaces that knot (two
    knots that close would make nearly identical columns).
    """
    count = max(int(math.ceil((t_last_s - t_first_s) / spacing_s)), 1)
    grid = t_first_s + (t_last_s - t_first_s) * np.arange(count + 1) / count
    corners = np.array([c for c in corners_s if t_first_s < c < t_last_s and math.isfinite(c)], dtype=float)
    if len(corners):
        near = np.min(np.abs(grid[:, None] - corners[None, :]), axis=1) < 0.1 * spacing_s
        near[[0, -1]] = False  # the ends stay
        grid = grid[~near]
    return np.unique(np.concatenate((grid, corners)))


def sinusoid_basis(time_s: np.ndarray, frequencies_hz) -> np.ndarray:
    """Columns sin, cos for each frequency, with time measured from the first sample."""
    tau_s = time_s - time_s[0]
    columns = []
    for frequency in frequencies_hz:
        angle = 2.0 * np.pi * frequency * tau_s
        columns += [np.sin(angle), np.cos(angle)]
    return np.column_stack(columns) if columns else np.zeros((len(time_s), 0))


def _solve(design: np.ndarray, force_g: np.ndarray, use: np.ndarray) -> tuple[np.ndarray, float]:
    """Least-squares coefficients over the used rows, and the residual sum of squares there.

    Normal equations (a few dozen columns, well conditioned: hat functions and sinusoids),
    ten times faster than an SVD. A column with no used sample (a knot whose neighbourhood
    was excluded) would make them singular: a tiny ridge sets its coefficient to 0 instead.
    """
    rows = design[use]
    gram = rows.T @ rows
    ridge = 1e-10 * max(float(np.trace(gram)) / max(len(gram), 1), 1e-300)
    coefficients = np.linalg.solve(gram + ridge * np.eye(len(gram)), rows.T @ force_g[use])
    residual = force_g[use] - rows @ coefficients
    return coefficients, float(residual @ residual)


def fit_hum(time_s: np.ndarray, force_g: np.ndarray, frequencies_hz, knots_s: np.ndarray,
            exclude: np.ndarray | None = None) -> HumFit | None:
    """Fit sinusoids at `frequencies_hz` jointly with a linear spline on `knots_s`.

    `exclude` marks samples to leave out of the fit (e.g. those whose conversion window holds
    a corner, which a linear spline cannot follow); the hum is still evaluated at every sample.
    After a first fit, samples beyond OUTLIER_SIGMAS robust sigmas are dropped and it is repeated.
    Returns None when too few samples remain for the parameters.
    """
    time_s = np.asarray(time_s, dtype=float)
    force_g = np.asarray(force_g, dtype=float)
    frequencies_hz = tuple(float(f) for f in frequencies_hz)
    spline = hat_basis(time_s, np.asarray(knots_s, dtype=float))
    waves = sinusoid_basis(time_s, frequencies_hz)
    design = np.hstack((spline, waves))
    use = np.ones(len(time_s), dtype=bool) if exclude is None else ~np.asarray(exclude, dtype=bool)
    parameters = design.shape[1]
    if not frequencies_hz or np.count_nonzero(use) < parameters + 4:
        return None
    coefficients, rss = _solve(design, force_g, use)
    residual = force_g - design @ coefficients
    inliers = use & (np.abs(residual) <= OUTLIER_SIGMAS * max(robust_sigma(residual[use]), 1e-12))
    if np.count_nonzero(inliers) < np.count_nonzero(use) and np.count_nonzero(inliers) >= parameters + 4:
        use = inliers
        coefficients, rss = _solve(design, force_g, use)
    _, rss_without = _solve(spline, force_g, use)
    dof = max(int(np.count_nonzero(use)) - parameters, 1)
    noise_var = rss / dof
    hum_coefficients = coefficients[spline.shape[1]:]
    sines, cosines = hum_coefficients[0::2], hum_coefficients[1::2]
    return HumFit(
        frequencies_hz=frequencies_hz,
        amplitudes_g=tuple(float(a) for a in np.hypot(sines, cosines)),
        phases_rad=tuple(float(p) for p in np.arctan2(cosines, sines)),
        hum_g=waves @ hum_coefficients,
        residual_sigma_g=math.sqrt(noise_var),
        chi2_improvement=(rss_without - rss) / noise_var if noise_var > 0 else math.inf,
    )


def detect_mains_hum(time_s: np.ndarray, force_g: np.ndarray, knots_s: np.ndarray,
                     exclude: np.ndarray | None = None, candidates_hz=MAINS_LINES_HZ) -> HumFit | None:
    """The stronger of the mains lines (50 or 60 Hz) when the tap clearly holds it, else None.

    Each candidate is fitted alone with the same spline; the one that lowers the residual more
    is kept if it lowers it by at least DETECTION_MIN_CHI2 noise variances.
    """
    fits = [fit_hum(time_s, force_g, (frequency,), knots_s, exclude) for frequency in candidates_hz]
    fits = [fit for fit in fits if fit is not None]
    if not fits:
        return None
    best = max(fits, key=lambda fit: fit.chi2_improvement)
    return best if best.chi2_improvement >= DETECTION_MIN_CHI2 else None


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
