"""The paper's two-pass ABL through BED_MESH_CALIBRATE METHOD=two_pass on the virtual printer."""

from __future__ import annotations

import numpy as np
import pytest

from tapcell.extras.bed_mesh.two_pass import TwoPassMover
from tapcell.extras.load_cell_probe.threshold import ThresholdProber
from tapcell.mesh.abl import PlanStep

from machines import gcode_error

MESH = """
[bed_mesh]
mesh_min: 20, 20
mesh_max: 215, 215
probe_count: 3, 3
mesh_pps: 0
"""


@pytest.fixture
def abl_printer(make_printer):
    printer = make_printer(MESH, probe=True, scenario="tilted-bed")
    printer.gcode.run_script("G28")
    return printer


def test_two_pass_weighting_and_topology(abl_printer, make_printer):
    abl_printer.gcode.run_script("BED_MESH_CALIBRATE METHOD=two_pass")
    status = abl_printer.get_status()["bed_mesh"]
    points = status["last_calibration"]["points"]
    assert len(points) == 9
    for point in points:
        assert point["z_mm"] == pytest.approx(0.4 * point["z_fast_mm"] + 0.6 * point["z_slow_mm"], abs=1e-12)
    # Serpentine order into the matrix: point 4 (index 3) is the right end of the middle row; every
    # point is raised by the offset one analysed tap found at the middle point (index 4).
    offset_mm = status["last_calibration"]["tap_offset_mm"]
    assert status["last_calibration"]["tap_offset_xy_mm"] == [117.5, 117.5]
    probed = np.array(status["probed_matrix"])
    assert probed[1, 2] == pytest.approx(points[3]["z_mm"] + offset_mm, abs=1e-6)
    assert probed[2, 0] == pytest.approx(points[6]["z_mm"] + offset_mm, abs=1e-6)
    # The bed is tilted 0.4 mm across X (235 mm) and -0.25 mm across Y.
    topology = status["last_calibration"]["topology"]
    assert topology["tilt_x_mm_per_mm"] == pytest.approx(0.4 / 235.0, abs=0.0002)
    assert topology["tilt_y_mm_per_mm"] == pytest.approx(-0.25 / 235.0, abs=0.0002)
    text = "\n".join(make_printer.responses)
    assert "// Bed topology (two-pass probing, Z = 0.4 * fast + 0.6 * slow):" in text
    # G28 Z's backoffs measured the bed (3.2 g/um, x1.25): the force guard passes max_z_velocity's
    # 15 mm/s, but the fast pass moves at most 25 um per sample (its trigger falls anywhere in one).
    assert ("fast pass at 8 mm/s (25 um per sample at 320 samples/s; the paper moved its bed at 120 mm/s)"
            in text)
    # The surface shape is right; each height is where the force crossed the 75 g trigger, between
    # two samples: 75 g / stiffness below the contact, wherever in a conversion the contact fell.
    toolhead = abl_printer.lookup_object("toolhead")
    xs, ys = np.meshgrid([20.0, 117.5, 215.0], [20.0, 117.5, 215.0])
    truth = abl_printer.backend.truth.contact_z_at(xs, ys) + toolhead.frame_offset_mm["z"]
    error_um = (probed - offset_mm - truth) * 1000.0
    depth_um = 75.0 / abl_printer.backend.truth.stiffness_g_um
    # measured (seeds 1-6): 1.0-2.4 um spread, mean 0.1-0.4 um below the depth (the halt positions
    # spread 15-17 um: a sample of travel is 25 um at 8 mm/s)
    assert np.ptp(error_um) < 4.0 and error_um.mean() == pytest.approx(-depth_um, abs=1.5)
    # The tap takes the depth out: what is left is the spread (measured: |mean| <= 0.61, max 1.86 um).
    corrected_um = (probed - truth) * 1000.0
    assert abs(corrected_um.mean()) < 1.5 and np.abs(corrected_um).max() < 3.0


def test_no_contact_before_the_travel_limit_stops(abl_printer):
    toolhead = abl_printer.lookup_object("toolhead")
    toolhead.set_z_position(toolhead.get_position()[2] - 3.0)  # the bed is "3 mm higher": never reached
    assert gcode_error(abl_printer, "BED_MESH_CALIBRATE METHOD=two_pass") == ("BED_MESH_CALIBRATE METHOD=two_pass: no contact at point 1 of 9 (X=20.000 Y=20.000) "
                              "on the fast pass before the travel limit Z=-2.000 mm: probing stopped")
    assert abl_printer.get_status()["bed_mesh"]["profile_name"] == ""


def test_a_trigger_only_height_does_not_move_with_the_sample_phase(make_printer):
    """The fast pass from start heights an eighth of a sample's travel apart: each contact falls
    elsewhere in a conversion. Where the descent halted moves by up to a sample's travel; the
    height two_pass keeps (where the force crossed the trigger, between two samples) does not."""
    printer = make_printer(MESH, probe=True)
    printer.gcode.run_script("G28\nG1 X117.5 Y117.5 F6000")
    device = printer.lookup_object("load_cell_probe")
    prober = ThresholdProber(device)
    toolhead = prober.toolhead
    mover = TwoPassMover(prober, device.options.trigger_force_g, device.options.tare_time_s)
    speed_mm_s = 8.0
    travel_mm = speed_mm_s / device.sample_rate_sps  # 25 um
    kept_mm, halted_mm = [], []
    with device.guarded():
        for eighth in range(8):
            toolhead.move_to(z=1.0 + eighth / 8 * travel_mm, speed_mm_s=5.0)
            kept_mm.append(mover(PlanStep("probe", 117.5, 117.5, -2.0, speed_mm_s, "fast")))
            halted_mm.append(toolhead.get_position()[2])
    # measured (seed 1): halts 20.0 um apart, kept heights 1.28 um
    assert np.ptp(halted_mm) * 1000.0 > 15.0
    assert np.ptp(kept_mm) * 1000.0 < 3.0


def test_what_came_before_the_mesh_does_not_move_its_points(make_printer):
    """Two meshes that differ only in a dwell of a fraction of a sample before them: every point's
    passes land elsewhere on the sample grid. Measured (seed 1, quarter-period dwells): single
    passes 0.75 um apart at most, weighted points 0.54 um (halt positions: 22.5 and 17.5 um)."""
    runs = []
    for quarter in range(4):
        printer = make_printer(MESH, probe=True, scenario="tilted-bed")
        dwell_ms = quarter / 4 * 1000.0 / printer.lookup_object("load_cell_probe").sample_rate_sps
        printer.gcode.run_script(f"G28\nG4 P{dwell_ms:.4f}\nBED_MESH_CALIBRATE METHOD=two_pass")
        points = printer.get_status()["bed_mesh"]["last_calibration"]["points"]
        runs.append([(point["z_fast_mm"], point["z_slow_mm"], point["z_mm"]) for point in points])
    spread_um = np.ptp(np.array(runs), axis=0).max(axis=0) * 1000.0
    assert spread_um[0] < 2.0 and spread_um[1] < 2.0 and spread_um[2] < 1.5, spread_um
