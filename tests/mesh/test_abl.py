"""The paper's two-pass ABL: weighting, plan, no-contact stop, topology report."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from tapcell.mesh.abl import (
    NoContactError,
    PlanStep,
    TwoPassSettings,
    point_plan,
    run_two_pass,
    topology_report,
    weighted_z_mm,
)
from tapcell.mesh.errors import MeshError
from tapcell.mesh.grid import rectangular_grid

# The paper's Table 1: X, Y, first pass z1, second pass z2, weighted (mm).
TABLE_1 = np.array(
    [
        [0, 0, 0.11, 0.32, 0.236],
        [200, 0, 0.35, 0.55, 0.47],
        [400, 0, 0.15, 0.36, 0.276],
        [400, 200, 1.14, 1.4, 1.296],
        [200, 200, 0.4, 0.61, 0.526],
        [0, 200, 0.15, 0.45, 0.33],
        [0, 400, -0.43, -0.22, -0.304],
        [200, 400, -0.07, -0.28, -0.196],
        [400, 400, 1.52, 0.65, 0.998],
    ]
)


def test_weighting_on_hand_numbers():
    assert weighted_z_mm(0.11, 0.32) == pytest.approx(0.236, abs=1e-12)
    assert weighted_z_mm(1.0, 2.0) == pytest.approx(1.6)
    assert weighted_z_mm(1.0, 2.0, fast_weight=0.5) == pytest.approx(1.5)


def test_weighting_reproduces_table_1():
    np.testing.assert_allclose(weighted_z_mm(TABLE_1[:, 2], TABLE_1[:, 3]), TABLE_1[:, 4], atol=1e-12)


def test_point_plan_is_fast_pass_back_off_slow_pass_lift():
    plan = point_plan(200.0, 50.0, TwoPassSettings())
    assert [(s.kind, s.pass_name, s.z_mm, s.speed_mm_s) for s in plan[1:]] == [
        ("probe", "fast", -2.0, 120.0),
        ("retract", "", 1.0, 8.0),
        ("probe", "slow", -2.0, 8.0),
        ("retract", "", 3.0, 50.0),
    ]
    assert (plan[0].kind, plan[0].x_mm, plan[0].y_mm, plan[0].speed_mm_s) == ("travel", 200.0, 50.0, 50.0)


class FakeBed:
    """Contact at a known height per pass; records every step it is asked to do."""

    def __init__(self, heights, miss_at=None):
        self.heights = heights
        self.miss_at = miss_at
        self.steps: list[PlanStep] = []

    def __call__(self, step: PlanStep):
        self.steps.append(step)
        if step.kind != "probe":
            return None
        if (step.x_mm, step.y_mm, step.pass_name) == self.miss_at:
            return None
        fast, slow = self.heights[(step.x_mm, step.y_mm)]
        return fast if step.pass_name == "fast" else slow


def test_run_two_pass_weights_every_point_in_order():
    grid = rectangular_grid((0, 0), (400, 400), 3)
    bed = FakeBed({(x, y): (z1, z2) for x, y, z1, z2, _ in TABLE_1})
    results = run_two_pass(grid.probe_points_mm(), bed, TwoPassSettings())
    assert [r.z_mm for r in results] == pytest.approx(TABLE_1[:, 4].tolist())
    assert [(r.x_mm, r.y_mm) for r in results] == [(x, y) for x, y in TABLE_1[:, :2].tolist()]
    assert len(bed.steps) == 9 * 5
    assert json.loads(json.dumps(results[3].to_status()))["z_fast_mm"] == 1.14


def test_no_contact_before_the_travel_limit_stops_probing():
    grid = rectangular_grid((0, 0), (400, 400), 3)
    bed = FakeBed({(x, y): (z1, z2) for x, y, z1, z2, _ in TABLE_1}, miss_at=(400.0, 200.0, "slow"))
    with pytest.raises(NoContactError) as raised:
        run_two_pass(grid.probe_points_mm(), bed, TwoPassSettings(travel_limit_z_mm=-1.5))
    assert str(raised.value) == (
        "no contact at point 4 of 9 (X=400.000 Y=200.000) on the slow pass before the travel limit "
        "Z=-1.500 mm: probing stopped"
    )
    assert raised.value.index == 3
    assert len(bed.steps) == 3 * 5 + 4  # nothing after the miss


def test_settings_are_validated():
    with pytest.raises(MeshError, match="slow_speed_mm_s = 0: must be a positive number"):
        TwoPassSettings(slow_speed_mm_s=0)
    with pytest.raises(MeshError, match="fast_weight = 1.5: must be between 0 and 1"):
        TwoPassSettings(fast_weight=1.5)


def test_topology_of_a_hand_made_tilted_plane():
    # z = 0.1 + 0.002 x - 0.001 y over a 3 x 3 grid, plus a 0.05 mm bump in the middle.
    x, y = np.meshgrid([0.0, 100.0, 200.0], [0.0, 100.0, 200.0])
    z = 0.1 + 0.002 * x - 0.001 * y
    flat = topology_report(x, y, z)
    assert flat.tilt_x_mm_per_mm == pytest.approx(0.002)
    assert flat.tilt_y_mm_per_mm == pytest.approx(-0.001)
    assert flat.plane_z_at_center_mm == pytest.approx(0.2)
    assert flat.tilt_deg == pytest.approx(math.degrees(math.atan(math.sqrt(5) * 1e-3)))
    assert flat.flatness_after_tilt_mm == pytest.approx(0.0, abs=1e-12)
    assert (flat.min_z_mm, flat.min_at_xy_mm) == (pytest.approx(-0.1), (0.0, 200.0))
    assert (flat.max_z_mm, flat.max_at_xy_mm) == (pytest.approx(0.5), (200.0, 0.0))
    assert flat.range_mm == pytest.approx(0.6)
    assert flat.mean_z_mm == pytest.approx(0.2)
    z[1, 1] += 0.05
    bumped = topology_report(x, y, z)
    assert bumped.tilt_x_mm_per_mm == pytest.approx(0.002)  # a central bump does not tilt the plane
    assert bumped.plane_z_at_center_mm == pytest.approx(0.2 + 0.05 / 9)
    assert bumped.flatness_after_tilt_mm == pytest.approx(0.05)


def test_topology_of_table_1():
    report = topology_report(TABLE_1[:, 0], TABLE_1[:, 1], TABLE_1[:, 4])
    assert (report.min_z_mm, report.max_z_mm) == (pytest.approx(-0.304), pytest.approx(1.296))
    assert report.max_at_xy_mm == (400.0, 200.0)  # the paper: "maximum offset of 1.29 mm at (400,200)"
    assert report.range_mm == pytest.approx(1.6)
    assert report.mean_z_mm == pytest.approx(3.632 / 9)


def test_topology_needs_points_off_a_line():
    with pytest.raises(MeshError, match="at least 3 points that are not on one line"):
        topology_report([0, 1, 2], [0, 1, 2], [0, 0, 0])
    with pytest.raises(MeshError, match="as many x, y and z values; got 3, 3, 2"):
        topology_report([0, 1, 2], [0, 1, 2], [0, 0])
