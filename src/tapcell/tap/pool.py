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
   shared stiffness, onset and delay (its baseline solved in closed form), the samples weighed by
   their distance from contact: TAPER_ABOVE_UM in free air, TAPER_BELOW_G of force in contact (far
   from contact the baseline's slow wander costs more than a sample brings).
3. **One level.** The search fixes where the taps sit against each other, not the level (the sharp
   model assumes a shape the bed may not have). The level is the toe model's, with the toe shared
   by the taps (`shared_toe_contacts`: every toe of the grid weighted by its likelihood over all
   the taps): each pooled Z is its contact from step 2 plus the taps' mean difference between
   their shared-toe Z and that contact.
4. **A tap that does not fit.** A valid tap that the shared physics cannot place, or that its own
   stiffness fits MISFIT_EXCESS times better (a retried point that hit a blob, a tap the others do
   not resemble), is left out of the shared estimates and of the level, and keeps its own Z and
   sigma. Of two taps neither is (which would it be?); when every tap is one, nothing is shared
   and each keeps its own.

`sigma_um` of a pooled Z (`level_sigma_um`): the level's uncertainty and, in quadrature, the
spread of the pooled Zs about their mean (their sample sd: what is left of each tap's own noise).
The level's: of the taps' own variance (their z_sigma_um squared), the part their spread does not
show (an error every tap shares, the toe model's: it does not average out) plus the uncertainty of
the mean of the part it shows. The sigma at the shared toe itself is no measure of it: the more
the taps agree on a toe, the narrower it gets (0.08-0.9 µm over taplab's ADS1220 sessions, whose
levels err by 0.5 µm rms), while whether the toe family holds the bed's toe no number of taps of
the same toe can tell. So the pooled sigma follows the taps' own: as honest as theirs.

Measured by `python -m bench tap_pool` (both session sets, beside Kalico; docs/tap-analysis.md), and
with `--floor` against the floor of a pool that knew the shared physics exactly: 0.5x Kalico is at
or below that floor on the HX711 sessions ("The pool's floor" in docs/tap-analysis.md).
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
# How each tap's samples weigh in reading its contact: by exp(-height above contact / TAPER_ABOVE_UM)
# in free air and exp(-force the shared stiffness puts there / TAPER_BELOW_G) in contact (a force,
# not a depth: a soft sheet's contact shows over more micrometres). Far from contact the baseline's
# slow wander (1/f noise, a walk) costs more than a sample brings. Samples beyond TAPER_REACH of
# either scale are left out (their weight < 2 %). Chosen by the worst scenario of taplab's and the
# reference sessions, pooled within-session sigma over Kalico's: 30 µm / 60 g 0.79, 30 / 100 0.85,
# 20 / 80 0.81, 40 / 80 0.84; hard edges instead (every sample within 60 g below / 60 µm above
# alike) 0.82, (80 g / 80 µm) 0.87; a fixed 30 µm of depth and the whole departure 1.01. Checked on
# taplab's seed 2 (not tuned on): worst 0.87 tapered, 0.89 with hard edges.
TAPER_ABOVE_UM = 30.0
TAPER_BELOW_G = 60.0
TAPER_REACH = 4.0
# A tap whose residual at the shared stiffness is this many times that at its own (`free_stiffness_excess`)
# is pooled alone (step 4). The clean sessions of both sets reach at most 1.33 (taplab) and 1.47
# (reference, 1 tap of 800); a tap 10 % softer than the others 1.71; a soft-sheet or an HX711 tap
# among HX717 taps is not even placed.
MISFIT_EXCESS = 1.6


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
    """One tap's contact at the shared physics: its Z (mm, at the shared delay) and how much better
    its own stiffness would fit it (`free_stiffness_excess`)."""

    z_mm: float
    excess: float


def shared_physics(fits: list[PullbackFit]) -> SharedPhysics:
    """Step 1: the medians of the taps' own sharp fits."""
    return SharedPhysics(delay_s=float(np.median([fit.delay_s for fit in fits])),
                         stiffness_g_um=float(np.median([fit.stiffness_g_um for fit in fits])),
                         onset_um=float(np.median([fit.onset_um for fit in fits])))


def contact_at_shared(analysis: TapAnalysis, shared: SharedPhysics) -> SharedContact | None:
    """Step 2 for one tap: its contact with the shared stiffness, onset and delay (None: not found)."""
    fit = analysis.pullback_fit
    contact_um = contact_at_stiffness_um(fit, shared.stiffness_g_um, shared.onset_um)
    if contact_um is None:
        return None
    excess = free_stiffness_excess(fit, shared, contact_um)
    # The sharp Z is the halt plus the contact, read with the tap's own delay; a longer delay put
    # every height lower by pullback speed x delay.
    z_mm = (analysis.z_sharp_mm + (contact_um - fit.contact_um) / 1000.0
            + fit.pullback_speed_mm_s * (fit.delay_s - shared.delay_s))
    return SharedContact(z_mm, excess)


def _fitting(analysis: TapAnalysis) -> bool:
    """A tap the pool reads: valid, with the sharp fit (step 2) and the toe grid (the level, step 3).
    The sharp model alone, or a calibrated onset, is not pooled: measured on neither set."""
    return (analysis.valid and analysis.pullback_fit is not None and analysis.z_sharp_mm is not None
            and analysis.toe_grid is not None and analysis.toe_z_origin_mm is not None)


def _misfits(members: list[int], contacts: dict[int, SharedContact]) -> set[int]:
    """Step 4: the taps the shared physics does not place, or fits MISFIT_EXCESS times worse than
    their own; none of two taps (which of them would it be?)."""
    if len(members) < 3:
        return set()
    return {i for i in members if i not in contacts or contacts[i].excess > MISFIT_EXCESS}


def pool_taps(analyses: list[TapAnalysis]) -> list[PooledZ | None]:
    """Each tap's pooled Z (None for taps that are invalid or were not read by the toe model).
    A valid tap the shared physics does not fit (step 4) keeps its own Z and sigma."""
    out: list[PooledZ | None] = [None] * len(analyses)
    members = [i for i, a in enumerate(analyses) if _fitting(a)]
    if not members:
        return out
    shared = shared_physics([analyses[i].pullback_fit for i in members])
    contacts = {i: found for i in members if (found := contact_at_shared(analyses[i], shared)) is not None}
    misfits = _misfits(members, contacts)
    if len(misfits) == len(members):  # no two taps alike: nothing is shared, each keeps its own
        return [PooledZ(a.z_mm, a.z_sigma_um or 0.0) if i in misfits else None for i, a in enumerate(analyses)]
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
    else:  # no toe every tap can place: the level of the taps' own Zs
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


def contact_at_stiffness_um(fit: PullbackFit, stiffness_g_um: float, onset_um: float | None = None) -> float | None:
    """The sharp contact height of a tap's pullback with the stiffness and onset fixed (the baseline
    free), near its own, its samples weighed by their distance from it (`_tapered_samples`): a
    coarse then a fine search, then a parabola. None when the least residual lies on the search's
    edge or too few samples are near. onset_um None: the tap's own."""
    onset_um = fit.onset_um if onset_um is None else onset_um
    samples = _tapered_samples(fit, stiffness_g_um)
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
    return float(fine_um[k] + offset * SEARCH_FINE_STEP_UM)


def free_stiffness_excess(fit: PullbackFit, shared: SharedPhysics, contact_um: float) -> float:
    """How much better the tap's samples (weighed as `contact_at_stiffness_um` weighs them) fit at
    its contact with the stiffness its own (solved in closed form) than with the shared one: the
    ratio of the residuals, 1 when they agree, more as the tap's bed differs from the others'."""
    x_min, span, force, weight = _tapered_samples(fit, shared.stiffness_g_um)
    mean, _ = window_mean_and_slope(np.array(contact_um), shared.onset_um, x_min, span, slope=False)
    mean_c, force_c = mean - mean @ weight, force - force @ weight
    shared_rss = float(np.square(force_c - shared.stiffness_g_um * mean_c) @ weight)
    spread = float(np.square(mean_c) @ weight)
    free_rss = shared_rss if spread <= 0 else float(np.square(force_c) @ weight) - float(force_c * mean_c @ weight) ** 2 / spread
    return shared_rss / free_rss if free_rss > 0 else 1.0


def _tapered_samples(fit: PullbackFit, stiffness_g_um: float):
    """(window low edge, span, force, weight) of the samples near the tap's own contact, weighed by
    their distance from it (TAPER_ABOVE_UM above, TAPER_BELOW_G / stiffness below); None when fewer
    than 4."""
    height_um = fit.x_min_um + 0.5 * fit.span_um - fit.contact_um
    below_um = TAPER_BELOW_G / stiffness_g_um
    near = (height_um < TAPER_REACH * TAPER_ABOVE_UM) & (height_um > -TAPER_REACH * below_um)
    if np.count_nonzero(near) < 4:
        return None
    height_um = height_um[near]
    weight = np.exp(np.where(height_um > 0, -height_um / TAPER_ABOVE_UM, height_um / below_um))
    return fit.x_min_um[near], fit.span_um[near], fit.force_g[near], weight / weight.sum()


def _rss_at(heights_um: np.ndarray, stiffness_g_um: float, onset_um: float, samples) -> np.ndarray:
    """Weighted mean square residual of the sharp model (stiffness and onset fixed, baseline free:
    the weighted mean) at each contact height."""
    x_min, span, force, weight = samples
    mean, _ = window_mean_and_slope(heights_um[:, None], onset_um, x_min[None, :], span[None, :], slope=False)
    residual = force[None, :] - stiffness_g_um * mean
    baseline = residual @ weight
    return np.square(residual - baseline[:, None]) @ weight


def apply_pool(analyses: list[TapAnalysis]) -> None:
    """Write each tap's pooled Z into its analysis (`z_pooled_mm`, `z_pooled_sigma_um`: in the JSON as
    `z_pooled`, `z_pooled_sigma_um`)."""
    for analysis, pooled in zip(analyses, pool_taps(analyses)):
        if pooled is not None:
            analysis.z_pooled_mm, analysis.z_pooled_sigma_um = pooled.z_mm, pooled.sigma_um
