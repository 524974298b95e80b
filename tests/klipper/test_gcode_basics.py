"""Klipper's basic G-code on the virtual printer: the G-code frame with E, offsets, dwell,
motors off, emergency stop, messages, object labels, probe z_offset, unknown parameters."""

from __future__ import annotations

import pytest

from machines import gcode_error
from machines_klipper import BED_SLINGER, calibrated_voron, run, start
from tapcell.host.config import ConfigError
from tapcell.host.gcode import GCodeError
from tapcell.host.printer import Printer


@pytest.fixture
def slinger(tmp_path):
    printer, responses = start(tmp_path, BED_SLINGER)
    run(printer, responses, "G28")
    return printer, responses


def positions(printer):
    status = printer.get_status()
    return status["gcode_move"]["gcode_position"], status["toolhead"]["position"]


def test_g92_e0_leaves_x_y_z_alone(slinger):
    printer, responses = slinger
    run(printer, responses, "M109 S200\nG1 X50 Y60 Z5 F6000\nG1 E5 F300\nG92 E0\nG1 Z0.2")
    gcode, toolhead = positions(printer)
    assert gcode == pytest.approx([50.0, 60.0, 0.2, 0.0])
    assert toolhead == pytest.approx([50.0, 60.0, 0.2, 5.0])  # the nozzle is at Z 0.2, not 5.2
    run(printer, responses, "G92 X10")
    assert positions(printer)[0] == pytest.approx([10.0, 60.0, 0.2, 0.0])
    run(printer, responses, "G92")  # no axis: every axis, E too
    assert positions(printer)[0] == pytest.approx([0.0, 0.0, 0.0, 0.0])


def test_extruder_axis_relative_absolute_and_factor(slinger):
    printer, responses = slinger
    assert gcode_error(printer, "G1 E1") == ("Error on 'G1 E1': Extrude below minimum temp\n"
                                             "See the 'min_extrude_temp' config option for details")
    run(printer, responses, "M109 S210\nG1 X20 Y20 F6000\nM83\nG1 X30 E0.4 F1200\nG1 X40 E0.4")
    assert positions(printer)[1][3] == pytest.approx(0.8)
    run(printer, responses, "M82\nG92 E0\nG1 X50 E0.5\nM221 S50\nG1 X60 E1.0")
    # Absolute E: 0.5 at 100 %, then +0.5 of G-code E at 50 % is +0.25 at the nozzle.
    assert positions(printer)[1][3] == pytest.approx(0.8 + 0.5 + 0.25)
    assert positions(printer)[0][3] == pytest.approx(1.0)
    assert printer.get_status()["gcode_move"]["extrude_factor"] == 0.5
    assert gcode_error(printer, "M221 S100\nG1 E100") == (
        "Error on 'G1 E100': Extrude only move too long (99.000mm vs 50.000mm)\n"
        "See the 'max_extrude_only_distance' config option for details")
    t0 = printer.backend.now_s
    run(printer, responses, "M82\nG92 E0\nM221 S100\nG1 E-5 F1800")  # retraction: 5 mm at 30 mm/s
    assert printer.backend.now_s - t0 == pytest.approx(5.0 / 30.0)


def test_dwell_speed_factor_and_velocity_limits(slinger):
    printer, responses = slinger
    t0 = printer.backend.now_s
    run(printer, responses, "G4 P1500")
    assert printer.backend.now_s - t0 == pytest.approx(1.5)
    run(printer, responses, "M220 S50\nG1 X100 F6000")
    status = printer.get_status()["gcode_move"]
    assert (status["speed_factor"], status["speed"]) == (0.5, 6000.0)
    out = run(printer, responses, "SET_VELOCITY_LIMIT ACCEL=1000 ACCEL_TO_DECEL=500\nSET_VELOCITY_LIMIT")
    assert out == ["// max_velocity: 300.000000", "// max_accel: 1000.000000", "// minimum_cruise_ratio: 0.500000",
                   "// square_corner_velocity: 5.000000"]
    run(printer, responses, "M204 P2000 R3000 T1500")
    assert printer.get_status()["toolhead"]["max_accel"] == 1500.0


def test_motors_off_needs_homing_again(slinger):
    printer, responses = slinger
    run(printer, responses, "M84 X Y E")  # Cura's axis letters: every motor goes off, as in Klipper
    assert printer.get_status()["toolhead"]["homed_axes"] == ""
    assert gcode_error(printer, "G1 X10") == "Must home axis first: X (run G28)"
    run(printer, responses, "G28\nM18")
    assert printer.get_status()["toolhead"]["homed_axes"] == ""


