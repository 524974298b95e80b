"""[z_thermal_adjust]: the compensation arithmetic applied to G-code moves."""

from __future__ import annotations

import pytest

from tapcell.host.config import ConfigError

from machines import gcode_error

THERMAL = """
[z_thermal_adjust nozzle]
temp_coeff: -0.00045455
sensor_type: temperature_combined
sensor_list: extruder
combination_method: max
min_temp: 0
max_temp: 400
max_z_adjustment: 0.1
"""


def toolhead_z(printer) -> float:
    toolhead = printer.lookup_object("toolhead")
    return toolhead.get_position()[2]


def test_hot_nozzle_lifts_the_toolhead_by_coeff_times_temperature_rise(make_printer, home_without_probe):
    printer = make_printer(THERMAL)
    home_without_probe(printer, z_mm=10.0)  # reference: the cold nozzle (25 C)
    printer.gcode.run_script("G1 Z1 F600")
    assert toolhead_z(printer) == pytest.approx(1.0, abs=0.0013)
    printer.backend.set_nozzle_temperature(200.0, wait=True)
    rise_c = printer.backend.nozzle_temperature_c - 25.0  # read as the move starts
    printer.gcode.run_script("G1 X50 Z1")
    assert rise_c == pytest.approx(175.0, abs=1.0)
    assert toolhead_z(printer) == pytest.approx(1.0 + 0.00045455 * rise_c, abs=0.0013)  # 79.5 um up
    printer.gcode.run_script("M114")
    assert make_printer.responses[-1].startswith("X:50.000 Y:")
    assert make_printer.responses[-1].split("Z:")[1].startswith(("1.000", "0.999", "1.001"))
    status = printer.get_status()["z_thermal_adjust nozzle"]
    assert status["z_adjust_ref_temperature"] == pytest.approx(25.0)
    assert status["current_z_adjust"] == pytest.approx(0.00045455 * rise_c, rel=1e-6)


def test_adjustment_is_clamped_and_can_be_switched_off(make_printer, home_without_probe):
    printer = make_printer(THERMAL.replace("max_z_adjustment: 0.1", "max_z_adjustment: 0.05"))
    home_without_probe(printer, z_mm=10.0)
    printer.backend.set_nozzle_temperature(250.0, wait=True)
    printer.gcode.run_script("G1 Z2 F600")
    assert toolhead_z(printer) == pytest.approx(2.05, abs=0.0013)  # 0.102 mm clamped to 0.05
    printer.gcode.run_script("SET_Z_THERMAL_ADJUST ENABLE=0")
    assert "z_thermal_adjust: disabled" in make_printer.responses[-1]
    printer.gcode.run_script("G1 Z2")
    assert toolhead_z(printer) == pytest.approx(2.0, abs=0.0013)


def test_set_temp_coeff_from_gcode(make_printer, home_without_probe):
    printer = make_printer(THERMAL)
    home_without_probe(printer, z_mm=10.0)
    printer.backend.set_nozzle_temperature(125.0, wait=True)
    rise_c = printer.backend.nozzle_temperature_c - 25.0
    printer.gcode.run_script("SET_Z_THERMAL_ADJUST TEMP_COEFF=0.0002\nG1 Z3 F600")
    assert toolhead_z(printer) == pytest.approx(3.0 - 0.0002 * rise_c, abs=0.0013)  # positive: moves down


def test_only_the_nozzle_sensor_exists(make_printer):
    with pytest.raises(ConfigError) as err:
        make_printer(THERMAL.replace("sensor_list: extruder", "sensor_list: chamber"))
    assert "[z_thermal_adjust nozzle] sensor_list = chamber: must list temperature sensors" in str(err.value)
    with pytest.raises(ConfigError) as err:
        make_printer(THERMAL.replace("sensor_type: temperature_combined", "sensor_type: EPCOS 100K B57560G104F"))
    assert "use sensor_type: temperature_combined with sensor_list: extruder" in str(err.value)


def test_calibrate_checks_its_temperatures(make_printer, home_without_probe):
    printer = make_printer(THERMAL)
    assert gcode_error(printer, "Z_THERMAL_CALIBRATE TEMP_COLD=200 TEMP_HOT=180") == ("Error on 'Z_THERMAL_CALIBRATE TEMP_COLD=200 TEMP_HOT=180': TEMP_HOT (180) must be "
                              "above TEMP_COLD (200); the guide uses 180 and 290")
