"""One tap's Z uncertainty (`z_sigma_um`) from the parts the tap itself shows (issue 21).

The contact fit's own sd holds the noise only if the model is right. What the model assumes, and
how far Z moves with each assumption, is measured on the tap and added in quadrature:

* `noise_um`: the sharp contact fit's sd: the noise over the samples that set Z, with the contact's
  shape held (the toe fit's marginal sd adds the trade-off of width against height along the
  residual's flat valley, which is mostly the width prior's, not the tap's);
* `shape_um`: half the range of the contact over the toe's assumed shapes (Hertz against
  parabolic, `toe.shape_spread_um`): it grows with the toe the tap shows; weighed by SHAPE_WEIGHT;
* `thread_um`: a pull on the departure that lets go within the fit's reach (an ooze strand):
  the toe's baseline is taken over the departure, so the zero it reads the contact against is
  uncertain by that pull, over the stiffness;
* `misfit_um`: what the contact model leaves near contact beyond the noise and the Z staircase
  (a soft stage, a film squeezed), over the stiffness, weighed by MISFIT_WEIGHT;
* `squeeze_um`: contact on the way down above break contact on the way up beyond what the two
  fits allow: a film or soft layer squeezed while pressed; what is left of it is under the break
  contact too (weighed by SQUEEZE_WEIGHT);
* `film_um`: what a squeezed film can have left under the break contact: the squeeze, at most as
  much as the toe model lifts Z above the sharp contact (`film_um`); a film left on the bed reads
  as a toe, and Z rests on it by that lift;
* `floor_um`: 1 g over the stiffness at contact: the contact model misplaces a force of a few
  grams (the onset's shape below what the noise shows), and a soft bed turns it into more height
  (error × stiffness is 1.5-3.6 g on every clean and soft scenario of both sets); weighed by
  FLOOR_WEIGHT, which is that force in g;
* `staircase_um`: the Z steps' sawtooth as the sensor's window sees it, averaged over the steps
  the fit's reach spans;
* `delay_um`: the sensor delay read off the halt moves Z by pullback speed × its uncertainty;
* `ringing_um`: a ringing the dwell shows (a gantry rung by the halt and the pullback's start,
  `stage.dwell_ringing`) over the pullback's samples within the fit's reach of contact: what a smooth
  contact shape takes of it (`stage.ringing_noise_g2`, a sum of squares over those n samples) is,
  at the end of the two lines that meet at contact, an offset of 2 sqrt(that / n) g where the force
  crosses zero, over the stiffness (`ringing_um`);
  weighed by RINGING_WEIGHT;
* `stage_um`: under a narrow toe, where the departure shows two stages the analysis cannot tell
  from a drift or a walk at its noise (`stage.unnamed_stage_um`), how far their first touch lies
  from the toe's contact: the tap is not rejected, its Z may be that far low. Not weighed (a
  distance the tap shows, not a fit's sd).

The weights are chosen by the worst scenario over taplab and the reference taps: `python -m bench
tap_sigma` prints rms(error / z_sigma_um) per scenario per set with them and the weights it would
choose on the analysis as it stands (re-run it when the Z estimator changes).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from tapcell.tap import native
from tapcell.tap.stage import Ringing, ringing_noise_g2
from tapcell.tap.toe import PENETRATION_REACH_UM, ToeGridResult, shape_spread_um
from tapcell.tap.validate import CONSISTENCY_SIGMAS

# The parts and their sum in one call in C (c/uncertainty.c); None: its numpy twin, `tap_sigma_parts`'s body.
_C = native.load("uncertainty")

# Chosen by `python -m bench tap_sigma` on taplab seeds 1 and 3 (40 taps a scenario each, the two
# seeds' taps together per scenario) and the reference taps (2026-11-27, main 446959e's Z and
# rejections), over its grid (two passes): the worst scenario's rms(error / sigma) as near 1 as the
# grid allows (1.39: the reference soft sheet 1.38, taplab's mild ooze 1.36, clean HX717 and cable
# drift 1.34, each held up by a bias no part sees), then the mean over the others. Seed 2 is scored,
# not used. Where each lands: the sharp fit's sd a little above face value, NOISE 1.25; the shape
# spread grows with the toe the tap shows (0.25-0.3 µm on clean reference taps, 0.9 on soft sheets,
# 1.85 on a two-stage mount), SHAPE 2.5; a film squeezed between the approach and the pullback
# beyond what the fits and the approach's sample grid allow, SQUEEZE 1.5; what the film left under
# the toe, FILM 2 (the top of its grid: further up only the mean over the scenarios moves); a thread
# letting go, THREAD 0.5; a force floor of 0.5 g over the stiffness (soft sheets: reference 1.47 ->
# 1.38). The misfit beyond the noise is kept in the parts but does not count (MISFIT 0: on noisy
# mains it is the hum's, 1.35 µm).
NOISE_WEIGHT = 1.25
SHAPE_WEIGHT = 2.5
MISFIT_WEIGHT = 0.0
THREAD_WEIGHT = 0.5
SQUEEZE_WEIGHT = 1.5
FILM_WEIGHT = 2.0
FLOOR_WEIGHT = 0.5  # g
# The ringing part is the ringing's own effect on the contact, not a fit: weight 1 (see `ringing_um`;
# `python -m bench tap_sigma` cannot weigh it: no tap of taplab or the reference set shows one).
RINGING_WEIGHT = 1.0
# How far a contact read off the approach scatters for the sample grid alone, as a share of the
# approach's travel per sample: the down contact rests on the few samples wholly in contact (1-3 on
# a slow sensor), and its fit's sigma does not see where the contact falls between two of them.
# On the clean scenarios of both sets down minus up contact scatters by 0.5-2.9 µm (sd) at 2.5-25
# µm a sample, 2-6x the fits' sigma; 0.05 of the travel (0.8 µm at 15.6 µm a sample, 1.25 at 25)
# is the largest share that leaves taplab's mild-ooze films a squeeze (0.1: none on seed 3).
APPROACH_GRID_SHARE = 0.05


class SigmaWeights(NamedTuple):
    """How much of each part of `ZSigmaParts` counts; the parts not named here count fully. (A
    NamedTuple: immutable, its values in the kernel's order as they are, and ~6x cheaper to make at
    import than a frozen dataclass.)"""

    noise: float = NOISE_WEIGHT
    shape: float = SHAPE_WEIGHT
    misfit: float = MISFIT_WEIGHT
    thread: float = THREAD_WEIGHT
    squeeze: float = SQUEEZE_WEIGHT
    film: float = FILM_WEIGHT
    floor: float = FLOOR_WEIGHT
    ringing: float = RINGING_WEIGHT


_DEFAULT_WEIGHTS = SigmaWeights()
_DEFAULT_WEIGHT_VALUES = tuple(_DEFAULT_WEIGHTS)  # the kernel's weights argument


@dataclass(eq=False, repr=False)  # not frozen: a frozen dataclass sets each field through object.__setattr__, ~1 µs a tap
class ZSigmaParts:
    """The parts of a tap's Z uncertainty, each a 1 sigma in µm (module docstring)."""

    noise_um: float = 0.0
    shape_um: float = 0.0
    thread_um: float = 0.0
    misfit_um: float = 0.0
    squeeze_um: float = 0.0
    film_um: float = 0.0
    floor_um: float = 0.0
    staircase_um: float = 0.0
    delay_um: float = 0.0
    ringing_um: float = 0.0
    stage_um: float = 0.0


