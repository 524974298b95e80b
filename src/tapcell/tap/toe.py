"""Break contact with the contact's toe fitted per tap, and the sensor lag read off the halt.

Two estimates the tap itself carries (issue 12):

* **Lag from the halt.** The approach presses in at tens of g per millisecond and stops dead at
  the halt, whose time the motion gives exactly. The compression and dwell lines of the five-line
  split meet at the halt as the sensor saw it: P2's time minus the halt is the sensor's whole lag
  (pipeline delay + half the conversion window, or the centroid of any other averaging kernel).
  Any lag moves break contact up by pullback speed × lag, so this removes it per tap.
* **The toe.** A first touch is not a hinge: the stiffness grows over the first micrometres
  (Hertz: force ~ depth^1.5) before the contact turns linear, and a sharp model reads such a
  contact low by a fraction of that width. Over the pullback the force is fitted as
  baseline + drift · x + k · H(c − x; w, p) averaged over each sample's conversion window, H a
  power-law toe of width w (stiffness ~ (depth/w)^p) joining the linear region with a continuous
  slope. The drift (g per µm of height: a cable or bowden pulling in proportion to Z) comes from
  the approach line when the caller knows it, else it is fitted with the rest. For every
  (p, w, c) on a grid, baseline and k are solved in closed form (variable projection: the
  fixed columns are projected out once, each toe column costs a few dot products).

`contact_um` is the mean of c with the toe marginalised out, and `sigma_um` its sd
(`marginal_contact_um`): the toe width and the contact height trade off along a flat valley of
the residual, and the single best toe wanders along it with the noise. Averaging over the toes the
data allow (weighted by their likelihood) is steadier than the best one, and the sd keeps that
trade-off: on the independent generator's clean taps the error over this sigma has an rms of
1.0-1.3 (docs/tap-analysis.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

TOE_WIDTHS_UM = (0.0, 1.0, 2.0, 3.0, 4.5, 6.0, 8.0, 10.0, 13.0, 16.0)
TOE_POWERS = (0.5, 1.0)  # Hertz sphere on flat; a parabolic force onset


def _width_prior(widths_um: tuple[float, ...]) -> np.ndarray:
    """Each grid width's share of a uniform prior over 0..widest: the span it stands for (half the
    gaps to its neighbours). The grid is finer at narrow toes; counting every width alike would
    favour narrow toes, which read the contact low."""
    w = np.array(widths_um)
    edges = np.concatenate(([w[0]], 0.5 * (w[1:] + w[:-1]), [w[-1]]))
    return np.diff(edges) / (w[-1] - w[0])


WIDTH_PRIOR = _width_prior(TOE_WIDTHS_UM)
COARSE_STEP_UM = 0.5
COARSE_BELOW_UM = 3.0  # the sharp estimate reads a toe low: search mostly above it
COARSE_ABOVE_UM = 10.0
PENETRATION_REACH_UM = 30.0  # samples deeper than this in contact are left out (relaxation, hysteresis)
# Samples past break contact that set the baseline. Far enough that an adhesion thread pulling for
# the first tens of µm cannot pass for the baseline (10: mild ooze +4.7 µm, 40: +3.6 µm).
DEPARTURE_REACH_SAMPLES = 40
SUBSAMPLES = 2  # points per conversion window for its average
MAX_LAG_PERIODS = 4.0
# Adhesion (a plastic thread pulling the nozzle after break contact): the force's dip below the
# free-air level, over the first ADHESION_REACH_UM above contact, against the level further up.
ADHESION_REACH_UM = 40.0
ADHESION_LEVEL_UM = 100.0  # the free-air level from samples between the reach and this height
ADHESION_RUN_SAMPLES = 5  # the dip is the lowest mean of this many consecutive samples
ADHESION_MIN_LEVEL_SAMPLES = 10
# The baseline's random walk is weighed in when over the fit it adds as much variance as the white noise
# (0.25 and 0.5 gave the same drift sigma and 0.01 um more on clean taps).
WANDER_SHARE = 1.0
# Variogram lags (samples) for the walk estimate. From 3: an ADS1220's sinc3 averages over three
# periods, so neighbouring samples share noise and short lags would read that as a walk.
WANDER_LAGS = range(3, 15)


@dataclass
class ToeFit:
    contact_um: float  # height above the halt where the force reaches the baseline
    sigma_um: float
    width_um: float
    power: float
    stiffness_g_um: float
    residual_sigma_g: float


def toe_shape(depth_um: np.ndarray, width_um, power: float) -> np.ndarray:
    """Force / linear stiffness at a depth into contact: power-law toe, then linear (slope 1).

    width_um may be an array broadcasting against depth_um (a width of 0 is a hinge).
    """
    depth_um = np.maximum(depth_um, 0.0)
    width_um = np.maximum(width_um, 1e-9)
    u = np.minimum(depth_um / width_um, 1.0)
    if power == 0.5:
        lifted = u * np.sqrt(u)  # the Hertz toe without a general power (the hot path)
    elif power == 1.0:
        lifted = u * u
    else:
        lifted = u ** (power + 1.0)
    return width_um * lifted / (power + 1.0) + np.maximum(depth_um - width_um, 0.0)


def lag_from_halt_s(compression_end_time_s: float, halt_time_s: float, period_s: float) -> float | None:
    """The sensor's whole lag (s) from P2 and the halt, or None when it is not plausible."""
    lag_s = compression_end_time_s - halt_time_s
    if not math.isfinite(lag_s) or not 0.0 <= lag_s <= MAX_LAG_PERIODS * period_s:
        return None
    return lag_s


