"""BED_MESH_CALIBRATE with tap analysis on the virtual printer, against the true bed."""

from __future__ import annotations

import numpy as np
import pytest

from machines import gcode_error

MESH = """
[bed_mesh]
speed: 150
mesh_min: 20, 20
mesh_max: 215, 215
probe_count: 5, 5
algorithm: bicubic
move_check_distance: 3
split_delta_z: 0.01
horizontal_z_clearance: 0.4
"""

THERMAL = """
[z_thermal_adjust]
sensor_type: temperature_combined
sensor_list: extruder
min_temp: 0
max_temp: 400
"""


def home_accurately(printer) -> None:
    printer.gcode.run_script("G28\nG1 X117.5 Y117.5 Z3 F6000\nPROBE HOME=Z")


def true_bed_mm(printer):
    frame_z_mm = printer.lookup_object("toolhead").frame_offset_mm["z"]
    return lambda x, y: printer.backend.truth.contact_z_at(x, y) + frame_z_mm


def test_mesh_matches_the_warped_bed(make_printer):
    printer = make_printer(MESH, probe=True, scenario="warped-bed")
    home_accurately(printer)
    toolhead = printer.lookup_object("toolhead")
    travel_heights = []
    move_to = toolhead.move_to

    def recording_move_to(x=None, y=None, z=None, speed_mm_s=5.0):
        if x is not None:  # a travel to the next point: at which height?
            travel_heights.append(toolhead.get_position()[2])
        move_to(x=x, y=y, z=z, speed_mm_s=speed_mm_s)

    toolhead.move_to = recording_move_to
    progress = []
    printer.register_event_handler("bed_mesh:progress", lambda done, total: progress.append((done, total)))
    printer.gcode.run_script("BED_MESH_CALIBRATE")
    toolhead.move_to = move_to
    assert progress == [(n, 25) for n in range(1, 26)]
    status = printer.get_status()["bed_mesh"]
    probed = np.array(status["probed_matrix"])
    xs, ys = np.meshgrid(np.linspace(20, 215, 5), np.linspace(20, 215, 5))
    error_um = (probed - true_bed_mm(printer)(xs, ys)) * 1000.0
    assert np.max(np.abs(error_um)) <= 3.0
    # The bed spans ~0.3 mm; the mesh sees that.
    assert np.ptp(probed) == pytest.approx(np.ptp(true_bed_mm(printer)(xs, ys)), abs=0.004)
    # Between points the nozzle rose only 0.4 mm above the last contact (one Z step: 2.5 um).
    serpentine = probed.copy()
    serpentine[1::2] = serpentine[1::2, ::-1]
    contacts = serpentine.ravel()
    assert np.array(travel_heights[1:]) == pytest.approx(contacts[:-1] + 0.4, abs=0.003)
    assert printer.get_status()["bed_mesh"]["last_calibration"]["time_s"] < 35.0  # 25 points


def test_oozy_mesh_completes_with_circle(make_printer):
    printer = make_printer(MESH.replace("probe_count: 5, 5", "probe_count: 3, 3").replace(
        "algorithm: bicubic", "algorithm: lagrange"), probe=True, scenario="oozy")
    # The guide's sequence on a hot, oozing nozzle: home, clean the nozzle, mesh with CIRCLE.
    printer.gcode.run_script("G28\nG1 X117.5 Y117.5 Z3 F6000\nPROBE HOME=Z BAD_PROBE_STRATEGY=ignore\n"
                             "G1 Z0.4\nNOZZLE_CLEANUP\nBED_MESH_CALIBRATE BAD_PROBE_STRATEGY=CIRCLE")
    probed = np.array(printer.get_status()["bed_mesh"]["probed_matrix"])
    xs, ys = np.meshgrid(np.linspace(20, 215, 3), np.linspace(20, 215, 3))
    assert np.max(np.abs(probed - true_bed_mm(printer)(xs, ys))) < 0.004  # measured: 2.6 um


def test_calibrate_needs_homing_and_checks_parameters(make_printer):
    printer = make_printer(MESH, probe=True)
    assert gcode_error(printer, "BED_MESH_CALIBRATE") == "BED_MESH_CALIBRATE: home all axes first (G28)"
    assert gcode_error(printer, "BED_MESH_CALIBRATE METHOD=magic") == "Error on 'BED_MESH_CALIBRATE METHOD=magic': METHOD=magic: must be one of tap, two_pass, prusa"
    assert gcode_error(printer, "BED_MESH_CALIBRATE PROBE_COUNT=2") == (
        "Error on 'BED_MESH_CALIBRATE PROBE_COUNT=2': PROBE_COUNT must have minimum of 3 (allowed: 3 to 50)")
    assert gcode_error(printer, "BED_MESH_CALIBRATE PROBE_COUNT=3,4,5") == (
        "Error on 'BED_MESH_CALIBRATE PROBE_COUNT=3,4,5': PROBE_COUNT=3,4,5: must be one integer or a pair X, Y")
    assert "HORIZONTAL_Z_CLEARANCE must be above 0" in gcode_error(printer, "BED_MESH_CALIBRATE HORIZONTAL_Z_CLEARANCE=0")


def test_thermal_calibrate_measures_the_nozzle_growth(make_printer):
    printer = make_printer(THERMAL, probe=True)
    printer.gcode.run_script("G28\nG1 X117.5 Y117.5 Z2 F6000\nZ_THERMAL_CALIBRATE TEMP_COLD=100 TEMP_HOT=160 SAMPLES=5")
    coeff = printer.lookup_object("z_thermal_adjust").state.settings.temp_coeff_mm_per_c
    # The virtual nozzle grows 0.45 um per degree C: the guide's -0.00045455 mm/C.
    assert coeff == pytest.approx(-0.00045, rel=0.02)  # measured: -0.000449
    assert printer.config.pending_changes()["z_thermal_adjust"]["temp_coeff"] == f"{coeff:.8f}"