def z_sigma_um(parts: ZSigmaParts, weights: SigmaWeights = SigmaWeights()) -> float:
    """The parts added in quadrature, each weighed."""
    weighed = (weights.noise * parts.noise_um, weights.shape * parts.shape_um,
               weights.thread * parts.thread_um, weights.misfit * parts.misfit_um, weights.squeeze * parts.squeeze_um,
               weights.film * parts.film_um, weights.floor * parts.floor_um, parts.staircase_um, parts.delay_um,
               weights.ringing * parts.ringing_um, parts.stage_um)
    return math.sqrt(sum(part * part for part in weighed))


def misfit_um(residual_g: float | None, noise_g: float | None, step_g: float | None, stiffness_g_um: float) -> float:
    """The residual near contact beyond the noise and the staircase, as height (µm). noise_g: the
    scatter the samples have away from contact too (hum and slow noise the contact model cannot
    follow are no misfit of the contact)."""
    if residual_g is None or noise_g is None or not stiffness_g_um > 0:
        return 0.0
    excess_g2 = residual_g * residual_g - noise_g * noise_g - (step_g or 0.0) ** 2
    return math.sqrt(max(excess_g2, 0.0)) / stiffness_g_um


def squeeze_um(down_um: float | None, up_um: float | None, allowance_um: float) -> float:
    """How far contact on the way down lies above break contact on the way up beyond what the two
    fits' noise allows (`allowance_um`): a film or soft layer squeezed while pressed moved the
    surface under the nozzle by about that much between the two, and what is left of it lies under
    the break contact too. Below TAP_CONTACT_MISMATCH's limit, which also allows hysteresis and a
    sample of travel each way (they would hide every film on taplab's mild ooze)."""
    if down_um is None or up_um is None:
        return 0.0
    return max(down_um - up_um - allowance_um, 0.0)


