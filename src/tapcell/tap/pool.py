"""Taps at one spot share their toe: each tap's Z with the toe estimated jointly (issue 21).

PROBE_ACCURACY, `SAMPLES=` and a retried mesh point tap one spot of one bed with one sensor: the
contact's toe (its width and shape) is the same in every tap, while each tap has its own noise,
baseline, stiffness reading and halt. One tap alone cannot tell a wider toe from a higher contact
(the toe and the contact height trade off along a flat valley of the residual), so its marginal
over the toes wanders with the noise from tap to tap: on the reference sessions that was most of
the spread a user sees in PROBE_ACCURACY.

1. **The shared toe.** For every toe of the grid (tapcell.tap.toe: shape x width) each tap has its
   best contact height, least residual and curvature (`toe_minima`, the Laplace approximation).
   The pooled weight of a toe is its prior times the product over the taps of
   exp(-(rss - least) / 2 noise var) x the width of its Gaussian in c: the toe is pinned by all
   the taps. Each tap's contact at the shared toe is the weighted mean of its heights.
2. **The stiffness, shared.** The sharp model's contact height and stiffness trade off within a tap
   (the contact is where the unloading line meets the baseline); the bed's stiffness is the
   same in every tap, so each tap's contact is searched again with the taps' median stiffness
   (over the samples within the toe fit's PENETRATION_REACH_UM of contact, as the toe reads them).
3. **The toe's correction, shared.** What the toe adds to a tap is the shared toe's, so it is the
   mean over the taps of (contact at the shared toe - the sharp model's contact), and each tap's
   pooled Z is its shared-stiffness sharp Z plus that correction: the sharp model's small spread
   (it assumes no toe; the toe moves every tap alike) with the toe model's level.

`sigma_um` of a pooled Z: its sharp fit's sigma and, common to every tap, the toe's: the mean of
the taps' own (unpooled) toe sigmas squared. Pooling pins the toe *within* the model's family of
toes, which is what the taps' spread shows; whether that family holds the bed's toe no number of
taps of the same toe can tell (at the shared weights the sigma understated the error 1.4-2.8x on
taplab's sessions). So the spread of the pooled Zs is the repeatability, and their sigma the
absolute uncertainty of any one of them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tapcell.tap.contact import window_mean_and_slope
from tapcell.tap.model import PullbackFit, TapAnalysis
from tapcell.tap.toe import PENETRATION_REACH_UM, toe_minima

# The contact searched again at the shared stiffness: this far either side of the tap's own (µm), on
# this many heights, then the parabola through the least three.
SHARED_STIFFNESS_SEARCH_UM = 3.0
SHARED_STIFFNESS_HEIGHTS = 121


@dataclass
class PooledZ:
    z_mm: float
    sigma_um: float


def shared_toe_contacts(analyses: list[TapAnalysis]) -> dict[int, PooledZ]:
    """Each valid toe-model tap's Z (by index) read at the toe shared by all of them (step 1)."""
    members = [i for i, a in enumerate(analyses)
               if a.valid and a.toe_grid is not None and a.toe_z_origin_mm is not None]
    if not members:
        return {}
    minima = {i: toe_minima(analyses[i].toe_grid.contacts_um, analyses[i].toe_grid.rss,
                            analyses[i].toe_grid.noise_var) for i in members}
    prior = analyses[members[0]].toe_grid.prior.tolist()
    # The toes every tap can place (a toe with no interior minimum for one tap is left out).
    toes = [j for j in range(len(prior)) if prior[j] > 0 and all(minima[i][j] is not None for i in members)]
    if not toes:
        return {}
    least = {i: min(toe[1] for toe in minima[i] if toe is not None) for i in members}
    log_weights = []
    for j in toes:
        total = math.log(prior[j])
        for i in members:
            _, rss, var = minima[i][j]
            total += -(rss - least[i]) / (2.0 * analyses[i].toe_grid.noise_var) + 0.5 * math.log(var)
        log_weights.append(total)
    top = max(log_weights)
    weights = [math.exp(w - top) for w in log_weights]
    norm = sum(weights)
    pooled = {}
    for i in members:
        mean_um = sum(w * minima[i][j][0] for w, j in zip(weights, toes)) / norm
        var_um2 = sum(w * (minima[i][j][2] + (minima[i][j][0] - mean_um) ** 2) for w, j in zip(weights, toes)) / norm
        pooled[i] = PooledZ(analyses[i].toe_z_origin_mm + mean_um / 1000.0, math.sqrt(max(var_um2, 0.0)))
    return pooled


