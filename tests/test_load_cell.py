"""[load_cell] on the virtual printer: options, calibration session, errors, status,
SAVE_CONFIG, orientation, several cells, macros. Every response is checked."""

from __future__ import annotations

import os
import re
import textwrap

import pytest

from tapcell.extras import load_cell
from tapcell.tools import frontend
from tapcell.host.config import ConfigError
from tapcell.host.gcode import GCodeError
from tapcell.host.printer import Printer

CELL = """
[load_cell]
sensor_type: hx717
sclk_pin: PA5
dout_pin: PA4
"""
# 240 counts/g: a 500 g calibration moves the reading by 1.4 % of the range (> 1 %).
SIM_240 = """
[virtual_printer]
scenario: clean
seed: 3
counts_per_gram: 240
"""


def write_config(tmp_path, text: str, name: str = "printer.cfg") -> str:
    path = tmp_path / name
    path.write_text(text)
    return str(path)


def run_tapcell(tmp_path, capsys, config: str, script: str, *extra: str) -> tuple[int, list[str]]:
    script_path = tmp_path / "script.gcode"
    script_path.write_text(textwrap.dedent(script))
    code = frontend.main(["run", "--echo", *extra, "--config", config, str(script_path)])
    return code, capsys.readouterr().out.splitlines()


def start(tmp_path, text: str) -> tuple[Printer, list[str]]:
    responses: list[str] = []
    return Printer.from_config(write_config(tmp_path, text), responses=responses), responses


def run(printer: Printer, responses: list[str], script: str) -> list[str]:
    responses.clear()
    printer.gcode.run_script(textwrap.dedent(script))
    return list(responses)


def match_lines(lines: list[str], patterns: list[str]) -> list[re.Match]:
    """Every line must fully match its pattern (the whole text is pinned, numbers captured)."""
    assert len(lines) == len(patterns), "\n".join(lines)
    matches = []
    for line, pattern in zip(lines, patterns):
        found = re.fullmatch(pattern, line)
        assert found, f"{line!r} does not match {pattern!r}"
        matches.append(found)
    return matches


NUM = r"(-?\d+\.\d+)"
INT = r"(-?\d+)"


def test_whole_calibration_session_through_tapcell_run(tmp_path, capsys):
    config = write_config(tmp_path, SIM_240 + CELL)
    code, lines = run_tapcell(tmp_path, capsys, config, """\
        LOAD_CELL_CALIBRATE
        TARE
        SIM_PLACE_WEIGHT GRAMS=500
        CALIBRATE GRAMS=500
        ACCEPT
        SIM_REMOVE_WEIGHT
        SAVE_CONFIG
        SIM_PLACE_WEIGHT GRAMS=1000
        LOAD_CELL_READ
        """)
    assert code == 0
    found = match_lines(lines, [
        r"> LOAD_CELL_CALIBRATE",
        r"// Starting load cell calibration of 'load_cell':",
        r"// 1\. Remove all load from the cell, then run TARE\.",
        r"// 2\. Apply a known load, then run CALIBRATE GRAMS=nnn \(50 to 25000 grams\)\.",
        r"// 3\. Run ACCEPT to keep the result; SAVE_CONFIG then writes it to the config file\.",
        r"// Run ABORT to quit at any time\.",
        r"> TARE",
        rf"// Load cell tare value: {NUM}% \({INT}\)",
        r"// Now apply a known load to the cell and run CALIBRATE GRAMS=nnn",
        r"> SIM_PLACE_WEIGHT GRAMS=500",
        r"// A 500 g weight now rests on the load cell",
        r"> CALIBRATE GRAMS=500",
        rf"// Calibration value: {NUM}% \({INT}\), Counts/gram: (\d+\.\d{{6}}), Total capacity: \+/- {NUM}Kg",
        # 34.9 kg of capacity at the HX717's highest gain: no "capacity is more than 25kg" advice to follow.
        r"// Accept calibration with the ACCEPT command\.",
        r"> ACCEPT",
        r"// Load cell calibration settings:",
        r"// ",
        r"// counts_per_gram: (\d+\.\d{6})",
        rf"// reference_tare_counts: {INT}",
        r"// ",
        r"// The SAVE_CONFIG command will update the printer config file with the above and restart the printer\.",
        r"> SIM_REMOVE_WEIGHT",
        r"// The weight is off the load cell",
        r"> SAVE_CONFIG",
        rf"// Config saved to {re.escape(config)}; restarting",
        r"// Printer is ready",
        r"> SIM_PLACE_WEIGHT GRAMS=1000",
        r"// A 1000 g weight now rests on the load cell",
        r"> LOAD_CELL_READ",
        rf"// {NUM}g \({NUM}%\)",
    ])
    tare_percent, tare_counts = float(found[7][1]), int(found[7][2])
    # The virtual cell's zero is -38000 counts (-0.45 % of the range); noise is ~80 counts.
    assert tare_counts == pytest.approx(-38000, abs=150)
    assert tare_percent == pytest.approx(tare_counts / 0x7FFFFF * 100, abs=0.005)
    loaded_counts, counts_per_gram = int(found[12][2]), float(found[12][3])
    assert loaded_counts == pytest.approx(-38000 + 500 * 240, abs=200)
    assert counts_per_gram == pytest.approx(240.0, rel=0.002)
    assert float(found[12][4]) == pytest.approx((0x7FFFFF + tare_counts) / counts_per_gram / 1000, abs=0.01)
    assert float(found[17][1]) == counts_per_gram
    assert int(found[18][1]) == tare_counts
    # After calibrating with 500 g, 1000 g reads as 1000 g within 0.5 %.
    assert float(found[29][1]) == pytest.approx(1000.0, rel=0.005)
    saved = open(config).read()
    assert f"#*# counts_per_gram = {counts_per_gram:.6f}" in saved
    assert f"#*# reference_tare_counts = {tare_counts}" in saved


