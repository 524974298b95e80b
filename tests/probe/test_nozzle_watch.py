"""The nozzle watch (issue 19): every move that can touch the bed runs with the trigger armed.

Each reproducer runs twice on the calibrated example printer: with the watch off
(`nozzle_watch_height: 0`, today's main) the true peak force (SIM_TRUTH) is far past
force_safety_limit (2000 g) and the nozzle ends pressed into the bed; with the default watch the
move stops at the first sample over nozzle_watch_force, the nozzle is lifted and the command ends
with the collision error naming the command that moved.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from probe_vprinter import make_printer, run_measured

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the bench package beside tests/
from bench.nozzle_watch import bump_csv  # noqa: E402  (after the path)
from tapcell.extras.load_cell_probe.watch import DEFAULT_FORCE_G, is_watched, read_watch_options  # noqa: E402

FORCE_SAFETY_LIMIT_G = 2000.0
WATCH_OFF = "nozzle_watch_height: 0"
COLLISION = "Load Cell Probe Error: nozzle collision at "


def printer_in(folder, **options):
    folder.mkdir()
    printer, _ = make_printer(folder, **options)
    return printer


def assert_stopped(error, peak_g, clearance_mm, command: str):
    assert error is not None and error.startswith(COLLISION), error
    assert f"during {command}" in error
    assert peak_g < FORCE_SAFETY_LIMIT_G
    assert clearance_mm > 0.0


def test_offset_below_the_bed_is_stopped(tmp_path):
    """SET_GCODE_OFFSET Z=-1.9 then G1 Z0.1: 6,085 g and 1.83 mm into the bed without the watch."""
    script = "SET_GCODE_OFFSET Z=-1.9\nG1 Z0.1 F600"
    off = printer_in(tmp_path / "off", probe_options=WATCH_OFF)
    error, peak_g, clearance_mm = run_measured(off, script)
    assert error is None and peak_g > 3 * FORCE_SAFETY_LIMIT_G and clearance_mm < -1.8
    on = printer_in(tmp_path / "on")
    error, peak_g, clearance_mm = run_measured(on, script)
    assert_stopped(error, peak_g, clearance_mm, "'G1 Z0.1 F600'")
    # Measured 366 g: the first sample past 250 g (the trigger), plus one sample of travel at 10 mm/s.
    assert peak_g < 2 * DEFAULT_FORCE_G
    x, y, z = (float(v) for v in error[len(COLLISION):].split(" ")[0].split(","))
    assert (x, y) == (110.0, 110.0) and -0.2 < z < 0.0  # where it stopped: just below the bed at Z 0
    assert on.lookup_object("toolhead").nozzle_watch.collisions == 1


def test_deactivate_gcode_below_the_bed_is_stopped(tmp_path):
    """`deactivate_gcode: G1 Z-1.5`: about 5 kg after every G28 without the watch."""
    options = "deactivate_gcode: G1 Z-1.5 F600"
    off = printer_in(tmp_path / "off", probe_options=f"{options}\n{WATCH_OFF}", home=False)
    error, peak_g, clearance_mm = run_measured(off, "G28")
    assert error is None and peak_g > 2 * FORCE_SAFETY_LIMIT_G and clearance_mm < -1.4
    on = printer_in(tmp_path / "on", probe_options=options, home=False)
    error, peak_g, clearance_mm = run_measured(on, "G28")
    assert_stopped(error, peak_g, clearance_mm, "'G1 Z-1.5 F600' in 'G28'")


@pytest.mark.parametrize("height_mm", [1.0, 1.5])
def test_blob_between_mesh_points_is_stopped(tmp_path, height_mm):
    """A blob between the 2nd and 3rd mesh points, travel 0.4 mm above the bed (horizontal_z_clearance):
    1,984 g (1.0 mm) and 3,649 g (1.5 mm) and a mesh reported done without the watch."""
    bed = bump_csv(tmp_path / "blob.csv", 66.0, 15.0, height_mm, 3.0)
    off = printer_in(tmp_path / "off", probe_options=WATCH_OFF, virtual_printer=bed)
    error, peak_g, _ = run_measured(off, "BED_MESH_CALIBRATE")
    assert error is None and peak_g > 0.95 * FORCE_SAFETY_LIMIT_G
    on = printer_in(tmp_path / "on", virtual_printer=bed)
    error, peak_g, clearance_mm = run_measured(on, "BED_MESH_CALIBRATE")
    assert_stopped(error, peak_g, clearance_mm, "'BED_MESH_CALIBRATE'")
    assert on.lookup_object("bed_mesh").mesh is None  # no mesh from the stopped command
    x = float(error[len(COLLISION):].split(",")[0])
    assert 60.0 < x < 66.0  # stopped on the blob's near flank


@pytest.mark.parametrize("scenario", ["clean", "slow-adc"])
def test_steep_blob_is_stopped_below_the_limit_at_any_sample_rate(tmp_path, scenario):
    """A 1.5 mm blob with 45-degree flanks met at the mesh's 150 mm/s: the watch alone (at the
    travel speed asked) stopped it at 2,475 g (320 sps) and 3,651 g (80 sps); capped to the speed
    at which the trigger stops a 45-degree flank in time: 627 g and 1,298 g."""
    bed = bump_csv(tmp_path / "blob.csv", 66.0, 15.0, 1.5, 1.5)
    on = printer_in(tmp_path / "on", scenario=scenario, virtual_printer=bed)
    error, peak_g, clearance_mm = run_measured(on, "BED_MESH_CALIBRATE")
    assert_stopped(error, peak_g, clearance_mm, "'BED_MESH_CALIBRATE'")
    assert peak_g < 0.7 * FORCE_SAFETY_LIMIT_G


def test_watched_speed_cap_follows_the_assumed_bed(tmp_path):
    """At 320 sps G28 Z's backoffs measure the bed (3.26 g/um, x1.25): the trigger stops a head-on
    contact within 2000 g up to 40 mm/s (also once the tap measured 3.5 g/um). Unmeasured
    (max_bed_stiffness, 100 g/um) only up to 2 mm/s. A force must read on two samples in a row (a
    corrupted frame is not a collision): that sample of travel is what halves the cap (80 mm/s and
    3 mm/s with a single sample). A diagonal move meets a 45-degree flank and the bed at once:
    1/sqrt(2) of that."""
    printer = printer_in(tmp_path / "p", home=False)
    printer.gcode.run_script("G28")
    watch = printer.lookup_object("toolhead").nozzle_watch
    device = printer.lookup_object("load_cell_probe")
    stiffness_g_um, measured = device.speed_guard.assumed_stiffness_g_um()
    assert measured and 3.5 < stiffness_g_um < 4.5 and not device.last_taps
    assert watch.speed_cap_mm_s((1.0, 0.0, 0.0)) == 40.0
    device.home_stiffness_g_um = None   # as if G28 Z could not read its backoffs
    assert device.speed_guard.assumed_stiffness_g_um() == (100.0, False)
    assert watch.speed_cap_mm_s((1.0, 0.0, 0.0)) == 2.0
    assert watch.speed_cap_mm_s((0.0, 0.0, -1.0)) == 2.0
    assert watch.speed_cap_mm_s((1.0, 0.0, -1.0)) == pytest.approx(2.0 / np.sqrt(2.0))
    printer.gcode.run_script("G1 X110 Y110 F6000\nPROBE")
    stiffness_g_um, measured = device.speed_guard.assumed_stiffness_g_um()
    assert measured and 4.2 < stiffness_g_um < 4.6 and device.last_taps   # the tap read 3.5 g/um
    assert watch.speed_cap_mm_s((1.0, 0.0, 0.0)) == 40.0


def test_local_warp_under_mesh_travel_is_stopped(tmp_path):
    """A bed bulging 1.3 mm between mesh points (a local warp the travel height cannot predict)."""
    bed = bump_csv(tmp_path / "warp.csv", 66.0, 15.0, 1.3, 6.0, gaussian=True)
    off = printer_in(tmp_path / "off", probe_options=WATCH_OFF, virtual_printer=bed)
    error, peak_g, _ = run_measured(off, "BED_MESH_CALIBRATE")
    assert error is None and peak_g > FORCE_SAFETY_LIMIT_G
    on = printer_in(tmp_path / "on", virtual_printer=bed)
    error, peak_g, clearance_mm = run_measured(on, "BED_MESH_CALIBRATE")
    assert_stopped(error, peak_g, clearance_mm, "'BED_MESH_CALIBRATE'")


def test_moves_above_the_watch_height_and_rising_moves_are_not_watched(tmp_path):
    printer, _ = make_printer(tmp_path)
    watch = printer.lookup_object("toolhead").nozzle_watch
    before = watch.watched_moves
    printer.gcode.run_script("G1 Z5 F600\nG1 X100 Y100 F6000\nG1 Z2.5")
    assert watch.watched_moves == before
    printer.gcode.run_script("G1 Z1 F600\nG1 Z3\nG1 X110 Z1.5")  # down below 2 mm: watched; up only: not
    assert watch.watched_moves == before + 2


@pytest.mark.parametrize("start, target, watched", [
    ((0, 0, 5.0), (10, 0, 5.0), False),   # travel above the height
    ((0, 0, 5.0), (0, 0, 1.0), True),     # ends below
    ((0, 0, 1.0), (10, 0, 5.0), True),    # starts below, moves sideways
    ((0, 0, 1.0), (0, 0, 5.0), False),    # only rises
    ((0, 0, 0.2), (50, 0, 0.2), True),    # a first-layer line
])
def test_which_moves_are_watched(start, target, watched):
    assert is_watched(start, target, 2.0) is watched
    assert is_watched(start, target, 0.0) is False  # nozzle_watch_height: 0 turns the watch off


@pytest.mark.parametrize("clearance, expected_mm", [(None, 2.0), ("0.4", 2.0), ("3", 4.0)])
def test_watch_height_default_follows_horizontal_z_clearance(make_section, tmp_path, clearance, expected_mm):
    from tapcell.host.config import ConfigFile

    text = "[load_cell_probe]\nsensor_type: hx711\n"
    if clearance is not None:
        text += f"[bed_mesh]\nhorizontal_z_clearance: {clearance}\n"
    path = tmp_path / "p.cfg"
    path.write_text(text)
    options = read_watch_options(ConfigFile.read(path).getsection("load_cell_probe"))
    assert options.height_mm == expected_mm
    assert options.force_g == DEFAULT_FORCE_G


def test_a_press_cannot_creep_up_in_small_steps(tmp_path):
    """50 moves of 0.05 mm down from Z 2, each after a rest (163 g each on this bed, below
    nozzle_watch_force): each is measured from the tare taken clear of the bed, not from the press
    the previous one left (tared on it, the steps would go on to the 2,000 g force window)."""
    printer = printer_in(tmp_path / "p")
    error, peak_g, clearance_mm = run_measured(printer, "G91\n" + "G1 Z-0.05 F60\nG4 P200\n" * 50)
    assert_stopped(error, peak_g, clearance_mm, "'G1 Z-0.05 F60'")
    assert peak_g < 2 * DEFAULT_FORCE_G  # one step past 250 g at most


def test_a_saturated_sensor_in_a_watched_move_is_named_not_a_collision(tmp_path):
    printer = printer_in(tmp_path / "p")
    at_s = printer.backend.now_s + 0.3
    printer.gcode.run_script(f"SIM_FAULT NAME=saturation AT={at_s:.3f}")
    error, peak_g, clearance_mm = run_measured(printer, "G1 Z1 F60")
    assert error.startswith("Load Cell Probe Error: the load cell reading is at the end of the ADC's range (")
    assert error.endswith("during 'G1 Z1 F60')") and "nozzle watch stopped the move at 110.000,110.000,1." in error
    assert peak_g == 0.0 and clearance_mm > 1.0