@dataclass
class _Projected:
    """The samples and linear columns of one toe fit, prepared once for every candidate toe.

    basis: the linear columns beside the toe (orthonormal: the baseline, and the drift unless it
    is known); the force has them projected out (`y_free`). For a toe column h the fit needs only
    h·h - |hᵀB|² and h·y_free (variable projection). Samples above every candidate contact have
    h = 0 and drop out; samples pressed past every candidate's toe have h = a - x (a = c - the
    toe's lift deficit), so they enter through a few sums; only the samples in between are
    evaluated per candidate.
    """

    near_window_um: np.ndarray  # (n, SUBSAMPLES) heights of the in-between samples
    near_basis: np.ndarray
    near_y: np.ndarray
    pressed_n: int
    pressed_x: float
    pressed_xx: float
    pressed_basis: np.ndarray  # Σ B over the pressed samples (m,)
    pressed_x_basis: np.ndarray  # Σ x B (m,)
    pressed_y: float
    pressed_xy: float
    yy: float

    @classmethod
    def prepare(cls, window_um: np.ndarray, x_mid: np.ndarray, basis: np.ndarray, y: np.ndarray,
                lowest_contact_um: float, highest_contact_um: float, widest_um: float) -> _Projected:
        y_free = y - basis @ (basis.T @ y)
        pressed = window_um.max(axis=1) <= lowest_contact_um - widest_um
        near = ~pressed & (window_um.min(axis=1) < highest_contact_um)
        x_p, y_p, b_p = x_mid[pressed], y_free[pressed], basis[pressed]
        return cls(window_um[near], basis[near], y_free[near], int(np.count_nonzero(pressed)), float(x_p.sum()),
                   float(x_p @ x_p), b_p.sum(axis=0), x_p @ b_p, float(y_p.sum()), float(x_p @ y_p),
                   float(y_free @ y_free))


