"""BED_MESH_CALIBRATE ADAPTIVE=1 (objects from the exclude_object status) and [bed_mesh]
faulty_region_N_min/max on the virtual printer."""

from __future__ import annotations

import re

import numpy as np
import pytest

from tapcell.host.config import ConfigError

from machines import gcode_error
from test_bed_mesh import MESH as MESH_3X3, TILTED as TILTED_PROFILE
from test_bed_mesh_calibrate import MESH

TILTED = "\n[virtual_printer]\nbed_shape: tilted\nbed_tilt_x_mm: 0.6\nbed_tilt_y_mm: 0.3\n"
TAP_LINE = re.compile(r"// probe at (-?\d+\.\d+),(-?\d+\.\d+) is z=(-?\d+\.\d+)")


class ExcludeObjectStatus:
    """The `exclude_object` printer object as EXCLUDE_OBJECT_DEFINE leaves it (Klipper's fields)."""

    def __init__(self, objects):
        self.objects = objects

    def get_status(self, eventtime=None):
        return {"objects": self.objects, "excluded_objects": [], "current_object": None}


def taps(responses) -> list[tuple[float, float, float]]:
    return [tuple(float(v) for v in m.groups()) for m in map(TAP_LINE.fullmatch, responses) if m]


def home(printer):
    printer.gcode.run_script("G28\nG1 X117.5 Y117.5 Z3 F6000\nPROBE HOME=Z")


def test_adaptive_mesh_probes_only_around_the_objects(make_printer):
    printer = make_printer(MESH + "adaptive_margin: 5\n", probe=True)
    printer.add_object("exclude_object", ExcludeObjectStatus([
        {"name": "PART_A", "center": [110, 110], "polygon": [[100, 100], [120, 100], [120, 120], [100, 120]]},
        {"name": "PART_B", "center": [140, 95], "polygon": [[135, 90], [145, 90], [145, 100], [135, 100]]},
    ]))
    home(printer)
    make_printer.responses.clear()
    printer.gcode.run_script("BED_MESH_CALIBRATE ADAPTIVE=1")
    status = printer.get_status()["bed_mesh"]
    assert (status["mesh_min"], status["mesh_max"]) == ([95.0, 85.0], [150.0, 125.0])
    # 55 of 195 mm at 5 points: ceil(1.4) = 2 -> the minimum 3; 40 mm -> 3.
    assert np.array(status["probed_matrix"]).shape == (3, 3)
    tapped = np.array(taps(make_printer.responses))[:, :2]
    assert len(tapped) == 9
    assert tapped.min(axis=0) == pytest.approx([95, 85]) and tapped.max(axis=0) == pytest.approx([150, 125])
    assert ("// Found 2 objects, within (100.0, 90.0) .. (145.0, 120.0); adaptive_margin 5 mm. Adapted mesh: "
            "(95.0, 85.0) .. (150.0, 125.0), 3 x 3 points (configured: (20.0, 20.0) .. (215.0, 215.0), 5 x 5)"
            ) in make_printer.responses
    # ADAPTIVE_MARGIN= overrides the config; the interpolation follows the new count (3: lagrange).
    printer.gcode.run_script("BED_MESH_CALIBRATE ADAPTIVE=1 ADAPTIVE_MARGIN=0")
    assert printer.get_status()["bed_mesh"]["mesh_min"] == [100.0, 90.0]
    assert printer.lookup_object("bed_mesh").mesh.interpolation.algorithm == "lagrange"


def test_adaptive_without_objects_probes_the_full_mesh(make_printer):
    printer = make_printer(MESH.replace("5, 5", "3, 3").replace("bicubic", "lagrange"), probe=True)
    home(printer)
    printer.gcode.run_script("BED_MESH_CALIBRATE ADAPTIVE=1")
    assert ("// Exclude objects not enabled ([exclude_object] is missing): ADAPTIVE=1 has no objects to fit. "
            "Using the full mesh") in make_printer.responses
    assert printer.get_status()["bed_mesh"]["mesh_max"] == [215.0, 215.0]
    printer.add_object("exclude_object", ExcludeObjectStatus([]))
    printer.gcode.run_script("BED_MESH_CALIBRATE ADAPTIVE=1")
    assert "// No objects defined (EXCLUDE_OBJECT_DEFINE with POLYGON=): using the full mesh" in make_printer.responses
    assert "ADAPTIVE must have maximum of 1" in gcode_error(printer, "BED_MESH_CALIBRATE ADAPTIVE=2")


