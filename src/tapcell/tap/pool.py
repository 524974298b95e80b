"""Taps at one spot share their physics: each tap's Z with everything shared estimated jointly (issue 21).

PROBE_ACCURACY, `SAMPLES=` and a retried mesh point tap one spot of one bed with one sensor: the
bed's stiffness, the contact's onset (its toe), the sensor's lag are the same in every tap, while
each tap has its own noise, baseline and halt. One tap alone must estimate them all, and they trade
off against its contact height (a stiffer line or a wider toe moves the contact), so its Z wanders
with its noise. Pooled, they are estimated once from all the taps, and each tap's Z is read with
only its own contact height and baseline free: the spread a user sees in PROBE_ACCURACY is then
its noise's alone.

1. **The shared physics.** The sensor delay, the stiffness and the onset width are the medians over
   the taps of their own sharp fits (a median: one bad tap in a pool does not move them).
2. **Each tap's contact.** Each tap's pullback is searched again for its contact height with the
   shared stiffness, onset and delay (its baseline solved in closed form), over the samples near
   contact: those the shared stiffness puts within POOL_REACH_G below contact (a force, not a
   depth: a soft sheet's contact shows over more micrometres), and those up to POOL_ABOVE_UM above
   it in free air (further up the baseline's slow wander costs more than its samples bring).
3. **One level.** The search fixes where the taps sit against each other, not the level (the sharp
   model assumes a shape the bed may not have). The level is the toe model's, with the toe shared
   by the taps (`shared_toe_contacts`: every toe of the grid weighted by its likelihood over all
   the taps): each pooled Z is its contact from step 2 plus the taps' mean difference between
   their shared-toe Z and that contact.
4. **A tap that does not fit.** A valid tap whose residual at the shared physics is several times
   the pool's (a retried mesh point that hit a blob, a tap the others do not resemble) is left out
   of the shared estimates and of the level, and keeps its own Z and sigma.

`sigma_um` of a pooled Z: the level's uncertainty (the rms of the taps' sigmas at the shared toe:
the toe's error is the same in every tap and does not average out) and, in quadrature, the
spread of the pooled Zs about their mean (the sample sd: what is left of each tap's own noise).

Measured by `python -m bench tap_pool` (both session sets, beside Kalico; docs/tap-analysis.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tapcell.tap.contact import window_mean_and_slope
from tapcell.tap.model import PullbackFit, TapAnalysis
from tapcell.tap.toe import toe_minima

# The contact searched again at the shared physics: this far either side of the tap's own (µm), in
# coarse steps, then in fine steps one coarse step either side of the least, then the parabola
# through the least three (34 heights where an even 0.05 µm grid took 121: a 10-tap pool 2.5 -> 1.4 ms).
SHARED_STIFFNESS_SEARCH_UM = 3.0
SEARCH_COARSE_STEP_UM = 0.5
SEARCH_FINE_STEP_UM = 0.05
# The samples each tap's contact is read from: in contact, those the shared stiffness puts within
# this force of contact; in free air, those this far above it. Chosen by the worst scenario of
# taplab's and the reference sessions (pooled within-session sigma over Kalico's: 60 g / 60 µm
# 0.82, 80 / 80 0.87, 60 / 100 0.90, 140 / 80 1.01; a fixed 30 µm of depth and the whole
# departure, as the single tap reads it, 1.01).
POOL_REACH_G = 60.0
POOL_ABOVE_UM = 60.0
# A tap whose residual variance at the shared physics is this many times that at its own stiffness
# and onset is pooled alone (step 4). The clean sessions of both sets reach at most 1.09 (taplab)
# and 1.27 (reference); a soft-sheet or an HX711 tap among HX717 taps is not even placed.
MISFIT_EXCESS = 1.5


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


@dataclass
class SharedPhysics:
    """What the taps at one spot share, as the pool reads each tap's contact with it."""

    delay_s: float
    stiffness_g_um: float
    onset_um: float


@dataclass
class SharedContact:
    """One tap's contact at the shared physics: its Z (mm, at the shared delay) and the residual
    variance of its samples there (g²); None where the search found no interior minimum."""

    z_mm: float
    residual_var_g2: float
    excess: float  # residual variance at the shared physics over that at the tap's own stiffness and onset


def shared_physics(fits: list[PullbackFit]) -> SharedPhysics:
    """Step 1: the medians of the taps' own sharp fits."""
    return SharedPhysics(delay_s=float(np.median([fit.delay_s for fit in fits])),
                         stiffness_g_um=float(np.median([fit.stiffness_g_um for fit in fits])),
                         onset_um=float(np.median([fit.onset_um for fit in fits])))


