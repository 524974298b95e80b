"""A pullback too short to reach its speed is a triangle, as a printer's planner moves it: the
generator wrote a cruise of negative time there (the sweep's hum4000, seed 99 tap 13: -0.56 ms),
and the reader refused the tap ("start_v and move_t must be >= 0")."""

from __future__ import annotations

import math

import pytest

from bench.tap_sweep import CASES, case_taps
from tapcell.tap.readers import tap_from_object

CASE = {case.name: case for case in CASES}


@pytest.mark.parametrize("seed,k", [(99, 13), (64, 20)])
def test_a_short_fast_pullback_is_a_triangle(seed, k):
    tap, _ = case_taps(CASE["hum4000"], seed, k + 1, None)[k]
    pullback = tap["moves"][2:]
    assert all(move["move_t"] >= 0.0 and move["start_v"] >= 0.0 for move in tap["moves"])
    accelerate, cruise, decelerate = pullback
    top_mm_s = accelerate["accel"] * accelerate["move_t"]
    assert top_mm_s < float(tap["probe"]["pullback_speed"])  # short of the speed asked
    assert cruise["move_t"] == pytest.approx(0.0, abs=1e-12)
    assert decelerate["start_v"] == pytest.approx(top_mm_s, rel=1e-9)
    # The distance the moves lift is the pullback's.
    lifted_mm = 2 * 0.5 * accelerate["accel"] * accelerate["move_t"] ** 2
    assert lifted_mm == pytest.approx(float(tap["probe"]["pullback_distance"]), rel=1e-9)
    assert math.isclose(decelerate["start_z"] - accelerate["start_z"], 0.5 * lifted_mm, rel_tol=1e-9)
    tap_from_object(tap)  # readable