def test_emergency_stop_halts_until_restart(slinger):
    printer, responses = slinger
    run(printer, responses, "M104 S200\nM140 S60")
    assert run(printer, responses, "M112") == ["!! Shutdown due to M112 command"]
    assert printer.state == "shutdown"
    message = printer.state_message
    assert message == "Shutdown due to M112 command\nOnce the underlying issue is corrected, use RESTART"
    assert printer.backend.heater("extruder").target_c == 25.0  # heater off: heading for the room
    assert gcode_error(printer, "G28") == message
    run(printer, responses, "RESTART")
    assert printer.state == "ready"
    run(printer, responses, "G28")


def test_messages_m117_m118_respond(slinger):
    printer, responses = slinger
    run(printer, responses, "M117 Printing 20% done")
    assert printer.get_status()["display_status"]["message"] == "Printing 20% done"
    run(printer, responses, "M73 P42 R10")
    assert printer.get_status()["display_status"]["progress"] == 0.42
    assert run(printer, responses, "M118 Hello world!") == ["echo: Hello world!"]
    assert run(printer, responses, 'RESPOND TYPE=error MSG="filament out"') == ["!! filament out"]
    assert run(printer, responses, 'RESPOND PREFIX=info: MSG="two words"') == ["info: two words"]
    assert gcode_error(printer, "RESPOND TYPE=shout MSG=x") == (
        "RESPOND TYPE 'shout' is invalid. Must be one of 'echo', 'command', or 'error'")


def test_get_position_and_gcode_offsets(slinger):
    printer, responses = slinger
    run(printer, responses, "G1 X100 Y50 Z5 F6000\nSET_GCODE_OFFSET Z=0.1")
    gcode, toolhead = positions(printer)
    assert gcode[2] == pytest.approx(4.9) and toolhead[2] == pytest.approx(5.0)  # no move without MOVE=1
    run(printer, responses, "SET_GCODE_OFFSET Z_ADJUST=-0.05 MOVE=1")
    gcode, toolhead = positions(printer)
    assert gcode[2] == pytest.approx(4.9) and toolhead[2] == pytest.approx(4.95)  # moved by the change
    assert printer.get_status()["gcode_move"]["homing_origin"] == pytest.approx([0.0, 0.0, 0.05, 0.0])
    run(printer, responses, "G1 Z1")
    assert printer.lookup_object("toolhead").get_position()[2] == pytest.approx(1.05)
    out = run(printer, responses, "G92 X0\nGET_POSITION")
    machine = printer.backend.position
    assert out == [
        f"// mcu: stepper_x:{round(machine[0] / 0.0125)} stepper_y:{round(machine[1] / 0.0125)} "
        f"stepper_z:{round(machine[2] / 0.0025)}",
        f"// stepper: stepper_x:{machine[0]:.6f} stepper_y:{machine[1]:.6f} stepper_z:{machine[2]:.6f}",
        "// kinematic: X:100.000000 Y:50.000000 Z:1.050000",
        "// toolhead: X:100.000000 Y:50.000000 Z:1.050000 E:0.000000",
        "// gcode: X:0.000000 Y:50.000000 Z:1.000000 E:0.000000",
        "// gcode base: X:100.000000 Y:0.000000 Z:0.050000 E:0.000000",
        "// gcode homing: X:0.000000 Y:0.000000 Z:0.050000",
    ]
    # Homing drops the G92 part of an offset and keeps the SET_GCODE_OFFSET part.
    run(printer, responses, "G28")
    assert printer.get_status()["gcode_move"]["gcode_position"][:3] == pytest.approx([0.0, 0.0, 9.95])