def squeeze_allowance_um(down_sigma_um: float, up_sigma_um: float, approach_travel_um: float) -> float:
    """What the two contact fits and the approach's sample grid allow between contact on the way
    down and break contact on the way up: CONSISTENCY_SIGMAS of the fits' sigmas and of the grid's
    share of the approach's travel per sample, in quadrature. Without the grid, a slow sensor's one
    or two samples in contact read as a squeezed film (taplab's HX711 80 sps: 2.5 µm rms)."""
    return CONSISTENCY_SIGMAS * math.sqrt(down_sigma_um * down_sigma_um + up_sigma_um * up_sigma_um
                                          + (APPROACH_GRID_SHARE * approach_travel_um) ** 2)


def film_um(squeeze: float, toe_lift_um: float) -> float:
    """A film squeezed while pressed (`squeeze`, µm) leaves some of itself on the bed, and the
    departure reads it as a toe: Z rests on it by as much as the toe model lifts the contact above
    the sharp one (`toe_lift_um`). What it left is at most either."""
    return min(max(squeeze, 0.0), abs(toe_lift_um))


def floor_um(stiffness_g_um: float) -> float:
    """1 g over the stiffness at contact (µm); FLOOR_WEIGHT g of it counts. 0 when the stiffness
    is not known."""
    return 1.0 / stiffness_g_um if stiffness_g_um > 0 else 0.0


def staircase_um(window_staircase_um: float, z_step_um: float) -> float:
    """The staircase's sigma as one sample sees it (`step_staircase_sigma_um`), averaged over the
    independent steps the fit reads into contact (PENETRATION_REACH_UM)."""
    if not z_step_um > 0:
        return window_staircase_um
    return window_staircase_um / math.sqrt(max(PENETRATION_REACH_UM / z_step_um, 1.0))


def thread_um(near_pull_g: float | None, far_pull_g: float | None, walk_var_g2: float, stiffness_g_um: float) -> float:
    """A pull on the departure (against the approach's free-air line, `thread_pull_g`) that changes
    between near contact and further up (a thread letting go), as height, beyond what the
    baseline's random walk moves it between the two (`walk_var_g2`: the walk's variance over that
    distance); the whole near pull when the pullback does not reach far enough to tell. A pull
    that stays (a cable pulling another way on the way up) moves the toe's baseline, not its Z."""
    if near_pull_g is None or not stiffness_g_um > 0:
        return 0.0
    letting_go_g = near_pull_g if far_pull_g is None else near_pull_g - far_pull_g
    return math.sqrt(max(letting_go_g * letting_go_g - walk_var_g2, 0.0)) / stiffness_g_um


def ringing_um(ringing: Ringing | None, samples: int, stiffness_g_um: float) -> float:
    """What a ringing the dwell shows moves the contact by (µm): over the `samples` pullback samples
    the contact is read from, a smooth contact shape takes `ringing_noise_g2` of its energy (a sum
    of squares: all n v of a variance v when they span at most a period, v P^2 / n beyond). The
    contact is where two fitted lines meet, at the end of each: a line's value at the end of its n
    samples takes 4 / n of what its fit takes (its leverage there: 1/n + 3/n), an offset of
    2 sqrt(that / n) g where the force crosses zero, over the stiffness: 2 sqrt(v) / k for a
    ringing slower than the departure, falling as P / n for a faster one. 0 without a ringing."""
    if ringing is None or samples <= 0 or not stiffness_g_um > 0:
        return 0.0
    return 2.0 * math.sqrt(ringing_noise_g2(ringing, samples) / samples) / stiffness_g_um


