"""A real Klipper printer.cfg loads; the virtual printer stands in for what the config describes."""

from __future__ import annotations

import math

import pytest

from machines_klipper import BED_SLINGER, CALIBRATE, calibrated_voron, run, start, voron_text
from tapcell.host.config import ConfigError
from tapcell.host.gcode import GCodeError
from tapcell.host.printer import Printer


def test_voron_printer_cfg_loads_with_one_notice_of_what_is_simulated(tmp_path):
    printer, _ = start(tmp_path, voron_text())
    assert printer.state == "ready" and printer.warnings == []
    world, (simulated, accepted) = printer.notices[0], printer.notices[1].split("\n")
    assert world.startswith("Virtual printer: scenario 'clean' (well-built printer")
    assert world.endswith("[virtual_printer] sets bed_x_mm=300.0, bed_y_mm=300.0. The machine is the printer "
                          "config's: load cell ads1220 at 2000 sps, gain 128; X 0..300, Y 0..300, Z down to -5 mm")
    assert simulated.startswith("The virtual printer simulates: [printer] [stepper_x] [stepper_y] [stepper_z] "
                                "(motion); [extruder] (nozzle heater, E axis without filament); [heater_bed] (heater)")
    assert "[load_cell_probe] (load cell under the nozzle, bed contact)" in simulated
    for section in ("[mcu]", "[mcu toolboard]", "[board_pins octopus]", "[tmc2209 stepper_x]", "[stepper_z1]",
                    "[adxl345]", "[input_shaper]", "[save_variables]", "[firmware_retraction]"):
        assert section in accepted, section
    for section in ("[neopixel sb_leds] (colour recorded)", "[z_tilt] (one Z motor: nothing to level)",
                    "[virtual_sdcard] (prints files)", "[force_move] (FORCE_MOVE, STEPPER_BUZZ, SET_KINEMATIC_POSITION)"):
        assert section in simulated and section.split(" (")[0] not in accepted, section
    status = printer.get_status()
    assert {"toolhead", "gcode_move", "extruder", "heater_bed", "fan", "heater_fan hotend_fan", "heaters", "pause_resume",
            "display_status", "exclude_object", "temperature_sensor chamber", "output_pin caselight",
            "idle_timeout", "motion_report", "system_stats", "query_endstops", "print_stats", "virtual_sdcard",
            "z_tilt", "neopixel sb_leds"} <= set(status)
    assert status["heaters"]["available_heaters"] == ["extruder", "heater_bed"]
    assert status["output_pin caselight"] == {"value": 0.5}


@pytest.mark.parametrize("old, new, message", [
    # Modelled sections still check every option name, as Klipper does.
    ("heater_temp: 50.0", "heater_tmp: 50.0",
     "[heater_fan hotend_fan] heater_tmp = 50.0: Option 'heater_tmp' is not valid in section 'heater_fan hotend_fan'"),
    ("pressure_advance: 0.04", "pressure_advanse: 0.04",
     "[extruder] pressure_advanse = 0.04: Option 'pressure_advanse' is not valid in section 'extruder'"),
    ("z_hop: 10", "z_hopp: 10", "[safe_z_home] z_hopp = 10: Option 'z_hopp' is not valid in section 'safe_z_home'"),
    ("max_temp: 120", "max_temp: -5", "[heater_bed] max_temp = -5: must be above 0 (allowed: above 0 and at "
                                      "most 1000)"),
])
def test_typos_in_modelled_sections_are_errors(tmp_path, old, new, message):
    path = tmp_path / "printer.cfg"
    path.write_text(voron_text({old: new}))
    with pytest.raises(ConfigError) as info:
        Printer.from_config(str(path))
    assert str(info.value) == f"{path}: {message}"


def test_accepted_sections_take_their_options_as_written(tmp_path):
    board_specific = {"stealthchop_threshold: 0\n\n[stepper_y]": "stealthchop_threshold: 0\ndriver_SGTHRS: 255\n"
                                                                   "diag_pin: ^PG6\n\n[stepper_y]"}
    printer, _ = start(tmp_path, voron_text(board_specific))
    assert printer.state == "ready"