def contact_at_shared(analysis: TapAnalysis, shared: SharedPhysics) -> SharedContact | None:
    """Step 2 for one tap: its contact with the shared stiffness, onset and delay (None: not found)."""
    fit = analysis.pullback_fit
    found = contact_at_stiffness_um(fit, shared.stiffness_g_um, shared.onset_um)
    if found is None:
        return None
    contact_um, found_var_g2 = found
    # How much worse the shared physics fits this tap than its own sharp fit does on the samples
    # the shared stiffness picks (about 1: as well).
    own_var_g2 = residual_var_g2(fit, fit.stiffness_g_um, fit.onset_um, fit.contact_um,
                                 POOL_REACH_G / shared.stiffness_g_um)
    excess = found_var_g2 / own_var_g2 if own_var_g2 else 1.0
    # The sharp Z is the halt plus the contact, read with the tap's own delay; a longer delay put
    # every height lower by pullback speed x delay.
    z_mm = (analysis.z_sharp_mm + (contact_um - fit.contact_um) / 1000.0
            + fit.pullback_speed_mm_s * (fit.delay_s - shared.delay_s))
    return SharedContact(z_mm, found_var_g2, excess)


def _fitting(analysis: TapAnalysis) -> bool:
    return analysis.valid and analysis.pullback_fit is not None and analysis.z_sharp_mm is not None


def _misfits(members: list[int], contacts: dict[int, SharedContact]) -> set[int]:
    """Step 4: the taps the shared physics does not place, or fits MISFIT_EXCESS times worse than
    their own; none of two taps (which of them would it be?)."""
    if len(members) < 3:
        return set()
    return {i for i in members if i not in contacts or contacts[i].excess > MISFIT_EXCESS}


def pool_taps(analyses: list[TapAnalysis]) -> list[PooledZ | None]:
    """Each tap's pooled Z (None for taps that are invalid or were not read by the contact model).
    A valid tap the shared physics does not fit (step 4) keeps its own Z and sigma."""
    out: list[PooledZ | None] = [None] * len(analyses)
    members = [i for i, a in enumerate(analyses) if _fitting(a)]
    if not members:
        return out
    shared = shared_physics([analyses[i].pullback_fit for i in members])
    contacts = {i: found for i in members if (found := contact_at_shared(analyses[i], shared)) is not None}
    misfits = _misfits(members, contacts)
    if misfits:
        # Again without them: the shared physics from the taps that show it.
        good = [i for i in members if i not in misfits]
        shared = shared_physics([analyses[i].pullback_fit for i in good])
        contacts = {i: found for i in good if (found := contact_at_shared(analyses[i], shared)) is not None}
    # A tap whose contact the search could not place at the shared physics keeps its sharp Z.
    pooled_mm = {i: contacts[i].z_mm if i in contacts else analyses[i].z_sharp_mm
                 for i in members if i not in misfits}
    at_shared_toe = shared_toe_contacts([a if i in pooled_mm else _left_out(a) for i, a in enumerate(analyses)])
    levelled = [i for i in pooled_mm if i in at_shared_toe]
    if levelled:
        correction_mm = float(np.mean([at_shared_toe[i].z_mm - pooled_mm[i] for i in levelled]))
    else:  # no toe model: the level of the taps' own Zs
        correction_mm = float(np.mean([analyses[i].z_mm - pooled_mm[i] for i in pooled_mm]))
    zs_mm = {i: z + correction_mm for i, z in pooled_mm.items()}
    sigma_um = math.hypot(level_sigma_um([analyses[i] for i in zs_mm]), _sample_sd_um(list(zs_mm.values())))
    for i, z in zs_mm.items():
        out[i] = PooledZ(z, sigma_um)
    for i in misfits:
        out[i] = PooledZ(analyses[i].z_mm, analyses[i].z_sigma_um or 0.0)
    return out


def level_sigma_um(analyses: list[TapAnalysis]) -> float:
    """The uncertainty of the pool's level: of the taps' own variance (their z_sigma_um squared, mean),
    the part their spread does not show (an error every tap shares: the toe model's), and the
    uncertainty of the mean of the part it shows (their sample variance over the taps)."""
    own_var_um2 = sum((a.z_sigma_um or 0.0) ** 2 for a in analyses) / len(analyses)
    if len(analyses) < 2:
        return math.sqrt(own_var_um2)
    spread_var_um2 = _sample_sd_um([a.z_mm for a in analyses]) ** 2
    return math.sqrt(max(own_var_um2 - spread_var_um2, 0.0) + spread_var_um2 / len(analyses))