def _rss_over_contacts(contacts_um, widths_um, power, data: _Projected):
    """Residual sum of squares of the linear solve at every (toe width, candidate contact) at once,
    and the toe's stiffness there. contacts_um, widths_um: equal-length 1-D arrays (one row per
    candidate); power: the toe's."""
    depth = contacts_um[:, None, None] - data.near_window_um[None]
    h = toe_shape(depth, widths_um[:, None, None], power).mean(axis=2)  # (C, n) the in-between samples
    # The pressed samples: h = a - x with a = c - w p / (p + 1) (the toe lifts w / (p + 1), not w).
    a = contacts_um - widths_um * (power / (power + 1.0))
    h_basis = h @ data.near_basis + a[:, None] * data.pressed_basis[None] - data.pressed_x_basis[None]
    hh_all = np.einsum("cn,cn->c", h, h) + a * a * data.pressed_n - 2.0 * a * data.pressed_x + data.pressed_xx
    hh = hh_all - np.einsum("cm,cm->c", h_basis, h_basis)
    hy = h @ data.near_y + a * data.pressed_y - data.pressed_xy
    # A candidate whose toe column is (nearly) a combination of the others cannot be solved.
    usable = hh > 1e-9 * (hh_all + 1e-300)
    stiffness = np.divide(hy, hh, out=np.zeros_like(hy), where=usable)
    rss = np.where(usable & (stiffness > 0.0), data.yy - stiffness * hy, np.inf)  # must press, not pull
    return rss, stiffness


@dataclass(frozen=True)
class Wander:
    """White noise plus a random walk of the baseline (thermal drift of the cell, a cable settling).

    white_var_g2: per sample; walk_var_g2: the walk's variance growth per sample. Over the ~100
    samples of a toe fit a walk of a few g/sqrt(s) bends the baseline by as much as the white
    noise, and an ordinary least-squares fit reads the bend as toe (bowden/cable drift taps of the
    independent generator: sigma 0.85 um; weighting by the true covariance: 0.71).
    """

    white_var_g2: float
    walk_var_g2: float

    def matters(self, samples: int) -> bool:
        """Whether the walk over `samples` adds a noticeable share to the white variance."""
        return self.walk_var_g2 * samples > WANDER_SHARE * self.white_var_g2


def wander_from_free_air(segments: list[np.ndarray]) -> Wander | None:
    """White and random-walk variances from force samples in free air (each segment evenly sampled).

    Each segment's straight line is removed (Z-proportional drift, a steady trend); the variogram
    of what is left, E[(r[i+L] - r[i])^2] = 2 white + L walk, is pooled over the segments for
    WANDER_LAGS and fitted by least squares. None when the segments are too short.
    """
    lags, values = [], []
    for force_g in segments:
        n = len(force_g)
        if n < 2 * WANDER_LAGS[-1]:
            continue
        i = np.arange(n, dtype=float) - 0.5 * (n - 1)
        r = force_g - force_g.mean() - i * (i @ force_g) / (i @ i)
        for lag in WANDER_LAGS:
            d = r[lag:] - r[:-lag]
            lags.append(lag)
            values.append(float(d @ d) / len(d))
    if not lags:
        return None
    design = np.column_stack((np.full(len(lags), 2.0), np.array(lags, dtype=float)))
    (white, walk), *_ = np.linalg.lstsq(design, np.array(values), rcond=None)
    if not white > 0.0:
        return None
    return Wander(white_var_g2=float(white), walk_var_g2=max(float(walk), 0.0))


@dataclass
class _Whitened:
    """The samples of one toe fit whitened by the Cholesky factor of white + random-walk covariance.

    Whitening mixes every sample into the ones after it, so the pressed-sample sums of `_Projected`
    do not apply: each candidate's toe column is evaluated over all samples (only taps whose walk
    matters take this path).
    """

    window_um: np.ndarray  # (n, SUBSAMPLES)
    whiten: np.ndarray  # (n, n) L^-1
    basis: np.ndarray  # whitened, orthonormal baseline column(s)
    y_free: np.ndarray
    yy: float

    @classmethod
    def prepare(cls, window_um: np.ndarray, x_mid: np.ndarray, y: np.ndarray, wander: Wander) -> _Whitened:
        # The pullback rises monotonically, so the sample order is the time order of the walk.
        order = np.arange(len(y), dtype=float)
        covariance = wander.white_var_g2 * np.eye(len(y)) + wander.walk_var_g2 * np.minimum.outer(order, order)
        whiten = np.linalg.inv(np.linalg.cholesky(covariance))
        basis = np.linalg.qr(whiten @ np.ones((len(y), 1)))[0]
        y_w = whiten @ y
        y_free = y_w - basis @ (basis.T @ y_w)
        return cls(window_um, whiten, basis, y_free, float(y_free @ y_free))


