"""A physical contact model of force against commanded Z, fitted by Gauss-Newton.

Force while the nozzle presses into the bed, with x the commanded height above the
halt (µm) and c the contact height (µm above the halt):

    force = baseline + stiffness * h(c - x; onset)

h is a hinge with a gradual onset of width `onset` (a soft or textured sheet): zero
above the contact, a parabola over the first `onset` µm of compression, then linear:

    h(u) = 0                  u <= 0
    h(u) = u² / (2 onset)     0 < u < onset
    h(u) = u - onset / 2      u >= onset

The sensor reports each sample as the mean force over its conversion window, so the
model averages h over the heights the nozzle passed during that window: with G the
antiderivative of h, mean h over [x_lo, x_hi] = (G(c - x_lo) - G(c - x_hi)) / (x_hi - x_lo).
A line fit ignores both effects; the model fit removes their biases (onset/2 low,
half a sample period of lag high).

`fit_fixed_onset` runs in C when the kernel tapcell.tap._c_contact is built (the same search and
formulas; sums in another order, so equal to rounding); the numpy functions it is made of here are
the reference and the fallback. The kernel also holds the analysis's whole pullback and compression
fits around it (analysis.pullback_fit, compression_fit; `fit_of_kernel` reads their answers).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tapcell.tap import native

_C = native.load("contact")

_TINY_UM = 1e-9


def _onset_parts(u: np.ndarray, onset_um: float) -> tuple[np.ndarray, np.ndarray]:
    w = max(onset_um, _TINY_UM)
    inside = (u > 0) & (u < w)
    beyond = u >= w
    return inside, beyond


def hinge(u: np.ndarray, onset_um: float) -> np.ndarray:
    inside, beyond = _onset_parts(u, onset_um)
    w = max(onset_um, _TINY_UM)
    return np.where(beyond, u - 0.5 * onset_um, np.where(inside, u * u / (2 * w), 0.0))


def _hinge_slope(u: np.ndarray, onset_um: float) -> np.ndarray:
    inside, beyond = _onset_parts(u, onset_um)
    return np.where(beyond, 1.0, np.where(inside, u / max(onset_um, _TINY_UM), 0.0))


def _hinge_d_onset(u: np.ndarray, onset_um: float) -> np.ndarray:
    inside, beyond = _onset_parts(u, onset_um)
    w = max(onset_um, _TINY_UM)
    return np.where(beyond, -0.5, np.where(inside, -u * u / (2 * w * w), 0.0))


def _hinge_integral(u: np.ndarray, onset_um: float) -> np.ndarray:
    inside, beyond = _onset_parts(u, onset_um)
    w = max(onset_um, _TINY_UM)
    return np.where(beyond, 0.5 * u * u - 0.5 * onset_um * u + onset_um * onset_um / 6,
                    np.where(inside, u ** 3 / (6 * w), 0.0))


def _hinge_integral_d_onset(u: np.ndarray, onset_um: float) -> np.ndarray:
    inside, beyond = _onset_parts(u, onset_um)
    w = max(onset_um, _TINY_UM)
    return np.where(beyond, -0.5 * u + onset_um / 3, np.where(inside, -u ** 3 / (6 * w * w), 0.0))


def window_mean_hinge(contact_um: float, onset_um: float, x_lo_um: np.ndarray, x_hi_um: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mean of h over each sample's height window, and its derivatives by contact and onset.

    Most windows lie wholly on the linear part (mean = u_mid - onset/2) or wholly above the
    contact (0); only the few windows touching the onset need the exact integral.
    """
    u_lo, u_hi = np.broadcast_arrays(contact_um - x_lo_um, contact_um - x_hi_um)
    shape = u_lo.shape
    u_lo, u_hi = u_lo.ravel(), u_hi.ravel()
    u_mid = 0.5 * (u_lo + u_hi)
    u_min = np.minimum(u_lo, u_hi)
    pressed = u_min >= onset_um
    mean = np.where(pressed, u_mid - 0.5 * onset_um, 0.0)
    d_contact = pressed.astype(float)
    d_onset = np.where(pressed, -0.5, 0.0)
    edge = np.flatnonzero(~pressed & (np.maximum(u_lo, u_hi) > 0))
    if len(edge):
        lo, hi, mid = u_lo[edge], u_hi[edge], u_mid[edge]
        span = lo - hi  # = x_hi - x_lo
        moving = np.abs(span) > 1e-6
        safe = np.where(moving, span, 1.0)
        mean[edge] = np.where(moving, (_hinge_integral(lo, onset_um) - _hinge_integral(hi, onset_um)) / safe,
                              hinge(mid, onset_um))
        d_contact[edge] = np.where(moving, (hinge(lo, onset_um) - hinge(hi, onset_um)) / safe,
                                   _hinge_slope(mid, onset_um))
        d_onset[edge] = np.where(moving, (_hinge_integral_d_onset(lo, onset_um)
                                          - _hinge_integral_d_onset(hi, onset_um)) / safe,
                                 _hinge_d_onset(mid, onset_um))
    return mean.reshape(shape), d_contact.reshape(shape), d_onset.reshape(shape)