def test_a_bed_heats_in_minutes_of_printer_time_and_no_wall_time(tmp_path):
    printer, responses = start(tmp_path, BED_SLINGER)
    t0 = printer.backend.now_s
    out = run(printer, responses, "M190 S60")
    waited_s = printer.backend.now_s - t0
    # A heated bed takes minutes to reach 60 C from the room; a nozzle about a minute to 215 C.
    assert 120.0 < waited_s < 300.0, waited_s
    assert abs(printer.get_status()["heater_bed"]["temperature"] - 60.0) <= 1.0
    assert out == [f"// heater_bed: {printer.get_status()['heater_bed']['temperature']:.1f}C, target 60C "
                   f"(waited {waited_s:.1f} s of printer time)"]
    t1 = printer.backend.now_s
    run(printer, responses, "M109 S215")
    assert 30.0 < printer.backend.now_s - t1 < 120.0
    status = printer.get_status()["extruder"]
    assert abs(status["temperature"] - 215.0) <= 1.0 and status["can_extrude"] is True
    assert run(printer, responses, "M105") == [f"ok T0:{status['temperature']:.1f} /215.0 "
                                               f"B:{printer.get_status()['heater_bed']['temperature']:.1f} /60.0"]
    # Off: back toward the room, never below it.
    run(printer, responses, "M140 S0\nG4 P600000")
    assert 25.0 <= printer.get_status()["heater_bed"]["temperature"] < 26.0
    with pytest.raises(GCodeError, match=r"Requested temperature \(140.0\) out of range \(0.0:130.0\)"):
        printer.gcode.run_script("M140 S140")


def test_fans_and_pins_are_recorded(tmp_path):
    path = calibrated_voron(tmp_path)
    printer, responses = start(tmp_path, path.read_text(), "again.cfg")
    outputs = printer.backend.outputs
    run(printer, responses, "M106 S128\nG4 P1000\nM106 S13\nM107\nSET_PIN PIN=caselight VALUE=1")
    assert [value for _, value in outputs.changes["fan"]] == pytest.approx([128 / 255, 0.0])  # 13/255 < off_below
    assert outputs.value("output_pin caselight") == 1.0
    status = printer.get_status()
    assert status["heater_fan hotend_fan"]["speed"] == 0.0 and status["controller_fan controller_fan"]["speed"] == 0.0
    run(printer, responses, "M104 S200\nG28")
    status = printer.get_status()
    assert status["heater_fan hotend_fan"]["speed"] == 1.0  # a target on the hotend turns its fan on
    assert status["controller_fan controller_fan"]["speed"] == 1.0  # motors on
    assert outputs.value("heater_fan hotend_fan") == 1.0


def test_virtual_printer_follows_the_printers_sensor(tmp_path):
    # The Voron's cell: an ADS1220 at 2000 samples/s, on the toolhead board (the stop is relayed).
    path = calibrated_voron(tmp_path)
    printer, responses = start(tmp_path, path.read_text(), "again.cfg")
    params = printer.backend.params
    assert (params.chip, params.sample_rate_sps, params.multi_mcu_delay_s) == ("ads1220", 2000.0, 0.004)
    measured = [line for line in run(printer, responses, "LOAD_CELL_DIAGNOSTIC") if "Measured" in line]
    rate = float(measured[0].split(": ")[1].split(",")[0])
    assert abs(rate - 2000.0) < 2.0 and measured[0].endswith("configured: 2000.0")
    # An HX711 measures its 80 samples/s, on the main board.
    hx711 = {"sensor_type: ads1220\ncs_pin: toolboard:PA4\ndata_ready_pin: toolboard:PA2\nspi_bus: spi1\n"
             "gain: 128\nsample_rate: 2000": "sensor_type: hx711\nsclk_pin: PA5\ndout_pin: PA4\nsample_rate: 80\n"
                                               "gain: A-64"}
    printer, responses = start(tmp_path, voron_text(hx711), "hx711.cfg")
    assert (printer.backend.params.chip, printer.backend.params.multi_mcu_delay_s) == ("hx711", 0.0)
    # Gain 64: half the counts per gram of the same cell at 128 (110 counts/g in the clean scenario).
    assert printer.backend.truth.counts_per_gram == pytest.approx(55.0)
    measured = [line for line in run(printer, responses, "LOAD_CELL_DIAGNOSTIC") if "Measured" in line]
    assert abs(float(measured[0].split(": ")[1].split(",")[0]) - 80.0) < 1.0


