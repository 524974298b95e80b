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
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

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
    contact_um: float  # contact height above the halt
    stiffness_g_um: float
    baseline_g: float
    onset_um: float
    contact_sigma_um: float  # 1 sigma from the fit covariance
    onset_sigma_um: float
    residual_sigma_g: float
    rss_g2: float
    samples_in_contact: int
    samples_used: int


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
        onset_sigma_um=float(np.sqrt(max(covariance[3, 3], 0.0))) if fit_onset else 0.0,
        residual_sigma_g=float(np.sqrt(residual_var)),
        rss_g2=rss,
        samples_in_contact=in_contact,
        samples_used=len(force_g),
    )


def profile_search(force_g: np.ndarray, x_lo_um: np.ndarray, x_hi_um: np.ndarray, contacts_um: np.ndarray,
                   onsets_um: tuple[float, ...]) -> tuple[float, float, float, float, float]:
    """Global search of the contact model over a grid of (contact, onset).

    For each grid point stiffness and baseline are solved in closed form (the model is
    linear in them), so the residual is exact; the hinge's residual has a local minimum
    in almost every sample interval, which is why Gauss-Newton alone is not enough.
    Returns (rss, contact, onset, stiffness, baseline) of the best grid point.
    """
    n = len(force_g)
    sum_y, sum_yy = float(force_g.sum()), float(force_g @ force_g)
    best = (np.inf, 0.0, 0.0, 0.0, 0.0)
    for onset in onsets_um:
        mean, _, _ = window_mean_hinge(contacts_um[:, None], onset, x_lo_um[None, :], x_hi_um[None, :])
        sum_m = mean.sum(axis=1)
        s_mm = (mean * mean).sum(axis=1) - sum_m * sum_m / n
        s_my = mean @ force_g - sum_m * sum_y / n
        s_yy = sum_yy - sum_y * sum_y / n
        with np.errstate(divide="ignore", invalid="ignore"):
            rss = np.where(s_mm > 0, s_yy - s_my * s_my / s_mm, np.inf)
            stiffness = s_my / s_mm
        k = int(np.argmin(np.where(stiffness > 0, rss, np.inf)))
        if rss[k] < best[0] and stiffness[k] > 0:
            baseline = (sum_y - stiffness[k] * sum_m[k]) / n
            best = (float(rss[k]), float(contacts_um[k]), float(onset), float(stiffness[k]), float(baseline))
    return best