@dataclass
class ContactFit:
    """The sharp contact model fitted over the pullback or the approach (`fit_contact`)."""

    contact_um: float  # contact height above the halt
    stiffness_g_um: float
    baseline_g: float
    onset_um: float
    contact_sigma_um: float  # 1 sigma from the fit covariance
    residual_sigma_g: float
    rss_g2: float


def fit_contact(force_g: np.ndarray, x_lo_um: np.ndarray, x_hi_um: np.ndarray, contact_um: float,
                stiffness_g_um: float, baseline_g: float, onset_um: float, fit_onset: bool,
                iterations: int = 15) -> ContactFit | None:
    """Least-squares fit of the contact model (Gauss-Newton with step halving).

    Parameters: contact height, stiffness, baseline, and the onset width when `fit_onset`
    (else held at `onset_um`). None when it does not converge to a contact.
    """
    n_free = 4 if fit_onset else 3
    if len(force_g) <= n_free + 1:
        return None

    def evaluate(theta: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
        mean, d_contact, d_onset = window_mean_hinge(theta[0], theta[3], x_lo_um, x_hi_um)
        residual = force_g - (theta[2] + theta[1] * mean)
        columns = [theta[1] * d_contact, mean, np.ones_like(mean)]
        if fit_onset:
            columns.append(theta[1] * d_onset)
        return float(residual @ residual), residual, np.column_stack(columns)

    theta = np.array([contact_um, stiffness_g_um, baseline_g, max(onset_um, 0.0)])
    rss, residual, jacobian = evaluate(theta)
    converged = False
    for _ in range(iterations):
        try:
            step = np.linalg.solve(jacobian.T @ jacobian, jacobian.T @ residual)
        except np.linalg.LinAlgError:
            return None
        for _ in range(6):  # halve the step until the residual does not grow
            if fit_onset and theta[3] + step[3] < 0:
                step = step * (0.5 * theta[3] / -step[3])  # approach a zero onset, never cross it
            trial = theta.copy()
            trial[:n_free] += step
            trial_rss, trial_residual, trial_jacobian = evaluate(trial)
            if trial_rss <= rss * (1 + 1e-12):
                break
            step = 0.5 * step
        else:
            converged = True  # no step improves: at the minimum to rounding
            break
        theta, rss, residual, jacobian = trial, trial_rss, trial_residual, trial_jacobian
        if abs(step[0]) < 1e-4:  # 0.1 nm: far below any noise
            converged = True
            break
    if not converged:
        return None
    dof = len(force_g) - n_free
    residual_var = rss / dof
    try:
        covariance = np.linalg.inv(jacobian.T @ jacobian) * residual_var
    except np.linalg.LinAlgError:
        return None
    in_contact = int(np.count_nonzero(theta[0] - np.minimum(x_lo_um, x_hi_um) > 0))
    if not np.all(np.isfinite(theta)) or theta[1] <= 0 or in_contact < 2:
        return None
    return ContactFit(
        contact_um=float(theta[0]),
        stiffness_g_um=float(theta[1]),
        baseline_g=float(theta[2]),
        onset_um=float(theta[3]),
        contact_sigma_um=float(np.sqrt(max(covariance[0, 0], 0.0))),
        residual_sigma_g=float(np.sqrt(residual_var)),
        rss_g2=rss,
    )


# Windows narrower than this (µm) count as this wide: the mean over them equals the point
# value to far below a nanometre, and no division by a zero width is needed.
MIN_SPAN_UM = 1e-6


def window_mean_and_slope(contact_um, onset_um: float, x_min_um: np.ndarray, span_um: np.ndarray,
                          slope: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
    """Mean of h(c - x) over each window [x_min, x_min + span] and its derivative by c (broadcasts).

    The lean form of `window_mean_hinge` for the search (few numpy calls); `span_um` must be at
    least `MIN_SPAN_UM`. Sharp contact: p = the part of the window below c, mean = p (u - p/2) / span
    with u = c - x_min, slope = p / span. With an onset, through the antiderivative G of h:
    mean = (G(u) - G(u - span)) / span, slope = (h(u) - h(u - span)) / span.
    """
    u = contact_um - x_min_um
    if onset_um <= 0:
        below = np.minimum(np.maximum(u, 0.0), span_um)
        fraction = below / span_um
        return fraction * (u - 0.5 * below), (fraction if slope else None)
    w = onset_um
    u_top = u - span_um

    def antiderivative(v):
        inside = np.minimum(np.maximum(v, 0.0), w)  # the part of v on the onset parabola
        beyond = np.maximum(v - w, 0.0)  # the part on the linear branch
        return inside * inside * inside / (6 * w) + beyond * (0.5 * beyond + 0.5 * w)

    mean = (antiderivative(u) - antiderivative(u_top)) / span_um
    return mean, ((hinge(u, w) - hinge(u_top, w)) / span_um if slope else None)


def profile_rss(force_g: np.ndarray, x_min_um: np.ndarray, span_um: np.ndarray, low_um: float, high_um: float,
                onset_um: float, contacts_um: np.ndarray) -> np.ndarray:
    """Residual sum of squares per candidate contact height in [low, high] (onset fixed), stiffness
    and baseline solved in closed form; inf where the stiffness would not be positive.

    Samples pressed for every candidate (their whole window at least an onset below `low_um`) have
    mean h = c - x' with x' = window middle + onset/2, so they enter the sums only through four
    totals; free samples (window above `high_um`) only through the force totals. Only the few
    samples in between are evaluated per candidate, laid out (samples, candidates) so the
    candidates run along the long, contiguous axis.
    """
    c = contacts_um
    count = len(force_g)
    top_um = x_min_um + span_um
    if onset_um:
        top_um += onset_um
    pressed = top_um <= low_um
    near = (x_min_um < high_um) > pressed  # below the highest candidate and not pressed
    near_x = x_min_um[near]
    near_y = force_g[near]
    mean, _ = window_mean_and_slope(c, onset_um, near_x[:, None], span_um[near, None], slope=False)
    sum_m = mean.sum(axis=0)
    sum_my = near_y @ mean  # Σ mean h × force over the samples in between
    sum_mm = np.einsum("ij,ij->j", mean, mean)
    sum_y = float(force_g.sum())
    mean_y = sum_y / count
    pressed_count = int(np.count_nonzero(pressed))
    if pressed_count:
        x_pressed = x_min_um[pressed] + 0.5 * (span_um[pressed] + onset_um)
        y_pressed = force_g[pressed]
        pressed_x, pressed_xx = float(x_pressed.sum()), float(x_pressed @ x_pressed)
        pressed_m = pressed_count * c - pressed_x  # the pressed samples' sum of mean h
        sum_m += pressed_m
        sum_mm += (pressed_m - pressed_x) * c
        sum_mm += pressed_xx
        sum_my += c * float(y_pressed.sum())
        sum_my -= float(x_pressed @ y_pressed)
    s_mm = sum_mm - sum_m * sum_m / count
    s_my = sum_my - sum_m * mean_y
    # A stiffness <= 0 explains nothing (-inf); s_mm is then never divided (it may be 0).
    explained = np.divide(s_my * s_my, s_mm, out=np.full(len(c), -np.inf), where=s_my > 0)
    return (float(force_g @ force_g) - sum_y * sum_y / count) - explained


# The global contact search spans this many samples either side of the line estimate.
SEARCH_SAMPLES = 4
# Candidate contact heights per sample spacing: fine enough that each interval between the
# model's kinks (where the residual has its local minima) holds several candidates.
CANDIDATES_PER_SAMPLE = 32


def window_edges(x_lo_um: np.ndarray, x_hi_um: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(lower edge, width >= MIN_SPAN_UM) of each sample's height window."""
    x_min = np.minimum(x_lo_um, x_hi_um)
    return x_min, np.maximum(np.maximum(x_lo_um, x_hi_um) - x_min, MIN_SPAN_UM)


def search_contact(force_g: np.ndarray, x_min_um: np.ndarray, span_um: np.ndarray, low_um: float, high_um: float,
                   onset_um: float, spacing_um: float) -> float | None:
    """The contact height in [low, high] with the least residual (onset fixed).

    Stiffness and baseline are solved in closed form for each candidate height, so the profile
    residual is exact. It is smooth between the kinks of the model (heights where a window
    edge, or an edge + onset, meets the contact) and has a local minimum in almost every
    interval between them (about one sample spacing apart), so all candidates on a grid of
    spacing/CANDIDATES_PER_SAMPLE are evaluated at once (vectorised) and a parabola through the
    best one and its neighbours gives the minimum. None when no candidate has a positive stiffness.
    """
    count = int(round((high_um - low_um) / spacing_um * CANDIDATES_PER_SAMPLE)) + 1
    step_um = (high_um - low_um) / (count - 1)
    candidates = low_um + step_um * np.arange(count)
    rss = profile_rss(force_g, x_min_um, span_um, low_um, high_um, onset_um, candidates)
    best = int(rss.argmin())
    if not math.isfinite(rss[best]):
        return None
    contact = float(candidates[best])
    if 0 < best < count - 1:
        before, at, after = float(rss[best - 1]), float(rss[best]), float(rss[best + 1])
        contact += parabola_vertex_offset(before, at, after) * step_um
    return contact


def parabola_vertex_offset(before: float, at: float, after: float) -> float:
    """Offset (in grid steps) of the vertex of the parabola through three equally spaced values
    around a minimum `at`; 0 when there is no such vertex.

    A neighbour can be infinite (its stiffness would not be positive, so `profile_rss` marks it
    unusable): the parabola is then undefined (inf/inf), and the grid point itself is the answer.
    Three equal values (zero curvature) have no vertex either.
    """
    curvature = before - 2.0 * at + after
    if not (math.isfinite(before) and math.isfinite(after)) or curvature <= 0.0:
        return 0.0
    return 0.5 * (before - after) / curvature


def fit_contact_at(force_g: np.ndarray, x_min_um: np.ndarray, span_um: np.ndarray, contact_um: float,
                   onset_um: float) -> tuple[ContactFit, np.ndarray] | None:
    """The contact model at a given contact height: stiffness and baseline by least squares,
    the 1-sigma of the contact height from the 3-parameter covariance, and the residuals."""
    count = len(force_g)
    if count <= 4:
        return None
    mean, d_contact = window_mean_and_slope(contact_um, onset_um, x_min_um, span_um)
    sum_m, sum_y, sum_d = float(mean.sum()), float(force_g.sum()), float(d_contact.sum())
    m_m, m_d, d_d = float(mean @ mean), float(mean @ d_contact), float(d_contact @ d_contact)
    s_mm = m_m - sum_m * sum_m / count
    if not s_mm > 0:
        return None
    stiffness = (float(mean @ force_g) - sum_m * sum_y / count) / s_mm
    baseline = (sum_y - stiffness * sum_m) / count
    residual = force_g - baseline - stiffness * mean
    rss = float(residual @ residual)
    residual_var = rss / (count - 3)
    # Variance of c: residual variance / the Schur complement of the (stiffness, baseline) block
    # of JᵀJ, J = [stiffness * d_contact, mean, 1]; the centred sums eliminate the baseline.
    s_dd = stiffness * stiffness * (d_d - sum_d * sum_d / count)
    s_dm = stiffness * (m_d - sum_d * sum_m / count)
    information = s_dd - s_dm * s_dm / s_mm
    in_contact = int(np.count_nonzero(x_min_um < contact_um))
    if not (stiffness > 0 and math.isfinite(stiffness) and information > 0 and in_contact >= 2):
        return None
    return ContactFit(contact_um=float(contact_um), stiffness_g_um=float(stiffness), baseline_g=float(baseline),
                      onset_um=float(onset_um), contact_sigma_um=math.sqrt(residual_var / information),
                      residual_sigma_g=math.sqrt(residual_var), rss_g2=rss), residual


def fit_fixed_onset(force_g: np.ndarray, x_min_um: np.ndarray, span_um: np.ndarray, contact0_um: float,
                    spacing_um: float, onset_um: float) -> tuple[ContactFit, np.ndarray] | None:
    """Global search of the contact height within SEARCH_SAMPLES samples of the estimate, and the
    model there (`fit_contact_at`): the fit and its residuals, or None.

    A minimum on the edge of the range means the estimate was off: the range moves there
    (at most twice) so the answer is an interior minimum of the residual.
    """
    if _C is not None:
        residual = np.empty(len(force_g))
        found = _C.fit_fixed_onset(force_g, x_min_um, span_um, contact0_um, spacing_um, onset_um, SEARCH_SAMPLES,
                                   residual)
        return None if found is None else (fit_of_kernel(found, onset_um), residual)
    reach_um = SEARCH_SAMPLES * spacing_um
    centre_um = contact0_um
    for _ in range(3):
        low, high = centre_um - reach_um, centre_um + reach_um
        contact_um = search_contact(force_g, x_min_um, span_um, low, high, onset_um, spacing_um)
        if contact_um is None:
            return None
        if low + 1e-3 * spacing_um < contact_um < high - 1e-3 * spacing_um:
            break
        centre_um = contact_um
    return fit_contact_at(force_g, x_min_um, span_um, contact_um, onset_um)


def fit_of_kernel(found: tuple[float, ...], onset_um: float) -> ContactFit:
    """The ContactFit of a kernel's answer (contact, stiffness, baseline, contact sigma, residual sigma, rss;
    _c_contact's fit_fixed_onset, and the first six numbers of fit_pullback's and fit_compression's)."""
    # Positional, in the fields' order (keywords cost three times as much; twice a tap).
    return ContactFit(found[0], found[1], found[2], float(onset_um), found[3], found[4], found[5])
