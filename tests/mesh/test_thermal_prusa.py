"""z_thermal_adjust arithmetic and the Prusa-matched thresholds, tares and checks."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from tapcell.mesh.errors import MeshError, MeshOptionError
from tapcell.mesh.prusa import (
    Thresholds,
    check_tare_deviation,
    mesh_tares,
    retry_offsets_mm,
    z_home_tares,
)
from tapcell.mesh.thermal import (
    ThermalAdjustSettings,
    ZThermalAdjust,
    measure_temp_coeff,
    smooth_temperature_c,
    z_adjustment_mm,
)


def test_temp_coeff_from_the_guides_example():
    coeff = measure_temp_coeff(z_cold_mm=1.20, t_cold_c=180.0, z_hot_mm=1.15, t_hot_c=290.0)
    assert coeff == pytest.approx(-0.05 / 110, rel=1e-9)
    assert round(coeff, 8) == -0.00045455


def test_temp_coeff_needs_two_different_temperatures():
    with pytest.raises(MeshError, match=r"the two temperatures \(200 and 200.5 degC\) must differ by at least 1 degC"):
        measure_temp_coeff(0.0, 200, 0.01, 200.5)


def test_adjustment_sign_and_clamp():
    coeff = -0.00045455
    assert z_adjustment_mm(290.0, 180.0, coeff, 1.0) == pytest.approx(0.0500005)  # nozzle grew: lift it
    assert z_adjustment_mm(290.0, 180.0, coeff, 0.03) == 0.03
    assert z_adjustment_mm(70.0, 180.0, coeff, 0.03) == -0.03
    assert z_adjustment_mm(200.0, 180.0, 0.01, 1.0) == pytest.approx(-0.2)  # config ref: +0.01 moves Z down


def test_smoothing_moves_toward_the_reading_by_dt_over_smooth_time():
    assert smooth_temperature_c(100.0, 200.0, 0.5, 2.0) == pytest.approx(125.0)
    assert smooth_temperature_c(125.0, 200.0, 0.5, 2.0) == pytest.approx(143.75)
    assert smooth_temperature_c(100.0, 200.0, 5.0, 2.0) == 200.0  # a long gap jumps to the reading


def test_adjuster_references_the_temperature_at_homing():
    settings = ThermalAdjustSettings(
        temp_coeff_mm_per_c=-0.0005, smooth_time_s=1.0, max_z_adjustment_mm=0.1, z_adjust_off_above_mm=10.0
    )
    adjuster = ZThermalAdjust(settings)
    adjuster.on_temperature(0.0, 180.0)
    assert adjuster.adjusted_z_mm(0.2) == 0.2  # not homed yet
    adjuster.on_z_homed()
    adjuster.on_temperature(0.5, 240.0)  # smoothed: 180 + 60 * 0.5 = 210
    assert adjuster.adjusted_z_mm(0.2) == pytest.approx(0.2 + 0.015)
    adjuster.on_temperature(2.0, 240.0)  # smoothed reaches 240
    assert adjuster.adjusted_z_mm(12.0) == pytest.approx(12.015)  # above z_adjust_off_above: held
    assert adjuster.adjusted_z_mm(5.0) == pytest.approx(5.03)
    status = json.loads(json.dumps(adjuster.to_status()))
    assert status == {
        "temperature": 240.0,
        "measured_min_temp": 180.0,
        "measured_max_temp": 240.0,
        "current_z_adjust": pytest.approx(0.03),
        "z_adjust_ref_temperature": 180.0,
        "enabled": True,
    }
    adjuster.enabled = False
    assert adjuster.adjusted_z_mm(5.0) == 5.0


def test_adjuster_refuses_readings_outside_the_sensor_range():
    adjuster = ZThermalAdjust(ThermalAdjustSettings(min_temp_c=0, max_temp_c=300))
    with pytest.raises(MeshError, match=r"\[z_thermal_adjust\] temperature 350.0 degC is outside min_temp 0 .. max_temp 300"):
        adjuster.on_temperature(1.0, 350.0)
    with pytest.raises(MeshError, match="no temperature reading yet"):
        adjuster.on_z_homed()


def test_thermal_settings_validation_names_the_option():
    with pytest.raises(MeshOptionError, match=r"\[z_thermal_adjust\] smooth_time = 0: must be a positive number"):
        ThermalAdjustSettings(smooth_time_s=0)
    with pytest.raises(MeshOptionError, match=r"max_z_adjustment = -0.1: must be 0 or more mm"):
        ThermalAdjustSettings(max_z_adjustment_mm=-0.1)
    with pytest.raises(MeshOptionError, match=r"max_temp = 10: must be greater than min_temp \(20\)"):
        ThermalAdjustSettings(min_temp_c=20, max_temp_c=10)


def test_prusa_thresholds_and_release_levels():
    thresholds = Thresholds()
    assert [thresholds.value_g(k) for k in ("z_fast", "z_slow", "mesh", "xy")] == [125, 125, 125, 40]
    assert thresholds.release_g("z_fast") == 45.0  # -125 g + 80 g hysteresis
    assert thresholds.release_g("xy") == 20.0
    changed = thresholds.with_threshold("mesh", 150)
    assert (changed.mesh_g, changed.z_fast_g, thresholds.mesh_g) == (150.0, 125.0, 125.0)
    assert changed.to_status()["mesh_g"] == 150.0
    assert thresholds.with_threshold("xy", 30).xy_g == 30.0  # XY has no 80 g hysteresis


def test_threshold_validation_names_the_command_and_value():
    with pytest.raises(MeshError, match=r"SET_Z_SLOW_THRESHOLD VALUE=60: must be above the hysteresis \(80 g\)"):
        Thresholds().with_threshold("z_slow", 60)
    with pytest.raises(MeshError, match=r"SET_XY_THRESHOLD VALUE=-5: must be a number of grams above 0"):
        Thresholds().with_threshold("xy", -5)
    with pytest.raises(MeshError, match=r"SET_Z_FAST_THRESHOLD VALUE=1500: .* at most 1000"):
        Thresholds().with_threshold("z_fast", 1500)
    with pytest.raises(MeshError, match="unknown threshold 'nozzle': must be one of z_fast, z_slow, mesh, xy"):
        Thresholds().value_g("nozzle")


def test_tare_counts():
    assert len(z_home_tares()) == 2
    assert len(mesh_tares(9)) == 10  # 3 x 3 mesh: 1 + 9, not 1 + 9 x 2
    assert len(mesh_tares(49)) == 50
    first = mesh_tares(9)[0]
    assert (first.purpose, first.settle_s, first.sample_count) == ("session reference", 0.3, 48)
    assert first.duration_s == pytest.approx(0.45)  # 300 ms settle + 48 samples at 320 Hz
    with pytest.raises(MeshError, match="point count 0 must be a positive integer"):
        mesh_tares(0)


def test_reference_tare_deviation_decision():
    assert check_tare_deviation(1100.0, 1000.0).action == "accept"
    assert check_tare_deviation(1125.0, 1000.0).action == "accept"  # exactly 125 g is still fine
    pulled = check_tare_deviation(874.9, 1000.0)
    assert (pulled.action, pulled.lift_mm) == ("lift_and_retare", 20.0)
    assert pulled.deviation_g == pytest.approx(-125.1)
    assert check_tare_deviation(1200.0, 1000.0, limit_g=250.0).to_status() == {
        "action": "accept",
        "deviation_g": 200.0,
        "lift_mm": 0.0,
    }


def test_retry_positions_are_rings_two_mm_apart():
    offsets = retry_offsets_mm()
    assert offsets.shape == (40, 2)
    radii = np.hypot(offsets[:, 0], offsets[:, 1])
    ring_sizes = [int(np.sum(np.isclose(radii, r))) for r in (0.0, 2.0, 4.0, 6.0)]
    assert ring_sizes == [1, 7, 13, 19]
    assert offsets[1].tolist() == pytest.approx([2.0, 0.0])
    assert offsets[2].tolist() == pytest.approx([2 * math.cos(2 * math.pi / 7), 2 * math.sin(2 * math.pi / 7)])
    assert len(retry_offsets_mm(5)) == 5
    with pytest.raises(MeshError, match="retry attempts 41: must be an integer from 1 to 40"):
        retry_offsets_mm(41)