@pytest.mark.parametrize("sensor_type, gain, higher", [
    ("hx717", "A-128", None), ("hx717", "A-64", "A-128"), ("hx717", "B-8", "B-64"), ("hx717", "B-64", None),
    ("hx711", "A-64", "A-128"), ("hx711", "B-32", None), ("ads1220", "64", "128"), ("ads1220", "128", None),
])
def test_higher_gain_stays_on_the_channel(sensor_type, gain, higher):
    assert load_cell.higher_gain(sensor_type, gain) == higher


def test_the_capacity_warning_names_the_higher_gain_only_when_there_is_one(tmp_path):
    """The issue's case: a correct calibration at the HX717's highest gain warned 'capacity is more than 25kg'."""
    script = "LOAD_CELL_CALIBRATE\nTARE\nSIM_PLACE_WEIGHT GRAMS=1000\nCALIBRATE GRAMS=1000\n"
    printer, responses = start(tmp_path, SIM_240 + CELL)
    assert [line for line in run(printer, responses, script) if "WARNING" in line] == []
    printer, responses = start(tmp_path, SIM_240 + CELL + "gain: A-64\n")
    warnings = [line for line in run(printer, responses, script) if "WARNING" in line]
    assert warnings == ["// WARNING: Load cell capacity is more than 25kg! Readings will be coarse; consider a "
                        "higher gain setting (gain: A-128) or a more sensitive load cell."]


def test_restart_keeps_the_calibration_and_a_failed_write_keeps_the_old_file(tmp_path, monkeypatch):
    printer, responses = start(tmp_path, SIM_240 + CELL)
    run(printer, responses, """\
        LOAD_CELL_CALIBRATE
        TARE
        SIM_PLACE_WEIGHT GRAMS=500
        CALIBRATE GRAMS=500
        ACCEPT
        SAVE_CONFIG
        """)
    status = printer.get_status()["load_cell"]
    assert status["is_calibrated"] is True
    assert status["counts_per_gram"] == pytest.approx(240.0, rel=0.002)
    saved_text = open(printer.config_path).read()
    # A second calibration whose write fails half way: the file on disk stays as it was.
    run(printer, responses, """\
        LOAD_CELL_CALIBRATE
        TARE
        SIM_PLACE_WEIGHT GRAMS=800
        CALIBRATE GRAMS=500
        ACCEPT
        """)

    def broken_replace(src, dst):
        raise OSError("disk full")

    monkeypatch.setattr(os, "replace", broken_replace)
    with pytest.raises(Exception):
        printer.gcode.run_line("SAVE_CONFIG")
    monkeypatch.undo()
    assert open(printer.config_path).read() == saved_text
    restarted = Printer.from_config(printer.config_path)
    assert restarted.get_status()["load_cell"]["counts_per_gram"] == status["counts_per_gram"]
    assert restarted.get_status()["load_cell"]["reference_tare_counts"] == status["reference_tare_counts"]


