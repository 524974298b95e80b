"""The Klipper surface UIs and slicers use, on the printer itself (no server): G28 per axis,
M106 P, QUERY_ENDSTOPS, motion_report and idle_timeout over the print clock, system_stats, the
mesh's completion line, BED_MESH_OFFSET, SET_KINEMATIC_POSITION, TURN_OFF_HEATERS, SET_LED and
the gantry-levelling stand-ins."""

from __future__ import annotations

import pytest

from machines import PROBE_SECTION, gcode_error, machine_config
from tapcell.host.print_clock import PrintClock
from tapcell.host.printer import Printer

PROBE = PROBE_SECTION.format(counts_per_gram=110, reference_tare_counts=-38000)
HEATED = """
[extruder]
step_pin: PA0
dir_pin: PA1
nozzle_diameter: 0.4
filament_diameter: 1.75
rotation_distance: 33.5
microsteps: 16
heater_pin: PA2
sensor_type: EPCOS 100K B57560G104F
sensor_pin: PA3
control: pid
pid_kp: 22
pid_ki: 1
pid_kd: 100
min_temp: 0
max_temp: 280
"""


def build(tmp_path, extra: str = "", probe: bool = False, scenario: str = "clean"):
    path = tmp_path / "printer.cfg"
    path.write_text(machine_config(scenario) + (PROBE if probe else "") + extra)
    responses: list[str] = []
    return Printer.from_config(str(path), responses=responses.append), responses


def test_g28_x_homes_x_only_and_g28_y_homes_y_only(tmp_path):
    printer, _ = build(tmp_path)
    toolhead = printer.lookup_object("toolhead")
    start_x, start_y, _ = printer.backend.position
    printer.gcode.run_script("G28 X")
    assert toolhead.homed_axes == {"x"}
    assert printer.backend.position[0] == pytest.approx(0.0) and printer.backend.position[1] == start_y
    printer.gcode.run_script("G1 X50 F6000\nG28 Y")
    assert toolhead.homed_axes == {"x", "y"}
    assert printer.backend.position[:2] == pytest.approx((50.0, 0.0))
    assert start_x != 0.0 and start_y != 0.0  # the machine starts away from both switches


def test_m106_p_is_read_and_ignored_like_klipper(tmp_path):
    printer, responses = build(tmp_path, "\n[fan]\npin: PA8\n")
    printer.gcode.run_script("M106 P2 S0")  # OrcaSlicer's auxiliary fan: the part fan, as in Klipper
    assert printer.get_status()["fan"]["speed"] == 0.0
    printer.gcode.run_script("M106 P1 S127.5\nM107 P3")
    assert printer.lookup_object("fan").speed == 0.0
    printer.gcode.run_script("M106 P1 S127.5")
    assert printer.lookup_object("fan").speed == pytest.approx(0.5)
    assert not [line for line in responses if "unknown parameter" in line]


def test_query_endstops_reads_the_switches_where_the_carriage_is(tmp_path):
    printer, responses = build(tmp_path)
    printer.gcode.run_script("G28 X\nQUERY_ENDSTOPS")
    assert responses[-1] == "// x:TRIGGERED y:open z:open"
    printer.gcode.run_script("G28 Y\nG1 X0.1 F600\nM119")
    assert responses[-1] == "// x:open y:TRIGGERED z:open"
    assert printer.get_status()["query_endstops"]["last_query"] == {"x": False, "y": True, "z": False}


def test_motion_report_follows_a_g1_as_it_plays(tmp_path):
    printer, _ = build(tmp_path)
    printer.gcode.run_script("G28 X Y")
    clock = PrintClock(printer.backend)
    printer.print_clock = clock
    start_s = printer.backend.now_s
    printer.gcode.run_script("G1 X100 F6000")  # 100 mm at 100 mm/s, 3000 mm/s^2: 1.033 s
    report = printer.lookup_object("motion_report")
    assert report.get_status()["live_position"][0] == pytest.approx(0.0, abs=1e-9)
    assert printer.backend.now_s - start_s == pytest.approx(100 / 100 + 100 / 3000, abs=1e-3)
    clock.advance(0.5)
    # 1/60 s accelerating (1.667 mm) then cruising: 1.667 + 100 * (0.5 - 1/30) = 48.33 mm
    status = report.get_status()
    assert status["live_position"][0] == pytest.approx(100 / 60 + 100 * (0.5 - 1 / 30), abs=0.01)
    assert status["live_velocity"] == pytest.approx(100.0, abs=1e-6)
    assert printer.get_status()["idle_timeout"]["state"] == "Printing"
    toolhead = printer.get_status()["toolhead"]  # Klipper's two clocks: queued moves end 0.533 s ahead
    assert toolhead["print_time"] - toolhead["estimated_print_time"] == pytest.approx(1 + 1 / 30 - 0.5, abs=1e-3)
    clock.advance(0.6)
    printer.run_background()
    status = report.get_status()
    assert status["live_position"][:3] == pytest.approx([100.0, 0.0, printer.backend.position[2]], abs=1e-6)
    assert status["live_velocity"] == 0.0
    assert printer.get_status()["idle_timeout"]["state"] == "Ready"
    # The clock never trails the moves by more than its limit: a long dwell shows only its end.
    printer.gcode.run_script("G4 P60000")
    clock.advance(0.0)
    assert printer.backend.now_s - clock.estimated_s == pytest.approx(clock.max_lag_s)


