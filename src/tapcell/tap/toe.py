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
  baseline + drift · x + k · H(c − x; w, p) averaged over each sample's conversion window, H a
  power-law toe of width w (stiffness ~ (depth/w)^p) joining the linear region with a continuous
  slope. The drift (g per µm of height: a cable or bowden pulling in proportion to Z) comes from
  the approach line when the caller knows it, else it is fitted with the rest. For every
  (p, w, c) on a grid, baseline and k are solved in closed form (variable projection: the
  fixed columns are projected out once, each toe column costs a few dot products).

The baseline may also wander (a random walk: temperature, a cable settling). When the tap's free
air shows a walk that matters over the fit (`walk_beside_height_pull`: told apart from a pull
curved in height, `Wander.matters`), the fit weighs the samples by white + walk covariance
(`_Whitened`: the same grid, the same three parts of the toe column, a recursion instead of plain
sums).

`contact_um` is the mean of c with the toe marginalised out (the widths 0-16 µm weighed by a
prior falling off as exp(-width / 4 µm), the two shapes alike), and `sigma_um` its sd
(`marginal_contact_um`): the toe width and the contact height trade off along a flat valley of
the residual, and the single best toe wanders along it with the noise. Averaging over the toes the
data allow (weighted by their likelihood) is steadier than the best one, and the sd keeps that
trade-off (docs/tap-analysis.md gives the rms of error over sigma per scenario and set).

Speed (the grid is 2 shapes × 10 widths × 27 contacts, every candidate solved exactly):
* a candidate's samples fall in three runs along the pullback: pressed past its toe (their toe
  column is linear in x, so they enter through prefix sums, `_Projected`), in its toe (a few
  samples each: the only ones evaluated) and in free air (zero). All candidates' in-toe samples
  are laid end to end in one flat array and summed per candidate by `np.bincount`;
* the in-toe run depends on the width, not the shape, so both shapes share it (`toe_shapes`);
  the walk-weighted fit runs both shapes' candidates through one recursion (`_rss_whitened`);
