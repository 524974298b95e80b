"""[bed_mesh] options, profiles through SAVE_CONFIG, BED_MESH_OUTPUT/CLEAR, and G1 following the mesh."""

from __future__ import annotations

import numpy as np
import pytest

from tapcell.host.config import ConfigError

from machines import gcode_error

MESH = """
[bed_mesh]
mesh_min: 20, 20
mesh_max: 220, 220
probe_count: 3, 3
mesh_pps: 0
move_check_distance: 3
split_delta_z: 0.01
"""

# A tilted plane z = 0.001 x + 0.0005 y sampled at X, Y = 20, 120, 220 (front row first).
TILTED = """
[bed_mesh tilted]
version = 1
points =
  0.030000, 0.130000, 0.230000
  0.080000, 0.180000, 0.280000
  0.130000, 0.230000, 0.330000
x_count = 3
y_count = 3
mesh_x_pps = 0
mesh_y_pps = 0
algo = direct
tension = 0.2
min_x = 20.0
max_x = 220.0
min_y = 20.0
max_y = 220.0
"""


def plane_mm(x, y):
    return 0.001 * x + 0.0005 * y


def machine_z(printer) -> float:
    return printer.backend.position[2]


def test_options_are_checked_with_file_section_option_and_value(make_printer):
    with pytest.raises(ConfigError) as err:
        make_printer(MESH.replace("probe_count: 3, 3", "probe_count: 2, 3"))
    assert "[bed_mesh] probe_count = 2, 3: item '2' must be at least 3 (allowed: 3 to 50)" in str(err.value)
    with pytest.raises(ConfigError) as err:
        make_printer(MESH.replace("split_delta_z: 0.01", "split_delta_z: 0.001"))
    assert "[bed_mesh] split_delta_z = 0.001: must be at least 0.01 (allowed: 0.01 to 10)" in str(err.value)
    with pytest.raises(ConfigError) as err:
        make_printer(MESH + "relative_reference_index: 4\nzero_reference_position: 120, 120\n")
    assert "cannot be combined with zero_reference_position" in str(err.value)
    with pytest.raises(ConfigError) as err:
        make_printer(MESH.replace("probe_count: 3, 3", "probe_count: 7, 7").replace("mesh_pps: 0", "mesh_pps: 2"))
    assert "[bed_mesh] probe_count = 7, 7: lagrange allows at most 6 points per axis" in str(err.value)
    with pytest.raises(ConfigError) as err:
        make_printer(MESH + "method: magic\n")
    assert "[bed_mesh] method = magic" in str(err.value)


def test_no_mesh_output_and_status(make_printer):
    printer = make_printer(MESH)
    printer.gcode.run_script("BED_MESH_OUTPUT")
    assert make_printer.responses[-1] == "// Bed has not been probed"
    printer.gcode.run_script("BED_MESH_MAP")
    assert make_printer.responses[-1] == "// Bed has not been probed"
    status = printer.get_status()["bed_mesh"]
    assert status["profile_name"] == "" and status["profiles"] == {}
    printer.gcode.run_script("BED_MESH_OUTPUT PGP=1")
    assert make_printer.responses[-11:] == [
        "// bed_mesh: generated points", "// Index |  Tool Adjusted  |   Probe",
        "//   0   | (20.0, 20.0)    | (20.0, 20.0)", "//   1   | (120.0, 20.0)   | (120.0, 20.0)",
        "//   2   | (220.0, 20.0)   | (220.0, 20.0)", "//   3   | (220.0, 120.0)  | (220.0, 120.0)",
        "//   4   | (120.0, 120.0)  | (120.0, 120.0)", "//   5   | (20.0, 120.0)   | (20.0, 120.0)",
        "//   6   | (20.0, 220.0)   | (20.0, 220.0)", "//   7   | (120.0, 220.0)  | (120.0, 220.0)",
        "//   8   | (220.0, 220.0)  | (220.0, 220.0)"]


def test_g1_follows_the_loaded_mesh_and_m114_reports_gcode_z(make_printer, home_without_probe):
    printer = make_printer(MESH + TILTED)
    home_without_probe(printer, z_mm=10.0)
    frame_mm = 10.0 - machine_z(printer)  # toolhead Z = machine Z + frame
    printer.gcode.run_script("BED_MESH_PROFILE LOAD=tilted")
    assert make_printer.responses[-1] == "// Bed mesh profile 'tilted' loaded: moves follow it"
    printer.gcode.run_script("G1 X70 Y170 Z0.2 F6000")
    expected = 0.2 + plane_mm(70, 170)
    assert machine_z(printer) + frame_mm == pytest.approx(expected, abs=0.0013)  # one Z step is 2.5 um
    printer.gcode.run_script("M114")
    assert make_printer.responses[-1].startswith("X:70.000 Y:170.000 Z:0.20")
    # A long move is split: it ends on the mesh at its end point.
    printer.gcode.run_script("G1 X210 Y30")
    assert machine_z(printer) + frame_mm == pytest.approx(0.2 + plane_mm(210, 30), abs=0.0013)
    printer.gcode.run_script("BED_MESH_CLEAR")
    printer.gcode.run_script("G1 X100 Y100 Z0.5")
    assert machine_z(printer) + frame_mm == pytest.approx(0.5, abs=0.0013)


