"""The floor: how well *any* analysis can know the contact height of a generated tap (numpy only).

Truth side: it uses the generator's own physics (`noise_free_samples`) and the tap's true spec.

What it computes, for one tap spec and the motion its file recorded (halt, pullback, sample count
held fixed; the conversion times are those the spec implies, so the sample clock is known):

* the sensitivities G (samples × parameters) of the noise-free sample values to the tap's own
  physical parameters (`PARAMETERS`: contact height, stiffness, onset width, power and blend,
  unloading ratio, relaxation fraction and time constant, force offset, Z-proportional drift,
  ADC latency; plus sine and cosine of the three mains harmonics), by central finite differences
  (the hum columns are exact: the samples are linear in them);
* the Fisher information J = Gᵀ Σ⁻¹ G for two noise covariances Σ: `white` (the ADC's white noise
  alone, adc.white_g² I) and `coloured` (white + the 1/f noise with the generator's spectrum + the
  thermal random walk through the conversion window, exact covariances; Gaussian throughout);
* the Cramér-Rao bound sqrt((J⁻¹)_zz) on the σ of the contact height for several sets of unknowns
  (`UNKNOWN_SETS`: everything above unknown; the toe's shape known; the whole toe known; only the
  contact height unknown), and the Van Trees bound of a whole scenario (`van_trees_sigma_um`).

What it is, and is not:
* A lower bound on the σ of any *unbiased* estimator of z_contact that does not know the listed
  parameters, with the noise no worse than Σ. It is local (at the tap's true parameters) and
  says nothing about bias. Anything an analysis must also estimate and that is held known here
  (the sample clock, timestamp jitter, the mains frequency, the polarity, the motion) only makes
  the real problem harder, so those choices keep the bound a valid floor; so does the white bound
  against the coloured one, and `coloured` leaves out the hum's randomness (its amplitudes are
  unknowns instead) and the corrupt frames. The 1/f covariance is its spectrum's; the generator
  also rescales every draw to its rms, which makes the real noise slightly less correlated.
* Not reachable in general: the CRB is approached by maximum likelihood only when the model is
  right and the noise small against the curvature of the likelihood. It is a floor, not a goal.
* Not a bound on a *biased* estimator: one that pulls the toe's shape towards its prior (as any
  analysis with a toe family does) can read below the CRB on some taps and above it on others.
  The Van Trees (Bayesian) bound covers every estimator, biased or not, for taps drawn from the
  scenario's priors: mean squared error >= [(E J + J_prior)⁻¹]_zz with E J the Fisher matrix
  averaged over the scenario's taps and J_prior the Fisher information of the priors. The
  generator's uniform priors have no finite Fisher information (their edges are steps), so this
  is the bound for a *smoothed generator*: every uniform convolved with a Gaussian of
  `PRIOR_SMOOTHING` × its span (the ranges are read from many draws of the scenario), with E J
  taken over the taps given (a Monte Carlo mean). It is loose here: averaging J over taps whose
  nearly degenerate directions differ fills those directions in (Jensen), so it sits well below
  what the toe costs any single tap.
* The two-point floor (`nearest_twin`) covers every estimator too, for one pair of taps: a twin
  `shift` higher or lower, its other parameters inside the scenario's ranges, found by a local
  search for the samples closest to this tap's; no analysis has a smaller rms error over the two
  than `pair_floor_um` (their Bayes error with equal weights). It is a floor for an analysis that
  must do well on *every* tap of the ranges, not for the average over the prior.
* Degenerate directions (two parameters that move the samples alike) show as a near-singular J.
  Columns are scaled to unit information first; eigenvalues below `DEGENERATE` × the largest are
  dropped (a pseudo-inverse: the bound of the estimable part) and the tap is flagged.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass, replace

import numpy as np

from tapcell.taplab.generate import (
    SUBSAMPLES,
    RecordedMotion,
    Scenario,
    TapSpec,
    noise_free_samples,
    noise_record_length,
)
from tapcell.taplab.sensor import conversion_kernel

_ERF = np.vectorize(math.erf, otypes=[float])
DEGENERATE = 1e-12  # eigenvalue of the unit-scaled Fisher matrix below this × the largest: dropped
PRIOR_SMOOTHING = 0.05  # the smoothed generator: Gaussian σ as a share of each prior's span
PRIOR_DRAWS = 2000  # draws of a scenario to read its prior ranges from


@dataclass(frozen=True)
class Parameter:
    """One unknown of the tap: how to move it by `delta` in its own unit, and a finite-difference step."""

    name: str
    step: float
    shift: Callable[[TapSpec, float], TapSpec]
    value: Callable[[TapSpec], float]


def _contact(**field_of):
    def shift(spec: TapSpec, delta: float) -> TapSpec:
        (name,) = field_of
        return replace(spec, contact=replace(spec.contact, **{name: field_of[name](spec.contact, delta)}))
    return shift


def _move_contact_height(spec: TapSpec, delta_um: float) -> TapSpec:
    # The motion stays where the file put it: the start height z_contact + approach is kept.
    delta_mm = delta_um / 1000.0
    return replace(spec, z_contact_mm=spec.z_contact_mm + delta_mm, approach_mm=spec.approach_mm - delta_mm)


def _later_read(spec: TapSpec, delta_periods: float) -> TapSpec:
    # The sample times are what the file recorded: more read latency means earlier conversions.
    return replace(spec, adc=replace(spec.adc, latency_periods=spec.adc.latency_periods + delta_periods),
                   sample_phase=spec.sample_phase - delta_periods)


PARAMETERS: tuple[Parameter, ...] = (
    Parameter("z_contact_um", 0.05, _move_contact_height, lambda s: s.z_contact_mm * 1000.0),
    Parameter("stiffness_g_um", 0.005, _contact(stiffness_g_um=lambda c, d: c.stiffness_g_um + d),
              lambda s: s.contact.stiffness_g_um),
    Parameter("onset_um", 0.02, _contact(onset_um=lambda c, d: c.onset_um + d), lambda s: s.contact.onset_um),
    Parameter("onset_power", 0.01, _contact(onset_power=lambda c, d: c.onset_power + d),
              lambda s: s.contact.onset_power),
    Parameter("onset_blend", 0.01, _contact(onset_blend=lambda c, d: c.onset_blend + d),
              lambda s: s.contact.onset_blend),
    Parameter("unload_ratio", 0.002, _contact(unload_ratio=lambda c, d: c.unload_ratio + d),
              lambda s: s.contact.unload_ratio),
    Parameter("relax_fraction", 0.001, _contact(relax_fraction=lambda c, d: (c.relax_fraction[0] + d,)),
              lambda s: s.contact.relax_fraction[0]),
    Parameter("relax_tau_s", 0.002, _contact(relax_tau_s=lambda c, d: (c.relax_tau_s[0] + d,)),
              lambda s: s.contact.relax_tau_s[0]),
    Parameter("offset_g", 0.5, lambda s, d: replace(s, offset_g=s.offset_g + d), lambda s: s.offset_g),
    Parameter("drift_g_per_mm", 0.5, lambda s, d: replace(s, drift_g_per_mm=s.drift_g_per_mm + d),
              lambda s: s.drift_g_per_mm),
    Parameter("latency_periods", 0.01, _later_read, lambda s: s.adc.latency_periods),
)
HUM = tuple(f"hum{k + 1}_{part}_g" for k in range(3) for part in ("sin", "cos"))
NAMES: tuple[str, ...] = tuple(p.name for p in PARAMETERS) + HUM

UNKNOWN_SETS: dict[str, tuple[str, ...]] = {
    "all unknown": NAMES,
    "toe shape known": tuple(n for n in NAMES if n not in ("onset_power", "onset_blend")),
    "toe known": tuple(n for n in NAMES if n not in ("onset_um", "onset_power", "onset_blend")),
    "only z unknown": ("z_contact_um",),
}


def _samples(spec: TapSpec, motion: RecordedMotion) -> np.ndarray:
    if spec.ooze is not None:
        raise ValueError("the bound models a clean contact (no ooze)")
    # The relaxation starts at the exact touch, not the first grid point past it: smooth in z_contact.
    return noise_free_samples(spec, motion, touch_s=spec.approach_mm / spec.approach_speed_mm_s)


def sensitivities(spec: TapSpec, motion: RecordedMotion, step_scale: float = 1.0) -> np.ndarray:
    """G: d(sample)/d(parameter) for every name in NAMES (samples × parameters, g per unit)."""
    return np.column_stack([parameter_sensitivities(spec, motion, PARAMETERS, step_scale),
                            hum_sensitivities(spec, motion)])


def parameter_sensitivities(spec: TapSpec, motion: RecordedMotion, parameters: Iterable[Parameter],
                            step_scale: float = 1.0) -> np.ndarray:
    """d(sample)/d(parameter) for `parameters` (samples × parameters), by central differences."""
    columns = []
    for parameter in parameters:
        h = parameter.step * step_scale
        up = _samples(parameter.shift(spec, h), motion)
        down = _samples(parameter.shift(spec, -h), motion)
        columns.append((up - down) / (2.0 * h))
    return np.column_stack(columns)


def hum_sensitivities(spec: TapSpec, motion: RecordedMotion) -> np.ndarray:
    """d(sample)/d(hum component) for HUM (samples × 6): exact, the samples are linear in them."""
    # Mains harmonics: unknown amplitude and phase each; a quarter cycle later turns the sine to a cosine.
    silent = replace(spec, hum_g=(0.0, 0.0, 0.0))
    base = _samples(silent, motion)
    columns = []
    for k in range(3):
        unit = tuple(1.0 if j == k else 0.0 for j in range(3))
        quarter_s = 0.25 / ((k + 1) * spec.mains_hz)
        for origin_s in (spec.time_origin_s, spec.time_origin_s + quarter_s):
            columns.append(_samples(replace(silent, hum_g=unit, time_origin_s=origin_s), motion) - base)
    return np.column_stack(columns)


def walk_covariance(spec: TapSpec, count: int) -> np.ndarray:
    """Covariance (g²) of the thermal random walk as the first `count` samples see it.

    The walk steps on the fine grid (variance walk² dt per step from the grid's start) and each
    sample averages it over its conversion window: cov = walk² dt (s_i + 1 + M(s_j − s_i)) for
    s_i <= s_j the windows' first fine indices, M(Δ) = Σ_a Σ_b K_a K_b min(a, Δ + b)."""
    kernel = conversion_kernel(spec.adc)
    length = len(kernel)
    offsets = np.arange(length)
    lag_steps = np.arange(0, length + SUBSAMPLES, SUBSAMPLES)  # window overlaps, in fine steps
    overlap = np.array([kernel @ np.minimum(offsets[:, None], lag + offsets[None, :]) @ kernel for lag in lag_steps])
    first = SUBSAMPLES * spec.adc.window_periods - length + SUBSAMPLES * np.arange(count)
    lower = np.minimum(first[:, None], first[None, :])
    lag_index = np.minimum(np.abs(np.arange(count)[:, None] - np.arange(count)[None, :]), len(lag_steps) - 1)
    dt_s = spec.adc.period_s / SUBSAMPLES
    return spec.walk_g_per_sqrt_s ** 2 * dt_s * (lower + 1.0 + overlap[lag_index])


def pink_covariance(spec: TapSpec, count: int) -> np.ndarray:
    """Covariance (g²) of the generator's 1/f noise: a circular process with power 1/f over the
    samples it is drawn for (no DC), scaled to its rms; Toeplitz over the first `count` samples."""
    _, record = noise_record_length(spec)
    power = np.zeros(record // 2 + 1)
    power[1:] = 1.0 / np.arange(1, record // 2 + 1)
    autocovariance = np.fft.irfft(power, n=record)
    autocovariance *= spec.adc.pink_g ** 2 / autocovariance[0]
    lags = np.abs(np.arange(count)[:, None] - np.arange(count)[None, :])
    return autocovariance[lags]


def noise_covariance(spec: TapSpec, count: int) -> np.ndarray:
    """Σ of the coloured bound: white + 1/f + random walk (g²) over the first `count` samples."""
    return spec.adc.white_g ** 2 * np.eye(count) + pink_covariance(spec, count) + walk_covariance(spec, count)


def fisher(G: np.ndarray, spec: TapSpec, coloured: bool) -> np.ndarray:
    """J = Gᵀ Σ⁻¹ G with the white or the coloured noise covariance."""
    if not coloured:
        return G.T @ G / spec.adc.white_g ** 2
    return G.T @ np.linalg.solve(noise_covariance(spec, G.shape[0]), G)


def whitener(spec: TapSpec, count: int, coloured: bool) -> np.ndarray:
    """W with W Σ Wᵀ = I (the inverse of Σ's Cholesky factor): noise sigmas from grams."""
    if not coloured:
        return np.eye(count) / spec.adc.white_g
    return np.linalg.inv(np.linalg.cholesky(noise_covariance(spec, count)))


@dataclass(frozen=True)
class Floor:
    sigma_um: float  # sqrt of the bound on the variance of z_contact
    degenerate: bool  # directions of J were dropped (pseudo-inverse)


def crb(J: np.ndarray, unknown: Iterable[str], prior: np.ndarray | None = None) -> Floor:
    """Bound on the σ of z_contact (µm) from a Fisher matrix over NAMES, with `unknown` unknown
    (the rest known); `prior` (per NAMES) adds a diagonal prior information (Van Trees)."""
    index = [NAMES.index(name) for name in unknown]
    if index[0] != NAMES.index("z_contact_um"):
        raise ValueError("the first unknown must be z_contact_um")
    sub = J[np.ix_(index, index)]
    if prior is not None:
        sub = sub + np.diag(prior[index])
    scale = np.sqrt(np.diag(sub))
    unit = sub / np.outer(scale, scale)
    values, vectors = np.linalg.eigh(unit)
    keep = values > DEGENERATE * values[-1]
    inverse_zz = float(np.sum(vectors[0, keep] ** 2 / values[keep]))
    return Floor(sigma_um=float(np.sqrt(inverse_zz)) / scale[0], degenerate=not keep.all())


@dataclass(frozen=True)
class TapFloor:
    white: dict[str, Floor]  # per UNKNOWN_SETS name
    coloured: dict[str, Floor]
    fisher_white: np.ndarray  # J over NAMES (for the Van Trees bound of a scenario)
    fisher_coloured: np.ndarray


def tap_floor(spec: TapSpec, motion: RecordedMotion) -> TapFloor:
    """The Cramér-Rao floor of one tap for every set of unknowns, with either noise."""
    G = sensitivities(spec, motion)
    J_white = fisher(G, spec, coloured=False)
    J_coloured = fisher(G, spec, coloured=True)
    return TapFloor(white={name: crb(J_white, unknown) for name, unknown in UNKNOWN_SETS.items()},
                    coloured={name: crb(J_coloured, unknown) for name, unknown in UNKNOWN_SETS.items()},
                    fisher_white=J_white, fisher_coloured=J_coloured)


# --- the Van Trees bound of a scenario -------------------------------------------------------------

def _support(draws: np.ndarray) -> list[tuple[float, float, float]]:
    """The intervals a uniform (or a union of uniforms) was drawn from: (low, high, share of draws)."""
    draws = np.sort(draws)
    span = draws[-1] - draws[0]
    if span <= 0:
        return []
    cuts = np.flatnonzero(np.diff(draws) > 0.05 * span) + 1
    return [(float(part[0]), float(part[-1]), len(part) / len(draws)) for part in np.split(draws, cuts)]


def smoothed_uniform_information(intervals: list[tuple[float, float, float]], smoothing: float) -> float:
    """Fisher information ∫ p'²/p of a mixture of uniforms convolved with a Gaussian of σ = smoothing."""
    low = min(a for a, _, _ in intervals) - 8 * smoothing
    high = max(b for _, b, _ in intervals) + 8 * smoothing
    x = np.linspace(low, high, 8001)
    density = np.zeros_like(x)
    slope = np.zeros_like(x)
    for a, b, share in intervals:
        for edge, sign in ((a, 1.0), (b, -1.0)):
            z = (x - edge) / smoothing
            density += sign * share / (b - a) * 0.5 * (1.0 + _ERF(z / np.sqrt(2.0)))
            slope += sign * share / (b - a) * np.exp(-0.5 * z * z) / (smoothing * np.sqrt(2.0 * np.pi))
    density = np.maximum(density, 1e-300)
    return float(np.sum(slope ** 2 / density) * (x[1] - x[0]))


def prior_ranges(scenario: Scenario, draws: int = PRIOR_DRAWS, seed: int = 0) -> dict[str, list[tuple]]:
    """Per parameter of PARAMETERS, the intervals the scenario draws it from (low, high, share),
    read from `draws` draws of the scenario itself; [] for a constant."""
    rng = np.random.default_rng([seed, 12])
    specs = [scenario.draw(rng) for _ in range(draws)]
    return {p.name: _support(np.array([p.value(s) for s in specs])) for p in PARAMETERS}


def prior_information(ranges: dict[str, list[tuple]]) -> np.ndarray:
    """Diagonal Fisher information (per NAMES) of the smoothed generator's priors (`prior_ranges`).

    Hum components and constants get infinite information (held known: the hum's prior, amplitude
    uniform × phase uniform, has none finite); holding them known only lowers the bound."""
    information = np.full(len(NAMES), np.inf)
    for i, parameter in enumerate(PARAMETERS):
        intervals = ranges[parameter.name]
        if intervals:
            span = intervals[-1][1] - intervals[0][0]
            information[i] = smoothed_uniform_information(intervals, PRIOR_SMOOTHING * span)
    return information


def van_trees_sigma_um(fishers: list[np.ndarray], prior: np.ndarray, unknown: Iterable[str]) -> Floor:
    """Van Trees bound on the rms error of z_contact over a scenario's taps: [(E J + J_prior)⁻¹]_zz^½.

    Parameters with infinite prior information are held known (dropped from the unknowns)."""
    unknown = [name for name in unknown if np.isfinite(prior[NAMES.index(name)])]
    return crb(np.mean(fishers, axis=0), unknown, prior=prior)


# --- the two-point floor: a twin the samples cannot tell apart --------------------------------------

TWIN_INTERIOR = 0.0  # share of each contact parameter's range at either end that twins keep out of
_CONTACT = ("stiffness_g_um", "onset_um", "onset_power", "onset_blend", "unload_ratio", "relax_fraction", "relax_tau_s")


def pair_floor_um(shift_um: float, distance: float) -> float:
    """The least rms error of z any analysis can have over two taps, `shift_um` apart in z, whose
    noise-free samples are `distance` noise sigmas apart (Mahalanobis), each equally likely: the
    Bayes error of the pair, shift × sqrt(E[p(1 − p)]) with p the posterior of one of them (its
    log-odds ~ N(distance²/2, distance²)). At distance 0 it is half the shift."""
    z = np.linspace(-8.0, 8.0, 1601)
    weight = np.exp(-0.5 * z * z)
    weight /= weight.sum()
    log_odds = np.clip(0.5 * distance ** 2 + distance * z, -700.0, 700.0)
    p = 1.0 / (1.0 + np.exp(-log_odds))
    return abs(shift_um) * float(np.sqrt(np.sum(weight * p * (1.0 - p))))


@dataclass(frozen=True)
class Twin:
    shift_um: float  # its z_contact − the tap's
    distance: float  # between the two taps' noise-free samples, in noise sigmas (Mahalanobis; hum projected out)
    parameters: dict[str, float]  # the twin's other parameters (PARAMETERS after z_contact)
    floor_um: float  # pair_floor_um(shift_um, distance)


def _with_values(spec: TapSpec, values: np.ndarray) -> TapSpec:
    for parameter, value in zip(PARAMETERS[1:], values):
        spec = parameter.shift(spec, float(value) - parameter.value(spec))
    return spec


def nearest_twin(spec: TapSpec, motion: RecordedMotion, shift_um: float, ranges: dict[str, list[tuple]],
                 interior: float = TWIN_INTERIOR, coloured: bool = False, iterations: int = 40) -> Twin:
    """A tap `shift_um` higher or lower whose samples come as close as a search finds to this tap's,
    its other parameters inside the scenario's ranges (the contact's inside the central
    1 − 2 × interior of each) and its hum free; distances with the white or the coloured noise. Projected Levenberg-Marquardt from the tap's own
    parameters: a local search, so the distance is an upper bound on the nearest twin's and the
    floor it gives a lower bound on the pair's."""
    low, high = [], []
    for parameter in PARAMETERS[1:]:
        a, b = ranges[parameter.name][0][0], ranges[parameter.name][-1][1]  # hull of the intervals
        margin = interior * (b - a) if parameter.name in _CONTACT else 0.0
        low.append(a + margin)
        high.append(b - margin)
    low, high = np.array(low), np.array(high)
    target = _samples(spec, motion)
    white = whitener(spec, len(target), coloured)
    shifted = PARAMETERS[0].shift(spec, shift_um)
    hum = white @ hum_sensitivities(shifted, motion)
    keep_out_hum = (np.eye(len(target)) - hum @ np.linalg.pinv(hum)) @ white

    def residual(values: np.ndarray) -> np.ndarray:
        return keep_out_hum @ (_samples(_with_values(shifted, values), motion) - target)

    values = np.clip([p.value(spec) for p in PARAMETERS[1:]], low, high)
    r = residual(values)
    cost = float(r @ r)
    damping = 1e-2
    for _ in range(iterations):
        # Only the twin's free parameters (z is held at the shift; the hum is projected out).
        G = keep_out_hum @ parameter_sensitivities(_with_values(shifted, values), motion, PARAMETERS[1:])
        normal, gradient = G.T @ G, G.T @ r
        for _ in range(8):
            trial = np.clip(values - np.linalg.solve(normal + damping * np.diag(np.diag(normal)), gradient), low, high)
            r_trial = residual(trial)
            cost_trial = float(r_trial @ r_trial)
            if cost_trial < cost:
                break
            damping *= 4.0
        else:
            break  # no step downhill
        gain = (cost - cost_trial) / cost
        values, r, cost, damping = trial, r_trial, cost_trial, damping / 3.0
        if gain < 1e-5:
            break
    distance = float(np.sqrt(cost))
    return Twin(shift_um=shift_um, distance=distance,
                parameters={p.name: float(v) for p, v in zip(PARAMETERS[1:], values)},
                floor_um=pair_floor_um(shift_um, distance))
