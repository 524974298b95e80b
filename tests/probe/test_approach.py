"""Where a tap starts and where it gives up (tapcell.extras.probe.approach) on the virtual printer:
room to reach the probing speed, and the paper's no-contact rule."""

from __future__ import annotations

import re

import pytest

from tapcell.extras.probe.approach import BedHeightMemory, acceleration_distance_mm, approach_height_mm
from tapcell.host.gcode import GCodeError

from probe_vprinter import make_printer


def test_approach_height_arithmetic():
    assert acceleration_distance_mm(10.0, 200.0) == pytest.approx(0.25)  # v^2 / 2a
    # + 4 samples of cruise at 320 sps (0.125 mm) + 0.1 mm for a bed higher than expected.
    assert approach_height_mm(10.0, 200.0, 320.0) == pytest.approx(0.25 + 0.125 + 0.1)
    memory = BedHeightMemory(lambda x, y: None)
    assert memory.expected_z_mm(50, 50) == 0.0  # homing put the bed at Z 0
    memory.remember(100, 100, 0.3)
    assert memory.expected_z_mm(105, 100) == 0.3 and memory.expected_z_mm(10, 10) == 0.3
    with_mesh = BedHeightMemory(lambda x, y: 0.01 * x)
    with_mesh.remember(100, 100, 0.3)
    assert with_mesh.expected_z_mm(105, 100) == 0.3  # a contact this close beats the mesh
    assert with_mesh.expected_z_mm(20, 100) == pytest.approx(0.2)  # far from any contact: the mesh
    with_mesh.forget()
    assert with_mesh.expected_z_mm(105, 100) == pytest.approx(1.05)


def test_a_faster_probe_right_after_a_pullback_lifts_first(tmp_path):
    """PROBE_ACCURACY ends at the top of its last pullback, 0.12 mm up; 10 mm/s needs 0.25 mm
    to reach its speed at 200 mm/s^2. The second command failed with COASTING_MOVE_ACCELERATION."""
    printer, responses = make_printer(tmp_path)
    printer.gcode.run_script("G1 Z2\nPROBE HOME=Z\nG1 Z1\nPROBE_ACCURACY PROBE_SPEED=2 SAMPLES=3")
    z_after_mm = printer.lookup_object("toolhead").get_position()[2]
    assert z_after_mm < 0.25  # measured 0.119 (the halt is ~30 um below the contact)
    responses.clear()
    printer.gcode.run_script("PROBE_ACCURACY PROBE_SPEED=10 SAMPLES=3")
    result = re.fullmatch(r"// probe accuracy results: .* standard deviation (\d+\.\d+), .*", responses[-1])
    assert result is not None and float(result[1]) < 0.0005
    assert not any("COASTING" in line for line in responses)


def test_no_contact_two_mm_below_the_expected_bed_stops_there(tmp_path):
    """The ABL paper's rule: no hit by 2 mm below the expected bed -> error, even when the axis
    could go deeper (position_min -5 here). The bed at X 5 lies 2.9 mm below the homed centre."""
    # Homed at X0 Y0 where the bed is lowest: travelling at the homed Z 2 would meet the bed near
    # X74 (the nozzle watch stops that as a collision), so lift first.
    printer, _ = make_printer(tmp_path, virtual_printer="bed_shape: tilted\nbed_tilt_x_mm: 6.5\nz_position_min_mm: -5",
                              replace={"position_min: -2": "position_min: -5"}, home=False)
    printer.gcode.run_script("G28\nG1 Z5 F600\nG1 X117.5 Y117.5 Z3 F6000\nPROBE HOME=Z\nG1 Z3\nG1 X5 F6000")
    with pytest.raises(GCodeError) as info:
        printer.gcode.run_script("PROBE")
    assert str(info.value).startswith(
        "Load Cell Probe Error: no contact down to Z=-2.000, 2 mm below the expected bed height 0.000: probing "
        "stopped there. Likely cause: the nozzle is not over the bed")
    assert printer.lookup_object("toolhead").get_position()[2] >= -2.0 - 0.0025  # one Z step