def test_g1_is_split_by_move_check_distance_and_split_delta_z(make_printer, home_without_probe):
    printer = make_printer(MESH + TILTED)
    home_without_probe(printer, z_mm=10.0)
    printer.gcode.run_script("BED_MESH_PROFILE LOAD=tilted\nG1 X20 Y20 Z0.2 F6000")
    bed_mesh = printer.lookup_object("bed_mesh")
    sent = []
    real_next = bed_mesh.next_target

    class Recorder:
        def move(self, position, speed_mm_s):
            sent.append(position)
            real_next.move(position, speed_mm_s)

        def get_position(self):
            return real_next.get_position()

    bed_mesh.next_target = Recorder()
    printer.gcode.run_script("G1 X220 Y20")  # 200 mm in X: the mesh rises 0.2 mm
    # Check points every 3 mm; a cut when the mesh moved 0.01 mm = 10 mm of travel -> at 12, 24, ... mm.
    xs = [round(p[0], 6) for p in sent]
    assert xs[:3] == [32.0, 44.0, 56.0]
    assert xs[-1] == 220.0 and len(sent) == 17
    z = np.array([p[2] for p in sent])
    assert z == pytest.approx(0.2 + plane_mm(np.array([p[0] for p in sent]), 20.0), abs=1e-9)


def test_fade_reduces_the_correction_with_height(make_printer, home_without_probe):
    printer = make_printer(MESH + "fade_start: 1\nfade_end: 10\nfade_target: 0\n" + TILTED)
    home_without_probe(printer, z_mm=10.0)
    frame_mm = 10.0 - machine_z(printer)
    printer.gcode.run_script("BED_MESH_PROFILE LOAD=tilted\nG1 X220 Y220 Z5.5 F6000")
    # Half way through the fade: half of the mesh height 0.33 mm.
    assert machine_z(printer) + frame_mm == pytest.approx(5.5 + 0.5 * 0.33, abs=0.0013)
    printer.gcode.run_script("G1 Z12")
    assert machine_z(printer) + frame_mm == pytest.approx(12.0, abs=0.0013)


def test_profiles_survive_save_config_and_restart(make_printer):
    printer = make_printer(MESH + TILTED)
    gcode = printer.gcode
    gcode.run_script("BED_MESH_PROFILE LOAD=tilted\nBED_MESH_PROFILE SAVE=copy")
    assert make_printer.responses[-1] == ("// Bed mesh profile 'copy' saved; run SAVE_CONFIG to write it "
                                          "to the config file")
    gcode.run_script("SAVE_CONFIG")
    printer = make_printer.tmp_path / "printer.cfg"
    text = printer.read_text()
    block = [line.removeprefix("#*#").strip() for line in text.splitlines() if line.startswith("#*#")]
    assert "[bed_mesh copy]" in block and "0.080000, 0.180000, 0.280000" in block
    from tapcell.host.printer import Printer

    restarted = Printer.from_config(str(printer), responses=make_printer.responses)
    status = restarted.get_status()["bed_mesh"]
    assert sorted(status["profiles"]) == ["copy", "tilted"]
    assert status["profiles"]["copy"]["points"][2] == pytest.approx([0.13, 0.23, 0.33])
    assert status["profile_name"] == ""  # only 'default' loads by itself
    restarted.gcode.run_script("BED_MESH_PROFILE LOAD=copy\nBED_MESH_OUTPUT")
    out = make_printer.responses[-14:]
    assert out[:4] == ["// Mesh Leveling Probed Z positions:", "//  0.030000 0.130000 0.230000",
                       "//  0.080000 0.180000 0.280000", "//  0.130000 0.230000 0.330000"]
    assert out[8] == "Mesh Range: min=0.0300 max=0.3300"
    assert out[-3] == "  0.130000  0.230000  0.330000"  # direct: the probed points, back row first
    restarted.gcode.run_script("BED_MESH_PROFILE REMOVE=copy\nSAVE_CONFIG")
    assert "[bed_mesh copy]" not in printer.read_text()
    assert sorted(restarted.get_status()["bed_mesh"]["profiles"]) == ["tilted"]


def test_default_profile_is_loaded_at_start(make_printer):
    printer = make_printer(MESH + TILTED.replace("[bed_mesh tilted]", "[bed_mesh default]"))
    assert printer.get_status()["bed_mesh"]["profile_name"] == "default"


def test_profile_command_errors(make_printer):
    printer = make_printer(MESH)
    assert gcode_error(printer, "BED_MESH_PROFILE LOAD=nothing") == "Error on 'BED_MESH_PROFILE LOAD=nothing': no bed mesh profile 'nothing' (known: none)"
    assert gcode_error(printer, "BED_MESH_PROFILE REMOVE=nothing") == "Error on 'BED_MESH_PROFILE REMOVE=nothing': no bed mesh profile 'nothing' (known: none)"
    assert "give exactly one of SAVE=name, LOAD=name, REMOVE=name" in gcode_error(printer, "BED_MESH_PROFILE SAVE=x LOAD=y")
    assert "no active mesh to save" in gcode_error(printer, "BED_MESH_PROFILE SAVE=x")


def test_broken_profile_section_names_option(make_printer):
    with pytest.raises(ConfigError) as err:
        make_printer(MESH + TILTED.replace("algo = direct", "algo = cubic"))
    assert "[bed_mesh tilted] algo = cubic: must be one of: lagrange, bicubic, direct" in str(err.value)
