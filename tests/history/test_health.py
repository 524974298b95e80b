"""Probe health from stored taps: the change test, repeatability, faulty_region suggestions,
the mesh difference and the monitor's printer names. Pure functions, known numbers."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tapcell.store import health
from tapcell.tools.history import printer_specs
from tapcell.tools.web.views import MeshMismatch, bed_map, mesh_difference


def test_the_change_test_is_welchs_t_on_the_latest_taps():
    rng = np.random.default_rng(3)
    baseline = rng.normal(1.0, 0.1, 200)
    recent = rng.normal(1.2, 0.1, 50)
    result = health.trend("noise_sigma_g", [*rng.normal(5.0, 1.0, 30), *baseline, *recent])  # older taps ignored
    expected = (recent.mean() - baseline.mean()) / math.sqrt(recent.var(ddof=1) / 50 + baseline.var(ddof=1) / 200)
    assert result.t == pytest.approx(expected, rel=1e-12)
    assert (result.recent_n, result.baseline_n) == (50, 200)
    assert result.flagged and result.t > 10


def test_an_unchanged_printer_is_not_flagged_in_most_windows():
    rng = np.random.default_rng(5)
    flags = sum(health.trend("noise", list(rng.normal(1.0, 0.1, 250))).flagged for _ in range(500))
    assert flags <= 2  # |t| > 4 under no change: p ≈ 6e-5 per window


def test_the_rejected_share_uses_the_pooled_two_proportion_z():
    # 0 rejects in the latest 50, 16 in the 200 before: Welch's t would be -4.7 (zero variance
    # on one side); the pooled z is -2.07, no flag.
    series = [1.0] * 16 + [0.0] * 184 + [0.0] * 50
    result = health.trend("rejected", series, proportion=True)
    pooled = 16 / 250
    assert result.t == pytest.approx(-0.08 / math.sqrt(pooled * (1 - pooled) * (1 / 50 + 1 / 200)), rel=1e-12)
    assert result.t == pytest.approx(-2.067, abs=1e-3) and not result.flagged
    assert health.trend("rejected", [0.0] * 200 + [1.0] * 10 + [0.0] * 40, proportion=True).flagged  # 0 % -> 20 %


def test_too_few_taps_give_no_verdict():
    result = health.trend("noise", [1.0] * 55)  # 50 recent, 5 before
    assert result.t is None and not result.flagged


def test_repeatability_pools_spots_tapped_more_than_once():
    # Spot A: 0.100, 0.104 (squares 2 × 0.002²), spot B once (no freedom), spot C: 0.2, 0.2, 0.2.
    value = health.repeatability_um([10, 10, 50, 90, 90, 90], [10, 10.2, 50, 90, 90, 90],
                                    [0.100, 0.104, 0.3, 0.2, 0.2, 0.2])
    assert value == pytest.approx(math.sqrt(2 * 0.002**2 / 3) * 1000.0, rel=1e-9)
    assert health.repeatability_um([1.0], [1.0], [0.1]) is None


def test_a_spot_that_keeps_failing_is_suggested_as_a_faulty_region():
    spots = [(51.0, 61.0, True), (52.5, 62.0, True), (53.0, 60.5, True), (55.0, 65.0, False),  # 3 of 4 rejected
             (150.0, 150.0, True), (151.0, 151.0, True),  # two rejects: not enough
             (120.0, 20.0, True), (121.0, 21.0, True), (122.0, 22.0, True),
             *[(125.0, 25.0, False)] * 4]  # 3 rejects of 7: under half
    regions = health.faulty_regions(spots)
    assert len(regions) == 1
    assert regions[0].config_lines(1) == ["faulty_region_1_min: 49.0, 58.5", "faulty_region_1_max: 55.0, 64.0"]
    assert (regions[0].rejected, regions[0].taps) == (3, 4)


def test_the_mesh_difference_is_point_by_point_on_one_grid():
    base = {"id": 1, "matrix": [[0.0, 0.1], [0.2, 0.3]], "x_min_mm": 10, "y_min_mm": 10, "x_max_mm": 200,
            "y_max_mm": 200, "profile": "default", "recorded_s": 1.0}
    later = dict(base, id=2, matrix=[[0.01, 0.1], [0.25, 0.3]])
    view = mesh_difference(later, base)
    assert np.allclose(view["matrix"], [[0.01, 0.0], [0.05, 0.0]])
    assert view["max_z_mm"] == pytest.approx(0.05) and view["min_z_mm"] == pytest.approx(0.0)
    with pytest.raises(MeshMismatch, match=r"mesh 3 \(3×2 .*\) and mesh 1 \(2×2 .*\) are not on the same grid"):
        mesh_difference(dict(base, id=3, matrix=[[0, 0, 0], [0, 0, 0]]), base)


def test_printers_are_named_or_take_their_host():
    specs = printer_specs(["voron=http://voron.local:7125", "http://10.0.0.5:7125", "ws://box:7125/klippysocket"])
    assert [(s.name, s.url) for s in specs] == [("voron", "http://voron.local:7125"),
                                                ("10.0.0.5:7125", "http://10.0.0.5:7125"),
                                                ("box:7125", "ws://box:7125/klippysocket")]
    with pytest.raises(ValueError, match="printer name 'a' is given twice"):
        printer_specs(["a=http://x:1", "a=http://y:1"])


def test_a_retry_is_the_same_spot_right_after_a_rejected_tap():
    spots = [(10.0, 10.0, True), (10.1, 10.0, False),  # rejected, then retried there
             (50.0, 50.0, False), (50.0, 50.0, False),  # repeated, nothing rejected: no retry
             (90.0, 90.0, True), (95.0, 90.0, True)]  # moved on after a reject: no retry
    assert bed_map(spots)["retried"] == [False, True, False, False, False, False]