def test_exclude_object_status_and_skipped_moves(slinger):
    printer, responses = slinger
    run(printer, responses, "EXCLUDE_OBJECT_DEFINE NAME=part_a CENTER=50,50 POLYGON=[[40,40],[60,40],[60,60]]\n"
                            "EXCLUDE_OBJECT_DEFINE NAME=part_b CENTER=150,150")
    status = printer.get_status()["exclude_object"]
    assert status == {"objects": [{"name": "PART_A", "center": [50.0, 50.0],
                                   "polygon": [[40.0, 40.0], [60.0, 40.0], [60.0, 60.0]]},
                                  {"name": "PART_B", "center": [150.0, 150.0]}],
                      "excluded_objects": [], "current_object": None}
    assert run(printer, responses, "EXCLUDE_OBJECT NAME=part_b") == ["// Excluding object PART_B"]
    run(printer, responses, "G1 X50 Y50 F6000\nEXCLUDE_OBJECT_START NAME=part_b\nG1 X150 Y150")
    assert printer.get_status()["exclude_object"]["current_object"] == "PART_B"
    assert printer.backend.position[:2] == pytest.approx((50.0, 50.0))  # the excluded object's move is skipped
    assert positions(printer)[0][:2] == pytest.approx([150.0, 150.0])  # the G-code position follows it
    run(printer, responses, "EXCLUDE_OBJECT_END NAME=part_b\nG1 X70 Y80")
    assert printer.backend.position[:2] == pytest.approx((70.0, 80.0))
    assert gcode_error(printer, "EXCLUDE_OBJECT_DEFINE NAME=c POLYGON=[[1,2],[3]]") == (
        "Error on 'EXCLUDE_OBJECT_DEFINE NAME=c POLYGON=[[1,2],[3]]': POLYGON must be a JSON list of [x,y] points "
        "(got '[[1,2],[3]]')")


def test_unknown_parameter_gets_a_warning_naming_it(slinger):
    printer, responses = slinger
    run(printer, responses, "G1 X10 F6000")
    assert run(printer, responses, "G1 X20 Q5") == ["// G1: unknown parameter Q ignored"]
    assert run(printer, responses, "G4 P10 Q1") == ["// G4: unknown parameter Q ignored"]
    printer.gcode.register_command("SAMPLER", lambda gcmd: gcmd.get_int("SAMPLES", 10, minval=1, maxval=100))
    run(printer, responses, "SAMPLER SAMPLES=3")
    assert run(printer, responses, "SAMPLER SAMPLE=5") == [
        "// SAMPLER: unknown parameter SAMPLE ignored (did you mean SAMPLES?)"]
    # A macro takes every parameter (it may read them through params).
    assert run(printer, responses, "M118 A=1 B=2") == ["echo: A=1 B=2"]


def test_probe_commands_refuse_unknown_parameters_and_take_kalicos_spellings(tmp_path):
    path = calibrated_voron(tmp_path, {"probe_count: 5, 5": "probe_count: 3, 3"})
    printer, responses = start(tmp_path, path.read_text(), "again.cfg")
    run(printer, responses, "G28")
    # A probing command refuses a parameter it does not know before anything moves (issue 19): a
    # misspelled option must not let the probe run with the default instead.
    z_before = printer.backend.position[2]
    assert gcode_error(printer, "PROBE_ACCURACY SAMPLE=2") == (
        "Error on 'PROBE_ACCURACY SAMPLE=2': unknown parameter SAMPLE (did you mean SAMPLES?) for PROBE_ACCURACY; "
        "nothing was moved")
    assert printer.backend.position[2] >= z_before
    assert not [line for line in responses if "unknown parameter SAMPLE ignored" in line]
    # Kalico's TAPS= is tapcell's COUNT=.
    out = run(printer, responses, "SIM_TAP FORCE=300 DELAY=0.3\nLOAD_CELL_TEST_TAP TAPS=1 TIMEOUT=5")
    assert out[-3].endswith("Tap the load cell 1 times:") and out[-2].startswith("// Tap Detected!")
    assert out[-1].startswith("// Test complete, 1 taps detected")
    assert gcode_error(printer, "LOAD_CELL_TEST_TAP TAPS=1 COUNT=2") == (
        "Error on 'LOAD_CELL_TEST_TAP TAPS=1 COUNT=2': TAPS (Kalico's name) and COUNT are the same parameter; "
        "give one")