def test_virtual_printer_follows_travel_and_z_speed(tmp_path):
    printer, responses = start(tmp_path, voron_text({"max_z_velocity: 15": "max_z_velocity: 5"}))
    assert printer.backend.limits == {"x": (0.0, 300.0), "y": (0.0, 300.0), "z": (-5.0, 250.0)}
    # Z steps: 40 mm per turn through an 80:16 gearbox, 200 steps x 32 microsteps.
    assert printer.backend.step_distance_mm[2] == pytest.approx(40 / 5 / 6400)
    run(printer, responses, CALIBRATE + "\nG28")
    # X/Y home at their position_endstop (300, the Voron's max end): the frames agree there.
    assert printer.lookup_object("toolhead").frame_offset_mm["x"] == 0.0
    t0 = printer.backend.now_s
    run(printer, responses, "G1 Z60 F6000")  # asks 100 mm/s; the machine's Z does 5 mm/s
    elapsed_s = printer.backend.now_s - t0
    assert elapsed_s == pytest.approx(50.0 / 5.0 + 5.0 / 350.0, rel=0.01)


def test_virtual_printer_section_is_only_the_world(tmp_path):
    text = voron_text({"bed_y_mm: 300": "bed_y_mm: 300\nchip: hx711"})
    path = tmp_path / "printer.cfg"
    path.write_text(text)
    with pytest.raises(ConfigError) as info:
        Printer.from_config(str(path))
    assert str(info.value) == (f"{path}: [virtual_printer] chip = hx711: the printer's own config sets this "
                               "([load_cell_probe] sensor_type = ads1220); [virtual_printer] describes only the "
                               "world (bed, noise, faults, scenario)")
    printer, _ = start(tmp_path, voron_text({"scenario: clean": "scenario: noisy-mains"}), "noisy.cfg")
    assert printer.notices[0].startswith(
        "Virtual printer: scenario 'noisy-mains' (50 Hz hum coupled into the cell wiring, plus a noisier ground), "
        "seed 1: changes hum_counts=1500, hum_hz=50, white_noise_counts=160, pink_noise_counts=80")
    printer, _ = start(tmp_path, voron_text({"scenario: clean": "scenario: slow-adc"}), "slow.cfg")
    assert ("chip=hx711, sample_rate_sps=80.0 are for the printer config to say (it has ads1220 at 2000 sps)"
            in printer.notices[0])
    assert printer.backend.params.chip_rate_error == 0.015  # the scenario's world still applies


def test_position_min_zero_warns_and_taps_say_coasting(tmp_path):
    path = calibrated_voron(tmp_path, {"position_min: -5": "position_min: 0"})
    printer, responses = start(tmp_path, path.read_text(), "again.cfg")
    assert printer.warnings == [
        "[stepper_z] position_min = 0: taps need room below zero. The nozzle presses a little past the bed before "
        "the probe triggers, so a probing move that ends at Z=0 slows down first and every tap fails with "
        "COASTING_MOVE_ACCELERATION; set a negative position_min, e.g. position_min: -5"]
    run(printer, responses, "G28")  # homing itself is not limited by position_min
    with pytest.raises(GCodeError) as info:
        printer.gcode.run_script("PROBE BAD_PROBE_STRATEGY=fail")
    assert "COASTING_MOVE_ACCELERATION - the probing move was slowing down when the probe triggered" in str(info.value)
    assert "negative position_min" in str(info.value)  # the fix, in the guide's words
    assert printer.backend.position[2] > printer.backend.truth.contact_z_at(150.0, 150.0)  # lifted off the bed


