"""Probe health from stored taps: repeatability, the change test behind the fleet's trend flag,
and `faulty_region` suggestions from where taps keep failing. Pure numpy over plain lists."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

# Taps at one spot: XY rounded to this grid (a PROBE repeated at the same place lands within it).
SPOT_MM = 0.5
# The change test: the latest RECENT_TAPS against up to BASELINE_TAPS before them.
RECENT_TAPS = 50
BASELINE_TAPS = 200
MIN_TAPS_PER_SIDE = 10
# |t| (or |z|) above this flags a change: two-sided p ≈ 6e-5 under no change (normal
# approximation), so a fleet of 50 printers × 3 metrics sees a false flag about once in 100
# page views of unchanged printers.
TREND_T_THRESHOLD = 4.0
# Bed spots: rejected taps grouped on this grid; a cell with at least FAULTY_MIN_REJECTS rejects
# that are at least FAULTY_MIN_SHARE of its taps is suggested as a faulty_region.
FAULTY_CELL_MM = 10.0
FAULTY_MIN_REJECTS = 3
FAULTY_MIN_SHARE = 0.5
FAULTY_PAD_MM = 2.0


def repeatability_um(x_mm: list, y_mm: list, z_mm: list) -> float | None:
    """Pooled within-spot standard deviation of Z (µm) over spots tapped at least twice."""
    groups: dict[tuple[int, int], list[float]] = {}
    for x, y, z in zip(x_mm, y_mm, z_mm):
        if x is None or y is None or z is None:
            continue
        groups.setdefault((round(x / SPOT_MM), round(y / SPOT_MM)), []).append(z)
    squares = 0.0
    freedom = 0
    for values in groups.values():  # a few taps per spot: plain sums beat numpy's per-call cost
        if len(values) >= 2:
            mean = math.fsum(values) / len(values)
            squares += math.fsum((value - mean) ** 2 for value in values)
            freedom += len(values) - 1
    return None if freedom == 0 else math.sqrt(squares / freedom) * 1000.0


@dataclass(frozen=True)
class Trend:
    """Welch's two-sample t between the latest taps and the ones before them."""

    metric: str
    t: float | None  # None: too few taps on a side
    recent_mean: float | None
    baseline_mean: float | None
    recent_n: int
    baseline_n: int

    @property
    def flagged(self) -> bool:
        return self.t is not None and abs(self.t) > TREND_T_THRESHOLD

    def to_json(self) -> dict:
        return {"metric": self.metric, "t": self.t, "flagged": self.flagged, "recent_mean": self.recent_mean,
                "baseline_mean": self.baseline_mean, "recent_n": self.recent_n, "baseline_n": self.baseline_n}


def trend(metric: str, values_oldest_first: list, proportion: bool = False) -> Trend:
    """The change test on one metric's series (None values are left out).

    A measured metric (noise, stiffness): Welch's t. A share (0/1 per tap, the rejected taps):
    the two-proportion z with the pooled share, which stays right when a window holds no
    reject at all (Welch's t then divides by a zero variance and flags nothing real)."""
    values = np.asarray([v for v in values_oldest_first if v is not None], dtype=float)
    recent = values[-RECENT_TAPS:]
    baseline = values[-(RECENT_TAPS + BASELINE_TAPS):-RECENT_TAPS] if len(values) > RECENT_TAPS else values[:0]
    if len(recent) < MIN_TAPS_PER_SIDE or len(baseline) < MIN_TAPS_PER_SIDE:
        return Trend(metric, None, _mean(recent), _mean(baseline), len(recent), len(baseline))
    if proportion:
        pooled = (recent.sum() + baseline.sum()) / (len(recent) + len(baseline))
        spread = pooled * (1.0 - pooled) * (1.0 / len(recent) + 1.0 / len(baseline))
    else:
        spread = recent.var(ddof=1) / len(recent) + baseline.var(ddof=1) / len(baseline)
    difference = recent.mean() - baseline.mean()
    if spread == 0.0:
        t = 0.0 if difference == 0.0 else math.copysign(math.inf, difference)
    else:
        t = difference / math.sqrt(spread)
    return Trend(metric, float(t), float(recent.mean()), float(baseline.mean()), len(recent), len(baseline))


def _mean(values: np.ndarray) -> float | None:
    return float(values.mean()) if len(values) else None


@dataclass(frozen=True)
class FaultyRegion:
    x_min_mm: float
    y_min_mm: float
    x_max_mm: float
    y_max_mm: float
    rejected: int
    taps: int

    def config_lines(self, number: int) -> list[str]:
        """[bed_mesh] lines, Klipper's faulty_region_N_min/_max syntax."""
        return [f"faulty_region_{number}_min: {self.x_min_mm:.1f}, {self.y_min_mm:.1f}",
                f"faulty_region_{number}_max: {self.x_max_mm:.1f}, {self.y_max_mm:.1f}"]


def faulty_regions(spots: list[tuple[float, float, bool]]) -> list[FaultyRegion]:
    """Regions where taps keep failing, from (x_mm, y_mm, rejected) per tap; largest count first."""
    cells: dict[tuple[int, int], list[tuple[float, float, bool]]] = {}
    for x, y, rejected in spots:
        cells.setdefault((math.floor(x / FAULTY_CELL_MM), math.floor(y / FAULTY_CELL_MM)), []).append((x, y, rejected))
    regions = []
    for members in cells.values():
        bad = [(x, y) for x, y, rejected in members if rejected]
        if len(bad) >= FAULTY_MIN_REJECTS and len(bad) >= FAULTY_MIN_SHARE * len(members):
            xs, ys = [x for x, _ in bad], [y for _, y in bad]
            regions.append(FaultyRegion(min(xs) - FAULTY_PAD_MM, min(ys) - FAULTY_PAD_MM,
                                        max(xs) + FAULTY_PAD_MM, max(ys) + FAULTY_PAD_MM, len(bad), len(members)))
    regions.sort(key=lambda region: (-region.rejected, region.x_min_mm, region.y_min_mm))
    return regions