def test_probe_calibrate_and_z_offset_apply_probe(tmp_path):
    path = calibrated_voron(tmp_path, {"probe_count: 5, 5": "probe_count: 3, 3"})
    printer, responses = start(tmp_path, path.read_text(), "again.cfg")
    run(printer, responses, "G28\nG1 X150 Y150 F6000")
    out = run(printer, responses, "PROBE_CALIBRATE")
    toolhead = printer.lookup_object("toolhead")
    probed_z = printer.lookup_object("probe").last_result.z_mm  # z_offset is 0: the bed is where it triggered
    lifted_z = toolhead.get_position()[2]
    assert lifted_z == pytest.approx(probed_z + 5.0, abs=0.002)
    assert out[-3:] == ["// Starting manual Z probe. Use TESTZ to adjust position.",
                        "// Finish with ACCEPT or ABORT command.", f"// Z position: ?????? --> {lifted_z:.3f} <-- ??????"]
    out = run(printer, responses, "TESTZ Z=-4.9")
    paper_z = toolhead.get_position()[2]
    assert out == [f"// Z position: ?????? --> {paper_z:.3f} <-- {lifted_z:.3f}"]
    out = run(printer, responses, "TESTZ Z=+")  # halfway back to the nearest position tried above
    assert out == [f"// Z position: {paper_z:.3f} --> {(paper_z + lifted_z) / 2:.3f} <-- {lifted_z:.3f}"]
    run(printer, responses, "TESTZ Z=-")
    assert toolhead.get_position()[2] == pytest.approx(paper_z + (lifted_z - paper_z) / 4, abs=0.002)
    out = run(printer, responses, f"TESTZ Z={probed_z + 0.08 - toolhead.get_position()[2]:.4f}\nACCEPT")
    z_offset = probed_z - toolhead.get_position()[2]
    assert z_offset == pytest.approx(-0.08, abs=0.002)  # the nozzle 0.08 mm above where the probe found the bed
    assert out[-3:] == [f"// load_cell_probe: z_offset: {z_offset:.3f}", "// The SAVE_CONFIG command will update the "
                        "printer config file", "// with the above and restart the printer."]
    assert printer.config.pending_changes()["load_cell_probe"] == {"z_offset": f"{z_offset:.3f}"}
    assert not printer.gcode.is_registered("TESTZ")
    run(printer, responses, "PROBE_CALIBRATE")
    assert run(printer, responses, "ABORT") == ["// Manual probe aborted: z_offset unchanged"]
    assert run(printer, responses, "Z_OFFSET_APPLY_PROBE") == ["// Nothing to do: Z Offset is 0"]
    out = run(printer, responses, "SET_GCODE_OFFSET Z=0.025\nZ_OFFSET_APPLY_PROBE")
    assert out[0] == "// load_cell_probe: z_offset: -0.025"


def test_testz_refuses_to_press_the_nozzle_into_the_bed(tmp_path):
    path = calibrated_voron(tmp_path)
    printer, responses = start(tmp_path, path.read_text(), "again.cfg")
    run(printer, responses, "G28\nPROBE_CALIBRATE\nTESTZ Z=-4.9")
    z_before = printer.lookup_object("toolhead").get_position()[2]
    with pytest.raises(GCodeError, match=r"mm below the bed the probe found .*: the nozzle would press into the bed "
                                         r"\(at most 0.05 mm below it\)"):
        printer.gcode.run_script("TESTZ Z=-0.2")
    assert printer.lookup_object("toolhead").get_position()[2] == z_before


def test_status_objects_have_klippers_fields(slinger):
    printer, responses = slinger
    run(printer, responses, "M106 S255")
    status = printer.get_status()
    assert set(status["gcode_move"]) == {"speed_factor", "speed", "extrude_factor", "absolute_coordinates",
                                         "absolute_extrude", "homing_origin", "position", "gcode_position"}
    assert {"homed_axes", "axis_minimum", "axis_maximum", "position", "extruder", "print_time",
            "estimated_print_time", "stalls", "max_velocity", "max_accel", "minimum_cruise_ratio",
            "square_corner_velocity"} <= set(status["toolhead"])
    assert {"temperature", "target", "power", "can_extrude", "pressure_advance", "smooth_time"} <= set(status["extruder"])
    assert set(status["heater_bed"]) == {"temperature", "target", "power"}
    assert status["fan"] == {"speed": 1.0, "rpm": None}
    assert status["toolhead"]["extruder"] == "extruder" and len(status["toolhead"]["position"]) == 4


def test_save_and_restore_gcode_state(slinger):
    printer, responses = slinger
    run(printer, responses, "M109 S200\nG1 X30 Y40 Z5 F3000\nSAVE_GCODE_STATE NAME=before\n"
                            "G91\nM83\nG1 X10 E2 F600\nSET_GCODE_OFFSET Z=0.2")
    run(printer, responses, "RESTORE_GCODE_STATE NAME=before MOVE=1")
    status = printer.get_status()["gcode_move"]
    assert (status["absolute_coordinates"], status["absolute_extrude"], status["speed"]) == (True, True, 3000.0)
    assert status["homing_origin"] == [0.0, 0.0, 0.0, 0.0]
    assert printer.lookup_object("toolhead").get_position() == pytest.approx((30.0, 40.0, 5.0))  # moved back
    assert status["gcode_position"][3] == pytest.approx(0.0)  # E continues from the saved G-code E
    assert status["position"][3] == pytest.approx(2.0)  # the filament is not pulled back
    assert gcode_error(printer, "RESTORE_GCODE_STATE NAME=nope") == (
        "Error on 'RESTORE_GCODE_STATE NAME=nope': Unknown g-code state: nope")