def test_calibration_errors(tmp_path):
    printer, responses = start(tmp_path, SIM_240 + CELL)

    def error_of(line: str) -> str:
        with pytest.raises(GCodeError) as info:
            printer.gcode.run_line(line)
        return str(info.value)

    run(printer, responses, "LOAD_CELL_CALIBRATE")
    assert error_of("LOAD_CELL_CALIBRATE") == "Already Calibrating a Load Cell. Use ABORT to quit."
    assert error_of("CALIBRATE GRAMS=500") == "Run TARE with no load on the cell before CALIBRATE GRAMS=nnn"
    assert error_of("ACCEPT") == ("Load cell calibration is incomplete: run TARE, then CALIBRATE GRAMS=nnn, "
                                  "before ACCEPT (or ABORT to quit)")
    run(printer, responses, "TARE")
    assert error_of("ACCEPT") == ("Load cell calibration is incomplete: run CALIBRATE GRAMS=nnn before ACCEPT "
                                  "(or ABORT to quit)")
    assert error_of("CALIBRATE GRAMS=10") == "Error on 'CALIBRATE GRAMS=10': GRAMS must have minimum of 50 (allowed: 50 to 25000)"
    assert error_of("CALIBRATE GRAMS=30000") == "Error on 'CALIBRATE GRAMS=30000': GRAMS must have maximum of 25000 (allowed: 50 to 25000)"
    assert error_of("CALIBRATE GRAMS=heavy") == ("Error on 'CALIBRATE GRAMS=heavy': unable to parse 'heavy' for "
                                                 "GRAMS (expected a number)")
    assert error_of("CALIBRATE") == "Error on 'CALIBRATE': missing GRAMS"
    # 300 g moves the reading by 72,000 counts = 0.86 % of the range.
    run(printer, responses, "SIM_PLACE_WEIGHT GRAMS=300")
    message = error_of("CALIBRATE GRAMS=300")
    assert re.fullmatch(r"ERROR: Tare and Calibration readings are less than 1% different! \(0\.8\d%\) "
                        r"Use more force, or a higher gain setting\.", message), message
    run(printer, responses, "SIM_PLACE_WEIGHT GRAMS=40000")
    assert error_of("CALIBRATE GRAMS=5000") == ("ERROR: Sensor is saturated with too much load! Use less force "
                                                "for calibration.")
    # The session is still open after errors; ABORT ends it and removes its commands.
    assert run(printer, responses, "ABORT") == ["// Load cell calibration aborted"]
    assert error_of("TARE") == 'Unknown command:"TARE"'
    assert printer.get_status()["load_cell"]["is_calibrated"] is False


def test_identical_readings_are_refused(tmp_path):
    printer, responses = start(tmp_path, SIM_240 + CELL)
    # A stuck sensor repeats one value: tare and calibration read the same.
    run(printer, responses, "SIM_FAULT NAME=stuck\nLOAD_CELL_CALIBRATE\nTARE\nSIM_PLACE_WEIGHT GRAMS=500")
    with pytest.raises(GCodeError) as info:
        printer.gcode.run_line("CALIBRATE GRAMS=500")
    assert str(info.value) == ("ERROR: Tare and Calibration readings are the same! Check the wiring and that "
                               "the force really rests on the load cell.")


def test_tare_read_status_and_uncalibrated_read(tmp_path):
    printer, responses = start(tmp_path, SIM_240 + CELL)
    (read,) = run(printer, responses, "LOAD_CELL_READ")
    assert re.fullmatch(r"// ---\.-g \(-0\.45%\)", read), read
    (tare,) = run(printer, responses, "LOAD_CELL_TARE")
    counts = int(re.fullmatch(r"// Load cell tare value: -0\.45% \((-\d+)\)", tare)[1])
    status = printer.get_status()["load_cell"]
    assert status == {"is_calibrated": False, "counts_per_gram": None, "reference_tare_counts": None,
                      "tare_counts": counts, "force_g": None, "min_force_g": None, "max_force_g": None,
                      "errors": 0, "overflows": 0, "sample_rate": 320.0}


