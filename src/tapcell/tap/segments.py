"""Least-squares lines over sample ranges in O(1) each, and the optimal five-line split.

Segments are half-open index ranges [i, j). Prefix sums are taken over time and force
re-centred on the analysed region, so the expanded sums stay small and the
"sum of squares minus square of sums" differences do not cancel catastrophically.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

MIN_SEGMENT_SAMPLES = 2


@dataclass
class PrefixSums:
    t_ref_s: float
    f_ref_g: float
    s_t: np.ndarray
    s_f: np.ndarray
    s_tt: np.ndarray
    s_tf: np.ndarray
    s_ff: np.ndarray


def prefix_sums(time_s: np.ndarray, force_g: np.ndarray) -> PrefixSums:
    t_ref = float(time_s[len(time_s) // 2])
    f_ref = float(np.median(force_g))
    t = time_s - t_ref
    f = force_g - f_ref
    stacked = np.empty((5, len(t) + 1))
    stacked[:, 0] = 0.0
    np.cumsum(np.stack((t, f, t * t, t * f, f * f)), axis=1, out=stacked[:, 1:])
    return PrefixSums(t_ref, f_ref, *stacked)


def segment_sse(ps: PrefixSums, i: np.ndarray, j: np.ndarray) -> np.ndarray:
    """Residual sum of squares of the best line over [i, j) (broadcasts over index arrays)."""
    # Empty or reversed ranges give inf/NaN here; the callers mask them out.
    with np.errstate(divide="ignore", invalid="ignore"):
        n = (j - i).astype(float)
        st = ps.s_t[j] - ps.s_t[i]
        sf = ps.s_f[j] - ps.s_f[i]
        sxx = ps.s_tt[j] - ps.s_tt[i] - st * st / n
        sxy = ps.s_tf[j] - ps.s_tf[i] - st * sf / n
        syy = ps.s_ff[j] - ps.s_ff[i] - sf * sf / n
        explained = np.where(sxx > 0, sxy * sxy / sxx, 0.0)
    return np.maximum(syy - explained, 0.0)


def segment_line(ps: PrefixSums, i: int, j: int) -> tuple[float, float]:
    """(slope g/s, intercept g at t = 0 of the original clock) of the best line over [i, j)."""
    n = j - i
    st = ps.s_t[j] - ps.s_t[i]
    sf = ps.s_f[j] - ps.s_f[i]
    sxx = ps.s_tt[j] - ps.s_tt[i] - st * st / n
    sxy = ps.s_tf[j] - ps.s_tf[i] - st * sf / n
    slope = sxy / sxx if sxx > 0 else 0.0
    # Line through the segment's centroid, then moved back to the original origins.
    intercept_centred = sf / n - slope * st / n
    return float(slope), float(intercept_centred + ps.f_ref_g - slope * ps.t_ref_s)


def _two_segment_costs(ps: PrefixSums, start: int, splits: np.ndarray, ends: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For every end e: min over split s of SSE[start, s) + SSE[s, e), and the best s."""
    s = splits[:, None]
    e = ends[None, :]
    cost = segment_sse(ps, np.full_like(s, start), s) + segment_sse(ps, s, e)
    allowed = (s - start >= MIN_SEGMENT_SAMPLES) & (e - s >= MIN_SEGMENT_SAMPLES)
    cost = np.where(allowed, cost, np.inf)
    best = np.argmin(cost, axis=0)
    return cost[best, np.arange(len(ends))], splits[best]


def _two_segment_costs_right(ps: PrefixSums, starts: np.ndarray, splits: np.ndarray, stop: int) -> tuple[np.ndarray, np.ndarray]:
    """For every start a: min over split s of SSE[a, s) + SSE[s, stop), and the best s."""
    a = starts[:, None]
    s = splits[None, :]
    cost = segment_sse(ps, a, s) + segment_sse(ps, s, np.full_like(s, stop))
    allowed = (s - a >= MIN_SEGMENT_SAMPLES) & (stop - s >= MIN_SEGMENT_SAMPLES)
    cost = np.where(allowed, cost, np.inf)
    best = np.argmin(cost, axis=1)
    return cost[np.arange(len(starts)), best], splits[best]


def best_five_segments(
    ps: PrefixSums,
    start: int,
    stop: int,
    contact: np.ndarray,
    peak: np.ndarray,
    release: np.ndarray,
    breaking: np.ndarray,
) -> tuple[int, int, int, int] | None:
    """Globally optimal boundaries (contact, peak, release, break) of five lines over [start, stop).

    Each boundary is searched exhaustively over its candidate indices; the total residual
    of all five lines is minimised jointly (the dwell line links the two halves), so the
    result is the exact optimum over the candidates, not a sequence of greedy elbows.
    Returns None when no arrangement gives every line two samples.
    """
    left_cost, best_contact = _two_segment_costs(ps, start, contact, peak)
    right_cost, best_break = _two_segment_costs_right(ps, release, breaking, stop)
    p = peak[:, None]
    r = release[None, :]
    dwell = np.where(r - p >= MIN_SEGMENT_SAMPLES, segment_sse(ps, p, np.maximum(r, p + 1)), np.inf)
    total = left_cost[:, None] + dwell + right_cost[None, :]
    flat = int(np.argmin(total))
    ip, ir = divmod(flat, total.shape[1])
    if not np.isfinite(total[ip, ir]):
        return None
    return int(best_contact[ip]), int(peak[ip]), int(release[ir]), int(best_break[ir])