def test_idle_timeout_runs_its_gcode_after_the_timeout(tmp_path):
    printer, responses = build(tmp_path, HEATED + "\n[idle_timeout]\ntimeout: 30\n")
    printer.gcode.run_script("G28 X Y\nM104 S200")
    clock = PrintClock(printer.backend)
    printer.print_clock = clock
    printer.gcode.run_script("G1 X50 F6000")
    printer.run_background()
    assert printer.get_status()["idle_timeout"]["state"] == "Printing"
    for _ in range(20):  # 10 s
        clock.advance(0.5)
        printer.run_background()
    assert printer.get_status()["idle_timeout"]["state"] == "Ready"
    assert printer.lookup_object("extruder").heater.target_c == 200.0
    for _ in range(60):  # 30 s more: past the timeout
        clock.advance(0.5)
        printer.run_background()
    assert printer.get_status()["idle_timeout"]["state"] == "Idle"
    assert printer.lookup_object("toolhead").homed_axes == set()  # M84
    assert printer.get_status()["extruder"]["target"] == 0.0  # TURN_OFF_HEATERS
    printer.gcode.run_script("SET_IDLE_TIMEOUT TIMEOUT=90")
    assert responses[-1] == "// idle_timeout: Timeout set to 90.00 s"


def test_system_stats_has_klippers_fields(tmp_path):
    printer, _ = build(tmp_path)
    stats = printer.get_status()["system_stats"]
    assert set(stats) == {"sysload", "cputime", "memavail"}
    assert stats["cputime"] > 0.0 and stats["memavail"] > 0 and stats["sysload"] >= 0.0


def test_a_finished_mesh_prints_klippers_completion_line_and_bed_mesh_offset_shifts_the_lookup(tmp_path):
    printer, responses = build(tmp_path, "\n[bed_mesh]\nmesh_min: 20, 20\nmesh_max: 200, 200\n"
                                         "probe_count: 3, 3\n", probe=True, scenario="tilted-bed")
    printer.gcode.run_script("G28\nBED_MESH_CALIBRATE")
    assert responses.count("// Mesh Bed Leveling Complete") == 1
    mesh = printer.lookup_object("bed_mesh").mesh
    toolhead = printer.lookup_object("toolhead")
    half_step_mm = printer.backend.step_distance_mm[2] / 2  # the steppers stop on whole microsteps
    printer.gcode.run_script("G1 X100 Y60 Z1 F6000")
    assert toolhead.get_position()[2] == pytest.approx(1.0 + mesh.z_at(100.0, 60.0), abs=half_step_mm)
    printer.gcode.run_script("BED_MESH_OFFSET X=30 Y=-10\nG1 X100 Y60 Z1")
    assert toolhead.get_position()[2] == pytest.approx(1.0 + mesh.z_at(130.0, 50.0), abs=half_step_mm)
    assert abs(mesh.z_at(130.0, 50.0) - mesh.z_at(100.0, 60.0)) > 4 * half_step_mm
    x, y, z, _ = printer.lookup_object("gcode_move").gcode_position()
    assert (x, y, z) == pytest.approx((100.0, 60.0, 1.0), abs=1e-6)


def test_set_kinematic_position_needs_force_move_enabled(tmp_path):
    printer, _ = build(tmp_path)
    assert gcode_error(printer, "SET_KINEMATIC_POSITION Z=5") == 'Unknown command:"SET_KINEMATIC_POSITION"'
    printer, responses = build(tmp_path, "\n[force_move]\nenable_force_move: True\n")
    toolhead = printer.lookup_object("toolhead")
    machine_z = printer.backend.position[2]
    printer.gcode.run_script("SET_KINEMATIC_POSITION Z=3.5")
    assert toolhead.get_position()[2] == pytest.approx(3.5) and toolhead.homed_axes == {"x", "y", "z"}
    printer.gcode.run_script("G1 Z13.5 F600")
    assert printer.backend.position[2] == pytest.approx(machine_z + 10.0, abs=1e-3)
    printer.gcode.run_script("SET_KINEMATIC_POSITION CLEAR_HOMED=Z")
    assert toolhead.homed_axes == {"x", "y"}
    assert "SET_HOMED must name axes" in gcode_error(printer, "SET_KINEMATIC_POSITION SET_HOMED=Q")


