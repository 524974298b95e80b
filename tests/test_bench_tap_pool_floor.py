"""The measured floor of a pooled Z (bench._tap_pool_floor) against the Cramér-Rao bound worked out
by hand on sessions whose physics is known: a hinge of known stiffness in white noise, and the
same with a random walk added (which must raise the floor, and which the white floor ignores)."""

import numpy as np
import pytest

from bench._tap_pool_floor import PullbackRecord, session_floor_um

STIFFNESS_G_UM = 2.0
WHITE_G = 1.5
RATE_SPS = 320.0
SPEED_UM_S = 320.0  # 1 µm per sample
TAPS = 10


def _session(seed: int, walk_g_per_sqrt_s: float = 0.0) -> tuple[list[PullbackRecord], list[float]]:
    """Ten pullbacks from 40 µm deep to 60 µm above a sharp contact, each with its own baseline,
    sample phase and noise; and each tap's exact floor for white noise (σ / sqrt(Σ (s − s̄)²))."""
    rng = np.random.default_rng(seed)
    records, exact = [], []
    for _ in range(TAPS):
        count = 100
        height_um = -40.0 + rng.uniform(0, 1) + np.arange(count) * SPEED_UM_S / RATE_SPS
        time_s = 10.0 * rng.uniform() + np.arange(count) / RATE_SPS
        walk = np.cumsum(rng.normal(0, walk_g_per_sqrt_s / np.sqrt(RATE_SPS), count + 300))
        noise = rng.normal(0, WHITE_G, count + 300) + walk
        force_g = rng.normal(0, 20) + STIFFNESS_G_UM * np.maximum(-height_um, 0.0) + noise[300:]
        records.append(PullbackRecord(height_um=height_um, force_g=force_g, time_s=time_s, free_g=noise[:300]))
        slope = np.where(height_um < 0, STIFFNESS_G_UM, 0.0)
        exact.append(WHITE_G / np.sqrt(np.sum(np.square(slope - slope.mean()))))
    return records, exact


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_the_white_floor_is_the_hand_worked_bound(seed):
    records, exact = _session(seed)
    measured = session_floor_um(records)
    ratio = np.sqrt(np.mean(np.square(measured["white"]))) / np.sqrt(np.mean(np.square(exact)))
    # Over seeds 1-9 the ratio is 0.86-1.19 (the spline's slopes and the variogram are estimated).
    assert 0.8 < ratio < 1.25
    # White noise: the measured variogram is flat but for its own noise, which the coloured floor reads
    # as a little structure to exploit (median ratio to the white floor 0.72-1.04 over seeds 1-9: the
    # measured floor errs low, as a floor may).
    assert 0.65 < np.median(np.divide(measured["coloured"], measured["white"])) < 1.1


def test_a_walk_raises_the_coloured_floor_and_not_the_white_one():
    still, _ = _session(4)
    walking, _ = _session(4, walk_g_per_sqrt_s=6.0)
    still_floor, walking_floor = session_floor_um(still), session_floor_um(walking)
    assert np.median(walking_floor["coloured"]) > 1.3 * np.median(still_floor["coloured"])
    assert np.median(walking_floor["white"]) < 1.15 * np.median(still_floor["white"])