def test_safe_z_home_hops_and_homes_z_over_the_bed(tmp_path):
    replace = {"z_hop_speed: 15": "z_hop_speed: 15\nmove_to_previous: True"}
    path = calibrated_voron(tmp_path, replace)
    printer, responses = start(tmp_path, path.read_text(), "again.cfg")
    vp = printer.backend
    z_start = vp.position[2]
    run(printer, responses, "G28 X Y")
    # Z unhomed: lifted by z_hop from where it stood before X/Y moved.
    assert vp.position[2] == pytest.approx(z_start + 10.0, abs=0.01)
    run(printer, responses, "G1 X40 Y50 F6000\nG28 Z")
    toolhead = printer.lookup_object("toolhead")
    x, y, z = toolhead.get_position()
    assert (x, y) == pytest.approx((40.0, 50.0)) and z == pytest.approx(10.0)  # back to the previous X/Y
    assert toolhead.homed_axes == {"x", "y", "z"}
    assert vp._tap_xy_mm == pytest.approx((150.0, 150.0))  # Z was homed at home_xy_position


def test_homing_override_runs_the_users_gcode(tmp_path):
    printer, responses = start(tmp_path, BED_SLINGER.replace("    G28 X Y\n", "    G28 X Y\n    RESPOND MSG=overridden\n"))
    out = run(printer, responses, "G28")
    assert out == ["echo: overridden"]
    toolhead = printer.lookup_object("toolhead")
    assert toolhead.homed_axes == {"x", "y", "z"} and toolhead.get_position() == pytest.approx((0.0, 0.0, 10.0))
    text = BED_SLINGER + "\n[safe_z_home]\nhome_xy_position: 100, 100\n"
    path = tmp_path / "both.cfg"
    path.write_text(text)
    with pytest.raises(ConfigError, match=r"\[safe_z_home\] and \[homing_override\] cannot be used together"):
        Printer.from_config(str(path))


def test_bed_heater_model_is_first_order(tmp_path):
    """The bed's temperature after a fixed time fits T = T_room + dT (1 - exp(-t / tau)) at three times."""
    printer, responses = start(tmp_path, BED_SLINGER)
    samples = []
    run(printer, responses, "M140 S100")
    for _ in range(3):
        run(printer, responses, "G4 P30000")
        samples.append(printer.get_status()["heater_bed"]["temperature"] - 25.0)
    # Successive 30 s steps close the same share of the remaining gap.
    shares = [(samples[1] - samples[0]) / (75.0 - samples[0]), (samples[2] - samples[1]) / (75.0 - samples[1])]
    assert shares[0] == pytest.approx(shares[1], abs=0.002)
    assert shares[0] == pytest.approx(1 - math.exp(-30.0 / printer.backend.params.bed_heater_tau_s), abs=0.002)


def test_temperature_wait_and_set_heater_temperature(tmp_path):
    printer, responses = start(tmp_path, BED_SLINGER + "\n[heater_generic chamber]\nheater_pin: PB5\n"
                               "sensor_type: Generic 3950\nsensor_pin: PB6\nmin_temp: 0\nmax_temp: 80\n"
                               "\n[temperature_sensor electronics]\nsensor_type: temperature_host\n"
                               "min_temp: 0\nmax_temp: 100\n")
    run(printer, responses, "SET_HEATER_TEMPERATURE HEATER=chamber TARGET=50\nTEMPERATURE_WAIT SENSOR=chamber MINIMUM=40")
    assert 40.0 <= printer.get_status()["heater_generic chamber"]["temperature"] < 40.1
    with pytest.raises(GCodeError, match=r"heater_generic chamber is heading for 50.0C and never reaches 60C"):
        printer.gcode.run_script("TEMPERATURE_WAIT SENSOR=chamber MINIMUM=60")
    with pytest.raises(GCodeError, match=r"temperature_sensor electronics stays at 25.0C .* never reaches 30C"):
        printer.gcode.run_script("TEMPERATURE_WAIT SENSOR=electronics MINIMUM=30")
    run(printer, responses, "TEMPERATURE_WAIT SENSOR=electronics MAXIMUM=30")  # already there: no wait
    assert printer.get_status()["heaters"]["available_sensors"] == ["extruder", "heater_bed", "heater_generic chamber",
                                                                     "temperature_sensor electronics"]


def test_status_repeats_the_load_warnings(tmp_path):
    printer, responses = start(tmp_path, voron_text({"position_min: -5": "position_min: 0"}))
    out = run(printer, responses, "STATUS")
    assert out[1] == f"// Warning: {printer.warnings[0]}"
