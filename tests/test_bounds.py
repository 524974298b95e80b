"""Issue 10, findings 8 and 9: unbounded numbers, includes and recursion are refused at once,
with a message that names the parameter (or option) and its allowed range; none reaches a hang,
a Python traceback or an "Internal error". (The tap-file cases of finding 9 are in
tests/tap/test_tap_readers.py.)"""

from __future__ import annotations

import time

import pytest
from probe.probe_vprinter import make_printer, printer_text

from tapcell.host.config import ConfigError
from tapcell.host.gcode import GCodeError
from tapcell.host.printer import Printer

# A refusal is a range check, not work: well under the one second the issue allows.
REFUSAL_S = 1.0


@pytest.fixture(scope="module")
def printer(tmp_path_factory):
    printer, _ = make_printer(tmp_path_factory.mktemp("bounds"))
    return printer


def refusal(printer, line: str) -> str:
    start = time.perf_counter()
    with pytest.raises(GCodeError) as caught:
        printer.gcode.run_script(line)
    assert time.perf_counter() - start < REFUSAL_S
    return str(caught.value)


@pytest.mark.parametrize("line, problem", [
    ("PROBE PROBE_SPEED=1e-6", "PROBE_SPEED must have minimum of 0.5 (allowed: 0.5 to 100)"),
    ("PROBE_ACCURACY SAMPLES=1000000", "SAMPLES must have maximum of 100 (allowed: 1 to 100)"),
    ("BED_MESH_CALIBRATE PROBE_COUNT=100000,100000", "PROBE_COUNT must have maximum of 50 (allowed: 3 to 50)"),
    ("NOZZLE_CLEANUP PATTERN_X=1e8", "unable to parse '1e8' for PATTERN_X (expected an integer)"),
    ("NOZZLE_CLEANUP PATTERN_X=100000000", "PATTERN_X must have maximum of 20 (allowed: 1 to 20)"),
    ("SIM_FAULT NAME=corrupt_frame COUNT=1e12", "unable to parse '1e12' for COUNT (expected an integer)"),
    ("SIM_FAULT NAME=corrupt_frame COUNT=1000000000000", "COUNT must have maximum of 1000 (allowed: 1 to 1000)"),
    ("SIM_FAULT NAME=corrupt_frame SPACING_S=0", "SPACING_S must have minimum of 0.001 (allowed: 0.001 to 60)"),
    # Finding 9: these overflowed inside the simulator.
    ("SIM_FAULT NAME=chip_reset OFFSET_JUMP_COUNTS=1e308",
     "OFFSET_JUMP_COUNTS must have maximum of 16777216 (allowed: -16777216 to 16777216)"),
    ("G1 X99999999999", "X must have maximum of 10000 (allowed: -10000 to 10000)"),
    ("G1 X10 F0.001", "F must have minimum of 6 (allowed: 6 to 600000)"),
    ("BED_MESH_CALIBRATE MESH_MIN=1e308,0", "MESH_MIN must have maximum of 10000 (allowed: -10000 to 10000)"),
    ("BED_MESH_CALIBRATE MESH_MAX=10,1e999", "unable to parse '1e999' in MESH_MAX (expected comma-separated numbers)"),
])
def test_unbounded_parameters_are_refused_at_once(printer, line, problem):
    assert refusal(printer, line) == f"Error on '{line}': {problem}"


def test_the_printer_still_works_after_the_refusals(printer):
    printer.gcode.run_script("PROBE")
    assert printer.lookup_object("probe").last_result.valid


def test_an_mcu_reset_is_a_gcode_error_not_a_traceback(tmp_path):
    printer, _ = make_printer(tmp_path, calibrate=False, home=False)
    printer.gcode.run_script("SIM_FAULT NAME=mcu_reset")
    assert refusal(printer, "STATUS").startswith("MCU error on 'STATUS': the MCU reset at ")
    printer.gcode.run_script("STATUS")  # the link is back


MACROS = """
[gcode_macro LOOP]
gcode: LOOP
[gcode_macro PING]
gcode: PONG
[gcode_macro PONG]
gcode: PING
[gcode_macro SCRUB]
gcode: PROBE
"""


def test_macro_recursion_is_refused(tmp_path):
    printer, _ = make_printer(tmp_path, sections=MACROS, calibrate=False, home=False)
    assert refusal(printer, "LOOP") == "LOOP called recursively (LOOP -> LOOP)"
    assert refusal(printer, "PING") == "PING called recursively (PING -> PONG -> PING)"


def test_a_probe_template_that_probes_is_refused(tmp_path):
    # Once homed, every probing session starts with activate_gcode, which probes...
    template = """activate_gcode:
  {% if printer.toolhead.homed_axes == "xyz" %}PROBE{% endif %}"""
    printer, _ = make_printer(tmp_path, probe_options=template)
    printer.backend.truth.take_peak_force_g()
    assert refusal(printer, "PROBE") == "PROBE called recursively (PROBE -> [load_cell_probe] activate_gcode -> PROBE)"
    assert printer.backend.truth.take_peak_force_g() == 0.0  # refused before any probing move


def test_a_nozzle_scrubber_that_probes_is_refused(tmp_path):
    # The oozy nozzle's first taps are bad, so the scrubber runs after the first one.
    printer, _ = make_printer(tmp_path, scenario="oozy", sections=MACROS,
                              probe_options="nozzle_scrubber_gcode: SCRUB\nscrubbing_frequency: 1")
    printer.gcode.run_script("M109 S150\nG1 Z0.4")
    message = refusal(printer, "PROBE")
    assert message == "PROBE called recursively (PROBE -> [load_cell_probe] nozzle_scrubber_gcode -> SCRUB -> PROBE)"


@pytest.mark.parametrize("virtual_printer, problem", [
    ("bed_x_mm: 1e308", "[virtual_printer] bed_x_mm = 1e308: must be at most 10000 (allowed: 10 to 10000)"),
    ("counts_per_gram: 1e308", "[virtual_printer] counts_per_gram = 1e308: must be at most 100000 "
                               "(allowed: 0.01 to 100000)"),
    ("bed_x_mm: inf", "[virtual_printer] bed_x_mm = inf: must be a finite number"),
    ("seed: " + "9" * 5000, "[virtual_printer] seed = " + "9" * 5000 + ": expected an integer, 0 to 4294967295"),
])
def test_huge_config_numbers_are_range_errors(tmp_path, virtual_printer, problem):
    path = tmp_path / "printer.cfg"
    path.write_text(printer_text(virtual_printer=virtual_printer))
    with pytest.raises(ConfigError) as caught:
        Printer.from_config(str(path))
    assert str(caught.value) == f"{path}: {problem}"


def test_an_include_chain_hundreds_deep_names_the_file(tmp_path):
    for level in range(300):
        (tmp_path / f"inc{level}.cfg").write_text(f"[include inc{level + 1}.cfg]\n")
    path = tmp_path / "printer.cfg"
    path.write_text("[include inc0.cfg]\n" + printer_text())
    start = time.perf_counter()
    with pytest.raises(ConfigError) as caught:
        Printer.from_config(str(path))
    assert time.perf_counter() - start < REFUSAL_S
    assert str(caught.value) == (f"{tmp_path}/inc20.cfg: includes are nested more than 20 deep "
                                 f"(included from {tmp_path}/inc19.cfg)")