def _rss_whitened(contacts_um, widths_um, power, data: _Whitened):
    """`_rss_over_contacts` under the whitened inner product (residuals in white-noise units)."""
    depth = contacts_um[:, None, None] - data.window_um[None]
    h = toe_shape(depth, widths_um[:, None, None], power).mean(axis=2) @ data.whiten.T  # (C, n)
    h -= (h @ data.basis) @ data.basis.T
    hh = np.einsum("cn,cn->c", h, h)
    hy = h @ data.y_free
    usable = hh > 1e-12
    stiffness = np.divide(hy, hh, out=np.zeros_like(hy), where=usable)
    rss = np.where(usable & (stiffness > 0.0), data.yy - stiffness * hy, np.inf)
    return rss, stiffness


def fit_toe(x_lo_um: np.ndarray, x_hi_um: np.ndarray, force_g: np.ndarray, contact0_um: float,
            spacing_um: float, drift_g_um: float | None = None, wander: Wander | None = None) -> ToeFit | None:
    """The toe model over pullback samples (conversion windows [x_lo, x_hi], µm above the halt).

    drift_g_um: the force's slope against height in free air when known (the approach shows it);
    None: fitted over the departure with the rest. wander: the baseline's random walk when the
    tap shows one (`Wander.matters`); the fit then weighs the samples by its covariance.
    """
    keep = (x_lo_um < contact0_um + COARSE_ABOVE_UM + DEPARTURE_REACH_SAMPLES * spacing_um) & (
        x_hi_um > contact0_um - PENETRATION_REACH_UM)
    x_lo_um, x_hi_um, y = x_lo_um[keep], x_hi_um[keep], force_g[keep]
    if len(y) < 8:
        return None
    fractions = (np.arange(SUBSAMPLES) + 0.5) / SUBSAMPLES
    window_um = x_lo_um[:, None] + (x_hi_um - x_lo_um)[:, None] * fractions[None, :]
    x_mid = 0.5 * (x_lo_um + x_hi_um)
    if drift_g_um is None:
        basis = np.linalg.qr(np.column_stack((np.ones_like(x_mid), x_mid - x_mid.mean())))[0]
    else:
        y = y - drift_g_um * x_mid
        basis = np.full((len(y), 1), 1.0 / math.sqrt(len(y)))
    coarse = contact0_um + np.arange(-COARSE_BELOW_UM, COARSE_ABOVE_UM + 1e-9, COARSE_STEP_UM)
    widths = np.array(TOE_WIDTHS_UM)
    grid_c = np.tile(coarse, len(widths))
    grid_w = np.repeat(widths, len(coarse))
    g2_per_unit = 1.0  # the residual's unit: g^2, or the white variance once whitened
    if wander is not None and wander.matters(len(y)):
        data = _Whitened.prepare(window_um, x_mid, y, wander)
        solve = _rss_whitened
        g2_per_unit = wander.white_var_g2
    else:
        data = _Projected.prepare(window_um, x_mid, basis, y, coarse[0], coarse[-1], widths.max())
        solve = _rss_over_contacts
    rss_grid = np.stack([solve(grid_c, grid_w, power, data)[0].reshape(len(widths), -1)
                         for power in TOE_POWERS])  # (power, width, contact)
    best = np.unravel_index(int(np.argmin(rss_grid)), rss_grid.shape)
    if not math.isfinite(rss_grid[best]):
        return None
    dof = max(len(y) - 4 - basis.shape[1], 1)
    residual_var = max(float(rss_grid[best]) / dof, 1e-12)
    contact, sigma = marginal_contact_um(coarse, rss_grid.reshape(-1, len(coarse)), residual_var,
                                         np.tile(WIDTH_PRIOR, len(TOE_POWERS)))
    if contact is None:
        return None
    width, power = widths[best[1]], TOE_POWERS[best[0]]
    _, stiffness = solve(np.array([contact]), np.array([width]), power, data)
    return ToeFit(contact_um=contact, sigma_um=sigma, width_um=float(width), power=float(power),
                  stiffness_g_um=float(stiffness[0]), residual_sigma_g=math.sqrt(residual_var * g2_per_unit))


