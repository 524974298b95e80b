"""The floor of a pooled Z on sessions whose physics the benchmark cannot see (the reference sessions).

A pool estimates what the taps of a session share; its best case is to know it exactly, leaving
each tap only its contact height and baseline to find. Taplab's floor for that case
(`tapcell.taplab.bound`) differentiates the generator's own physics. The reference files carry
no physics (their `truth` holds the contact height alone), so here the benchmark measures, from
the session itself and its truth (truth side: never the analysis), what the exact floor needs:

* **the force's slope with depth** along the pullback, G'(h) at each sample's height h above the
  true contact: the taps of a session share the bed, the onset and the sensor lag, and the
  pullback runs at one speed, so the force against the commanded height is one curve G(h) for all
  of them. G is fitted as a linear spline (a knot every KNOT_UM from FINE_BELOW_UM below the
  contact to FREE_ABOVE_UM above it, every DEEP_KNOT_UM deeper; G = 0 above: free air) with each
  tap's baseline and mains hum (HUM_HARMONICS of 50 or 60 Hz, whichever fits), by least squares
  over the session's pullbacks;
* **the noise**: its variogram γ(lag) = ½ E[(x(k + lag) − x(k))²] over each tap's free air before
  the contact (its samples more than FREE_ABOVE_UM above it, less their offset, drift with Z and
  hum: what an analysis can fit), pooled over the session's taps, as measured (no model), and
  beyond the longest lag measured extended by a straight line (a walk) through its second half.

The Fisher information of one tap's contact, its baseline free, over the session's shortest
pullback window (pullback start onwards): J = Δsᵀ C⁻¹ Δs with s = G'(h) per sample, Δs each
sample's against the window's last (the baseline drops out), C the contrasts' covariance γ(i) +
γ(j) − γ(|i − j|) (no direction of it quieter than QUIETEST_SHARE of γ(1)). White: Σ(s − s̄)² / γ(1).
The spline's own noise adds to J; its expected part, tr(M D Cov Dᵀ) (Cov: the knots' covariance
with white noise), is taken off; where that leaves nothing (a wide toe in strong 1/f noise: the
information is in the toe's curvature, which the spline's noise swamps) the tap's floor is not
measured (inf, counted in the table). Floor = J^-1/2.

Checked against taplab's exact floor on the same pullbacks (`python -m bench tap_pool --floor N`):
it reads 0.86-0.94 of it with white + 1/f + walk (it errs low, as a floor may: the free air's
drift fit takes a little of the walk), 0.95-1.21 with white noise alone; and against a hand-worked bound in
tests/test_bench_tap_pool_floor.py.

It is a floor for an analysis of the pullback (as the pool and the single-tap fits read): the
approach and the dwell also carry the contact, which only an exact physics could use.
`python -m bench tap_pool --floor N` checks it against taplab's exact floor on the same windows.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tapcell.tap.model import Move

KNOT_UM = 1.0  # the spline's knots near the contact (from FINE_BELOW_UM below it to FREE_ABOVE_UM above)
FINE_BELOW_UM = 12.0
DEEP_KNOT_UM = 6.0  # deeper, where the slope is the stiffness: wider knots (a knot no other tap reaches is noise)
FREE_ABOVE_UM = 30.0
HUM_HARMONICS = 3
QUIETEST_SHARE = 0.5  # no contrast direction quieter than this share of the lag-1 variogram


@dataclass
class PullbackRecord:
    """One tap's pullback as the floor reads it: the heights above the true contact (µm), the
    forces (g, contact positive) and the sample times (s)."""

    height_um: np.ndarray
    force_g: np.ndarray
    time_s: np.ndarray
    free_g: np.ndarray  # the free air before the contact, less its offset, drift with Z and hum


def read_record(tap: dict, z_contact_mm: float) -> PullbackRecord:
    """A tap file's dict (truth side: the caller gives the true contact)."""
    time_s = np.asarray(tap["time"], dtype=float)
    force_g = np.asarray(tap["force"], dtype=float)
    z_mm = np.asarray(tap["z"], dtype=float) if "z" in tap else _commanded_z_mm(tap, time_s)
    events = tap["events"]
    pressed = (time_s > events["home_end_time"]) & (time_s < events["pullback_start_time"])
    pullback = time_s >= events["pullback_start_time"]
    if np.median(force_g[pressed]) < np.median(force_g[pullback][-8:]):
        force_g = -force_g
    height_um = (z_mm - z_contact_mm) * 1000.0
    free = (time_s < events["home_end_time"]) & (height_um > FREE_ABOVE_UM)
    return PullbackRecord(height_um=height_um[pullback], force_g=force_g[pullback], time_s=time_s[pullback],
                          free_g=_without_drift_and_hum(time_s[free], z_mm[free], force_g[free]))