def test_turn_off_heaters_sets_every_target_to_zero(tmp_path):
    printer, _ = build(tmp_path, HEATED + "\n[heater_bed]\nheater_pin: PA9\nsensor_type: EPCOS 100K B57560G104F\n"
                                          "sensor_pin: PA10\ncontrol: watermark\nmin_temp: 0\nmax_temp: 130\n")
    printer.gcode.run_script("M104 S210\nM140 S60")
    status = printer.get_status()
    assert (status["extruder"]["target"], status["heater_bed"]["target"]) == (210.0, 60.0)
    printer.gcode.run_script("TURN_OFF_HEATERS")
    status = printer.get_status()
    assert (status["extruder"]["target"], status["heater_bed"]["target"]) == (0.0, 0.0)


def test_set_led_keeps_the_colours_of_a_declared_chain(tmp_path):
    printer, _ = build(tmp_path)
    assert gcode_error(printer, "SET_LED LED=sb RED=1") == 'Unknown command:"SET_LED"'
    printer, _ = build(tmp_path, "\n[neopixel sb]\npin: PA1\nchain_count: 3\ncolor_order: GRB\ninitial_BLUE: 0.25\n"
                                 "\n[led case]\nwhite_pin: PA2\n")
    printer.gcode.run_script("SET_LED LED=sb RED=1 GREEN=0.5 INDEX=2\nSET_LED LED=case WHITE=0.8")
    status = printer.get_status()
    assert status["neopixel sb"]["color_data"] == [[0, 0, 0.25, 0], [1.0, 0.5, 0, 0], [0, 0, 0.25, 0]]
    assert status["led case"]["color_data"] == [[0, 0, 0, 0.8]]
    assert "INDEX" in gcode_error(printer, "SET_LED LED=sb RED=1 INDEX=4")
    assert "not valid for LED" in gcode_error(printer, "SET_LED LED=nope RED=1")


@pytest.mark.parametrize("section, command", [("z_tilt", "Z_TILT_ADJUST"), ("quad_gantry_level", "QUAD_GANTRY_LEVEL")])
def test_gantry_levelling_answers_in_one_line_on_the_single_z_motor(tmp_path, section, command):
    printer, _ = build(tmp_path)
    assert gcode_error(printer, command) == f'Unknown command:"{command}"'  # as Klipper: only with the section
    printer, responses = build(tmp_path, f"\n[{section}]\npoints:\n  30, 5\n  270, 5\nspeed: 200\nretries: 5\n")
    assert printer.get_status()[section] == {"applied": False}
    printer.gcode.run_script(f"{command} RETRIES=2")
    assert responses[-1].startswith(f"// {command}: the virtual printer moves Z with one motor")
    assert printer.get_status()[section] == {"applied": True}
    printer.gcode.run_script("M84")
    assert printer.get_status()[section] == {"applied": False}


def test_macros_read_positions_as_klippers_coordinates(tmp_path):
    printer, responses = build(tmp_path, "\n[gcode_macro WHERE]\ngcode:\n    {action_respond_info('z=%.2f xmax=%g e=%g' "
                                         "% (printer.toolhead.position.z, printer.toolhead.axis_maximum.x, "
                                         "printer.gcode_move.gcode_position.e))}\n")
    printer.gcode.run_script("G28 X Y\nWHERE")
    assert responses[-1] == f"// z={printer.lookup_object('toolhead').get_position()[2]:.2f} xmax=235 e=0"
    assert type(printer.get_status()["toolhead"]["position"]) is list  # the status itself stays plain data


@pytest.mark.parametrize("config_says, world, fix", [
    ("sensor_orientation: inverted\n", "", "Set sensor_orientation: normal in [load_cell_probe] (it is inverted)"),
    ("", "cell_polarity: -1\n", "Set sensor_orientation: inverted in [load_cell_probe] (it is normal)"),
])
def test_a_wrong_sensor_orientation_fails_g28_with_the_cause_and_the_fix(tmp_path, config_says, world, fix):
    text = machine_config().replace("seed: 1\n", "seed: 1\n" + world) + PROBE + config_says
    (tmp_path / "printer.cfg").write_text(text)
    responses: list[str] = []
    printer = Printer.from_config(str(tmp_path / "printer.cfg"), responses=responses.append)
    message = gcode_error(printer, "G28")
    assert "the load cell reads the nozzle pressing on the bed as a negative force" in message
    assert "sensor_orientation is the wrong way round for this cell. " + fix + ", RESTART, then home again" in message
    assert printer.lookup_object("toolhead").get_position()[2] > 1.0  # lifted clear after the error