def samples_in_reach(x_lo_um: np.ndarray, x_hi_um: np.ndarray, contact_um: float) -> int:
    """How many pullback samples (conversion windows [x_lo, x_hi], µm) lie with their middle within
    the contact fit's reach (PENETRATION_REACH_UM) of the contact, either side."""
    return int(np.count_nonzero(np.abs(0.5 * (x_lo_um + x_hi_um) - contact_um) < PENETRATION_REACH_UM))


def toe_shape_um(grid: ToeGridResult) -> float:
    """The shape part of a toe fit's Z, from its grid (`toe.shape_spread_um`; the toe kernel's fit
    finds it with the marginal and keeps it in the grid)."""
    if grid.shape_um is not None:
        return grid.shape_um
    return shape_spread_um(grid.contacts_um, grid.rss, grid.noise_var)



def tap_sigma_parts(x_lo_um: np.ndarray, x_hi_um: np.ndarray, contact_um: float, stiffness_g_um: float,
                    noise_um: float, shape_um: float, walk_var_g2: float, near_pull_g: float | None,
                    far_pull_g: float | None, scatter_g: float, residual_g: float | None, step_g: float | None,
                    down_um: float | None, up_um: float | None, allowance_um: float, toe_lift_um: float,
                    window_staircase_um: float, z_step_um: float, delay_um: float, ringing: Ringing | None,
                    stage_um: float, weights: SigmaWeights = _DEFAULT_WEIGHTS) -> tuple[ZSigmaParts, float]:
    """A tap's parts (`ZSigmaParts`) and `z_sigma_um` of them, from what the analysis measured: the
    pullback's windows [x_lo, x_hi] (µm above the halt, for `samples_in_reach` of the contact),
    the stiffness, the noise and shape parts as they are, the thread's pulls and walk (`thread_um`),
    the scatter, residual and step near contact (`misfit_um`), the two contacts and what they allow
    (`squeeze_um`, `film_um` with the toe's lift), the staircase one sample sees and the Z step
    (`staircase_um`), the delay's part, the ringing (`ringing_um`) and the unnamed stage's distance.
    In C when built (one call a tap instead of a dozen; the same operations in the same order: bit
    for bit); the code below is its twin."""
    if _C is not None:
        found, total = _C.tap_sigma_parts(
            np.ascontiguousarray(x_lo_um, dtype=float), np.ascontiguousarray(x_hi_um, dtype=float), contact_um, PENETRATION_REACH_UM, stiffness_g_um, noise_um, shape_um, walk_var_g2,
            near_pull_g, far_pull_g, scatter_g, residual_g, step_g, down_um, up_um, allowance_um, toe_lift_um,
            window_staircase_um, z_step_um, delay_um, None if ringing is None else ringing.var_g2,
            None if ringing is None else ringing.period_samples, stage_um,
            _DEFAULT_WEIGHT_VALUES if weights is _DEFAULT_WEIGHTS else tuple(weights))
        return ZSigmaParts(*found), total
    squeeze = squeeze_um(down_um, up_um, allowance_um)
    parts = ZSigmaParts(
        noise_um=noise_um, shape_um=shape_um,
        thread_um=thread_um(near_pull_g, far_pull_g, walk_var_g2, stiffness_g_um),
        misfit_um=misfit_um(residual_g, scatter_g, step_g, stiffness_g_um),
        squeeze_um=squeeze, film_um=film_um(squeeze, toe_lift_um), floor_um=floor_um(stiffness_g_um),
        staircase_um=staircase_um(window_staircase_um, z_step_um), delay_um=delay_um,
        ringing_um=ringing_um(ringing, samples_in_reach(x_lo_um, x_hi_um, contact_um), stiffness_g_um),
        stage_um=stage_um)
    return parts, z_sigma_um(parts, weights)
