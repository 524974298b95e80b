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
2. **The toe's correction, shared.** What the toe adds to a tap is the shared toe's, so it is the
   mean over the taps of (contact at the shared toe - the sharp model's contact), and each tap's
   pooled Z is its sharp Z plus that correction: the sharp model's small spread (it assumes no
   toe; the toe moves every tap alike) with the toe model's level.

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

from tapcell.tap.model import TapAnalysis
from tapcell.tap.toe import toe_minima


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
    for i in sharp:
        sigma_um = math.sqrt((analyses[i].z_sharp_sigma_um or 0.0) ** 2 + toe_var_um2)
        out[i] = PooledZ(analyses[i].z_sharp_mm + correction_mm, sigma_um)
    return out


def apply_pool(analyses: list[TapAnalysis]) -> None:
    """Write each tap's pooled Z into its analysis (`z_pooled_mm`, `z_pooled_sigma_um`: in the JSON as
    `z_pooled`, `z_pooled_sigma_um`)."""
    for analysis, pooled in zip(analyses, pool_taps(analyses)):
        if pooled is not None:
            analysis.z_pooled_mm, analysis.z_pooled_sigma_um = pooled.z_mm, pooled.sigma_um