def test_faulty_region_is_never_tapped_and_its_point_is_the_edges_average(make_printer):
    region = "faulty_region_1_min: 100, 100\nfaulty_region_1_max: 130, 140\n"
    printer = make_printer(MESH.replace("5, 5", "3, 3").replace("bicubic", "lagrange") + region + TILTED,
                           probe=True)
    home(printer)
    make_printer.responses.clear()
    printer.gcode.run_script("BED_MESH_CALIBRATE")
    assert ("// Probing 9 points (3 x 3, method tap; 1 in faulty regions, probed at 4 places around them)"
            in make_printer.responses)
    tapped = taps(make_printer.responses)
    assert len(tapped) == 12
    inside = [(x, y) for x, y, _ in tapped if 100 <= x <= 130 and 100 <= y <= 140 and not
              (x in (100.0, 130.0) or y in (100.0, 140.0))]
    assert inside == []  # only the region's edges, never its inside
    # The centre point (117.5, 117.5) is the mean of its four edge places, as probed.
    edges = [(130.0, 117.5), (117.5, 140.0), (117.5, 100.0), (100.0, 117.5)]  # row 1 runs toward -X
    assert [(x, y) for x, y, _ in tapped[4:8]] == edges
    probed = np.array(printer.get_status()["bed_mesh"]["probed_matrix"])
    assert probed[1, 1] == pytest.approx(np.mean([z for _, _, z in tapped[4:8]]), abs=1e-6)
    printer.gcode.run_script("BED_MESH_OUTPUT PGP=1")
    assert make_printer.responses[-1] == ("// 4 (117.50, 117.50), substituted points: [(130.0, 117.5), "
                                          "(117.5, 140.0), (117.5, 100.0), (100.0, 117.5)]")


def test_faulty_region_config_errors(make_printer):
    with pytest.raises(ConfigError, match=r"\[bed_mesh\] faulty_region_2_min = 40, 40: faulty_region_2 \(40, 40\) "
                                          r"\.\. \(80, 80\) overlaps faulty_region_1"):
        make_printer(MESH + "faulty_region_1_min: 0, 0\nfaulty_region_1_max: 50, 50\n"
                            "faulty_region_2_min: 40, 40\nfaulty_region_2_max: 80, 80\n")
    with pytest.raises(ConfigError, match=r"faulty_region_3_max.*needs both faulty_region_3_min and "
                                          r"faulty_region_3_max"):
        make_printer(MESH + "faulty_region_3_min: 0, 0\n")
    with pytest.raises(ConfigError, match=r"\[bed_mesh\] faulty_region_100_min = .*N from 1 to 99"):
        make_printer(MESH + "faulty_region_100_min: 0, 0\nfaulty_region_100_max: 5, 5\n")
    with pytest.raises(ConfigError, match=r"mesh point 0 \(20, 20\) lies inside faulty_region_1"):
        make_printer(MESH + "faulty_region_1_min: 0, 0\nfaulty_region_1_max: 300, 300\n")


def test_generated_points_of_a_loaded_mesh_a_faulty_region_swallows_is_an_error(make_printer):
    # A profile probed before the region was configured (100..140 mm): every point lies inside
    # faulty_region_1 and none of its edges is within that mesh, so PGP=1 has no points to list.
    small = TILTED_PROFILE.replace("tilted", "small")
    for option, value in (("min_x", 100.0), ("max_x", 140.0), ("min_y", 100.0), ("max_y", 140.0)):
        small = re.sub(rf"{option} = .*", f"{option} = {value}", small)
    printer = make_printer(MESH_3X3 + "faulty_region_1_min: 90, 90\nfaulty_region_1_max: 150, 150\n" + small,
                           probe=True)
    printer.gcode.run_script("BED_MESH_PROFILE LOAD=small")
    swallowed = ("[bed_mesh] faulty_region_1_min: mesh point 0 (100, 100) lies inside faulty_region_1 (90, 90) .. "
                 "(150, 150) and no edge of the region around it is within the mesh to probe instead; make the "
                 "region smaller or the mesh larger")
    assert gcode_error(printer, "BED_MESH_OUTPUT PGP=1") == f"BED_MESH_OUTPUT: {swallowed}"
    # The same mesh asked of BED_MESH_CALIBRATE is refused before any probing.
    home(printer)
    assert gcode_error(printer, "BED_MESH_CALIBRATE MESH_MIN=100,100 MESH_MAX=140,140") == (
        f"BED_MESH_CALIBRATE: {swallowed}")