def test_force_status_averages_the_last_second_and_a_macro_reads_it(tmp_path):
    config = SIM_240 + CELL + textwrap.dedent("""\
        counts_per_gram: 240
        reference_tare_counts: -38000

        [gcode_macro SHOW_WEIGHT]
        gcode:
          {% set grams = printer.load_cell.force_g %}
          {action_respond_info("on the cell: %.0f g" % grams)}
        """)
    printer, responses = start(tmp_path, config)
    run(printer, responses, "SIM_PLACE_WEIGHT GRAMS=2000")
    printer.backend.dwell(2.0)
    status = printer.get_status()["load_cell"]
    assert status["force_g"] == pytest.approx(2000, abs=3)
    assert status["min_force_g"] < status["force_g"] < status["max_force_g"]
    assert status["max_force_g"] - status["min_force_g"] < 5  # noise only: the weight rests for > 1 s
    assert run(printer, responses, "SHOW_WEIGHT") == ["// on the cell: 2000 g"]


def test_inverted_orientation(tmp_path):
    inverted_sim = SIM_240 + "cell_polarity: -1\n"
    printer, responses = start(tmp_path, inverted_sim + CELL + "sensor_orientation: inverted\n")
    lines = run(printer, responses, """\
        LOAD_CELL_CALIBRATE
        TARE
        SIM_PLACE_WEIGHT GRAMS=500
        CALIBRATE GRAMS=500
        ACCEPT
        SIM_REMOVE_WEIGHT
        LOAD_CELL_TARE
        SIM_PLACE_WEIGHT GRAMS=1000
        LOAD_CELL_READ
        """)
    assert not any("opposite way" in line for line in lines)
    assert float(re.fullmatch(r"// (-?\d+\.\d)g \(.*\)", lines[-1])[1]) == pytest.approx(1000, rel=0.005)
    # The same cell configured 'normal' is warned about and reads negative.
    normal, responses = start(tmp_path, inverted_sim + CELL)
    lines = run(normal, responses, "LOAD_CELL_CALIBRATE\nTARE\nSIM_PLACE_WEIGHT GRAMS=500\nCALIBRATE GRAMS=500")
    assert ("// WARNING: The reading moved the opposite way to sensor_orientation: normal, so forces would read "
            "negative. Set sensor_orientation: inverted.") in lines
    run(normal, responses, "ACCEPT")
    assert normal.get_status()["load_cell"]["force_g"] == pytest.approx(-500, rel=0.01)


def test_two_named_cells(tmp_path):
    config = SIM_240 + CELL + textwrap.dedent("""
        [load_cell spool]
        sensor_type: hx711
        sclk_pin: PB5
        dout_pin: PB4
        """)
    printer, responses = start(tmp_path, config)
    assert printer.lookup_object("load_cell spool").sensor is not printer.lookup_object("load_cell").sensor
    run(printer, responses, "LOAD_CELL_TARE LOAD_CELL=spool\nSIM_PLACE_WEIGHT LOAD_CELL=spool GRAMS=750")
    spool = printer.lookup_object("load_cell spool")
    spool_counts = spool.average_counts()
    spool_moved = spool_counts - spool.tare_counts
    toolhead_cell = printer.lookup_object("load_cell")
    assert abs(spool_moved) > 10_000  # the weight is on the spool cell ...
    toolhead_counts = toolhead_cell.average_counts()
    assert toolhead_counts == pytest.approx(-38000, abs=300)  # ... not on the toolhead cell
    (rate_line,) = [line for line in run(printer, responses, "LOAD_CELL_DIAGNOSTIC LOAD_CELL=spool")
                    if line.startswith("// Measured")]
    assert re.fullmatch(r"// Measured samples per second: (79|80|81)\.\d, configured: 80\.0", rate_line)
    with pytest.raises(GCodeError) as info:
        printer.gcode.run_line("LOAD_CELL_READ LOAD_CELL=bogus")
    assert str(info.value) == ("Error on 'LOAD_CELL_READ LOAD_CELL=bogus': the value 'bogus' is not valid for "
                               "LOAD_CELL (one of: load_cell, spool)")


