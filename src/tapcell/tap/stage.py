"""A two-stage mount: a soft first stage (a magnetic sheet, a sprung bed) under the stiff contact.

The nozzle first presses a soft stage (stiffness k1 over d µm), then the contact proper. On the
way up the stiff contact lets go first, and the force then falls along the soft stage's line
until the nozzle leaves it d µm higher: above the contact the toe model finds (the stiff stage's),
the force keeps a ramp k1 (x_top - x) down to the free-air level. Read as contact, the stiff
stage is d µm below the first touch: on taplab's two-stage taps (d 8-30 µm, k1 10-30 % of k) the
toe model read them 1-28 µm low, 4 of 40 accepted beyond 20 µm with a small sigma.

`soft_stage` fits that ramp over the departure (a free level plus k1 clip(top - x, 0) for every
top on a 1 µm grid) against a flat level; the tap shows a soft stage when the ramp explains more
than STAGE_MIN_CHI2 noise variances (white noise plus the baseline's walk over the departure, or
what the ramp leaves of the departure where that is more) and is steeper than STAGE_MIN_SLOPE_SHARE
of the contact's stiffness (a walk or a cable's drift left over are a few tenths of a per cent of
it, the steepest reference bowden tap's 5 %; a stage's ten per cent and more).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tapcell.tap import native
from tapcell.tap.robust import median

# The two-stage fit's grid in C (c/stage.c, tapcell.tap.native); None: its numpy twin `_two_stage_grid`.
_C = native.load("stage")
# The dwell's ringing in C (c/ringing.c); None: its numpy twin, `dwell_ringing`'s own body.
_C_RINGING = native.load("ringing")

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


@dataclass(eq=False, repr=False)
class SoftStage:
    """A soft stage above the contact: a ramp the departure shows before the force returns to zero."""

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
    # Weighed against the noise, or against what the ramp leaves when that is more: a heater's PWM or
    # a ramp in time nobody modelled leaves the departure's level wandering by more than the noise
    # (a second difference hardly sees a 10 Hz square wave at 320 sps), and a stage explains its
    # departure down to the noise. As the two-stage fit weighs its evidence (`_two_stage_grid`).
    left_var_g2 = (float((f * f).sum()) - float(gain[best])) / max(n - 3, 1)
    return SoftStage(float(gain[best] / max(noise_var_g2, left_var_g2)), float(contact_um + STAGE_TOPS_UM[best]),
                     float(slope))


# Gantry ringing (issue 21): an oscillation in time that every change of speed excites, the halt
# and the pullback's start among them. The second-difference noise (tapcell.tap.analysis.noise_sigma_g)
# does not see an oscillation many samples long (40 Hz at 2000-4000 sps: 50-100 samples a period),
# while over an 85 µm departure at 2-4 mm/s (one or two periods) a ramp or a second stage takes it
# for a shape in height. The tap shows its ringing in the dwell, where the force is otherwise smooth
# in time (a relaxation: a quadratic takes it) and the halt rang the toolhead. A ringing is an
# oscillation: one frequency, at least RINGING_MIN_PERIODS periods within the dwell, explaining more
# of the dwell's residual than white noise ever does at its best frequency (RINGING_MIN_CHI2 noise
# variances; white noise's best of ~2n padded frequencies reaches 2 ln(n/2) + a few, 10-15 at these
# lengths). What a quadratic leaves of a squeeze or a wander lies at the lowest frequencies: a mild
# ooze tap's squeezed film (taplab seed 3) peaked at 2.75 periods a dwell; the sweep's 40 Hz ringing
# at 6-13 (1,000-4,000 sps, dwells of 0.1-0.33 s).
RINGING_MIN_SAMPLES = 16
RINGING_MIN_PERIODS = 3.5
RINGING_MIN_CHI2 = 25.0


@dataclass
class Ringing:
    """The ringing a dwell shows at one frequency (`dwell_ringing`)."""

    var_g2: float  # the variance over the dwell at its one frequency (of a ringing decaying in tau about 2 tau / dwell of it)
    period_samples: float  # its period, in sample periods


def dwell_ringing(time_s: np.ndarray, force_g: np.ndarray, white_var_g2: float) -> Ringing | None:
    """The oscillation the dwell shows (samples' times s, force g): what a quadratic in time leaves,
    its strongest frequency from RINGING_MIN_PERIODS per dwell up to the Nyquist rate; None when it
    explains no more than white noise would (RINGING_MIN_CHI2) or too few samples show it. In C when
    built: the same bins to rounding (another FFT), the period bit for bit given the bin."""
    if _C_RINGING is not None:
        found = _C_RINGING.dwell_ringing(time_s, force_g, white_var_g2, RINGING_MIN_SAMPLES, RINGING_MIN_PERIODS,
                                         RINGING_MIN_CHI2)
        return None if found is None else Ringing(*found)
    n = len(force_g)
    if n < RINGING_MIN_SAMPLES or white_var_g2 <= 0:
        return None
    t = time_s - float(time_s.sum()) / n
    span_s = float(time_s[-1] - time_s[0])
    if span_s <= 0:
        return None
    u = t / span_s
    basis = np.array((np.ones(n), u, u * u))
    # The least-squares quadratic by its 3 x 3 normal equations (a third of lstsq's cost; the
    # basis is centred and scaled, well conditioned): it runs on every tap for z_sigma_um's ringing part.
    coef = np.linalg.solve(basis @ basis.T, basis @ force_g)
    residual = force_g - coef @ basis
    period_s = span_s / (n - 1)
    # The periodogram 2 |sum r e^-iwt|^2 / n (uniform samples: an FFT), padded to a quarter of the
    # dwell's frequency resolution, from RINGING_MIN_PERIODS periods per dwell up.
    padded = 4 * n
    power = 2.0 * np.abs(np.fft.rfft(residual, padded)) ** 2 / n
    lowest = int(math.ceil(RINGING_MIN_PERIODS * padded * period_s / span_s))
    if lowest >= len(power):
        return None
    best = lowest + int(power[lowest:].argmax())
    if power[best] < RINGING_MIN_CHI2 * white_var_g2:
        return None
    hz = best / (padded * period_s)
    return Ringing(float(power[best]) / n, 1.0 / (hz * period_s))


def ringing_noise_g2(ringing: Ringing | None, samples: int) -> float:
    """What a ringing adds to the noise a stage is weighed against over `samples` samples: the part
    of its energy there a smooth shape (a ramp, two hinged lines) can take. All of it when the
    samples span at most a period; beyond, a kink's spectrum falls with the square of the periods
    spanned: period^2 / samples variances (40 Hz at 4000 sps over 60 samples: all 60; 50 Hz of hum
    left at 320 sps: 6.4^2 / 60, under one)."""
    if ringing is None or samples <= 0:
        return 0.0
    return ringing.var_g2 * min(float(samples), ringing.period_samples * ringing.period_samples / samples)


def departure_soft_stage(x_lo_um: np.ndarray, x_hi_um: np.ndarray, force_g: np.ndarray, drift_g_um: float,
                         contact_um: float, white_var_g2: float, walk_var_g2: float,
                         ringing: Ringing | None = None) -> SoftStage | None:
    """`soft_stage` over the pullback's samples (conversion windows [x_lo, x_hi], µm above the halt)
    near the contact found (`departure_near`), the drift (g/µm) taken out; the noise: white plus what
    the baseline's walk adds over those samples (a walk about its mean: n/6), plus what a ringing the
    dwell shows adds over them (`ringing_noise_g2`). In C when built."""
    if ringing is not None:
        count = int(departure_near(0.5 * (x_lo_um + x_hi_um), contact_um).sum())
        white_var_g2 = white_var_g2 + ringing_noise_g2(ringing, count)
    if _C is not None:
        found = _C.soft_stage(x_lo_um, x_hi_um, force_g, drift_g_um, contact_um, white_var_g2, walk_var_g2,
                              STAGE_TOPS_UM, STAGE_FROM_UM, STAGE_REACH_UM, STAGE_MIN_SAMPLES)
        return None if found is None else SoftStage(*found)
    x_um = 0.5 * (x_lo_um + x_hi_um)
    near = departure_near(x_um, contact_um)
    x_um = x_um[near]
    return soft_stage(x_um, force_g[near] - drift_g_um * x_um, contact_um, white_var_g2 + walk_var_g2 * len(x_um) / 6.0)


def shows_soft_stage(stage: SoftStage | None, stiffness_g_um: float, contact_um: float) -> bool:
    """The ramp is a stage: clearly there and steep enough."""
    return (stage is not None and stage.chi2 > STAGE_MIN_CHI2
            and stage.slope_g_um >= STAGE_MIN_SLOPE_SHARE * abs(stiffness_g_um))


# The two-stage departure fit (issue 21): measured against the one-stage toe on the same samples.
# A stage the toe model absorbs (8-15 µm, the toe wide) leaves the ramp above the toe's contact too
# short to show; fitted from below the stiff contact up, the two stages explain the departure
# better than any one-stage toe, by how much is the evidence.
TWO_STAGE_BELOW_UM = 25.0  # the samples fitted: this far below the contact found ...
TWO_STAGE_ABOVE_UM = 60.0  # ... to this far above it
TWO_STAGE_HINGES_UM = np.arange(-10.0, 30.0, 1.0)  # where the stiff stage lets go, about the contact found
TWO_STAGE_SPANS_UM = np.arange(2.0, 40.0, 1.0)  # the soft stage's travel above the hinge
ONE_STAGE_CONTACTS_UM = np.arange(-10.0, 35.0, 0.5)  # the one-stage toe's contact, about the contact found
ONE_STAGE_WIDTHS_UM = (0.0, 1.0, 2.0, 3.0, 4.5, 6.0, 8.0, 10.0, 13.0, 16.0, 20.0, 25.0, 30.0)
ONE_STAGE_POWERS = (0.5, 1.0)
_ONE_STAGE_WIDTHS, _ONE_STAGE_POWERS = np.array(ONE_STAGE_WIDTHS_UM), np.array(ONE_STAGE_POWERS)  # the kernel's
# The soft stage's stiffness over the stiff stage's: at 6 % a drift the approach left and a bed's
# walk pass for a stage over 40 µm (one reference clean tap of 960 at 87 noise variances); a first
# stage stiffer than half the contact is the contact's own toe.
TWO_STAGE_MIN_SOFT_SHARE = 0.08
TWO_STAGE_MAX_SOFT_SHARE = 0.5
TWO_STAGE_MIN_SPAN_UM = 5.0  # a shorter stage moves Z by less than the toe's own spread
TWO_STAGE_MIN_SPAN_WINDOWS = 2.0  # a stage shorter than two conversion windows (or sample steps) is a hinge they smeared
# The evidence for two stages, in noise variances, on the taps the fit runs on (TWO_STAGE_MIN_TOE_WIDTH_UM):
# clean and soft-sheet taps at most 12.5 (one reference session tap of 800; else 6.8), taplab seeds 1-2
# 5.3, the reference taps 5.3; the two-stage taps the ramp check misses 5.6-130 (taplab seeds 1-2, 24
# taps: 5 below 16, reading 2-10 µm low).
TWO_STAGE_MIN_EVIDENCE = 16.0
# With the drift held at the free air's (the approach's line, where the departure agrees with it:
# the toe fit's own baseline, `toe_drift_g_um`), a long soft stage can no longer trade against a
# drift fitted with it, and a stage shows more. Of the 43 two-stage taps the fitted drift left valid
# on taplab seeds 1-12 (2.3-13.5 um low), 14 then reach 12.5-33.4; the rest stay where clean taps
# are (an 8.5 um stage of 2.2 g under 0.8 g of noise: -1.4). Clean and soft-sheet taps reach 7.8 on
# taplab seeds 1-3, the reference taps and sessions (3,560 taps), 10.5 on seeds 4-12 (5,400 more,
# never tuned on; at 10, the first choice, that one tap would have been rejected). The noise then:
# white plus the walk over the longest stage's share of the samples, not the whole reach's (the two
# models differ over a stage's samples; the level takes the rest).
TWO_STAGE_HELD_MIN_EVIDENCE = 12.0
# ... with its first touch shown apart from the toe's contact, by 2 of its own sd: a clean ADS1220
# tap (seed 5) scored 12.1 for a top 1.03 um up, 1.2 sd; the stages named lie 2.04-10.5 sd up ...
TWO_STAGE_HELD_TOP_SDS = 2.0
# ... and within 2 sd (the two tops' sds combined) of where the fitted-drift fit puts it: a stage is a
# shape in height (two-stage taps 0.02-1.32 apart). A 10 sps HX711 tap (seed 4) whose baseline sank
# 2 g over its 9 s departure: held, a 19 um stage at 8 %, its top 14.7 um above the contact,
# evidence 18.6; fitted, 1.05 um above it: 20.5 apart.
TWO_STAGE_TOPS_AGREE_SDS = 2.0
TWO_STAGE_MATTERS_UM = 1.0  # a first touch this close to the toe's contact leaves its Z standing
# The toe absorbs a stage only by growing wide (the two-stage taps it misreads: toes of 10-16 µm);
# under a narrower toe the stage stays above its contact, where the ramp check sees it. The fit
# then runs on 5-30 % of clean taps (the toe's width prior keeps most narrow), most soft sheets.
TWO_STAGE_MIN_TOE_WIDTH_UM = 8.0


@dataclass(eq=False, repr=False)
class TwoStageFit:
    """The two-stage mount's fit over a pullback (`two_stage_fit`): a soft stage above a stiff one."""

    evidence_chi2: float  # residual of the best one-stage toe minus the two stages', in noise variances
    # (below TWO_STAGE_MIN_EVIDENCE, or with the top within TWO_STAGE_MATTERS_UM: an upper bound, a hinge's)
    top_um: float  # where the soft stage ends (the force returns to zero): the first touch, µm above the halt
    top_sigma_um: float  # its sd over the spans and hinges the data allow
    span_um: float  # the soft stage's travel (best fit)
    soft_share: float  # its stiffness over the stiff stage's
    drift_held: bool = False  # both models on the free air's drift (else each fitted a drift of its own)
    over_hinge_chi2: float = 0.0  # residual of a sharp contact (a hinge) minus the two stages', in noise variances

    @property
    def min_evidence(self) -> float:
        """The evidence that names two stages: less with the drift held (no long stage against a drift)."""
        return TWO_STAGE_HELD_MIN_EVIDENCE if self.drift_held else TWO_STAGE_MIN_EVIDENCE

    def reads_apart_um(self) -> float:
        """How far the first touch must lie from the toe's contact to stand apart from it: the
        TWO_STAGE_MATTERS_UM that leaves the contact standing, and with the drift held also
        TWO_STAGE_HELD_TOP_SDS of the top's own sd (the lower threshold asks the top to be shown)."""
        if not self.drift_held:
            return TWO_STAGE_MATTERS_UM
        return max(TWO_STAGE_MATTERS_UM, TWO_STAGE_HELD_TOP_SDS * self.top_sigma_um)


def _sorted_detrended(x_um: np.ndarray, force_g: np.ndarray,
                      drift_held: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray, float, float]:
    """The samples by height, the heights centred, and the force with a level and a drift
    (a line in height) removed: both models fit those too (what drift the approach left, a walk).
    With the drift held, the level alone: the centred heights' sum of squares is then infinite,
    which takes the drift's column out of every projection the grids make (x·x / inf = 0)."""
    order = x_um.argsort(kind="stable")
    x, f = x_um[order], force_g[order]
    n = len(x)
    xc = x - float(x.sum()) / n  # the means without np.mean's Python wrapper (the same sum and division)
    f = f - float(f.sum()) / n
    # The sums of products as (a * b).sum(), numpy's pairwise sum, not a @ b: BLAS's order depends
    # on the machine, and the grid's fits (differences of residuals of the force's size) carry a
    # rounding of ff into the top at 1e-6 µm. So the kernel (c/stage.c) repeats them bit for bit.
    if drift_held:
        return x, xc, f, math.inf, float((f * f).sum())
    sxx = float((xc * xc).sum())
    if sxx > 0:  # else every sample at one height: two_stage_fit has no stages to tell
        f = f - xc * (float((xc * f).sum()) / sxx)
    return x, xc, f, sxx, float((f * f).sum())


def _one_stage_rss(x: np.ndarray, f: np.ndarray, x_mean: float, sxx: float, ff: float, contact_um: float) -> float:
    """The least residual of a level, a drift and a one-stage toe (tapcell.tap.toe's shapes, widths
    to 30 µm, no prior: the toe as wide as the data like) over every contact on the grid, on the
    samples as `_sorted_detrended` leaves them (x_mean: their heights' mean). In C when built (the
    samples on the toe's linear part from prefix sums; the code below is its numpy twin)."""
    if _C is not None:
        return _C.one_stage_rss(x, f, ONE_STAGE_CONTACTS_UM, _ONE_STAGE_WIDTHS, _ONE_STAGE_POWERS, contact_um, sxx, ff,
                                x_mean)
    from tapcell.tap.toe import toe_shapes  # the shapes only; stage.py stays importable alone

    n = len(f)
    xc = x - x_mean  # the heights centred, as _sorted_detrended centres them
    contacts = contact_um + ONE_STAGE_CONTACTS_UM
    widths = np.array(ONE_STAGE_WIDTHS_UM)
    depth = np.broadcast_to(contacts[:, None] - x[None, :], (len(widths), len(contacts), n)).copy()
    shapes = toe_shapes(depth, widths[:, None, None], ONE_STAGE_POWERS)  # (powers, widths, contacts, n)
    s_sum, s_x = shapes.sum(axis=-1), shapes @ xc
    s_var = (shapes * shapes).sum(axis=-1) - s_sum * s_sum / n - s_x * s_x / sxx
    s_f = shapes @ f  # f is orthogonal to the level and the drift
    gain = np.where((s_f > 0) & (s_var > 0), s_f * s_f / np.maximum(s_var, 1e-300), 0.0)
    return ff - float(gain.max())


def two_stage_fit(x_um: np.ndarray, force_g: np.ndarray, contact_um: float, noise_var_g2: float,
                  window_um: float, drift_held: bool = False) -> TwoStageFit | None:
    """A level plus a stiff stage letting go at h plus a soft stage letting go at t > h (two hinged
    lines: force = b + k (h - x)+ + k1 (t - x)+), against the best one-stage toe, over the samples
    from TWO_STAGE_BELOW_UM below the contact found to TWO_STAGE_ABOVE_UM above it (heights µm above
    the halt, force drift removed). Both models fit a drift too, unless drift_held (the drift
    removed is the tap's; the grid still counts six parameters in what the two stages leave, one
    more than they then have: a noise a little larger). None when too few samples or no two-stage
    fit with both stiffnesses positive."""
    if _C is not None:
        # The selection, the sort, the level and drift taken out and the grid in one call (the kernel
        # reads C-contiguous float64; the analysis's arrays are, a caller's slice need not be); the
        # samples it fitted come back for the one-stage toe.
        x_sorted, f_sorted = np.empty(len(x_um)), np.empty(len(x_um))
        found = _C.two_stage_fit(np.ascontiguousarray(x_um, dtype=float), np.ascontiguousarray(force_g, dtype=float),
                                 contact_um, TWO_STAGE_BELOW_UM, TWO_STAGE_ABOVE_UM, STAGE_MIN_SAMPLES,
                                 noise_var_g2, window_um, TWO_STAGE_MIN_SPAN_UM, TWO_STAGE_MIN_SPAN_WINDOWS,
                                 TWO_STAGE_HINGES_UM, TWO_STAGE_SPANS_UM, TWO_STAGE_MIN_SOFT_SHARE,
                                 TWO_STAGE_MAX_SOFT_SHARE, drift_held, x_sorted, f_sorted)
        if found is None:
            return None
        *grid, ff, count, sxx, x_mean = found
        prepared = x_sorted[:count], f_sorted[:count], x_mean, sxx
    else:
        near = (x_um > contact_um - TWO_STAGE_BELOW_UM) & (x_um < contact_um + TWO_STAGE_ABOVE_UM)
        if int(near.sum()) < 2 * STAGE_MIN_SAMPLES or noise_var_g2 <= 0:
            return None
        x, xc, f, sxx, ff = _sorted_detrended(x_um[near], force_g[near], drift_held)
        if not sxx > 0:  # every sample at one height: no drift to tell, no stages
            return None
        spacing_um = median(np.diff(x))  # a sample's step in height: 20 µm at 10 sps, 0.2 mm/s
        shortest_um = max(TWO_STAGE_MIN_SPAN_UM, TWO_STAGE_MIN_SPAN_WINDOWS * max(window_um, spacing_um))
        grid = _two_stage_grid(x, f, contact_um, sxx, ff, noise_var_g2, shortest_um)
        if grid is None:
            return None
        prepared = x, f, float(x.sum()) / len(x), sxx  # x.mean(), as _sorted_detrended centred them
    least, noise_var_g2, top_mean, top_sd, best_span, soft_share, hinge_gain = grid
    # The one-stage toe's residual is at most a hinge's (a toe of width 0): when even the hinge
    # leaves too little to explain, the toe grid (most of the cost) is not needed.
    over_hinge_chi2 = float((ff - hinge_gain - least) / noise_var_g2)
    fit = TwoStageFit(over_hinge_chi2, top_mean, top_sd, float(TWO_STAGE_SPANS_UM[best_span]), soft_share,
                      drift_held, over_hinge_chi2)
    if fit.evidence_chi2 > fit.min_evidence and abs(top_mean - contact_um) > fit.reads_apart_um():
        fit.evidence_chi2 = (_one_stage_rss(*prepared, ff, contact_um) - least) / noise_var_g2
    fit.evidence_chi2 = float(fit.evidence_chi2)
    return fit


def _two_stage_grid(x: np.ndarray, f: np.ndarray, contact_um: float, sxx: float, ff: float, noise_var_g2: float,
                    shortest_um: float) -> tuple[float, float, float, float, int, float, float] | None:
    """The numpy twin of the kernel's `two_stage_grid` (c/stage.c): over every hinge and span, the two
    stages solved from prefix sums over the samples by height (x rising; f with a level and a drift
    removed); (least residual, the noise variance weighing the fits, the top's mean and sd over
    them, the best span's index, its soft share, the best hinge's gain alone), or None when no
    grid point is allowed."""
    n, x_mean = len(f), float(x.mean())
    sums = np.zeros((5, n + 1))
    np.cumsum(np.array((np.ones(n), x, x * x, f, x * f)), axis=1, out=sums[:, 1:])
    hinge = contact_um + TWO_STAGE_HINGES_UM[:, None]  # (hinges, 1)
    top = hinge + TWO_STAGE_SPANS_UM[None, :]  # (hinges, spans)
    s0h, s1h, s2h, sfh, sxfh = sums[:, x.searchsorted(hinge)]  # each (hinges, 1)
    s0t, s1t, s2t, sft, sxft = sums[:, x.searchsorted(top)]  # each (hinges, spans)
    # u = (h - x)+, v = (t - x)+: their sums, squares, cross products and products with f, with
    # the level and the drift projected out (f is already orthogonal to both).
    su, sv = hinge * s0h - s1h, top * s0t - s1t
    ux = hinge * s1h - s2h - x_mean * su  # u against the centred heights
    vx = top * s1t - s2t - x_mean * sv
    uu = hinge * hinge * s0h - 2.0 * hinge * s1h + s2h - su * su / n - ux * ux / sxx
    vv = top * top * s0t - 2.0 * top * s1t + s2t - sv * sv / n - vx * vx / sxx
    uv = hinge * top * s0h - (hinge + top) * s1h + s2h - su * sv / n - ux * vx / sxx  # u is 0 past its hinge
    uf, vf = hinge * sfh - sxfh, top * sft - sxft
    det = uu * vv - uv * uv
    ok = det > 1e-9 * np.maximum(uu * vv, 1e-300)
    det = np.where(ok, det, 1.0)
    k = (vv * uf - uv * vf) / det
    k1 = (uu * vf - uv * uf) / det
    gain = k * uf + k1 * vf
    ok &= (k1 >= TWO_STAGE_MIN_SOFT_SHARE * k) & (k1 <= TWO_STAGE_MAX_SOFT_SHARE * k)
    ok &= TWO_STAGE_SPANS_UM[None, :] >= shortest_um
    if not ok.any():
        return None
    rss = np.where(ok, ff - gain, np.inf)
    best = np.unravel_index(int(rss.argmin()), rss.shape)
    least = float(rss[best])
    # What the two stages leave is the noise when they are the tap; more than the noise estimate on
    # a tap with a hum or a walk nobody modelled, where the evidence is then weighed by it.
    noise_var_g2 = max(noise_var_g2, least / max(n - 6, 1))
    # The top marginalised over the fits the noise allows (their likelihoods), as the toe's contact is.
    weight = np.exp(-0.5 * (rss - least) / noise_var_g2)  # 0 where not ok
    total = float(weight.sum())
    top_mean = float((weight * top).sum()) / total
    top_sd = math.sqrt(max(float((weight * (top - top_mean) ** 2).sum()) / total, 0.0))
    hinge_gain = np.where((uf > 0) & (uu > 0), uf * uf / np.maximum(uu, 1e-300), 0.0)
    return least, noise_var_g2, top_mean, top_sd, int(best[1]), float(k1[best] / k[best]), float(hinge_gain.max())


def shows_two_stage(fit: TwoStageFit | None, contact_um: float) -> bool:
    """The departure is two stages, clearly, and its first touch is not the toe's contact."""
    return (fit is not None and fit.evidence_chi2 > fit.min_evidence
            and abs(fit.top_um - contact_um) > fit.reads_apart_um())


# A stage the toe absorbed whole (issue 21, the sweep's sprung stage on the reference taps): a 20-25
# um stage at a tenth of 1.1-4.7 g/um under 1-3 g of noise, its force too small for the two stages
# to beat the toe (evidence under TWO_STAGE_MIN_EVIDENCE), is taken for the toe at its widest and
# read 13-25 um low with a z_sigma_um of 1-4. What such a tap does show: an onset wider than the
# toe model reaches (the toe at TOE_WIDTHS_UM's last, 16 um) and a first touch well above the toe's
# contact that explains the departure clearly better than a sharp contact. Nothing it shows tells
# it from a clean tap's noise often enough to reject it (as TAP_TWO_STAGE_CONTACT: 1 of 20 taps of
# the sweep's 5 g noise and of its 4000 sps ringing, branch i21-absorbed9), so that first touch goes
# into z_sigma_um as the stage part (`unnamed_stage_um`'s). With the toe at 16 um the fit (drift
# fitted) puts it 12 um or more above at 6 noise variances or more over a hinge on no clean tap of
# the two benchmark sets (taplab seeds 1-2 and new) and the two sets of sessions (3,560 taps), on
# 4 of the reference's 280 soft-sheet taps, and on 21-66 % of the sprung reference taps of 20-30 um
# the other checks let through (seed 1).
ABSORBED_STAGE_MIN_EVIDENCE = 6.0
ABSORBED_STAGE_MIN_RISE_UM = 12.0


def shows_absorbed_stage(fit: TwoStageFit | None, contact_um: float, toe_at_widest: bool) -> bool:
    """Under a toe at the model's widest, the departure's two stages put the first touch
    ABSORBED_STAGE_MIN_RISE_UM or more above the toe's contact, ABSORBED_STAGE_MIN_EVIDENCE noise
    variances better than a sharp contact: an onset longer than the toe measures."""
    return (toe_at_widest and fit is not None and fit.over_hinge_chi2 >= ABSORBED_STAGE_MIN_EVIDENCE
            and fit.top_um - contact_um >= ABSORBED_STAGE_MIN_RISE_UM)


def same_first_touch(held: TwoStageFit, fitted: TwoStageFit | None) -> bool:
    """A stage is a shape in height: its first touch is the same whether the drift is held or fitted
    (within TWO_STAGE_TOPS_AGREE_SDS of their sds). A baseline wandering over a slow departure is
    not: held, it passes for a long shallow stage far above the contact; fitted, it is a tilt."""
    if fitted is None:
        return False
    return abs(held.top_um - fitted.top_um) <= TWO_STAGE_TOPS_AGREE_SDS * math.hypot(held.top_sigma_um,
                                                                                   fitted.top_sigma_um)


# The share of the fitted samples a soft stage can span at most (its longest span over the reach).
_LONGEST_STAGE_SHARE = float(TWO_STAGE_SPANS_UM[-1]) / (TWO_STAGE_BELOW_UM + TWO_STAGE_ABOVE_UM)


def two_stage_departure(x_lo_um: np.ndarray, x_hi_um: np.ndarray, force_g: np.ndarray, drift_g_um: float,
                        contact_um: float, toe_width_um: float, noise_g: float,
                        walk_var_g2: float, drift_held: bool = False, ringing: Ringing | None = None
                        ) -> TwoStageFit | None:
    """`two_stage_fit` over the pullback's samples (conversion windows [x_lo, x_hi], µm above the
    halt) about the toe's contact, when the toe is wide enough to have absorbed a stage.

    With drift_held (the toe fit held drift_g_um, the departure agreeing with the approach), first on
    that drift: the fit that shows two stages when one does. Else, or when it does not, with a
    drift fitted by both models (a baseline tilted over the departure: an ooze thread, a walk).
    The noise: white plus what the baseline's walk adds, about its mean over the samples (n/6)
    with a drift fitted, over the longest stage's share of them with the drift held; plus what a
    ringing the dwell shows adds over the samples (`ringing_noise_g2`)."""
    if toe_width_um < TWO_STAGE_MIN_TOE_WIDTH_UM:
        return None
    return _departure_fit(x_lo_um, x_hi_um, force_g, drift_g_um, contact_um, noise_g, walk_var_g2, drift_held, ringing)


def _departure_fit(x_lo_um: np.ndarray, x_hi_um: np.ndarray, force_g: np.ndarray, drift_g_um: float,
                   contact_um: float, noise_g: float, walk_var_g2: float, drift_held: bool,
                   ringing: Ringing | None) -> TwoStageFit | None:
    """`two_stage_departure`'s fits, whatever the toe's width."""
    low_um, high_um = contact_um - TWO_STAGE_BELOW_UM, contact_um + TWO_STAGE_ABOVE_UM
    if _C is not None:  # the selection in one call (a dozen numpy calls below: its twin)
        x_um, detrended_g = np.empty(len(force_g)), np.empty(len(force_g))
        count, window_um = _C.departure_near(x_lo_um, x_hi_um, force_g, drift_g_um, low_um, high_um, x_um,
                                             detrended_g)
        if not count:
            return None
        x_um, force_g = x_um[:count], detrended_g[:count]
    else:
        x_um = 0.5 * (x_lo_um + x_hi_um)
        near = (x_um > low_um) & (x_um < high_um)
        if not near.any():
            return None
        x_um, window_um = x_um[near], median(x_hi_um[near] - x_lo_um[near])
        force_g = force_g[near] - drift_g_um * x_um
    walk_g2 = walk_var_g2 * len(x_um) / 6.0
    white_g2 = noise_g * noise_g + ringing_noise_g2(ringing, len(x_um))
    fitted = two_stage_fit(x_um, force_g, contact_um, white_g2 + walk_g2, window_um)
    if drift_held and not shows_two_stage(fitted, contact_um):
        held = two_stage_fit(x_um, force_g, contact_um, white_g2 + walk_g2 * _LONGEST_STAGE_SHARE,
                             window_um, True)
        if shows_two_stage(held, contact_um) and same_first_touch(held, fitted):
            return held
    return fitted


# Under a narrow toe (issue 21, i21-stage4) a stage of 8-10 um at 11-16 % sits above the toe's
# contact with 3-4 g in all under 1 g of noise, too little for the ramp check, and the toe reads the
# stiff stage (taplab seed 4 k 27: accepted 10.2 um low, z_sigma_um 0.81). Run there, the two-stage
# fit finds it as often as it finds a drift or a walk passing for a long soft stage: on the 3,080
# should-accept taps of taplab seeds 1-7 it shows two stages under 7 narrow toes (cable drift, 10
# sps, latency, clean HX717: first touches 3.5-17.4 um up, at 8-14 % of the stiffness), and on seed
# 4 k 27 (8.5 um up at 14 %). Nothing the fit measures tells them apart at that noise (the soft
# share, 0.142 +- 0.032 against cable drift seed 4 k 20's 0.107 +- 0.028, with the noise's part of
# its variance), so the tap is not rejected: the first touch the fit found goes into z_sigma_um
# instead. A first touch above the contact leaves a ramp above it: the fits run only where the
# soft-stage ramp (`soft_stage`, computed on every tap) explains more than UNNAMED_STAGE_MIN_RAMP_CHI2
# noise variances, a ramp three of its sd strong (7 % of taplab's valid taps; the taps above score
# 17-227). On every narrow toe they would cost 0.18 ms a tap; so, 0.013 ms (taplab seed 1).
UNNAMED_STAGE_MIN_RAMP_CHI2 = 9.0


def unnamed_stage_um(x_lo_um: np.ndarray, x_hi_um: np.ndarray, force_g: np.ndarray, drift_g_um: float,
                     contact_um: float, toe_width_um: float, noise_g: float, walk_var_g2: float,
                     ramp: SoftStage | None, drift_held: bool = False, ringing: Ringing | None = None) -> float:
    """Under a toe narrower than TWO_STAGE_MIN_TOE_WIDTH_UM (where `two_stage_departure` does not
    run): how far the two stages' first touch lies from the toe's contact (µm) when the departure
    shows two stages as `two_stage_departure` weighs it (with the drift fitted or, where the toe fit
    held it and the fitted one shows none, held and the same first touch), ringing included; else 0
    (and where the soft-stage ramp above the contact, `ramp`, shows too little)."""
    if toe_width_um >= TWO_STAGE_MIN_TOE_WIDTH_UM or ramp is None or ramp.chi2 <= UNNAMED_STAGE_MIN_RAMP_CHI2:
        return 0.0
    fit = _departure_fit(x_lo_um, x_hi_um, force_g, drift_g_um, contact_um, noise_g, walk_var_g2, drift_held, ringing)
    return abs(fit.top_um - contact_um) if shows_two_stage(fit, contact_um) else 0.0