def pool_taps(analyses: list[TapAnalysis]) -> list[PooledZ | None]:
    """Each tap's pooled Z (None for taps that are invalid or were not read by the toe model)."""
    at_shared_toe = shared_toe_contacts(analyses)
    out: list[PooledZ | None] = [None] * len(analyses)
    sharp = [i for i in at_shared_toe if analyses[i].z_sharp_mm is not None]
    if not sharp:
        return out
    correction_mm = sum(at_shared_toe[i].z_mm - analyses[i].z_sharp_mm for i in sharp) / len(sharp)
    toe_var_um2 = sum((analyses[i].z_sigma_um or 0.0) ** 2 for i in sharp) / len(sharp)
    fits = [analyses[i].pullback_fit for i in sharp if analyses[i].pullback_fit is not None]
    stiffness_g_um = float(np.median([fit.stiffness_g_um for fit in fits])) if fits else None
    delay_s = float(np.median([fit.delay_s for fit in fits])) if fits else None
    for i in sharp:
        z_sharp_mm = analyses[i].z_sharp_mm
        fit = analyses[i].pullback_fit
        if stiffness_g_um is not None and fit is not None:
            moved_um = contact_at_stiffness_um(fit, stiffness_g_um)
            if moved_um is not None:
                z_sharp_mm += (moved_um - fit.contact_um) / 1000.0
            # Read with the shared delay: a longer delay put every height lower by speed x delay.
            z_sharp_mm += fit.pullback_speed_mm_s * (fit.delay_s - delay_s)
        sigma_um = math.sqrt((analyses[i].z_sharp_sigma_um or 0.0) ** 2 + toe_var_um2)
        out[i] = PooledZ(z_sharp_mm + correction_mm, sigma_um)
    return out


def contact_at_stiffness_um(fit: PullbackFit, stiffness_g_um: float) -> float | None:
    """The sharp contact height of a tap's pullback with the stiffness fixed (the baseline free),
    near its own: a search over SHARED_STIFFNESS_HEIGHTS heights, then a parabola. None when the
    least residual lies on the search's edge."""
    heights_um = fit.contact_um + np.linspace(-SHARED_STIFFNESS_SEARCH_UM, SHARED_STIFFNESS_SEARCH_UM,
                                              SHARED_STIFFNESS_HEIGHTS)
    near = fit.x_min_um + fit.span_um > fit.contact_um - PENETRATION_REACH_UM
    x_min, span, force = fit.x_min_um[near], fit.span_um[near], fit.force_g[near]
    if len(force) < 4:
        return None
    mean, _ = window_mean_and_slope(heights_um[:, None], fit.onset_um, x_min[None, :], span[None, :], slope=False)
    residual = force[None, :] - stiffness_g_um * mean
    rss = np.sum(np.square(residual - residual.mean(axis=1, keepdims=True)), axis=1)
    k = int(rss.argmin())
    if not 0 < k < len(rss) - 1:
        return None
    before, at, after = rss[k - 1], rss[k], rss[k + 1]
    bend = before - 2.0 * at + after
    offset = 0.5 * (before - after) / bend if bend > 0 else 0.0
    return float(heights_um[k] + offset * (heights_um[1] - heights_um[0]))


def apply_pool(analyses: list[TapAnalysis]) -> None:
    """Write each tap's pooled Z into its analysis (`z_pooled_mm`, `z_pooled_sigma_um`: in the JSON as
    `z_pooled`, `z_pooled_sigma_um`)."""
    for analysis, pooled in zip(analyses, pool_taps(analyses)):
        if pooled is not None:
            analysis.z_pooled_mm, analysis.z_pooled_sigma_um = pooled.z_mm, pooled.sigma_um
