"""Least-squares lines over sample ranges in O(1) each, and the optimal five-line split.

Segments are half-open index ranges [i, j). Prefix sums are taken over time and force
re-centred on the analysed region, so the expanded sums stay small and the
"sum of squares minus square of sums" differences do not cancel catastrophically.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

MIN_SEGMENT_SAMPLES = 2


@dataclass
class PrefixSums:
    """Running sums of 1, t, f, t², t·f, f² (rows of `sums`, a leading 0 column) over re-centred samples.

    The first row counts samples, so the difference of two columns is everything a line over
    that range needs, its sample count included.
    """

    t_ref_s: float
    f_ref_g: float
    sums: np.ndarray  # (6, n + 1)

    def segment_sums(self, i: int, j: int) -> list[float]:
        """[n, Σt, Σf, Σt², Σt·f, Σf²] over [i, j) as plain floats."""
        return (self.sums[:, j] - self.sums[:, i]).tolist()


def prefix_sums(time_s: np.ndarray, force_g: np.ndarray) -> PrefixSums:
    n = len(time_s)
    t_ref = float(time_s[n // 2])
    f_ref = float(force_g.sum()) / n  # the mean, without np.mean's call overhead
    sums = np.empty((6, n + 1))
    sums[0] = np.arange(n + 1)  # the running count needs no summing
    sums[1:, 0] = 0.0
    t, f, tt, tf, ff = sums[1:, 1:]
    np.subtract(time_s, t_ref, out=t)
    np.subtract(force_g, f_ref, out=f)
    np.multiply(t, t, out=tt)
    np.multiply(t, f, out=tf)
    np.multiply(f, f, out=ff)
    np.cumsum(sums[1:, 1:], axis=1, out=sums[1:, 1:])
    return PrefixSums(t_ref, f_ref, sums)


def _sse_of_sums(sums: np.ndarray) -> np.ndarray:
    """Residual sum of squares of the best line from segment sums (rows n, Σt, Σf, Σt², Σtf, Σf²)."""
    n, st, sf, stt, stf, sff = sums
    # Empty or reversed ranges give inf/NaN here; the callers mask them out.
    with np.errstate(divide="ignore", invalid="ignore"):
        inv_n = 1.0 / n
        t_mean = st * inv_n
        sxx = stt - t_mean * st
        sxy = stf - t_mean * sf
        explained = np.where(sxx > 0, sxy * sxy / sxx, 0.0)
        return np.maximum(sff - sf * sf * inv_n - explained, 0.0)


def segment_sse(ps: PrefixSums, i: np.ndarray, j: np.ndarray) -> np.ndarray:
    """Residual sum of squares of the best line over [i, j) (index arrays of one shape)."""
    sums = np.take(ps.sums, j, axis=1)  # take + in-place: several times faster than fancy indexing
    sums -= np.take(ps.sums, i, axis=1)
    return _sse_of_sums(sums)


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
    sums = (ps.sums[:, edges[1:]] - ps.sums[:, edges[:-1]]).T.tolist()
    return [_line_of_sums(ps, segment) for segment in sums]


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
    c, p, r, b = len(contact), len(peak), len(release), len(breaking)
    columns = ps.sums
    at_contact = columns[:, contact.start:contact.stop]
    at_peak = columns[:, peak.start:peak.stop]
    at_release = columns[:, release.start:release.stop]
    at_break = columns[:, breaking.start:breaking.stop]
    blocks = (
        at_contact - columns[:, start:start + 1],  # approach: (c,)
        (at_peak[:, None, :] - at_contact[:, :, None]).reshape(6, c * p),  # compression
        (at_release[:, None, :] - at_peak[:, :, None]).reshape(6, p * r),  # dwell
        (at_break[:, None, :] - at_release[:, :, None]).reshape(6, r * b),  # decompression
        columns[:, stop:stop + 1] - at_break,  # departure: (b,)
    )
    sums = np.concatenate(blocks, axis=1)
    sse = np.where(sums[0] >= MIN_SEGMENT_SAMPLES, _sse_of_sums(sums), np.inf)
    ends = list(itertools.accumulate((c, c * p, p * r, r * b)))
    approach, compression, dwell, decompression = (sse[a:z] for a, z in zip((0, *ends[:3]), ends))
    departure = sse[ends[3]:]
    left = approach[:, None] + compression.reshape(c, p)  # (contact, peak)
    right = decompression.reshape(r, b) + departure[None, :]  # (release, break)
    # Best total per (peak, release): each half at its best, the dwell between.
    total = left.min(axis=0)[:, None] + dwell.reshape(p, r) + right.min(axis=1)[None, :]
    ip, ir = divmod(int(np.argmin(total)), r)
    if not np.isfinite(total[ip, ir]):
        return None
    return contact[int(np.argmin(left[:, ip]))], peak[ip], release[ir], breaking[int(np.argmin(right[ir]))]