def _sample_sd_um(zs_mm: list[float]) -> float:
    return float(np.std(zs_mm, ddof=1)) * 1000.0 if len(zs_mm) > 1 else 0.0


def _left_out(analysis: TapAnalysis) -> TapAnalysis:
    """A stand-in that `shared_toe_contacts` skips (it pools the valid taps only)."""
    return TapAnalysis(valid=False)


def contact_at_stiffness_um(fit: PullbackFit, stiffness_g_um: float, onset_um: float | None = None,
                            reach_g: float = POOL_REACH_G, above_um: float = POOL_ABOVE_UM
                            ) -> tuple[float, float] | None:
    """The sharp contact height of a tap's pullback with the stiffness and onset fixed (the baseline
    free), near its own, and the residual variance there (g²): a coarse then a fine search, then a
    parabola. Samples within reach_g / stiffness below the tap's own contact and above_um above it.
    None when the least residual lies on the search's edge or too few samples are near. onset_um
    None: the tap's own."""
    onset_um = fit.onset_um if onset_um is None else onset_um
    samples = _near_samples(fit, reach_g / stiffness_g_um, above_um)
    if samples is None:
        return None
    coarse_um = fit.contact_um + np.arange(-SHARED_STIFFNESS_SEARCH_UM, SHARED_STIFFNESS_SEARCH_UM + 1e-9,
                                           SEARCH_COARSE_STEP_UM)
    rss = _rss_at(coarse_um, stiffness_g_um, onset_um, samples)
    k = int(rss.argmin())
    if not 0 < k < len(rss) - 1:
        return None
    fine_um = coarse_um[k] + np.arange(-SEARCH_COARSE_STEP_UM, SEARCH_COARSE_STEP_UM + 1e-9, SEARCH_FINE_STEP_UM)
    rss = _rss_at(fine_um, stiffness_g_um, onset_um, samples)
    k = min(max(int(rss.argmin()), 1), len(rss) - 2)  # the least is inside: the coarse search bracketed it
    before, at, after = rss[k - 1], rss[k], rss[k + 1]
    bend = before - 2.0 * at + after
    offset = 0.5 * (before - after) / bend if bend > 0 else 0.0
    return float(fine_um[k] + offset * SEARCH_FINE_STEP_UM), float(at) / (len(samples[2]) - 1)


def residual_var_g2(fit: PullbackFit, stiffness_g_um: float, onset_um: float, contact_um: float,
                    below_um: float, above_um: float = POOL_ABOVE_UM) -> float | None:
    """The residual variance (g², baseline free) of the sharp model at one contact height over a tap's
    samples from below_um below its own contact to above_um above it."""
    samples = _near_samples(fit, below_um, above_um)
    if samples is None:
        return None
    return float(_rss_at(np.array([contact_um]), stiffness_g_um, onset_um, samples)[0]) / (len(samples[2]) - 1)


def _near_samples(fit: PullbackFit, below_um: float, above_um: float):
    near = (fit.x_min_um + fit.span_um > fit.contact_um - below_um) & (fit.x_min_um < fit.contact_um + above_um)
    if np.count_nonzero(near) < 4:
        return None
    return fit.x_min_um[near], fit.span_um[near], fit.force_g[near]


def _rss_at(heights_um: np.ndarray, stiffness_g_um: float, onset_um: float, samples) -> np.ndarray:
    """Residual sum of squares of the sharp model (stiffness and onset fixed, baseline free) at each height."""
    x_min, span, force = samples
    mean, _ = window_mean_and_slope(heights_um[:, None], onset_um, x_min[None, :], span[None, :], slope=False)
    residual = force[None, :] - stiffness_g_um * mean
    return np.sum(np.square(residual - residual.mean(axis=1, keepdims=True)), axis=1)


def apply_pool(analyses: list[TapAnalysis]) -> None:
    """Write each tap's pooled Z into its analysis (`z_pooled_mm`, `z_pooled_sigma_um`: in the JSON as
    `z_pooled`, `z_pooled_sigma_um`)."""
    for analysis, pooled in zip(analyses, pool_taps(analyses)):
        if pooled is not None:
            analysis.z_pooled_mm, analysis.z_pooled_sigma_um = pooled.z_mm, pooled.sigma_um