def test_turning_off_what_the_printer_lacks_is_silent(tmp_path):
    # The example printer has no [fan] and no [heater_bed]: a slicer's "off" lines pass, as in Klipper.
    printer, responses = start(tmp_path, BED_SLINGER.replace("[fan]\npin: PA8\n", "").replace(
        "[heater_bed]", "[heater_generic bed]"))
    assert run(printer, responses, "M107\nM106 S0\nM140 S0\nM104 S0") == []
    assert gcode_error(printer, "M106 S255") == 'Unknown command:"M106"'
    assert gcode_error(printer, "M106") == 'Unknown command:"M106"'  # no S: full speed, which is not silent
    assert gcode_error(printer, "M140 S60") == 'Unknown command:"M140"'


@pytest.mark.parametrize("line, problem", [
    ("EXCLUDE_OBJECT_DEFINE NAME=a CENTER=1e9,0", "CENTER must be x,y within -10000..10000 mm (got '1e9,0')"),
    ("EXCLUDE_OBJECT_DEFINE NAME=a POLYGON=[[0,Infinity]]", "POLYGON must be a JSON list of [x,y] points "
                                                             "(got '[[0,Infinity]]')"),
    ("G1 X100000", "X must have maximum of 10000 (allowed: -10000 to 10000)"),
    ("M220 S0", "S must be above 0 (allowed: above 0 and at most 10000)"),
    ("M104 S5000", "S must have maximum of 1000 (allowed: 0 to 1000)"),
    ("SET_VELOCITY_LIMIT ACCEL=0", "ACCEL must have minimum of 1 (allowed: 1 to 1000000)"),
])
def test_every_number_has_a_range(slinger, line, problem):
    printer, _ = slinger
    assert gcode_error(printer, line) == f"Error on '{line}': {problem}"


# A web UI's include, in the style every Mainsail/Fluidd user has: macros that wrap the built-ins.
UI_MACROS = """
[gcode_macro PAUSE]
description: Pause and park
rename_existing: PAUSE_BASE
gcode:
    PAUSE_BASE
    G91
    G1 Z5 F600
    G90
    G1 X10 Y10 F6000

[gcode_macro RESUME]
rename_existing: RESUME_BASE
gcode:
    RESUME_BASE VELOCITY=100

[gcode_macro CANCEL_PRINT]
rename_existing: CANCEL_PRINT_BASE
gcode:
    M104 S0
    CANCEL_PRINT_BASE
"""


def test_macros_wrap_the_pause_commands_with_rename_existing(tmp_path):
    # [pause_resume] comes after the macros that rename its commands, as in many configs.
    printer, responses = start(tmp_path, BED_SLINGER + UI_MACROS + "\n[pause_resume]\nrecover_velocity: 80\n")
    run(printer, responses, "G28\nG1 X50 Y60 Z1 F6000\nPAUSE")
    toolhead = printer.lookup_object("toolhead")
    assert printer.get_status()["pause_resume"] == {"is_paused": True}
    assert toolhead.get_position() == pytest.approx((10.0, 10.0, 6.0))  # parked
    assert run(printer, responses, "PAUSE_BASE") == ["// Print already paused"]
    run(printer, responses, "RESUME")
    assert toolhead.get_position() == pytest.approx((50.0, 60.0, 1.0))  # back where it paused
    assert run(printer, responses, "RESUME") == ["// Print is not paused, resume aborted"]
    run(printer, responses, "M104 S200\nPAUSE\nCANCEL_PRINT")
    assert printer.get_status()["pause_resume"] == {"is_paused": False}
    assert printer.get_status()["extruder"]["target"] == 0.0
    path = tmp_path / "missing.cfg"
    path.write_text(BED_SLINGER + UI_MACROS)  # no [pause_resume]: nothing to rename
    with pytest.raises(ConfigError) as info:
        Printer.from_config(str(path))
    assert str(info.value) == (f"{path}: [gcode_macro PAUSE]: Existing command 'PAUSE' not found in "
                               "gcode_macro rename")
