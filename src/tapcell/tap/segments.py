"""Least-squares lines over sample ranges in O(1) each, and the optimal five-line split.

Segments are half-open index ranges [i, j). Prefix sums are taken over time and force
re-centred on the analysed region, so the expanded sums stay small and the
"sum of squares minus square of sums" differences do not cancel catastrophically.

`prefix_sums`, `segment_lines` and `best_five_segments` run in C when the kernel
tapcell.tap._c_segments is built (same arithmetic: the same sums, lines and boundaries, ties
included); the numpy code below is the reference and the fallback. `five_lines`, the split of a
tap's window, is one kernel call doing what those three and the candidate ranges do.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field

import numpy as np

from tapcell.tap import native
from tapcell.tap.angles import ANGLE_SCALE_S_PER_G, line_angles_deg
from tapcell.tap.context import recompute_points

_C = native.load("segments")

MIN_SEGMENT_SAMPLES = 2


@dataclass(eq=False, repr=False)
class PrefixSums:
    """Running sums of 1, t, f, t², t·f, f² (rows of `sums`, a leading 0 column) over re-centred samples.

    The first row counts samples, so the difference of two columns is everything a line over
    that range needs, its sample count included.
    """

    t_ref_s: float
    f_ref_g: float
    sums: np.ndarray  # (6, n + 1)
    # What the analysis derived from a range's sums, by (i, j): the checks and the Z uncertainty ask
    # for the same lines' scatter several times a tap (`segment_stats`); `five_lines` fills it for
    # the five lines of its split.
    derived: dict = field(default_factory=dict, repr=False, compare=False)

    def segment_sums(self, i: int, j: int) -> list[float]:
        """[n, Σt, Σf, Σt², Σt·f, Σf²] over [i, j) as plain floats."""
        return (self.sums[:, j] - self.sums[:, i]).tolist()


def segment_stats(ps: PrefixSums, i: int, j: int) -> tuple[float, float, float]:
    """(residual variance, mean re-centred time, Sxx) of the line over [i, j), computed once a range
    (`PrefixSums.derived`; the five-line kernel fills it for its five lines with this arithmetic)."""
    found = ps.derived.get((i, j))
    if found is None:
        n, st, sf, stt, stf, sff = ps.segment_sums(i, j)
        sxx = stt - st * st / n
        sxy = stf - st * sf / n
        syy = sff - sf * sf / n
        sse = max(syy - (sxy * sxy / sxx if sxx > 0 else 0.0), 0.0)
        found = ps.derived[i, j] = (sse / max(n - 2, 1), st / n, sxx)
    return found


def prefix_sums(time_s: np.ndarray, force_g: np.ndarray) -> PrefixSums:
    n = len(time_s)
    t_ref = float(time_s[n // 2])
    f_ref = float(force_g.sum()) / n  # the mean, without np.mean's call overhead
    sums = np.empty((6, n + 1))
    if _C is not None:
        _C.prefix_sums(time_s, force_g, t_ref, f_ref, sums)
        return PrefixSums(t_ref, f_ref, sums)
    sums[0] = np.arange(n + 1)  # the running count needs no summing
    sums[1:, 0] = 0.0
    t, f, tt, tf, ff = sums[1:, 1:]
    np.subtract(time_s, t_ref, out=t)
    np.subtract(force_g, f_ref, out=f)
    np.multiply(t, t, out=tt)
    np.multiply(t, f, out=tf)
    np.multiply(f, f, out=ff)
    np.add.accumulate(sums[1:, 1:], axis=1, out=sums[1:, 1:])  # np.cumsum without its wrapper
    return PrefixSums(t_ref, f_ref, sums)


def _sse_of_sums(sums: np.ndarray) -> np.ndarray:
    """Residual sum of squares of the best line from segment sums (rows n, Σt, Σf, Σt², Σtf, Σf²),
    inf for segments of fewer than MIN_SEGMENT_SAMPLES. Works in place: `sums` is scratch afterwards.
    """
    n, st, sf, stt, stf, sff = sums
    too_short = n < MIN_SEGMENT_SAMPLES
    # Empty or reversed ranges get a harmless count (their result is replaced by inf), so no
    # division by zero needs an np.errstate (which costs more than the arithmetic here).
    np.maximum(n, MIN_SEGMENT_SAMPLES, out=n)
    inv_n = 1.0 / n
    t_mean = st * inv_n
    st *= t_mean
    sxx = np.subtract(stt, st, out=stt)
    t_mean *= sf
    sxy = np.subtract(stf, t_mean, out=stf)
    sxy *= sxy
    # Only too-short segments can have sxx <= 0 (n >= 2 distinct times spread), and their result is
    # replaced below: a harmless divisor for them, then one plain division (no where=, no scratch array).
    sxx[too_short] = 1.0
    explained = np.divide(sxy, sxx, out=sxy)
    sf *= sf
    sf *= inv_n
    sse = np.subtract(sff, sf, out=sff)
    sse -= explained
    np.maximum(sse, 0.0, out=sse)
    sse[too_short] = np.inf
    return sse


def segment_sse(ps: PrefixSums, i: np.ndarray, j: np.ndarray) -> np.ndarray:
    """Residual sum of squares of the best line over [i, j) (index arrays of one shape)."""
    sums = np.take(ps.sums, j, axis=1)  # take + in-place: several times faster than fancy indexing
    sums -= np.take(ps.sums, i, axis=1)
    return _sse_of_sums(sums.reshape(6, -1)).reshape(sums.shape[1:])


def _line_of_sums(ps: PrefixSums, sums: list[float]) -> tuple[float, float]:
    n, st, sf, stt, stf, _ = sums
    sxx = stt - st * st / n
    sxy = stf - st * sf / n
    slope = sxy / sxx if sxx > 0 else 0.0
    # Line through the segment's centroid, then moved back to the original origins.
    intercept_centred = sf / n - slope * st / n
    return float(slope), float(intercept_centred + ps.f_ref_g - slope * ps.t_ref_s)


def segment_line(ps: PrefixSums, i: int, j: int) -> tuple[float, float]:
    """(slope g/s, intercept g at t = 0 of the original clock) of the best line over [i, j)."""
    return _line_of_sums(ps, ps.segment_sums(i, j))


def segment_lines(ps: PrefixSums, edges: list[int]) -> list[tuple[float, float]]:
    """The lines over consecutive segments [edges[k], edges[k + 1]) (one numpy call for all)."""
    if _C is not None:
        return _C.segment_lines(ps.sums, edges, ps.t_ref_s, ps.f_ref_g)
    at_edges = ps.sums.take(edges, axis=1).T.tolist()  # the prefix sums at each edge, as floats
    return [_line_of_sums(ps, [b - a for a, b in zip(first, end)]) for first, end in zip(at_edges, at_edges[1:])]


def _blocked(block: np.ndarray, rows: int, cols: int) -> np.ndarray:
    """A (6, rows * cols) slice of a work array seen as (6, rows, cols), as a view (writes land in the array)."""
    view = block.view()
    view.shape = (6, rows, cols)  # raises instead of silently copying
    return view


def best_five_segments(
    ps: PrefixSums,
    start: int,
    stop: int,
    contact: range,
    peak: range,
    release: range,
    breaking: range,
) -> tuple[int, int, int, int] | None:
    """Globally optimal boundaries (contact, peak, release, break) of five lines over [start, stop).

    Each boundary is searched exhaustively over its candidate indices (contiguous ranges); the
    total residual of all five lines is minimised jointly (the dwell line links the two halves),
    so the result is the exact optimum over the candidates, not a sequence of greedy elbows.
    Returns None when no arrangement gives every line two samples.

    Every candidate segment of every line is costed in one vectorised call:
    approach [start, contact), compression [contact, peak), dwell [peak, release),
    decompression [release, break), departure [break, stop). The sums of a block of segments
    (first boundary × second boundary) are one broadcast difference of two column slices.
    """
    if _C is not None:
        return _C.best_five_segments(ps.sums, start, stop, contact.start, contact.stop, peak.start, peak.stop,
                                     release.start, release.stop, breaking.start, breaking.stop)
    c, p, r, b = len(contact), len(peak), len(release), len(breaking)
    columns = ps.sums
    at_contact = columns[:, contact.start:contact.stop]
    at_peak = columns[:, peak.start:peak.stop]
    at_release = columns[:, release.start:release.stop]
    at_break = columns[:, breaking.start:breaking.stop]
    # One work array holds every block side by side; each block is written in place.
    # Blocks are laid out (first boundary, second boundary), except the compression's
    # (peak, contact): the long candidate axis innermost keeps numpy's loops long.
    ends = list(itertools.accumulate((c, p * c, p * r, r * b, b)))
    sums = np.empty((6, ends[-1]))
    approach, compression, dwell, decompression, departure = (
        sums[:, first:end] for first, end in zip((0, *ends[:4]), ends))
    np.subtract(at_contact, columns[:, start:start + 1], out=approach)
    np.subtract(at_peak[:, :, None], at_contact[:, None, :], out=_blocked(compression, p, c))
    np.subtract(at_release[:, None, :], at_peak[:, :, None], out=_blocked(dwell, p, r))
    np.subtract(at_break[:, None, :], at_release[:, :, None], out=_blocked(decompression, r, b))
    np.subtract(columns[:, stop:stop + 1], at_break, out=departure)
    sse = _sse_of_sums(sums)
    approach, compression, dwell, decompression, departure = (
        sse[first:end] for first, end in zip((0, *ends[:4]), ends))
    left = compression.reshape(p, c) + approach  # (peak, contact)
    right = decompression.reshape(r, b) + departure[None, :]  # (release, break)
    # Best total per (peak, release): each half at its best, the dwell between.
    total = left.min(axis=1)[:, None] + dwell.reshape(p, r) + right.min(axis=1)[None, :]
    ip, ir = divmod(int(total.argmin()), r)  # array methods: no numpy Python wrapper per call
    if not math.isfinite(total[ip, ir]):
        return None
    return contact[int(left[ip].argmin())], peak[ip], release[ir], breaking[int(right[ir].argmin())]


# Why a window has no five-line split (`five_lines` answers with one of these, SPLIT_FOUND: it has one).
SPLIT_FOUND, NO_DWELL_SAMPLES, TOO_FEW_AROUND, TOO_FEW_FOR_FIVE = 0, 1, 2, 3


Point = tuple[float, float]


def five_lines(time_s: np.ndarray, force_g: np.ndarray, phases_s: tuple[float, float, float], lag_samples: int,
               release_lag_samples: int, approach_share: float = 0.0
               ) -> tuple[PrefixSums, int, tuple[int, int, int, int] | None, list[tuple[float, float]] | None,
                          list[Point] | None, list[float] | None]:
    """The five-line split of a window of samples: (prefix sums, SPLIT_FOUND or why there is none,
    the boundaries (contact, peak, release, break), the five lines, their six points as
    `context.recompute_points` puts them over the window's first and last sample, the four angles
    between the lines, `angles.line_angles_deg`). The five lines' `segment_stats` are in the prefix
    sums' `derived` (the checks and the Z uncertainty read them).

    phases_s: the halt, the pullback's start and its cruise (s). The peak is searched from the
    sample before the halt up to `lag_samples` after it (not past the pullback's start), the
    release from the sample before the pullback's start up to `release_lag_samples` after its
    cruise begins; contact before the peak and at least `approach_share` of the samples before the
    halt into the window, break after the release, each line at least 2 samples.
    One kernel call when built (its glue cost as much as its search); the numpy code is its twin.
    """
    m = len(time_s)
    # A lag past the window's end reaches no further than its end (every range below stops at m);
    # capped, a file's absurd sample rate (1e300 sps: a lag of 1e298 samples) fits the kernel's ssize_t.
    lag_samples, release_lag_samples = min(lag_samples, m), min(release_lag_samples, m)
    if _C is not None:
        # The kernel takes the sums' reference time and force as prefix_sums does (numpy's sum, bit for bit).
        sums, derived = np.empty((6, m + 1)), {}
        t_ref, f_ref, *found = _C.five_lines(time_s, force_g, *phases_s, lag_samples, release_lag_samples,
                                             approach_share, ANGLE_SCALE_S_PER_G, sums, derived)
        return PrefixSums(t_ref, f_ref, sums, derived), *found
    ps = prefix_sums(time_s, force_g)
    home_end, pull_start, pull_cruise = np.minimum(time_s.searchsorted(phases_s), m - 1).tolist()
    peak = range(max(2, home_end - 1), min(pull_start, home_end + lag_samples) + 1)
    release = range(max(pull_start - 1, 0), min(m - 2, max(pull_start, pull_cruise) + release_lag_samples) + 1)
    if len(peak) == 0 or len(release) == 0:
        return ps, NO_DWELL_SAMPLES, None, None, None, None
    contact = range(max(2, int(approach_share * home_end)), peak[-1] - 1)
    breaking = range(release[0] + 2, m - 1)
    if len(contact) == 0 or len(breaking) == 0:
        return ps, TOO_FEW_AROUND, None, None, None, None
    bounds = best_five_segments(ps, 0, m, contact, peak, release, breaking)
    if bounds is None:
        return ps, TOO_FEW_FOR_FIVE, None, None, None, None
    edges = [0, *bounds, m]
    for first, end in zip(edges, edges[1:]):
        segment_stats(ps, first, end)
    lines = segment_lines(ps, edges)
    points = recompute_points(lines, float(time_s[0]), float(time_s[-1]))
    return ps, SPLIT_FOUND, bounds, lines, points, line_angles_deg(lines)