* flat 1-D arrays and `take` (2-D fancy indexing and broadcasting over a short last axis cost
  several times more on arrays this small), and plain floats where there are only a score of
  values or one series to step through (`marginal_contact_um`, `_stiffness_at`, `_whiten` on one
  row, the walk's least squares);
* the walk estimate's detrended variogram in closed form, cached per segment length.
On the independent benchmark this took the toe configuration from ~9 ms to ~3 ms a tap (this
machine, loaded), results equal to ~1e-9 µm.

The compiled kernel (c/toe.c; numpy twins here: `fit_toe`'s own code with `_toe_grid`, the
marginal contact's, `free_air_walks`' and the free-air variogram's numpy code) does one tap's whole
toe fit in one call (`_fit_toe_native`: the samples kept, either grid, the least residual, the
marginal contact and the stiffness there) and its free-air walks in another (`free_air_walks`);
it takes the walk-weighted fit's pressed and free runs from sums prepared once, so a candidate
costs its toe's samples only, and evaluates a window's two heights side by side (SSE2, the same
bits). The toe fit went from ~0.8 ms to ~0.12 ms a tap (median per-stage time, 25 taps of the
independent generator), then to ~16 µs a plain fit and ~20 µs a walk-weighted one, and the
free-air walks from ~14 µs to ~3 (docs/tap-analysis.md, "Speed against Kalico").
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from tapcell.tap import native
from tapcell.tap.robust import median

_C = native.load("toe")  # the compiled grids (c/toe.c), None: the numpy twins run

TOE_WIDTHS_UM = (0.0, 1.0, 2.0, 3.0, 4.5, 6.0, 8.0, 10.0, 13.0, 16.0)
TOE_POWERS = (0.5, 1.0)  # Hertz sphere on flat; a parabolic force onset
_NATIVE_POWERS = (0.5, 1.0)  # the shapes c/toe.c writes out; other TOE_POWERS run the numpy twin


# The prior over the toe's width falls off as exp(-width / WIDTH_PRIOR_SCALE_UM): a toe is taken only as
# wide as the tap shows it. A uniform prior over 0-16 µm let noise buy wide toes on taps that show
# none and read every hard bed high (issue 21: +0.8 µm on the reference taps' clean scenarios, and
# +0.8 µm on a hinge); the scale is chosen by the worst scenario over taplab's and the reference
# taps (docs/tap-analysis.md, "Contact onset"): 4 µm leaves |bias| <= 0.56 µm on every
# should-accept scenario of both sets, 6 µm 0.95, 8 µm 1.18, uniform 2.02.
WIDTH_PRIOR_SCALE_UM = 4.0


def _width_prior(widths_um: tuple[float, ...], scale_um: float | None = WIDTH_PRIOR_SCALE_UM) -> np.ndarray:
    """Each grid width's share of the prior: the span of widths it stands for (half the gaps to its
    neighbours; the grid is finer at narrow toes, and counting every width alike would weigh them
    by the grid, not by the prior) times the density exp(-width / scale_um) (None: uniform over
    0..widest), normalised."""
    w = np.array(widths_um)
    edges = np.concatenate(([w[0]], 0.5 * (w[1:] + w[:-1]), [w[-1]]))
    share = np.diff(edges) * (1.0 if scale_um is None else np.exp(-w / scale_um))
    return share / share.sum()


WIDTH_PRIOR = _width_prior(TOE_WIDTHS_UM)
COARSE_STEP_UM = 0.5
COARSE_BELOW_UM = 3.0  # the sharp estimate reads a toe low: search mostly above it
COARSE_ABOVE_UM = 10.0
PENETRATION_REACH_UM = 30.0  # samples deeper than this in contact are left out (relaxation, hysteresis)
# Samples past break contact that set the baseline. Far enough that an adhesion thread pulling for
# the first tens of µm cannot pass for the baseline (10: mild ooze +4.7 µm, 40: +3.6 µm).
DEPARTURE_REACH_SAMPLES = 40
SUBSAMPLES = 2  # points per conversion window for its average
MAX_LAG_PERIODS = 4.0
# Adhesion (a plastic thread pulling the nozzle after break contact): the force's dip below the
# free-air level, over the first ADHESION_REACH_UM above contact, against the level further up.
ADHESION_FROM_UM = 1.0  # the dip is looked for from this high above contact (the toe's own rounding below)
ADHESION_REACH_UM = 40.0
ADHESION_LEVEL_UM = 100.0  # the free-air level from samples between the reach and this height
ADHESION_RUN_SAMPLES = 5  # the dip is the lowest mean of this many consecutive samples
ADHESION_MIN_LEVEL_SAMPLES = 10
# A thread pulling the whole departure (`thread_pull_g`): heights above contact looked at (µm), and
# the fewest samples there.
THREAD_REACH_UM = (10.0, 60.0)
# Further up the departure (µm above contact): where a thread that lets go no longer pulls, while a
# baseline shift (a cable pulling one way on the way down and another on the way up) still does.
THREAD_FAR_REACH_UM = (60.0, 150.0)
THREAD_MIN_SAMPLES = 5
# All of them, in the order the compiled `adhesion` kernel takes them.
ADHESION_LIMITS = (ADHESION_FROM_UM, ADHESION_REACH_UM, ADHESION_LEVEL_UM, ADHESION_RUN_SAMPLES,
                   ADHESION_MIN_LEVEL_SAMPLES, THREAD_REACH_UM[0], THREAD_REACH_UM[1], THREAD_MIN_SAMPLES)
# The baseline's random walk is weighed in when over the fit it adds as much variance as the white noise
# (0.25 and 0.5 gave the same drift sigma and 0.01 um more on clean taps).
WANDER_SHARE = 1.0
# Variogram lags (samples) for the walk estimate, each up to a third of its segment (the fitted
# line takes most of a walk at longer lags). Not below 4: an ADS1220's sinc3 averages over three
# periods, so neighbouring samples share signal. Up to 40: mains hum (6.4 samples a cycle at 320
# sps, 40 at 2000) and 1/f noise raise short lags like a walk but stop growing. On 30 taps each the
# walk path is taken for 23 cable-drift, 10 clean HX717, 8 clean 2000-sps and 2 hum taps (with
# lags 3-14 and no line correction: 14 of 30 clean 2000-sps, 13 of 30 hum); on clean taps it
# leaves Z as it was (sigma 0.61 um either way on 60 HX717 taps).
WANDER_LAGS = range(4, 41, 4)


# The candidate grid (widths × contacts around the start), built once: contacts vary fastest.
_CONTACT_OFFSETS_UM = np.arange(-COARSE_BELOW_UM, COARSE_ABOVE_UM + 1e-9, COARSE_STEP_UM)
_GRID_OFFSETS_UM = np.tile(_CONTACT_OFFSETS_UM, len(TOE_WIDTHS_UM))
_GRID_WIDTHS_UM = np.repeat(TOE_WIDTHS_UM, len(_CONTACT_OFFSETS_UM))
_SUBSAMPLE_FRACTIONS = (np.arange(SUBSAMPLES) + 0.5) / SUBSAMPLES
_RUN_MEAN_KERNEL = np.full(ADHESION_RUN_SAMPLES, 1.0 / ADHESION_RUN_SAMPLES)
_TOE_PRIOR = np.tile(WIDTH_PRIOR, len(TOE_POWERS))  # per row of the grid: (shape, width)
def _lift_deficits(powers) -> np.ndarray:
    """How far short of its width a toe of each power lifts the linear part: w p / (p + 1), per unit w."""
    return np.array([power / (power + 1.0) for power in powers])


_LIFT_DEFICIT = _lift_deficits(TOE_POWERS)


@dataclass(eq=False, repr=False)
class ToeGridResult:
    """What the toe fit's marginal was computed from, kept for pooling taps (tapcell.tap.pool):
    the contact heights (µm above the halt), the residual per toe (row: shape, width) and height,
    the residual variance it was scaled by, and the prior per toe."""

    contacts_um: np.ndarray
    rss: np.ndarray
    noise_var: float
    prior: np.ndarray
    # `shape_spread_um` of this grid when the fit found it on the way (the kernel: from the minima its
    # marginal found, the same bits as computed from the grid); None: computed from the grid when asked.
    shape_um: float | None = None


@dataclass(eq=False, repr=False)
class ToeFit:
    """The toe model fitted to a pullback (`fit_pullback_toe`): its contact, sigma, onset width and
    stiffness, and the grid it was chosen from."""

    contact_um: float  # height above the halt where the force reaches the baseline
    sigma_um: float
    width_um: float
    power: float
    stiffness_g_um: float
    residual_sigma_g: float
    grid: ToeGridResult | None = None


def toe_shape(depth_um: np.ndarray, width_um, power: float) -> np.ndarray:
    """Force / linear stiffness at a depth into contact: power-law toe, then linear (slope 1).

    width_um may be an array broadcasting against depth_um (a width of 0 is a hinge).
    """
    return toe_shapes(depth_um, width_um, (power,))[0]


def toe_shapes(depth_um: np.ndarray, width_um, powers) -> np.ndarray:
    """`toe_shape` for each of `powers` (stacked on a new first axis), sharing the work they have in common."""
    pressed_um = np.maximum(depth_um, 0.0)
    width_um = np.maximum(width_um, 1e-9)
    u = np.divide(pressed_um, width_um)  # depth over width, 1 past the toe
    np.minimum(u, 1.0, out=u)
    beyond_um = np.subtract(pressed_um, width_um, out=pressed_um)  # the linear part past the toe
    np.maximum(beyond_um, 0.0, out=beyond_um)
    shapes = np.empty((len(powers), *beyond_um.shape))
    # In place (out=): these arrays hold thousands of values and run once per candidate grid.
    for row, power in zip(shapes, powers):
        if power == 0.5:
            np.sqrt(u, out=row)  # the Hertz toe without a general power (the hot path)
            row *= u
        elif power == 1.0:
            np.multiply(u, u, out=row)
        else:
            np.power(u, power + 1.0, out=row)
        row *= width_um * (1.0 / (power + 1.0))  # the widths are few: scale them, not the whole grid
        row += beyond_um
    return shapes


def lag_from_halt_s(compression_end_time_s: float, halt_time_s: float, period_s: float,
                    pipeline_s: float = 0.0) -> float | None:
    """The sensor's whole lag (s) from P2 and the halt, or None when it is not plausible: more than
    MAX_LAG_PERIODS (the conversion window's part) plus `pipeline_s` (a pipeline's delay, a time
    whatever the rate: 4 periods alone are 1 ms at 4000 sps, less than one sample's transfer)."""
    lag_s = compression_end_time_s - halt_time_s
    if not math.isfinite(lag_s) or not 0.0 <= lag_s <= MAX_LAG_PERIODS * period_s + pipeline_s:
        return None
    return lag_s


@dataclass(eq=False, repr=False)
class _Projected:
    """The samples and linear columns of one toe fit, prepared once for every candidate toe.

    basis: the linear columns beside the toe (orthonormal: the baseline, and the drift unless it
    is known); the force has them projected out (`y_free`). For a toe column h the fit needs only
    h·h - |hᵀB|² and h·y_free (variable projection). For a candidate (contact c, toe width w) the
    samples fall in three runs along the pullback: pressed past the toe (h = a - x, a = c - the
    toe's lift deficit: they enter through prefix sums of 1, x, x², y, x y, B, x B), in the toe
    (evaluated, a few samples per candidate) and in free air (h = 0: nothing to add).
    """

    window_um: np.ndarray  # (n, SUBSAMPLES) heights each sample averages over
    points_um: np.ndarray  # the same heights subsample-major, flat: subsample k of sample i at k n + i
    y_free: np.ndarray
    basis_rows: np.ndarray  # (m, n): the basis, one column per row
    # Sample i and every one before it are pressed past a toe ending at or above pressed_to_um[i]
    # (running max of the windows' tops); from i on every sample is free of a contact at or below
    # free_from_um[i] (running min, from the end, of the windows' bottoms). Both sorted, so one
    # searchsorted per candidate bounds its run in the toe, whatever the order of the samples.
    pressed_to_um: np.ndarray
    free_from_um: np.ndarray
    pressed_sums: np.ndarray  # (5 + 2m, n + 1) prefix sums of 1, x, x², y, x y, B (m), x B (m)
    yy: float

    @classmethod
    def prepare(cls, window_um: np.ndarray, x_mid: np.ndarray, basis: np.ndarray, y: np.ndarray) -> _Projected:
        y_free = y - basis @ (basis.T @ y)
        columns = np.vstack((np.ones_like(x_mid), x_mid, x_mid * x_mid, y_free, x_mid * y_free, basis.T,
                             x_mid * basis.T))
        sums = np.zeros((len(columns), len(x_mid) + 1))
        np.cumsum(columns, axis=1, out=sums[:, 1:])
        pressed_to = np.maximum.accumulate(window_um[:, -1])
        free_from = np.minimum.accumulate(window_um[::-1, 0])[::-1]
        return cls(window_um, window_um.T.ravel(), y_free, np.ascontiguousarray(basis.T), pressed_to, free_from, sums,
                   float(y_free @ y_free))


def _solvable(hh, hh_all):
    """A candidate whose toe column is (nearly) a combination of the others cannot be solved
    (hh: its squared norm with the basis projected out; floats or arrays)."""
    return hh > 1e-9 * (hh_all + 1e-300)


def _solve(hh_all, h_basis, hy, yy: float):
    """Residual sum of squares and toe stiffness of the linear solve from a toe column's sums
    (h·h, Bᵀh (m, ...), h·y_free); inf where the toe would pull, or cannot be told from B."""
    hh = hh_all - (h_basis * h_basis).sum(axis=0)
    usable = _solvable(hh, hh_all)
    stiffness = np.divide(hy, hh, out=np.zeros_like(hy), where=usable)
    rss = np.where(usable & (stiffness > 0.0), yy - stiffness * hy, np.inf)  # must press, not pull
    return rss, stiffness


def _rss_over_contacts(contacts_um: np.ndarray, widths_um: np.ndarray, data: _Projected):
    """Residual sum of squares of the linear solve at every (toe shape, width, candidate contact)
    at once: (len(TOE_POWERS), candidates). contacts_um, widths_um: equal-length 1-D arrays (one
    entry per candidate).

    Only the samples in each candidate's toe are evaluated, laid end to end in one flat array
    (`owner`: the candidate of each), and summed per candidate by bincount; the toe's run of
    samples depends on its width, not its shape, so every shape shares it.
    """
    candidates = len(contacts_um)
    first = data.pressed_to_um.searchsorted(contacts_um - widths_um, side="right")
    counts = np.maximum(data.free_from_um.searchsorted(contacts_um, side="left") - first, 0)
    owner = np.repeat(np.arange(candidates), counts)
    ends = counts.cumsum()
    index = np.arange(ends[-1]) + np.repeat(first - (ends - counts), counts)
    # One flat array, subsample-major (every array the same 1-D shape: numpy's fastest loops), and
    # take rather than fancy indexing (several times faster on these small arrays).
    in_toe = len(index)
    subsamples = len(data.points_um) // len(data.y_free)
    owners = np.concatenate([owner] * subsamples)
    depth = contacts_um.take(owners) - data.points_um.take(np.concatenate(
        [index + k * len(data.y_free) for k in range(subsamples)]))
    toe_widths = widths_um.take(owners)
    y_free, basis_rows = data.y_free.take(index), data.basis_rows.take(index, axis=1)
    pressed = data.pressed_sums.take(first, axis=1)  # 1, x, x², y, x y, B (m), x B (m) per candidate
    m = len(basis_rows)
    # Every shape's column over the run, (power, sample in a toe); the sums per (power, candidate)
    # by one bincount each, the powers' candidates numbered after one another.
    h = toe_shapes(depth, toe_widths, TOE_POWERS).reshape(len(TOE_POWERS), subsamples, in_toe).sum(axis=1)
    h *= 1.0 / subsamples
    owner_of_shape = (owner + candidates * np.arange(len(TOE_POWERS))[:, None]).ravel()
    bins = len(TOE_POWERS) * candidates

    def sum_per_candidate(values: np.ndarray) -> np.ndarray:
        # (in integers when no candidate has a sample in its toe: the pressed part's floats are
        # added to it, never into it)
        return np.bincount(owner_of_shape, values.ravel(), bins).reshape(len(TOE_POWERS), candidates)

    # The pressed samples: h = a - x with a = c - w p / (p + 1) (the toe lifts w / (p + 1), not w).
    a = contacts_um - widths_um * _LIFT_DEFICIT[:, None]  # (power, candidate)
    h_basis = np.array([sum_per_candidate(h * column) for column in basis_rows]) + (
        a * pressed[5:5 + m, None] - pressed[5 + m:, None])
    hh_all = sum_per_candidate(h * h) + (a * pressed[0] - 2.0 * pressed[1]) * a + pressed[2]
    hy = sum_per_candidate(h * y_free) + a * pressed[3] - pressed[4]
    return _solve(hh_all, h_basis, hy, data.yy)[0]


def _stiffness_at(contact_um: float, width_um: float, power: float, data: _Projected) -> float:
    """The toe's stiffness at one contact height and toe, its column evaluated over every sample."""
    h = toe_shape(contact_um - data.window_um, width_um, power).sum(axis=1) * (1.0 / data.window_um.shape[1])
    h_basis = data.basis_rows @ h
    hh_all = float(h @ h)
    hh = hh_all - float(h_basis @ h_basis)
    return float(h @ data.y_free) / hh if _solvable(hh, hh_all) else 0.0


@dataclass  # not frozen: a frozen dataclass sets each field through object.__setattr__ (two a tap)
class Wander:
    """White noise plus a random walk of the baseline (thermal drift of the cell, a cable settling).

    white_var_g2: per sample; walk_var_g2: the walk's variance growth per sample. Over the ~100
    samples of a toe fit a walk of a few g/sqrt(s) bends the baseline by as much as the white
    noise, and an ordinary least-squares fit reads the bend as toe (bowden/cable drift taps of the
    independent generator, 60 on seed 5: sigma 0.85 um; weighed by the true covariance 0.71; by
    the one estimated from the tap's free air, `wander_from_free_air`, 0.70).
    """

    white_var_g2: float
    walk_var_g2: float

    def matters(self, samples: int) -> bool:
        """Whether the walk over `samples` adds a noticeable share to the white variance."""
        return self.walk_var_g2 * samples > WANDER_SHARE * self.white_var_g2


def wander_from_free_air(segments: list[np.ndarray]) -> Wander | None:
    """White and random-walk variances from force samples in free air (each segment evenly sampled).

    Each segment's straight line is removed (Z-proportional drift, a steady trend); the variogram
    of what is left, E[(r[i+L] - r[i])^2], is pooled over the segments for WANDER_LAGS and fitted
    by least squares to its exact expectation under white noise plus a walk (removing the line
    takes a share of both, most of the walk at lags near the segment's length). None when the
    segments are too short.
    """
    return wander_from_variograms([free_air_variogram(force_g) for force_g in segments])


FreeAirVariogram = tuple[list[tuple[float, float]], list[float]]


def free_air_variogram(force_g: np.ndarray) -> FreeAirVariogram:
    """One free-air segment's share of `wander_from_free_air`: per lag, (its expectation for unit
    white noise, for a unit walk) and the measured mean squared difference; empty when too short.
    Kept apart so that estimates pooling different segments share the work."""
    n = len(force_g)
    lags = _variogram_lags(n)
    if lags is None:
        return [], []
    if _C is not None:
        return list(_detrended_variogram(n, lags)), _C.lag_mean_squares(force_g, lags)
    i = np.arange(n, dtype=float) - 0.5 * (n - 1)
    r = force_g - force_g.mean() - i * (i @ force_g) / (i @ i)
    # Every lag's differences in one flat array, averaged per lag by bincount.
    later, earlier, lag_of, pairs = _lag_pairs(n, lags)
    d = r.take(later) - r.take(earlier)
    return list(_detrended_variogram(n, lags)), (np.bincount(lag_of, d * d, len(lags)) / pairs).tolist()


def wander_from_variograms(variograms: list[FreeAirVariogram]) -> Wander | None:
    """The white and walk variances that fit the segments' variograms pooled (`wander_from_free_air`)."""
    return wanders_from_variograms(variograms)[-1]


def wanders_from_variograms(variograms: list[FreeAirVariogram]) -> list[Wander | None]:
    """`wander_from_variograms` of the first variogram alone, of the first two pooled, ..., of all
    pooled: each sum continues the one before (the same sums in the same order as each pooling on
    its own, the shared rows summed once)."""
    # Least squares in two unknowns by the normal equations, in plain floats: np.linalg.lstsq
    # costs ~0.05-0.4 ms a call here (LAPACK's set-up, its threads waking on a busy machine).
    # One loop sums all five in the rows' order (as five sum() calls would, at a third of the cost).
    ww = wk = kk = wv = kv = 0.0
    rows = 0
    wanders = []
    for expected, measured in variograms:
        rows += len(expected)
        for (white, walk), value in zip(expected, measured):
            ww += white * white
            wk += white * walk
            kk += walk * walk
            wv += white * value
            kv += walk * value
        wanders.append(_wander_of_normal_sums(rows, ww, wk, kk, wv, kv))
    return wanders


def _wander_of_normal_sums(rows: int, ww: float, wk: float, kk: float, wv: float, kv: float) -> Wander | None:
    if not rows:
        return None
    determinant = ww * kk - wk * wk
    if not determinant > 0.0:
        return None
    white, walk = (kk * wv - wk * kv) / determinant, (ww * kv - wk * wv) / determinant
    if not white > 0.0:
        return None
    return Wander(white_var_g2=float(white), walk_var_g2=max(float(walk), 0.0))


def height_pull_variogram(samples: int, step_um: float) -> list[float]:
    """Per lag of `free_air_variogram` (same samples), what a pull curved in height adds to it per
    unit of its curvature squared: a pull k x² / 2 over samples `step_um` apart in height, its line
    removed, differs over L samples by k step² L (2 i + L - n + 1) / 2, whose mean square is
    k² step⁴ L² ((n - L)² - 1) / 12."""
    return [per_step4 * step_um ** 4 for per_step4 in _height_pull_per_step4(samples)]


@functools.lru_cache(maxsize=4096)
def _height_pull_per_step4(samples: int) -> tuple[float, ...]:
    """`height_pull_variogram` per unit step⁴ (in the same operations: the step⁴ multiplies last).
    Cached: it depends on the samples alone."""
    lags = _variogram_lags(samples)
    return tuple(lag * lag * ((samples - lag) ** 2 - 1) / 12.0 for lag in lags) if lags else ()


def _variogram_lags(samples: int) -> tuple[int, ...] | None:
    """The lags of `free_air_variogram` over this many samples, None when too few."""
    lags = tuple(lag for lag in WANDER_LAGS if 3 * lag <= samples)  # longer ones: the line takes the walk
    return lags if len(lags) >= 3 else None


@functools.lru_cache(maxsize=4096)
def _free_air_model(samples: int) -> np.ndarray:
    """What `free_air_walks`'s kernel takes of a free-air segment of this many samples, per lag of
    `free_air_variogram`: (lag, its expectation for unit white noise, for a unit walk,
    `_height_pull_per_step4`); no rows when too short. Cached: it depends on the samples alone."""
    lags = _variogram_lags(samples)
    if lags is None:
        return np.empty((0, 4))
    model = np.empty((len(lags), 4))
    # One kernel call when built (c/toe.c `free_air_model`: the columns below, the same bits; a miss
    # is one tap in four of a run); past the kernel's exact sums, or without it, the columns here.
    if _C is not None and _C.free_air_model(samples, lags, model):
        return model
    model[:, 0] = lags
    model[:, 1:3] = _detrended_variogram(samples, lags)
    model[:, 3] = _height_pull_per_step4(samples)
    return model


def free_air_walks(approach_g: np.ndarray, departure_g: np.ndarray, steps_um: tuple[float, float]
                   ) -> tuple[Wander | None, Wander | None]:
    """The white noise and the walk of the approach's and the departure's free air with a pull
    curved in height beside them (`walk_beside_height_pull`; steps_um: the height each crosses per
    sample), and of the approach's alone (`wander_from_variograms`).

    One kernel call when built (c/toe.c `free_air_walks`: the variograms measured, the sums and
    both least squares in the twin's order, the variograms' expectations from `_free_air_model`);
    the code below is its numpy twin. They agree to rounding: the kernel measures each lag's
    differences with the line taken out of each, numpy out of each sample first."""
    if _C is not None:
        beside, approach = _C.free_air_walks(approach_g, departure_g, _free_air_model(len(approach_g)),
                                             _free_air_model(len(departure_g)), *steps_um)
        return (None if beside is None else Wander(*beside)), (None if approach is None else Wander(*approach))
    approach_variogram, departure_variogram = free_air_variogram(approach_g), free_air_variogram(departure_g)
    segments = [(approach_variogram, len(approach_g), steps_um[0]), (departure_variogram, len(departure_g), steps_um[1])]
    return walk_beside_height_pull(segments), wander_from_variograms([approach_variogram])


def walk_beside_height_pull(segments: list[tuple[FreeAirVariogram, int, float]]) -> Wander | None:
    """The white noise and the walk in time of free-air segments, each of its samples crossed
    `step_um` apart in height ((`free_air_variogram`, samples, step_um) per segment), with a pull
    curved in height beside them.

    A bowden tube or cable pulls with the height, and not along a straight line in it: over the
    approach, which crosses 15x the height per sample the pullback does, the curve's departure from
    the line grows with the lag like a walk's, and pooled with the departure it passed for one (the
    reference set's bowden taps: a walk 18-36x the departure's own). Its share of each variogram
    grows as step⁴ (`height_pull_variogram`), a walk's as the lag alone, so segments crossed at
    different speeds tell them apart: the three are fitted together (least squares, none negative)
    and the walk alone is the baseline's.
    """
    # The sums of products the least squares need, in one loop of plain floats (a score of rows).
    ww = wk = wp = kk = kp = pp = wy = ky = py = yy = 0.0
    rows = 0
    for (expected, measured), samples, step_um in segments:
        rows += len(expected)
        for (w, k), p, y in zip(expected, height_pull_variogram(samples, step_um), measured):
            ww += w * w
            wk += w * k
            wp += w * p
            kk += k * k
            kp += k * p
            pp += p * p
            wy += w * y
            ky += k * y
            py += p * y
            yy += y * y
    if rows < 2:
        return None
    found = _white_walk_pull(ww, wk, wp, kk, kp, pp, wy, ky, py, yy)
    return None if found is None else Wander(white_var_g2=found[0], walk_var_g2=found[1])


def _white_walk_pull(ww: float, wk: float, wp: float, kk: float, kp: float, pp: float,
                     wy: float, ky: float, py: float, yy: float) -> tuple[float, float] | None:
    """(white, walk) of the least squares in white, walk and pull with no share negative, from the
    sums of products (w, k, p: the three columns, y: measured): the fit of all three when none is
    negative, else, of the fits of the white with the walk, with the pull or alone whose shares are
    all positive, the one that leaves the least residual. Each column scaled to unit size, the
    normal equations solved by Cramer's rule in plain floats (numpy's per-call cost would be most of
    it: this runs on every tap)."""
    if not (ww > 0.0 and kk > 0.0 and pp > 0.0):
        return None
    sw, sk, sp = math.sqrt(ww), math.sqrt(kk), math.sqrt(pp)
    a, b, c = wk / (sw * sk), wp / (sw * sp), kp / (sk * sp)  # the scaled columns' products
    u, v, w = wy / sw, ky / sk, py / sp
    determinant = 1.0 - a * a - b * b - c * c + 2.0 * a * b * c
    if determinant > 1e-12:
        white = (u * (1.0 - c * c) - a * (v - c * w) + b * (v * c - w)) / determinant
        walk = (v - c * w - u * (a - c * b) + b * (a * w - v * b)) / determinant
        pull = (w - c * v - a * (a * w - v * b) + u * (a * c - b)) / determinant
        if white > 0.0 and walk >= 0.0 and pull >= 0.0:
            return white / sw, walk / sk
    best = None  # (residual, white, walk)
    for r, q, walk_column in ((a, v, True), (b, w, False)):  # the white with the walk, with the pull
        if 1.0 - r * r > 1e-12:
            white, other = (u - r * q) / (1.0 - r * r), (q - r * u) / (1.0 - r * r)
            if white > 0.0 and other >= 0.0:
                residual = yy - white * u - other * q
                if best is None or residual < best[0]:
                    best = (residual, white / sw, other / sk if walk_column else 0.0)
    if u > 0.0 and (best is None or yy - u * u < best[0]):  # the white alone
        best = (yy - u * u, u / sw, 0.0)
    return None if best is None else best[1:]


@functools.lru_cache(maxsize=4096)
def _lag_pairs(n: int, lags: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(i + L, i, the lag's number, pairs per lag) for every lag and i < n - L, laid end to end.
    Cached: it depends on n alone."""
    pairs = np.array([n - lag for lag in lags])
    lag_of = np.repeat(np.arange(len(lags)), pairs)
    earlier = np.concatenate([np.arange(n - lag) for lag in lags])
    return earlier + np.repeat(lags, pairs), earlier, lag_of, pairs


@functools.lru_cache(maxsize=4096)
def _detrended_variogram(n: int, lags: tuple[int, ...]) -> tuple[tuple[float, float], ...]:
    """Mean E[(r[i+L] - r[i])^2] per lag once a line is fitted out of n samples: (for unit white
    noise, for a unit random walk (covariance min(i, j))) per lag. Cached: it depends on n alone.

    In closed form (the n × n covariance algebra costs milliseconds a tap): with t the centred
    sample index, S = Σt² and P the line's projection, a difference d = e[i+L] - e[i] leaves the
    fit as v = d - t L / S (P d = t L / S). White: |v|² = 2 - L²/S. Walk: vᵀCv = L - 2 (L/S) tᵀCd
    + (L/S)² tᵀCt, where tᵀCd = f(i+L) - f(i) with f(m) = Σ t_k min(k, m), a running sum.

    In C when built (`detrended_variogram`: the same bits, its dot products exact; a miss of this
    cache cost ~50 µs, a quarter of the taps of a run over the reference set pay one); the code below is
    its twin, and what runs for segments too long for the kernel's exact sums (past ~2,000 samples).
    """
    if _C is not None:
        found = _C.detrended_variogram(n, lags)
        if found is not None:
            return found
    k = np.arange(n, dtype=float)
    t = k - 0.5 * (n - 1)
    s = float(t @ t)
    f = np.cumsum(k * t) - k * np.cumsum(t)  # f(m) = Σ t_k min(k, m) (Σ t = 0)
    f_sums = np.concatenate(([0.0], np.cumsum(f)))  # f_sums[m] = Σ f(k) over k < m
    lag = np.asarray(lags, dtype=float)
    at = np.asarray(lags)
    mean_df = (f_sums[n] - f_sums[at] - f_sums[n - at]) / (n - lag)  # mean of f(i+L) - f(i), i < n - L
    white = 2.0 - lag * lag / s
    walk = lag - 2.0 * (lag / s) * mean_df + (lag / s) ** 2 * float(t @ f)
    return tuple(zip(white.tolist(), walk.tolist()))


@dataclass(eq=False, repr=False)
class _Whitened:
    """`_Projected` under the metric of white + random-walk noise (generalised least squares).

    Differencing consecutive samples removes the baseline exactly and turns white noise σ² plus
    a walk of q per sample into noise with a tridiagonal covariance (2σ² + q on the diagonal, -σ²
    beside it), whose Cholesky factor is bidiagonal: whitening is then a recursion along the
    samples. The toe column keeps its three parts in time order: pressed past every toe first
    (h = a - x: its differences do not depend on the candidate), the in-between samples, then free
    air (h = 0: whitened, it decays geometrically). So each candidate costs a recursion over the
    in-between samples only; the pressed part and the free tail enter through precomputed sums.
    Residuals come out in units of the white noise variance.
    """

    near_window_um: np.ndarray  # (n, SUBSAMPLES) heights of the in-between samples
    first_near: int  # index of the first in-between sample (= number of pressed samples)
    diag: np.ndarray  # the bidiagonal Cholesky factor of the differences' covariance
    sub: np.ndarray
    x_mid: np.ndarray
    y_white: np.ndarray  # the force, differenced and whitened
    pressed_z: float  # the whitened toe column at the last pressed-pressed difference
    pressed_zz: float
    pressed_zy: float
    tail_zz: float  # free tail: Σ z² and Σ z·y_white per unit of the column at its start
    tail_zy: float
    yy: float

    @classmethod
    def prepare(cls, window_um: np.ndarray, x_mid: np.ndarray, y: np.ndarray, wander: Wander,
                lowest_contact_um: float, highest_contact_um: float, widest_um: float) -> _Whitened | None:
        pressed = window_um.max(axis=1) <= lowest_contact_um - widest_um
        near = ~pressed & (window_um.min(axis=1) < highest_contact_um)
        first, count = int(np.count_nonzero(pressed)), int(np.count_nonzero(near))
        if count < 2 or not (pressed[:first].all() and near[first:first + count].all()):
            return None  # not pressed, then in between, then free: not a plain rise
        m = len(y) - 1
        diag, sub = [math.sqrt(2.0 * wander.white_var_g2 + wander.walk_var_g2)], [0.0]  # plain floats: m steps
        for _ in range(1, m):
            sub.append(-wander.white_var_g2 / diag[-1])
            diag.append(math.sqrt(2.0 * wander.white_var_g2 + wander.walk_var_g2 - sub[-1] * sub[-1]))
        diag, sub = np.array(diag), np.array(sub)
        y_white = _whiten(np.diff(y)[None], diag, sub, 0, 0.0)[0]
        pressed_z = pressed_zz = pressed_zy = 0.0
        if first >= 2:
            z = _whiten(-np.diff(x_mid[:first])[None], diag, sub, 0, 0.0)[0]
            pressed_z, pressed_zz, pressed_zy = float(z[-1]), float(z @ z), float(z @ y_white[:first - 1])
        # Free air after the last in-between sample: z_j = z_k · Π (-sub / diag) over the tail.
        tail_start = first + count  # the first difference wholly in free air
        gain = np.cumprod(-sub[tail_start:] / diag[tail_start:])
        return cls(window_um[near], first, diag, sub, x_mid, y_white, pressed_z, pressed_zz, pressed_zy,
                   float(gain @ gain), float(gain @ y_white[tail_start:]), float(y_white @ y_white))


def _whiten(differences: np.ndarray, diag: np.ndarray, sub: np.ndarray, j0: int, z_before) -> np.ndarray:
    """Forward substitution through the bidiagonal factor for differences j0.. (rows: candidates).

    One row runs on plain floats (numpy's per-call cost would dominate a step on one value); many
    rows step a column at a time, held as contiguous rows.
    """
    steps = differences.shape[1]
    subs, diags = sub[j0:j0 + steps].tolist(), diag[j0:j0 + steps].tolist()
    if len(differences) == 1:
        whitened, previous = [], float(z_before)
        for difference, s, d in zip(differences[0].tolist(), subs, diags):
            previous = (difference - s * previous) / d
            whitened.append(previous)
        return np.array([whitened])
    columns = differences.T.copy()  # (step, candidate)
    previous = z_before
    for column, s, d in zip(columns, subs, diags):
        column -= s * previous
        column /= d
        previous = column
    return columns.T


def _rss_whitened(contacts_um, widths_um, powers: tuple[float, ...], data: _Whitened):
    """`_rss_over_contacts` under the noise's metric (residuals in white-noise units), and the
    stiffness, both (shape, candidate): every shape's candidates go through one recursion."""
    # (subsample, candidate, in-between sample): the long axes innermost
    depth = contacts_um[:, None] - data.near_window_um.T[:, None, :]
    # (shape × candidate, in-between sample)
    h = toe_shapes(depth, widths_um[:, None], powers).mean(axis=1).reshape(len(powers) * len(contacts_um), -1)
    first = data.first_near
    columns = [h]
    if first:  # the pressed sample before: h = a - x, with a = c - the toe's lift deficit
        a = contacts_um - widths_um * _lift_deficits(powers)[:, None]
        columns.insert(0, (a - data.x_mid[first - 1]).reshape(-1, 1))
    if first + h.shape[1] < len(data.x_mid):  # the free sample after: h = 0
        columns.append(np.zeros((len(h), 1)))
    column = np.hstack(columns)
    j0 = max(first - 1, 0)
    z = _whiten(np.diff(column, axis=1), data.diag, data.sub, j0, data.pressed_z)
    z_end = z[:, -1]
    hh = data.pressed_zz + np.einsum("cn,cn->c", z, z) + z_end * z_end * data.tail_zz
    hy = data.pressed_zy + z @ data.y_white[j0:j0 + z.shape[1]] + z_end * data.tail_zy
    usable = hh > 1e-12
    stiffness = np.divide(hy, hh, out=np.zeros_like(hy), where=usable)
    rss = np.where(usable & (stiffness > 0.0), data.yy - stiffness * hy, np.inf)
    return rss.reshape(len(powers), -1), stiffness.reshape(len(powers), -1)


def fit_toe(x_lo_um: np.ndarray, x_hi_um: np.ndarray, force_g: np.ndarray, contact0_um: float,
            spacing_um: float, drift_g_um: float | None = None, wander: Wander | None = None) -> ToeFit | None:
    """The toe model over pullback samples (conversion windows [x_lo, x_hi], µm above the halt).

    drift_g_um: the force's slope against height in free air when known (the approach shows it);
    None: fitted over the departure with the rest. wander: the baseline's random walk when the
    tap shows one (`Wander.matters`); the fit then weighs the samples by its covariance (with a
    known drift only: the walk-weighted fit has no drift column).
    """
    if _C is not None and TOE_POWERS == _NATIVE_POWERS:
        return _fit_toe_native(x_lo_um, x_hi_um, force_g, contact0_um, spacing_um, drift_g_um, wander)
    # The numpy twin of `_fit_toe_native`.
    keep = (x_lo_um < contact0_um + COARSE_ABOVE_UM + DEPARTURE_REACH_SAMPLES * spacing_um) & (
        x_hi_um > contact0_um - PENETRATION_REACH_UM)
    x_lo_um, x_hi_um, force_g = x_lo_um[keep], x_hi_um[keep], force_g[keep]
    samples = len(force_g)
    if samples < 8:
        return None
    contacts_um = contact0_um + _CONTACT_OFFSETS_UM
    grid_c = contact0_um + _GRID_OFFSETS_UM
    # The walk-weighted fit differences the samples (the baseline drops out) and has no drift column:
    # a drift to be fitted (None) runs the plain fit, which has one.
    walk = wander if wander is not None and drift_g_um is not None and wander.matters(samples) else None
    rss_grid, g2_per_unit, stiffness_at = _toe_grid(x_lo_um, x_hi_um, force_g, drift_g_um, walk, contacts_um, grid_c)
    # The least residual's (power, width): flat index arithmetic (np.unravel_index costs more here).
    best = int(rss_grid.argmin())
    least = float(rss_grid.flat[best])
    if not math.isfinite(least):
        return None
    power_index, width_index = divmod(best // len(_CONTACT_OFFSETS_UM), len(TOE_WIDTHS_UM))
    dof = max(samples - 4 - (2 if drift_g_um is None else 1), 1)  # the toe's c, w, p, k and the basis
    residual_var = max(least / dof, 1e-12)
    rss_rows = rss_grid.reshape(-1, len(contacts_um))
    contact, sigma = marginal_contact_um(contacts_um, rss_rows, residual_var, _TOE_PRIOR)
    if contact is None:
        return None
    width, power = TOE_WIDTHS_UM[width_index], TOE_POWERS[power_index]
    stiffness = stiffness_at(contact, width, power)
    return ToeFit(contact_um=contact, sigma_um=sigma, width_um=float(width), power=float(power),
                  stiffness_g_um=stiffness, residual_sigma_g=math.sqrt(residual_var * g2_per_unit),
                  grid=ToeGridResult(contacts_um, rss_rows, residual_var, _TOE_PRIOR))


# fit_toe's grid and limits as the kernel takes them (c/toe.c `fit`).
_FIT_GRID = (COARSE_ABOVE_UM, DEPARTURE_REACH_SAMPLES, PENETRATION_REACH_UM, WANDER_SHARE, SUBSAMPLES, 8,
             _CONTACT_OFFSETS_UM, np.array(TOE_WIDTHS_UM), _TOE_PRIOR)


def _fit_toe_native(x_lo_um: np.ndarray, x_hi_um: np.ndarray, force_g: np.ndarray, contact0_um: float,
                    spacing_um: float, drift_g_um: float | None, wander: Wander | None) -> ToeFit | None:
    """`fit_toe` in one kernel call (TOE_POWERS must be `_NATIVE_POWERS`): the samples kept, the
    grid, the least residual, the marginal contact and its stiffness, where the twin makes a score
    of numpy calls. The kernel repeats the twin's sums where it keeps them (the keep, the candidates,
    the marginal) and sums the grid's in another order: the fits agree to rounding
    (tests/tap/test_native_toe.py)."""
    contacts_um = np.empty(len(_CONTACT_OFFSETS_UM))
    rss = np.empty((len(_TOE_PRIOR), len(_CONTACT_OFFSETS_UM)))
    walk = (math.nan, math.nan) if wander is None else (wander.white_var_g2, wander.walk_var_g2)
    found = _C.fit(x_lo_um, x_hi_um, force_g, contact0_um, spacing_um, math.nan if drift_g_um is None else drift_g_um,
                   *walk, _FIT_GRID, contacts_um, rss)
    if found is None:
        return None
    contact, sigma, power_index, width_index, stiffness, residual_var, residual_sigma, shape_um = found
    # Positional (a dataclass's keywords cost three times as much): contact, sigma, width, power,
    # stiffness, residual sigma, grid.
    return ToeFit(contact, sigma, float(TOE_WIDTHS_UM[width_index]), float(TOE_POWERS[power_index]), stiffness,
                  residual_sigma, ToeGridResult(contacts_um, rss, residual_var, _TOE_PRIOR, shape_um))


def shape_spread_um(contacts_um: np.ndarray, rss_rows: np.ndarray, noise_var: float) -> float:
    """Half the range of the contact over the toe's shape assumptions: the marginal with each
    shape of TOE_POWERS alone (issue 21: z_sigma_um holds what the model's assumptions move; its
    shape part, tapcell.tap.uncertainty).

    The marginal weighs the shapes by their likelihood, and on a tap that fits one shape clearly
    its sd is that shape's alone, however far the other would put the contact (the real Voron
    capture: 0.11 um, while a parabolic toe reads it 2.8 um higher).

    One kernel call when built (`marginal_contact_and_spread`: each toe's minimum found once for
    both shapes, where the twin below makes two marginal calls); the code below is its numpy twin."""
    widths = len(TOE_WIDTHS_UM)
    if _C is not None and len(TOE_POWERS) * widths == len(rss_rows):
        # The kernel's third number; None: no toe has a minimum, so neither shape has one.
        found = _C.marginal_contact_and_spread(contacts_um, np.ascontiguousarray(rss_rows, dtype=float), noise_var,
                                               _TOE_PRIOR, len(TOE_POWERS))
        return 0.0 if found is None else found[2]
    contacts = [marginal_contact_um(contacts_um, rss_rows[k * widths:(k + 1) * widths], noise_var, WIDTH_PRIOR)[0]
                for k in range(len(TOE_POWERS))]
    known = [c for c in contacts if c is not None]
    return 0.5 * (max(known) - min(known)) if len(known) > 1 else 0.0


ToeGrid = tuple[np.ndarray, float, Callable[[float, float, float], float]]


def _toe_grid(x_lo_um: np.ndarray, x_hi_um: np.ndarray, force_g: np.ndarray, drift_g_um: float | None,
              wander: Wander | None, contacts_um: np.ndarray, grid_c: np.ndarray) -> ToeGrid:
    """The residual at every candidate toe, (len(TOE_POWERS), candidates); the residual's unit (g²,
    or the white variance once whitened); and the toe stiffness at one (contact, width, power).

    The samples as `fit_toe` keeps them; drift_g_um: the known drift, None to fit it with the
    baseline. wander: the walk to weigh the samples by, None for white noise. The numpy twin of
    the kernel's grids (c/toe.c `fit`).
    """
    window_um = x_lo_um[:, None] + (x_hi_um - x_lo_um)[:, None] * _SUBSAMPLE_FRACTIONS
    x_mid = 0.5 * (x_lo_um + x_hi_um)
    y = force_g if drift_g_um is None else force_g - drift_g_um * x_mid
    whitened = None
    if wander is not None:
        whitened = _Whitened.prepare(window_um, x_mid, y, wander, contacts_um[0], contacts_um[-1], TOE_WIDTHS_UM[-1])
    if whitened is not None:
        def whitened_stiffness(contact_um: float, width_um: float, power: float) -> float:
            return float(_rss_whitened(np.array([contact_um]), np.array([width_um]), (power,), whitened)[1][0, 0])

        return _rss_whitened(grid_c, _GRID_WIDTHS_UM, TOE_POWERS, whitened)[0], wander.white_var_g2, whitened_stiffness
    if drift_g_um is None:
        basis = np.linalg.qr(np.column_stack((np.ones_like(x_mid), x_mid - x_mid.mean())))[0]
    else:
        basis = np.full((len(y), 1), 1.0 / math.sqrt(len(y)))
    data = _Projected.prepare(window_um, x_mid, basis, y)
    return _rss_over_contacts(grid_c, _GRID_WIDTHS_UM, data), 1.0, functools.partial(_stiffness_at, data=data)


def marginal_contact_um(contacts_um: np.ndarray, rss: np.ndarray, noise_var: float,
                        prior: np.ndarray | None = None) -> tuple[float | None, float]:
    """Mean and sd of the contact height with the toe (width, shape) marginalised out.

    rss: (toes, contacts) residual sums on an even grid of contact heights. Per toe, a parabola
    through its least residual and the two neighbours gives that toe's best height, its residual
    and its curvature (a Gaussian in c, the Laplace approximation); each toe is weighted by its
    likelihood exp(-rss / 2 noise_var) times its width in c. The mean over toes is less noisy than
    the single best toe (the toe width and the contact height trade off along a flat valley, and
    noise moves the argmin along it), and the sd holds that trade-off: an honest sigma. prior: a
    weight per toe (row), e.g. `WIDTH_PRIOR` for each shape; None: every toe alike.
    """
    if _C is not None:
        prior = np.ones(len(rss)) if prior is None else prior
        mean_sd = _C.marginal_contact(contacts_um, np.ascontiguousarray(rss, dtype=float), noise_var, prior)
        return (None, COARSE_STEP_UM) if mean_sd is None else mean_sd
    prior = [1.0] * len(rss) if prior is None else prior.tolist()
    toes = [(*toe, row_prior) for toe, row_prior in zip(toe_minima(contacts_um, rss, noise_var), prior)
            if toe is not None]
    if not toes:
        return None, COARSE_STEP_UM
    least = min(toe[1] for toe in toes)
    weights = [math.exp(-(lowest - least) / (2.0 * noise_var)) * math.sqrt(var) * toe_prior
               for _, lowest, var, toe_prior in toes]
    total = sum(weights)
    mean = sum(weight * centre for weight, (centre, *_) in zip(weights, toes)) / total
    spread = sum(weight * (var + (centre - mean) ** 2) for weight, (centre, _, var, _) in zip(weights, toes)) / total
    return mean, math.sqrt(max(spread, 0.0))


def toe_minima(contacts_um: np.ndarray, rss: np.ndarray, noise_var: float
               ) -> list[tuple[float, float, float] | None]:
    """Per toe (row of rss): (best height, least residual, variance in c) from the parabola through
    its least residual and the two neighbours (the Laplace approximation), or None when the row
    has no curved interior minimum."""
    step = float(contacts_um[1] - contacts_um[0])
    count = rss.shape[1]
    heights = contacts_um.tolist()
    # Plain floats: a score of toes is far too few for numpy's per-call cost to pay.
    minima: list[tuple[float, float, float] | None] = []
    for row, k in zip(rss.tolist(), rss.argmin(axis=1).tolist()):
        minima.append(None)
        if not 0 < k < count - 1:
            continue
        before, at, after = row[k - 1], row[k], row[k + 1]
        if not (math.isfinite(before) and math.isfinite(after)):
            continue
        bend = before - 2.0 * at + after
        if not bend > 0:
            continue
        offset = 0.5 * (before - after) / bend
        # d2 rss / dc2 = bend / step^2; the Gaussian in c has variance 2 noise_var / that.
        minima[-1] = (heights[k] + offset * step, at - 0.25 * offset * (before - after),
                      2.0 * noise_var * step * step / bend)
    return minima


def adhesion_dip(x_um: np.ndarray, force_g: np.ndarray, drift_g_um: float, contact_um: float,
                 run_samples: int = ADHESION_RUN_SAMPLES) -> float | None:
    """How far (g) the force dips below the free-air level just above break contact, or None when
    the pullback does not reach far enough above contact to know the level.

    Adhesion and a plastic thread keep pulling the nozzle after it left the surface; the toe model
    reads that pull as more contact and puts Z high (mild ooze: +3.6 µm on the independent
    generator's taps, and the taps with the deepest dip err most). The drift (from the approach)
    is taken out first, so a cable pulling in proportion to Z does not look like a dip.
    """
    level_force = force_g - drift_g_um * x_um
    above = x_um - contact_um
    level = level_force[(above > ADHESION_REACH_UM) & (above < ADHESION_LEVEL_UM)]
    near = level_force[(above > ADHESION_FROM_UM) & (above <= ADHESION_REACH_UM)]
    if len(level) < ADHESION_MIN_LEVEL_SAMPLES or len(near) < run_samples:
        return None
    kernel = _RUN_MEAN_KERNEL if run_samples == ADHESION_RUN_SAMPLES else np.full(run_samples, 1.0 / run_samples)
    runs = np.convolve(near, kernel, mode="valid")
    return median(level) - float(runs.min())


def adhesion_measures(x_lo_um: np.ndarray, x_hi_um: np.ndarray, force_g: np.ndarray, drift_g_um: float,
                      contact_um: float, approach_at_halt_g: float,
                      run_samples: int = ADHESION_RUN_SAMPLES) -> tuple[float | None, float | None]:
    """(`adhesion_dip` over runs of `run_samples`, `thread_pull_g`) over the conversion windows'
    mid-heights (in C when built)."""
    if _C is not None:
        limits = (ADHESION_LIMITS if run_samples == ADHESION_RUN_SAMPLES else
                  (*ADHESION_LIMITS[:3], run_samples, *ADHESION_LIMITS[4:]))
        return _C.adhesion(x_lo_um, x_hi_um, force_g, drift_g_um, contact_um, approach_at_halt_g, limits)
    x_um = 0.5 * (x_lo_um + x_hi_um)
    return (adhesion_dip(x_um, force_g, drift_g_um, contact_um, run_samples),
            thread_pull_g(x_um, force_g, drift_g_um, approach_at_halt_g, contact_um))


def thread_pull_g(x_um: np.ndarray, force_g: np.ndarray, drift_g_um: float, approach_at_halt_g: float,
                  contact_um: float, reach_um: tuple[float, float] = THREAD_REACH_UM) -> float | None:
    """How far (g) the departure lies below the approach's free-air line at the same heights, or
    None when too few samples lie between `reach_um` (default THREAD_REACH_UM) above contact.

    A thread of ooze pulling the nozzle for a long way after break contact pulls the departure's
    whole level down, so `adhesion_dip` (the departure against itself) cannot see it; the approach
    crossed the same heights in free air before the tap, so its line, approach_at_halt_g at the
    halt's height plus drift_g_um per µm above it, is a reference the thread never touched (a
    heavy-ooze tap of the independent generator read valid 31 µm high that way).
    """
    above = x_um - contact_um
    near = (above > reach_um[0]) & (above < reach_um[1])
    if np.count_nonzero(near) < THREAD_MIN_SAMPLES:
        return None
    return median(approach_at_halt_g + drift_g_um * x_um[near] - force_g[near])


def thread_pulls_g(x_lo_um: np.ndarray, x_hi_um: np.ndarray, force_g: np.ndarray, drift_g_um: float,
                   approach_at_halt_g: float, contact_um: float, far_from_um: float
                   ) -> tuple[float | None, float | None]:
    """`thread_pull_g` over the conversion windows' mid-heights at THREAD_REACH_UM, and at
    THREAD_FAR_REACH_UM when the samples reach `far_from_um` above contact (else None), in one pass
    (in C when built)."""
    if _C is not None:
        near_g, far_g, highest_um = _C.thread_pulls(x_lo_um, x_hi_um, force_g, drift_g_um, approach_at_halt_g,
                                                    contact_um, THREAD_REACH_UM, THREAD_FAR_REACH_UM,
                                                    THREAD_MIN_SAMPLES)
        return near_g, far_g if highest_um - contact_um >= far_from_um else None
    x_um = 0.5 * (x_lo_um + x_hi_um)
    near_g = thread_pull_g(x_um, force_g, drift_g_um, approach_at_halt_g, contact_um)
    reaches_far = len(x_um) > 0 and float(x_um.max()) - contact_um >= far_from_um
    return near_g, (thread_pull_g(x_um, force_g, drift_g_um, approach_at_halt_g, contact_um, THREAD_FAR_REACH_UM)
                    if reaches_far else None)