def _without_drift_and_hum(time_s: np.ndarray, z_mm: np.ndarray, force_g: np.ndarray) -> np.ndarray:
    """The free air's force less what an analysis can fit there: an offset, a drift with Z and the
    mains hum (HUM_HARMONICS of 50 or 60 Hz, whichever leaves less)."""
    if len(force_g) < 4:
        return force_g[:0]
    best = None
    for mains_hz in (50.0, 60.0):
        hum = _hum_columns(time_s, mains_hz) if len(force_g) >= 8 * HUM_HARMONICS else np.zeros((len(time_s), 0))
        basis = np.column_stack([np.ones_like(time_s), z_mm - z_mm.mean(), hum])
        residual = force_g - basis @ np.linalg.lstsq(basis, force_g, rcond=None)[0]
        if best is None or residual @ residual < best @ best:
            best = residual
    return best


def _hum_columns(time_s: np.ndarray, mains_hz: float) -> np.ndarray:
    phase = 2 * np.pi * mains_hz * time_s
    return np.column_stack([f(k * phase) for k in range(1, HUM_HARMONICS + 1) for f in (np.sin, np.cos)])


def _commanded_z_mm(tap: dict, time_s: np.ndarray) -> np.ndarray:
    """The commanded Z at each sample from the tap's moves (a file with no `z` column)."""
    moves = sorted((Move.from_record(m) for m in tap["moves"]), key=lambda m: m.print_time)
    current = np.clip(np.searchsorted([m.print_time for m in moves], time_s, side="right") - 1, 0, len(moves) - 1)
    z_mm = np.empty_like(time_s)
    for k, move in enumerate(moves):
        z_mm[current == k] = move.z_at(time_s[current == k])
    return z_mm


def _hat_basis(height_um: np.ndarray, knots_um: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(values, slopes): each sample's linear-spline weights on the knots (the last knot's value is 0:
    free air) and d(value)/d(height) per knot."""
    count = len(knots_um) - 1
    values = np.zeros((len(height_um), count))
    slopes = np.zeros((len(height_um), count))
    inside = height_um < knots_um[-1]
    index = np.clip(np.searchsorted(knots_um, height_um, side="right") - 1, 0, count - 1)
    width = knots_um[index + 1] - knots_um[index]
    share = (height_um - knots_um[index]) / width
    rows = np.flatnonzero(inside)
    values[rows, index[rows]] = 1.0 - share[rows]
    slopes[rows, index[rows]] = -1.0 / width[rows]
    upper = rows[index[rows] + 1 < count]
    values[upper, index[upper] + 1] = share[upper]
    slopes[upper, index[upper] + 1] = 1.0 / width[upper]
    return values, slopes


def variogram(records: list[PullbackRecord], lags: int) -> np.ndarray:
    """γ(0..lags-1) of the free air, pooled over the session's taps; beyond the longest lag measured,
    a straight line (a walk) through the second half of what is."""
    measured = min(lags, max(len(r.free_g) for r in records))
    gamma = np.zeros(lags)
    for lag in range(1, measured):
        squares = [np.square(r.free_g[lag:] - r.free_g[:-lag]) for r in records if len(r.free_g) > lag]
        gamma[lag] = 0.5 * np.mean(np.concatenate(squares))
    if measured < 4:  # (almost) no free air to measure: white
        gamma[2:] = gamma[1]
    elif lags > measured:
        tail = np.arange(measured // 2, measured)
        slope, intercept = np.polyfit(tail, gamma[tail], 1)
        gamma[measured:] = np.maximum(intercept + max(slope, 0.0) * np.arange(measured, lags), gamma[measured - 1])
    return gamma


def _contrast_precision(gamma: np.ndarray, count: int) -> np.ndarray:
    """M with J = sᵀ M s for a baseline-free tap of `count` samples: Δᵀ C⁻¹ Δ over the contrasts
    against the last sample."""
    index = np.arange(count - 1)
    distance = count - 1 - index  # to the last sample
    cov = gamma[distance][:, None] + gamma[distance][None, :] - gamma[np.abs(index[:, None] - index[None, :])]
    values, vectors = np.linalg.eigh(cov)
    values = np.maximum(values, QUIETEST_SHARE * gamma[1])
    inverse = (vectors / values) @ vectors.T
    delta = np.hstack([np.eye(count - 1), -np.ones((count - 1, 1))])
    return delta.T @ inverse @ delta


def _tap_columns(record: PullbackRecord, mains_hz: float) -> np.ndarray:
    """A tap's own columns in the session's fit: its baseline and its hum (HUM_HARMONICS of mains_hz)."""
    return np.column_stack([np.ones(len(record.time_s)), _hum_columns(record.time_s, mains_hz)])


def session_fit(records: list[PullbackRecord], mains_hz: float):
    """The session's pullbacks fitted as one curve G(h) (the knots' values, free air 0) plus each
    tap's baseline and hum: (knots used, the design, the solution, per tap its slope rows)."""
    low = min(r.height_um.min() for r in records)
    deep_um = np.arange(-FINE_BELOW_UM, low - DEEP_KNOT_UM, -DEEP_KNOT_UM)[:0:-1]
    knots_um = np.concatenate([deep_um, np.arange(-FINE_BELOW_UM, FREE_ABOVE_UM + KNOT_UM / 2, KNOT_UM)])
    own = [_tap_columns(r, mains_hz) for r in records]
    width = own[0].shape[1]
    blocks, slope_rows = [], []
    for i, r in enumerate(records):
        values, slopes = _hat_basis(r.height_um, knots_um)
        slope_rows.append(slopes)
        mine = np.zeros((len(r.force_g), width * len(records)))
        mine[:, i * width:(i + 1) * width] = own[i]
        blocks.append(np.hstack([values, mine]))
    design = np.vstack(blocks)
    used = np.flatnonzero(np.any(design[:, :len(knots_um) - 1] != 0, axis=0))
    design = design[:, np.concatenate([used, np.arange(len(knots_um) - 1, design.shape[1])])]
    solution, *_ = np.linalg.lstsq(design, np.concatenate([r.force_g for r in records]), rcond=None)
    return used, design, solution, [rows[:, used] for rows in slope_rows]


