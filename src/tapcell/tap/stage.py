"""A two-stage mount: a soft first stage (a magnetic sheet, a sprung bed) under the stiff contact.

The nozzle first presses a soft stage (stiffness k1 over d µm), then the contact proper. On the
way up the stiff contact lets go first, and the force then falls along the soft stage's line
until the nozzle leaves it d µm higher: above the contact the toe model finds (the stiff stage's),
the force keeps a ramp k1 (x_top - x) down to the free-air level. Read as contact, the stiff
stage is d µm below the first touch: on taplab's two-stage taps (d 8-30 µm, k1 10-30 % of k) the
toe model read them 1-28 µm low, 4 of 40 accepted beyond 20 µm with a small sigma.

`soft_stage` fits that ramp over the departure (a free level plus k1 clip(top - x, 0) for every
top on a 1 µm grid) against a flat level; the tap shows a soft stage when the ramp explains more
than STAGE_MIN_CHI2 noise variances (white noise plus the baseline's walk over the departure)
and is steeper than STAGE_MIN_SLOPE_SHARE of the contact's stiffness (a walk or a cable's drift
left over are a few tenths of a per cent of it, the steepest reference bowden tap's 5 %; a stage's
ten per cent and more).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

STAGE_REACH_UM = 60.0  # the departure looked at, above the contact found
STAGE_FROM_UM = 0.5
STAGE_TOPS_UM = np.arange(2.0, 45.0, 1.0)  # where the soft stage may end, above the contact found
STAGE_MIN_SAMPLES = 10
# Reference taps and taplab's (issue 21): clean scenarios at most 25 (one tap of 1,600), two-stage
# taps 100-4,700 for stages the toe misses by more than 9 um.
STAGE_MIN_CHI2 = 36.0
STAGE_MIN_SLOPE_SHARE = 0.06
_TOPS_SQUARED = STAGE_TOPS_UM * STAGE_TOPS_UM
_TOPS_TWICE = 2.0 * STAGE_TOPS_UM


@dataclass
class SoftStage:
    chi2: float  # how much better the ramp explains the departure than a flat level (noise variances)
    top_um: float  # where the soft stage ends (µm above the halt): the first touch
    slope_g_um: float  # its stiffness


def departure_near(x_um: np.ndarray, contact_um: float) -> np.ndarray:
    """The samples `soft_stage` looks at: STAGE_FROM_UM to STAGE_REACH_UM above the contact found."""
    above = x_um - contact_um
    return (above > STAGE_FROM_UM) & (above < STAGE_REACH_UM)


def soft_stage(x_um: np.ndarray, force_g: np.ndarray, contact_um: float, noise_var_g2: float) -> SoftStage | None:
    """The best soft-stage ramp over the departure's samples (`departure_near`; heights x_um, µm
    above the halt, rising; force drift removed), or None when too few to tell."""
    n = len(force_g)
    if n < STAGE_MIN_SAMPLES or noise_var_g2 <= 0:
        return None
    # Heights above the contact found: the tops are then the constant STAGE_TOPS_UM. The ramp
    # clip(top - x, 0) of every top at once from prefix sums over the samples by height: those
    # below a top contribute (top - x), the others nothing.
    order = x_um.argsort(kind="stable")  # rising already but for the pullback's end
    x = x_um[order] - contact_um
    f = force_g[order]
    f = f - float(f.sum()) / n  # f.mean(), without its Python wrapper (the same sum and division)
    below = x.searchsorted(STAGE_TOPS_UM)
    sums = np.zeros((4, n + 1))
    np.add.accumulate(np.array((x, x * x, f, x * f)), axis=1, out=sums[:, 1:])  # np.cumsum without its wrapper
    sum_x, sum_xx, sum_f, sum_xf = sums[:, below]
    sum_r = STAGE_TOPS_UM * below - sum_x
    srr = _TOPS_SQUARED * below - _TOPS_TWICE * sum_x + sum_xx - sum_r * sum_r / n
    srf = STAGE_TOPS_UM * sum_f - sum_xf  # f has mean 0: no centring term
    gain = srf * srf / np.maximum(srr, 1e-300)  # the residual the ramp removes
    gain[srf <= 0.0] = 0.0  # a ramp rising with height is no stage
    best = int(gain.argmax())
    slope = srf[best] / srr[best] if srr[best] > 0 else 0.0
    return SoftStage(float(gain[best] / noise_var_g2), float(contact_um + STAGE_TOPS_UM[best]), float(slope))


def shows_soft_stage(stage: SoftStage | None, stiffness_g_um: float, contact_um: float) -> bool:
    """The ramp is a stage: clearly there and steep enough."""
    return (stage is not None and stage.chi2 > STAGE_MIN_CHI2
            and stage.slope_g_um >= STAGE_MIN_SLOPE_SHARE * abs(stiffness_g_um))
