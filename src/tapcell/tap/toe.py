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
  baseline + departure slope · x + k · H(c − x; w, p) averaged over each sample's conversion
  window, H a power-law toe of width w (stiffness ~ (depth/w)^p) joining the linear region with
  a continuous slope. c, w and p are searched on a grid (every candidate c at once per toe),
  baseline, slope and k solved in closed form; then c is refined. The departure slope lets
  Z-proportional cable drift tilt the baseline without pulling Z.

`sigma_um` is the profile-likelihood 1σ of c (minimised over the toe and the linear terms at
each c), so the onset/contact trade-off is in it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

TOE_WIDTHS_UM = (0.0, 1.0, 2.0, 3.0, 4.5, 6.0, 8.0, 10.0, 13.0, 16.0)
TOE_POWERS = (0.5, 1.0)  # Hertz sphere on flat; a parabolic force onset
COARSE_STEP_UM = 0.5
COARSE_BELOW_UM = 3.0  # the sharp estimate reads a toe low: search mostly above it
COARSE_ABOVE_UM = 10.0
FINE_STEP_UM = 0.05
PENETRATION_REACH_UM = 30.0  # samples deeper than this in contact are left out (relaxation, hysteresis)
DEPARTURE_REACH_SAMPLES = 10  # samples past break contact that set the baseline and its slope
SUBSAMPLES = 2  # points per conversion window for its average
MAX_LAG_PERIODS = 4.0


@dataclass
class ToeFit:
    contact_um: float  # height above the halt where the force reaches the baseline
    sigma_um: float
    width_um: float
    power: float
    stiffness_g_um: float
    departure_slope_g_um: float
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


def _rss_over_contacts(contacts_um, widths_um, power, window_um, x_mid, y):
    """Residual sum of squares of the linear solve at every (toe width, candidate contact) at once.

    contacts_um, widths_um: equal-length 1-D arrays (one row per candidate); power: the toe's.
    """
    depth = contacts_um[:, None, None] - window_um[None]
    h = toe_shape(depth, widths_um[:, None, None], power).mean(axis=2)  # (C, N)
    n = len(y)
    sx, sy = x_mid.sum(), y.sum()
    sxx, sxy, syy = x_mid @ x_mid, x_mid @ y, y @ y
    sh, shh, shx, shy = h.sum(axis=1), np.einsum("cn,cn->c", h, h), h @ x_mid, h @ y
    rows = len(contacts_um)
    normal = np.empty((rows, 3, 3))
    normal[:, 0, 0], normal[:, 0, 1], normal[:, 0, 2] = n, sx, sh
    normal[:, 1, 0], normal[:, 1, 1], normal[:, 1, 2] = sx, sxx, shx
    normal[:, 2, 0], normal[:, 2, 1], normal[:, 2, 2] = sh, shx, shh
    rhs = np.stack([np.full(rows, sy), np.full(rows, sxy), shy], axis=1)
    # A candidate whose toe column is (nearly) a combination of the others cannot be solved.
    usable = shh * n - sh * sh > 1e-9 * (shh * n + 1e-300)
    rss = np.full(rows, np.inf)
    solution = np.zeros((rows, 3))
    if usable.any():
        solution[usable] = np.linalg.solve(normal[usable], rhs[usable][..., None])[..., 0]
        rss[usable] = syy - np.einsum("ck,ck->c", solution[usable], rhs[usable])
    rss[solution[:, 2] <= 0.0] = np.inf  # the contact must press, not pull
    return rss, solution


def fit_toe(x_lo_um: np.ndarray, x_hi_um: np.ndarray, force_g: np.ndarray, contact0_um: float,
            spacing_um: float) -> ToeFit | None:
    """The toe model over pullback samples (conversion windows [x_lo, x_hi], µm above the halt)."""
    keep = (x_lo_um < contact0_um + COARSE_ABOVE_UM + DEPARTURE_REACH_SAMPLES * spacing_um) & (
        x_hi_um > contact0_um - PENETRATION_REACH_UM)
    x_lo_um, x_hi_um, y = x_lo_um[keep], x_hi_um[keep], force_g[keep]
    if len(y) < 8:
        return None
    fractions = (np.arange(SUBSAMPLES) + 0.5) / SUBSAMPLES
    window_um = x_lo_um[:, None] + (x_hi_um - x_lo_um)[:, None] * fractions[None, :]
    x_mid = 0.5 * (x_lo_um + x_hi_um)
    x_mid = x_mid - x_mid.mean()  # the slope's column re-centred: better conditioned
    coarse = contact0_um + np.arange(-COARSE_BELOW_UM, COARSE_ABOVE_UM + 1e-9, COARSE_STEP_UM)
    widths = np.array(TOE_WIDTHS_UM)
    grid_c = np.tile(coarse, len(widths))
    grid_w = np.repeat(widths, len(coarse))
    rss_grid = np.stack([_rss_over_contacts(grid_c, grid_w, power, window_um, x_mid, y)[0].reshape(len(widths), -1)
                         for power in TOE_POWERS])  # (power, width, contact)
    profile = rss_grid.min(axis=(0, 1))  # over the toes, per contact height
    power_index, width_index, k = np.unravel_index(int(np.argmin(rss_grid)), rss_grid.shape)
    if not math.isfinite(rss_grid[power_index, width_index, k]):
        return None
    width, power = widths[width_index], TOE_POWERS[power_index]
    fine = coarse[k] + np.arange(-COARSE_STEP_UM, COARSE_STEP_UM + 1e-9, FINE_STEP_UM)
    rss, solution = _rss_over_contacts(fine, np.full(len(fine), width), power, window_um, x_mid, y)
    j = int(np.argmin(rss))
    contact = float(fine[j])
    if 0 < j < len(fine) - 1 and np.isfinite(rss[j - 1:j + 2]).all():
        bend = rss[j - 1] - 2 * rss[j] + rss[j + 1]
        if bend > 0:
            contact += 0.5 * FINE_STEP_UM * (rss[j - 1] - rss[j + 1]) / bend
    dof = max(len(y) - 6, 1)
    residual_var = max(float(rss[j]) / dof, 1e-12)
    return ToeFit(contact_um=contact, sigma_um=_profile_sigma_um(coarse, profile, int(np.argmin(profile)),
                                                                 residual_var),
                  width_um=float(width), power=float(power), stiffness_g_um=float(solution[j, 2]),
                  departure_slope_g_um=float(solution[j, 1]), residual_sigma_g=math.sqrt(residual_var))


def _profile_sigma_um(contacts_um: np.ndarray, profile: np.ndarray, k: int, residual_var: float) -> float:
    """1σ of c from the profile residual: where it rises by one residual variance (parabola through
    the minimum and its neighbours; the grid step when the profile is flatter than that)."""
    if not 0 < k < len(profile) - 1 or not np.isfinite(profile[k - 1:k + 2]).all():
        return COARSE_STEP_UM
    step = contacts_um[1] - contacts_um[0]
    curvature = (profile[k - 1] - 2 * profile[k] + profile[k + 1]) / (step * step)  # d²RSS/dc²
    if curvature <= 0:
        return COARSE_STEP_UM
    return math.sqrt(2.0 * residual_var / curvature)
