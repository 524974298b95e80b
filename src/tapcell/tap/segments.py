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
    """Running sums of t, f, t², t·f, f² (rows of `sums`, a leading 0 column) over re-centred samples."""

    t_ref_s: float
    f_ref_g: float
    sums: np.ndarray  # (5, n + 1)

    def segment_sums(self, i: int, j: int) -> list[float]:
        """[n, Σt, Σf, Σt², Σt·f, Σf²] over [i, j) as plain floats."""
        return [float(j - i), *(self.sums[:, j] - self.sums[:, i]).tolist()]


def prefix_sums(time_s: np.ndarray, force_g: np.ndarray) -> PrefixSums:
    t_ref = float(time_s[len(time_s) // 2])
    f_ref = float(force_g.mean())
    t = time_s - t_ref
    f = force_g - f_ref
    sums = np.zeros((5, len(t) + 1))
    np.cumsum(np.stack((t, f, t * t, t * f, f * f)), axis=1, out=sums[:, 1:])
    return PrefixSums(t_ref, f_ref, sums)


def segment_sse(ps: PrefixSums, i: np.ndarray, j: np.ndarray) -> np.ndarray:
    """Residual sum of squares of the best line over [i, j) (index arrays of one shape)."""
    # Empty or reversed ranges give inf/NaN here; the callers mask them out.
    with np.errstate(divide="ignore", invalid="ignore"):
        sums = np.take(ps.sums, j, axis=1)  # take + in-place: several times faster than fancy indexing
        sums -= np.take(ps.sums, i, axis=1)
        st, sf, stt, stf, sff = sums
        inv_n = 1.0 / (j - i)
        t_mean = st * inv_n
        sxx = stt - t_mean * st
        sxy = stf - t_mean * sf
        explained = np.where(sxx > 0, sxy * sxy / sxx, 0.0)
        return np.maximum(sff - sf * sf * inv_n - explained, 0.0)


def segment_line(ps: PrefixSums, i: int, j: int) -> tuple[float, float]:
    """(slope g/s, intercept g at t = 0 of the original clock) of the best line over [i, j)."""
    n, st, sf, stt, stf, _ = ps.segment_sums(i, j)
    sxx = stt - st * st / n
    sxy = stf - st * sf / n
    slope = sxy / sxx if sxx > 0 else 0.0
    # Line through the segment's centroid, then moved back to the original origins.
    intercept_centred = sf / n - slope * st / n
    return float(slope), float(intercept_centred + ps.f_ref_g - slope * ps.t_ref_s)


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

    Every candidate segment of every line is costed in one vectorised call:
    approach [start, contact), compression [contact, peak), dwell [peak, release),
    decompression [release, break), departure [break, stop).
    """
    c, p, r, b = len(contact), len(peak), len(release), len(breaking)
    firsts = np.concatenate((np.full(c, start), np.repeat(contact, p), np.repeat(peak, r), np.repeat(release, b),
                             breaking))
    lasts = np.concatenate((contact, np.broadcast_to(peak, (c, p)).ravel(), np.broadcast_to(release, (p, r)).ravel(),
                            np.broadcast_to(breaking, (r, b)).ravel(), np.full(b, stop)))
    sse = np.where(lasts - firsts >= MIN_SEGMENT_SAMPLES, segment_sse(ps, firsts, lasts), np.inf)
    offsets = np.cumsum((c, c * p, p * r, r * b))
    approach, compression, dwell, decompression = (sse[a:z] for a, z in zip((0, *offsets[:3]), offsets))
    departure = sse[offsets[3]:]
    left = approach[:, None] + compression.reshape(c, p)  # (contact, peak)
    best_contact = np.argmin(left, axis=0)
    right = decompression.reshape(r, b) + departure[None, :]  # (release, break)
    best_break = np.argmin(right, axis=1)
    total = left[best_contact, np.arange(p)][:, None] + dwell.reshape(p, r) + right[np.arange(r), best_break][None, :]
    flat = int(np.argmin(total))
    ip, ir = divmod(flat, r)
    if not np.isfinite(total[ip, ir]):
        return None
    return int(contact[best_contact[ip]]), int(peak[ip]), int(release[ir]), int(breaking[best_break[ir]])