def test_diagnostic_reports_progress_rate_and_grams(tmp_path):
    config = SIM_240 + CELL + "counts_per_gram: 240\nreference_tare_counts: -38000\n"
    printer, responses = start(tmp_path, config)
    lines = run(printer, responses, "LOAD_CELL_DIAGNOSTIC")
    found = match_lines(lines, [
        r"// Collecting load cell data for 10 seconds\.\.\.",
        r"// \.\.\. 2 of 10 s, (\d+) samples",
        r"// \.\.\. 4 of 10 s, (\d+) samples",
        r"// \.\.\. 6 of 10 s, (\d+) samples",
        r"// \.\.\. 8 of 10 s, (\d+) samples",
        r"// Sensor reported no errors",
        r"// Samples Collected: (\d+)",
        rf"// Measured samples per second: {NUM}, configured: 320\.0",
        r"// Good samples: (\d+), Saturated samples: 0, Unique values: (\d+)",
        rf"// Sample range: \[{NUM}% to {NUM}%\]",
        r"// Sample range / sensor capacity: (\d\.\d{5})%",
        rf"// Sample range in grams: \[{NUM}g to {NUM}g\] \({NUM}g wide\)",
    ])
    assert int(found[1][1]) == pytest.approx(640, abs=2)
    samples = int(found[6][1])
    assert samples == pytest.approx(3200, abs=2)
    assert float(found[7][1]) == pytest.approx(320.0, abs=0.5)
    assert int(found[8][1]) == samples
    assert 100 < int(found[8][2]) < samples  # noisy but alive
    low, high = float(found[9][1]), float(found[9][2])
    assert low == pytest.approx(-0.455, abs=0.01) and high == pytest.approx(-0.455, abs=0.01)
    assert float(found[11][3]) < 10.0  # ~80 counts of noise = a few grams peak to peak


def test_diagnostic_counts_sensor_errors_and_refuses_silence(tmp_path):
    printer, responses = start(tmp_path, SIM_240 + CELL)
    lines = run(printer, responses, "SIM_FAULT NAME=corrupt_frame COUNT=3 SPACING_S=1 DETECTED=1\nLOAD_CELL_DIAGNOSTIC")
    (errors_line,) = [line for line in lines if line.startswith("// Sensor reported")]
    errors = int(re.fullmatch(r"// Sensor reported errors: (\d+) errors, 0 overflows", errors_line)[1])
    assert errors >= 3  # three detected corrupt frames (the sim may flag one twice across a chunk edge)
    assert printer.get_status()["load_cell"]["errors"] == errors
    printer.gcode.run_line("SIM_FAULT NAME=disconnected")
    responses.clear()
    with pytest.raises(GCodeError) as info:
        printer.gcode.run_line("LOAD_CELL_DIAGNOSTIC")
    assert str(info.value) == "No samples returned from sensor! Check the wiring and the sensor_type / pins."
    assert responses[-1] == "// Sensor reported no errors"
    with pytest.raises(GCodeError) as info:
        printer.gcode.run_line("LOAD_CELL_TARE")
    assert str(info.value) == ("No samples returned from sensor! (load_cell: nothing in 1 s; check the sensor "
                               "wiring and its sensor_type / pins)")


@pytest.mark.parametrize("options, message", [
    ("sensor_type: hx999\nsclk_pin: A\ndout_pin: B",
     "[load_cell] sensor_type = hx999: must be one of: hx711, hx717, ads1220"),
    ("sensor_type: hx717\nsclk_pin: A\ndout_pin: B\ncounts_per_gram: 0.5",
     "[load_cell] counts_per_gram = 0.5: must be at least 1 (allowed: 1 to 8388607)"),
    ("sensor_type: hx717\nsclk_pin: A\ndout_pin: B\nsample_rate: 100",
     "[load_cell] sample_rate = 100: must be one of: 10, 20, 80, 320"),
    ("sensor_type: hx711\nsclk_pin: A\ndout_pin: B\ngain: B-64",
     "[load_cell] gain = B-64: must be one of: A-128, B-32, A-64"),
    ("sensor_type: hx717\nsclk_pin: A",
     "[load_cell] dout_pin: must be specified"),
    ("sensor_type: hx717\nsclk_pin: A\ndout_pin: B\nsensor_orientation: upside",
     "[load_cell] sensor_orientation = upside: must be one of: normal, inverted"),
    ("sensor_type: hx717\nsclk_pin: A\ndout_pin: B\nreference_tare_counts: 12.5",
     "[load_cell] reference_tare_counts = 12.5: "),
    ("sensor_type: ads1220\ncs_pin: A\ndata_ready_pin: B\nvref: REF1",
     "[load_cell] vref = REF1: not allowed with these settings; allowed: internal, REF0, analog_supply with "
     "input_mux AIN0_AIN1"),
    ("sensor_type: ads1220\ncs_pin: A\ndata_ready_pin: B\nsample_rate: 20\nspi_speed: 512000",
     "[load_cell] spi_speed = 512000: 512000 needs a turbo sample_rate; with sample_rate 20 use 256000"),
    ("sensor_type: ads1220\ncs_pin: A\ndata_ready_pin: B\nspi_software_sclk_pin: C",
     "[load_cell] spi_software_mosi_pin: software SPI needs all of spi_software_sclk_pin, "
     "spi_software_mosi_pin and spi_software_miso_pin"),
    ("sensor_type: ads1220\ncs_pin: A\ndata_ready_pin: B\ngain: 3",
     "[load_cell] gain = 3: must be one of: 1, 2, 4, 8, 16, 32, 64, 128"),
])
def test_option_errors_name_file_section_option_value(tmp_path, options, message):
    with pytest.raises(ConfigError) as info:
        start(tmp_path, SIM_240 + "[load_cell]\n" + options + "\n")
    text = str(info.value)
    assert text.startswith(f"{tmp_path / 'printer.cfg'}: {message}"), text