def marginal_contact_um(contacts_um: np.ndarray, rss: np.ndarray, noise_var: float,
                        prior: np.ndarray | None = None) -> tuple[float | None, float]:
    """Mean and sd of the contact height with the toe (width, shape) marginalised out.

    rss: (toes, contacts) residual sums on an even grid of contact heights. Per toe, a parabola
    through its least residual and the two neighbours gives that toe's best height, its residual
    and its curvature (a Gaussian in c, the Laplace approximation); each toe is weighted by its
    likelihood exp(-rss / 2 noise_var) times its width in c. The mean over toes is less noisy than
    the single best toe (the toe width and the contact height trade off along a flat valley, and
    noise moves the argmin along it), and the sd holds that trade-off: an honest sigma.
    """
    step = float(contacts_um[1] - contacts_um[0])
    k = np.argmin(rss, axis=1)
    rows = np.arange(rss.shape[0])
    inner = (k > 0) & (k < rss.shape[1] - 1)
    k_in = np.clip(k, 1, rss.shape[1] - 2)
    before, at, after = rss[rows, k_in - 1], rss[rows, k_in], rss[rows, k_in + 1]
    with np.errstate(invalid="ignore", over="ignore"):
        bend = before - 2.0 * at + after
        usable = inner & np.isfinite(before) & np.isfinite(after) & (bend > 0)
        offset = np.where(usable, 0.5 * (before - after) / np.where(usable, bend, 1.0), 0.0)
    centre = contacts_um[k_in] + offset * step
    lowest = np.where(usable, at - 0.25 * offset * (before - after), np.inf)
    if not usable.any():
        return None, COARSE_STEP_UM
    # d2 rss / dc2 = bend / step^2; the Gaussian in c has variance 2 noise_var / that.
    var = np.where(usable, 2.0 * noise_var * step * step / np.where(usable, bend, 1.0), 0.0)
    log_weight = np.where(usable, -(lowest - lowest[usable].min()) / (2.0 * noise_var), -np.inf)
    weight = np.exp(log_weight) * np.sqrt(var) * (1.0 if prior is None else prior)
    weight /= weight.sum()
    mean = float(weight @ centre)
    spread = float(weight @ (var + (centre - mean) ** 2))
    return mean, math.sqrt(max(spread, 0.0))


def adhesion_dip(x_um: np.ndarray, force_g: np.ndarray, drift_g_um: float, contact_um: float) -> float | None:
    """How far (g) the force dips below the free-air level just above break contact, or None when
    the pullback does not reach far enough above contact to know the level.

    Adhesion and a plastic thread keep pulling the nozzle after it left the surface; the toe model
    reads that pull as more contact and puts Z high (mild ooze: +3.6 µm on the independent
    generator's taps, and the taps with the deepest dip err most). The drift (from the approach)
    is taken out first, so a cable pulling in proportion to Z does not look like a dip.
    """
    level_force = force_g - drift_g_um * x_um
    above = x_um - contact_um
    level = level_force[(above > ADHESION_REACH_UM) & (above < ADHESION_LEVEL_UM)]
    near = level_force[(above > 1.0) & (above <= ADHESION_REACH_UM)]
    if len(level) < ADHESION_MIN_LEVEL_SAMPLES or len(near) < ADHESION_RUN_SAMPLES:
        return None
    runs = np.convolve(near, np.full(ADHESION_RUN_SAMPLES, 1.0 / ADHESION_RUN_SAMPLES), mode="valid")
    return float(np.median(level) - runs.min())