def session_floor_um(records: list[PullbackRecord]) -> dict[str, list[float]]:
    """Per tap of one session, the floor (µm) of its contact with everything shared known: 'white'
    (the lag-1 variogram as white noise) and 'coloured' (the measured variogram); inf where the
    spline's own noise is more than the information (the tap's floor is not measured)."""
    fits = [session_fit(records, mains_hz) for mains_hz in (50.0, 60.0)]
    force = np.concatenate([r.force_g for r in records])
    used, design, solution, slope_rows = min(fits, key=lambda f: float(np.sum(np.square(force - f[1] @ f[2]))))
    # One window for every tap of the session (its shortest pullback: one covariance to invert; the
    # samples left out are the free air at the end).
    count = min(len(r.force_g) for r in records)
    gamma = variogram(records, count + 1)
    knot_cov = gamma[1] * np.linalg.inv(design.T @ design)[:len(used), :len(used)]
    theta = solution[:len(used)]
    centre = np.eye(count) - 1.0 / count
    precisions = {"white": centre / gamma[1], "coloured": _contrast_precision(gamma, count)}
    floors: dict[str, list[float]] = {name: [] for name in precisions}
    for rows in slope_rows:
        d = rows[:count]
        s = d @ theta
        for name, m in precisions.items():
            information = float(s @ m @ s) - float(np.sum((m @ d) * (d @ knot_cov)))
            floors[name].append(1.0 / np.sqrt(information) if information > 0 else float("inf"))
    return floors


def floors_of_set(directory: Path, labels) -> dict[str, dict[str, list[float]]]:
    """Per scenario, every tap's floors ('white', 'coloured'), session by session (truth side)."""
    sessions: dict[str, list] = {}
    for label in labels:
        sessions.setdefault(label.session, []).append(label)
    out: dict[str, dict[str, list[float]]] = {}
    for members in sessions.values():
        records = [read_record(json.loads((directory / label.file).read_text(encoding="utf-8")), label.z_contact_mm)
                   for label in members]
        floors = session_floor_um(records)
        scenario = out.setdefault(members[0].scenario, {"white": [], "coloured": []})
        for name in scenario:
            scenario[name].extend(floors[name])
    return out