def test_ads1220_options_are_read(tmp_path):
    config = SIM_240 + textwrap.dedent("""
        [load_cell]
        sensor_type: ads1220
        cs_pin: PA1
        data_ready_pin: PA2
        gain: 4
        input_mux: AIN1_AVSS
        sample_rate: 330
        spi_bus: spi1
        """)
    printer, _ = start(tmp_path, config)
    options = printer.lookup_object("load_cell").options
    assert (options.gain, options.sample_rate_sps, options.spi_speed_hz, options.spi_bus) == ("4", 330.0, 256000, "spi1")
    assert options.pga_bypass is True  # forced by the AVSS input
    assert len(options.ads1220_registers) == 4


def test_malformed_gcode_lines(tmp_path):
    printer, responses = start(tmp_path, SIM_240 + CELL)
    gcode = printer.gcode
    assert gcode.run_script_reporting_errors("LOAD_CELL_READ ; a comment is fine") is True
    for line, message in [
        ("LOAD_CELL_REED", '!! Unknown command:"LOAD_CELL_REED"'),
        ("LOAD_CELL_CALIBRATE\nCALIBRATE GRAMS=", "!! Error on 'CALIBRATE GRAMS=': unable to parse '' for GRAMS "
                                                   "(expected a number)"),
        ("SIM_PLACE_WEIGHT GRAMS=-5", "!! Error on 'SIM_PLACE_WEIGHT GRAMS=-5': GRAMS must be above 0 (allowed: above 0 and at most 100000)"),
        ("SIM_FAULT NAME=gremlin", "!! Error on 'SIM_FAULT NAME=gremlin': NAME must be one of disconnected, stuck, "
                                   "chip_reset, corrupt_frame, saturation, weight, bowden_tug, mcu_reset, not 'gremlin'"),
    ]:
        responses.clear()
        assert gcode.run_script_reporting_errors(line) is False
        assert responses[-1] == message


def test_sim_place_weight_replaces_the_weight_and_add_puts_one_on_top(tmp_path):
    """Calibrating with 500 g and then again with 1000 g finds the true 240 counts/g both times
    (the second weight replaced the first: a 1500 g total read 1.5 x too many counts per gram)."""
    printer, responses = start(tmp_path, SIM_240 + CELL)
    counts_per_gram = r"// Calibration value: .*, Counts/gram: (\d+\.\d+), .*"
    lines = run(printer, responses, "LOAD_CELL_CALIBRATE\nTARE\nSIM_PLACE_WEIGHT GRAMS=500\nCALIBRATE GRAMS=500\n"
                                    "SIM_PLACE_WEIGHT GRAMS=1000\nCALIBRATE GRAMS=1000")
    found = [float(m[1]) for m in (re.fullmatch(counts_per_gram, line) for line in lines) if m]
    assert "// A 1000 g weight now rests on the load cell" in lines
    assert found == [pytest.approx(240.0, rel=0.003)] * 2
    lines = run(printer, responses, "SIM_PLACE_WEIGHT GRAMS=400\nSIM_PLACE_WEIGHT GRAMS=600 ADD=1\n"
                                    "CALIBRATE GRAMS=1000")
    assert lines[:2] == ["// A 400 g weight now rests on the load cell",
                         "// 600 g more on the load cell: 1000 g rest on it now"]
    assert float(re.fullmatch(counts_per_gram, lines[2])[1]) == pytest.approx(240.0, rel=0.003)
    with pytest.raises(GCodeError, match="ADD must have maximum of 1"):
        run(printer, responses, "SIM_PLACE_WEIGHT GRAMS=10 ADD=2")
