"""tapcell.host.gcode: parsing, typed parameters, responses, the dispatcher; [gcode_macro]."""

from __future__ import annotations

import sys
import types

import pytest

from tapcell.extras import gcode_macro
from tapcell.host import gcode as gcode_module
from tapcell.host import printer as printer_module
from tapcell.host.gcode import GCodeCommand, GCodeDispatch, GCodeError, parse_line
from tapcell.host.printer import Printer


def gcode_error(func, *args) -> str:
    with pytest.raises(GCodeError) as info:
        func(*args)
    return str(info.value)


# -- parsing ---------------------------------------------------------------------


@pytest.mark.parametrize("line, command, params", [
    ("G1 Z5 F300", "G1", {"Z": "5", "F": "300"}),
    ("g1 x-1.5 y2", "G1", {"X": "-1.5", "Y": "2"}),
    ("G1Z5F300", "G1", {"Z": "5", "F": "300"}),
    ("G01 X1", "G1", {"X": "1"}),
    ("M104 S140 ; heat the nozzle", "M104", {"S": "140"}),
    ("N123 G28 X*71", "G28", {"X": ""}),
    ("  G90  ", "G90", {}),
    ("LOAD_CELL_CALIBRATE", "LOAD_CELL_CALIBRATE", {}),
    ("calibrate grams=500", "CALIBRATE", {"GRAMS": "500"}),
    ("load_cell_read Load_Cell=My_Cell", "LOAD_CELL_READ", {"LOAD_CELL": "My_Cell"}),
    ('RESPOND MSG="two words; not a comment" TYPE=echo', "RESPOND", {"MSG": "two words; not a comment",
                                                                     "TYPE": "echo"}),
    ("SET X='single quoted' Y=", "SET", {"X": "single quoted", "Y": ""}),
    ("A1_THING KEY=v", "A1_THING", {"KEY": "v"}),
    ("SET EXPR=a=b", "SET", {"EXPR": "a=b"}),
])
def test_parse_line(line, command, params):
    parsed = parse_line(line)
    assert (parsed.command, parsed.params) == (command, params)


def test_parse_keeps_commandline_and_rawparams():
    parsed = parse_line("N7 CALIBRATE  GRAMS=500 ; comment*12")
    assert parsed.commandline == "CALIBRATE  GRAMS=500"
    assert parsed.rawparams == "GRAMS=500"


@pytest.mark.parametrize("line", ["", "   ", "; only a comment", "N10", "N10 ;x"])
def test_blank_lines_parse_to_nothing(line):
    assert parse_line(line) is None


@pytest.mark.parametrize("line, message", [
    ("LOAD_CELL_READ FOO", "Malformed command 'LOAD_CELL_READ FOO': expected NAME=VALUE, got 'FOO'"),
    ('RESPOND MSG="open', "Malformed command 'RESPOND MSG=\"open': a quoted value is not closed"),
    ("G1 X10 @", "Malformed command 'G1 X10 @': expected a letter and a number, got '@'"),
    ("CMD =5", "Malformed command 'CMD =5': expected NAME=VALUE, got '=5'"),
])
def test_malformed_lines(line, message):
    assert gcode_error(parse_line, line) == message


# -- dispatcher and typed parameters -------------------------------------------


@pytest.fixture
def dispatch():
    responses: list[str] = []
    gcode = GCodeDispatch(responses)
    gcode.responses = responses
    return gcode


def capture(dispatch, name="CMD", desc=None):
    calls = []
    dispatch.register_command(name, calls.append, desc=desc)
    return calls


def test_commands_are_case_insensitive_and_get_parameters(dispatch):
    calls = capture(dispatch, "Probe_Me")
    dispatch.run_script("probe_me speed=2.5 SAMPLES=3 name=Left\nPROBE_ME")
    first, second = calls
    assert first.command == "PROBE_ME"
    assert first.get_float("speed", above=0, maxval=10) == 2.5
    assert first.get_int("samples", 1, minval=1, maxval=10) == 3
    assert first.get("NAME") == "Left"
    assert first.get_command_parameters() == {"SPEED": "2.5", "SAMPLES": "3", "NAME": "Left"}
    assert second.get_float("SPEED", 5.0, above=0, maxval=10) == 5.0
    assert second.get_int("SAMPLES", None, minval=1, maxval=10) is None


@pytest.mark.parametrize("line, call, message", [
    ("CALIBRATE", lambda g: g.get_float("GRAMS", minval=50, maxval=25000), "Error on 'CALIBRATE': missing GRAMS"),
    ("CALIBRATE GRAMS=abc", lambda g: g.get_float("GRAMS", minval=50, maxval=25000),
     "Error on 'CALIBRATE GRAMS=abc': unable to parse 'abc' for GRAMS (expected a number)"),
    ("CALIBRATE GRAMS=nan", lambda g: g.get_float("GRAMS", minval=50, maxval=25000),
     "Error on 'CALIBRATE GRAMS=nan': unable to parse 'nan' for GRAMS (expected a number)"),
    ("CALIBRATE GRAMS=1e309", lambda g: g.get_float("GRAMS", minval=50, maxval=25000),
     "Error on 'CALIBRATE GRAMS=1e309': unable to parse '1e309' for GRAMS (expected a number)"),
    ("CALIBRATE GRAMS=10", lambda g: g.get_float("GRAMS", minval=50, maxval=25000),
     "Error on 'CALIBRATE GRAMS=10': GRAMS must have minimum of 50 (allowed: 50 to 25000)"),
    ("CALIBRATE GRAMS=30000", lambda g: g.get_float("GRAMS", minval=50, maxval=25000),
     "Error on 'CALIBRATE GRAMS=30000': GRAMS must have maximum of 25000 (allowed: 50 to 25000)"),
    ("CALIBRATE GRAMS=0", lambda g: g.get_float("GRAMS", above=0, maxval=5),
     "Error on 'CALIBRATE GRAMS=0': GRAMS must be above 0 (allowed: above 0 and at most 5)"),
    ("CALIBRATE GRAMS=2.5", lambda g: g.get_float("GRAMS", minval=0, below=2.5),
     "Error on 'CALIBRATE GRAMS=2.5': GRAMS must be below 2.5 (allowed: at least 0 and below 2.5)"),
    ("CALIBRATE taps=1.5", lambda g: g.get_int("TAPS", 3, minval=1, maxval=10),
     "Error on 'CALIBRATE taps=1.5': unable to parse '1.5' for TAPS (expected an integer)"),
    ("CALIBRATE TAPS=11", lambda g: g.get_int("taps", 3, minval=1, maxval=10),
     "Error on 'CALIBRATE TAPS=11': TAPS must have maximum of 10 (allowed: 1 to 10)"),
    ("CALIBRATE TAPS=" + "9" * 5000, lambda g: g.get_int("taps", 3, minval=1, maxval=10),
     f"Error on 'CALIBRATE TAPS={'9' * 5000}': unable to parse '{'9' * 5000}' for TAPS (expected an integer)"),
    ("CALIBRATE AT=1,2", lambda g: g.get_floatlist("AT", count=3, minval=0, maxval=10),
     "Error on 'CALIBRATE AT=1,2': AT needs exactly 3 comma-separated numbers, got 2"),
    ("CALIBRATE AT=1,x", lambda g: g.get_floatlist("AT", minval=0, maxval=10),
     "Error on 'CALIBRATE AT=1,x': unable to parse 'x' in AT (expected comma-separated numbers)"),
    ("CALIBRATE COUNT=3,100000", lambda g: g.get_intlist("COUNT", minval=3, maxval=50),
     "Error on 'CALIBRATE COUNT=3,100000': COUNT must have maximum of 50 (allowed: 3 to 50)"),
])
def test_parameter_errors_name_the_parameter(dispatch, line, call, message):
    dispatch.register_command("CALIBRATE", call)
    assert gcode_error(dispatch.run_script, line) == message


def test_responses_are_prefixed_per_line(dispatch):
    def talk(gcmd):
        gcmd.respond_info("first\nsecond")
        gcmd.respond_raw("raw text")
    dispatch.register_command("TALK", talk)
    dispatch.run_script("TALK")
    dispatch.respond_error("bad\nworse")
    assert dispatch.responses == ["// first", "// second", "raw text", "!! bad", "!! worse"]


def test_callable_sink_receives_lines_as_they_come():
    seen = []
    gcode = GCodeDispatch(seen.append)
    gcode.respond_info("hello")
    gcode.set_response_sink(None)
    gcode.respond_info("dropped")
    assert seen == ["// hello"]


def test_unknown_command_and_script_stops_at_first_error(dispatch):
    calls = capture(dispatch)
    assert gcode_error(dispatch.run_script, "CMD\nFOO BAR=1\nCMD") == 'Unknown command:"FOO"'
    assert len(calls) == 1
    assert dispatch.run_script_reporting_errors("CMD\nG1 X1") is False
    assert dispatch.responses == ['!! Unknown command:"G1"']


def test_handler_bug_is_not_masked_as_a_message(dispatch):
    dispatch.register_command("BROKEN", lambda gcmd: 1 / 0)
    with pytest.raises(ZeroDivisionError):
        dispatch.run_script("BROKEN X=1")
    # The dispatcher is still usable afterwards (nothing is left marked as running).
    calls = capture(dispatch, "BROKEN2")
    dispatch.run_script("BROKEN2")
    assert len(calls) == 1


def test_numeric_parameter_without_a_range_is_a_programming_error(dispatch):
    dispatch.register_command("CMD", lambda gcmd: gcmd.get_float("X", 1.0, minval=0))
    with pytest.raises(TypeError, match="CMD X: a numeric option or parameter must declare its range"):
        dispatch.run_script("CMD")


def test_commands_calling_themselves_or_nesting_too_deep_are_refused(dispatch):
    dispatch.register_command("A", lambda gcmd: dispatch.run_script("B"))
    dispatch.register_command("B", lambda gcmd: dispatch.run_script("A"))
    assert gcode_error(dispatch.run_script, "A") == "A called recursively (A -> B -> A)"
    depth = gcode_module.MAX_NESTING
    for level in range(depth + 5):
        dispatch.register_command(f"NEST{level}", lambda gcmd, level=level: dispatch.run_script(f"NEST{level + 1}"))
    message = gcode_error(dispatch.run_script, "NEST0")
    assert message == f"NEST{depth}: G-code nested more than {depth} commands deep (NEST0 -> NEST1 -> NEST2 -> ...)"


def test_register_twice_and_temporary_commands(dispatch):
    capture(dispatch, "TARE")
    assert gcode_error(dispatch.register_command, "tare", print) == "Command 'TARE' is already registered"
    assert dispatch.is_registered("tare")
    dispatch.unregister_command("TARE")
    assert not dispatch.is_registered("TARE")
    assert gcode_error(dispatch.run_script, "TARE") == 'Unknown command:"TARE"'
    calls = capture(dispatch, "TARE")
    dispatch.run_script("TARE")
    assert len(calls) == 1


def test_help_lists_commands_with_help_text(dispatch):
    capture(dispatch, "ZED", desc="Last one")
    capture(dispatch, "ALPHA", desc="First one")
    capture(dispatch, "HIDDEN")
    dispatch.run_script("HELP")
    assert dispatch.responses == ["// Available commands:", "// ALPHA: First one",
                                  "// HELP: List the available commands with their help text", "// ZED: Last one"]


def test_mux_commands_select_by_key_with_a_default(dispatch):
    seen = []
    dispatch.register_mux_command("LOAD_CELL_READ", "LOAD_CELL", None, lambda g: seen.append("default"),
                                  desc="Read a load cell")
    dispatch.register_mux_command("LOAD_CELL_READ", "LOAD_CELL", "left", lambda g: seen.append("left"))
    dispatch.register_mux_command("load_cell_read", "load_cell", "right", lambda g: seen.append("right"))
    dispatch.run_script("LOAD_CELL_READ\nLOAD_CELL_READ LOAD_CELL=left\nload_cell_read load_cell=right")
    assert seen == ["default", "left", "right"]
    assert dispatch.get_command_help()["LOAD_CELL_READ"] == "Read a load cell"
    assert gcode_error(dispatch.run_script, "LOAD_CELL_READ LOAD_CELL=middle") == (
        "Error on 'LOAD_CELL_READ LOAD_CELL=middle': the value 'middle' is not valid for LOAD_CELL "
        "(one of: left, right)")
    assert gcode_error(dispatch.register_mux_command, "LOAD_CELL_READ", "LOAD_CELL", "left", print) == (
        "Command 'LOAD_CELL_READ' LOAD_CELL=left is already registered")
    assert gcode_error(dispatch.register_mux_command, "LOAD_CELL_READ", "LOAD_CELL", None, print) == (
        "Command 'LOAD_CELL_READ' without LOAD_CELL= is already registered")
    assert gcode_error(dispatch.register_mux_command, "LOAD_CELL_READ", "SENSOR", "x", print) == (
        "Command 'LOAD_CELL_READ' is already selected by LOAD_CELL=, not SENSOR=")


def test_mux_without_default_requires_the_key(dispatch):
    dispatch.register_mux_command("LOAD_CELL_TARE", "LOAD_CELL", "a", print)
    dispatch.register_mux_command("LOAD_CELL_TARE", "LOAD_CELL", "b", print)
    assert gcode_error(dispatch.run_script, "LOAD_CELL_TARE") == (
        "Error on 'LOAD_CELL_TARE': missing LOAD_CELL (one of: a, b)")


def test_clear_commands_keeps_only_help(dispatch):
    capture(dispatch, "CMD")
    dispatch.register_mux_command("MUX", "K", None, print)
    dispatch.clear_commands()
    assert not dispatch.is_registered("CMD") and not dispatch.is_registered("MUX")
    assert dispatch.is_registered("HELP")


# -- [gcode_macro] (through a printer with a fake load cell module) -------------


class FakeLoadCell:
    def __init__(self, force_g):
        self.force_g = force_g

    def get_status(self, eventtime):
        return {"force_g": self.force_g, "is_calibrated": True}


@pytest.fixture
def fake_load_cell_module(monkeypatch):
    module = types.ModuleType("tapcell_test_fake_load_cell")
    module.load_config = lambda section, printer: FakeLoadCell(section.getfloat("force_g", minval=-1e4, maxval=1e4))
    module.load_config_prefix = module.load_config
    package = types.ModuleType("tapcell_test_extras")
    package.__path__ = []
    monkeypatch.setitem(sys.modules, package.__name__, package)
    monkeypatch.setitem(sys.modules, f"{package.__name__}.load_cell", module)
    monkeypatch.setitem(sys.modules, f"{package.__name__}.gcode_macro", gcode_macro)
    monkeypatch.setattr(printer_module, "EXTRAS_PACKAGE", package.__name__)
    return module


def make_printer(tmp_path, text):
    path = tmp_path / "printer.cfg"
    path.write_text(text)
    responses: list[str] = []
    printer = Printer.from_config(str(path), backend=object(), responses=responses)
    responses.clear()  # start-up messages are not what these tests look at
    return printer, responses


MACROS = """\
[load_cell]
force_g: 12.34
[load_cell probe]
force_g: -3
[gcode_macro SHOW_FORCE]
description: Print the force
variable_limit_g: 500
variable_names: ['a', 'b']
gcode:
  {% set grams = printer.load_cell.force_g %}
  {action_respond_info("force: %.1fg of %d, probe %.1fg" % (grams, limit_g, printer["load_cell probe"].force_g))}
  ECHO WHAT={params.WHAT|default("nothing")} RAW="{rawparams}" N={names|length}
[gcode_macro echo]
gcode:
  {action_respond_info(params.WHAT ~ " " ~ params.RAW ~ " " ~ params.N)}
[gcode_macro FAIL_IF]
gcode:
  {% if params.LIMIT|float < printer.load_cell.force_g %}
    {action_raise_error("too much force: %.2f" % printer.load_cell.force_g)}
  {% endif %}
  ECHO WHAT=ok RAW=- N=0
[gcode_macro LOOP]
gcode: LOOP
[gcode_macro TYPO]
gcode: {printer.load_cell.forceg}
[gcode_macro SHOW_VAR]
gcode: {action_respond_info("limit=%s" % printer["gcode_macro SHOW_FORCE"].limit_g)}
"""


def test_macro_reads_status_params_and_variables(tmp_path, fake_load_cell_module):
    printer, responses = make_printer(tmp_path, MACROS)
    printer.gcode.run_script("show_force what=hi")
    assert responses == ["// force: 12.3g of 500, probe -3.0g", "// hi what=hi 2"]
    responses.clear()
    printer.gcode.run_script("HELP")
    assert "// SHOW_FORCE: Print the force" in responses
    assert "// ECHO: G-Code macro" in responses


def test_macro_errors(tmp_path, fake_load_cell_module):
    printer, responses = make_printer(tmp_path, MACROS)
    assert gcode_error(printer.gcode.run_script, "FAIL_IF LIMIT=5") == "too much force: 12.34"
    printer.gcode.run_script("FAIL_IF LIMIT=50")
    assert responses == ["// ok - 0"]
    assert gcode_error(printer.gcode.run_script, "LOOP") == "LOOP called recursively (LOOP -> LOOP)"
    assert gcode_error(printer.gcode.run_script, "TYPO") == (
        "Error in macro TYPO: 'dict object' has no attribute 'forceg'")


def test_set_gcode_variable(tmp_path, fake_load_cell_module):
    printer, responses = make_printer(tmp_path, MACROS)
    printer.gcode.run_script("SET_GCODE_VARIABLE MACRO=SHOW_FORCE VARIABLE=limit_g VALUE=750\nSHOW_VAR")
    assert responses == ["// limit=750"]
    assert printer.get_status()["gcode_macro SHOW_FORCE"] == {"limit_g": 750, "names": ["a", "b"]}
    assert gcode_error(printer.gcode.run_script, "SET_GCODE_VARIABLE MACRO=SHOW_FORCE VARIABLE=nope VALUE=1") == (
        "Error on 'SET_GCODE_VARIABLE MACRO=SHOW_FORCE VARIABLE=nope VALUE=1': unknown VARIABLE 'nope' "
        "(variables of SHOW_FORCE: limit_g, names)")
    assert gcode_error(printer.gcode.run_script, "SET_GCODE_VARIABLE MACRO=SHOW_FORCE VARIABLE=limit_g VALUE=x(") == (
        "Error on 'SET_GCODE_VARIABLE MACRO=SHOW_FORCE VARIABLE=limit_g VALUE=x(': unable to parse 'x(' for VALUE "
        "(expected a Python literal)")


@pytest.mark.parametrize("section, problem", [
    ("[gcode_macro X]\ngcode: {% if %}\n", "gcode = {% if %}: template error on line 1 of the template: "),
    ("[gcode_macro X]\ngcode: G28\nvariable_speed: fast\n",
     "variable_speed = fast: must be a Python literal: a number, 'quoted text', a list, a dict, True, False or None"),
    ("[gcode_macro X]\n", "gcode: must be specified (a value)"),
])
def test_macro_config_errors(tmp_path, section, problem):
    path = tmp_path / "printer.cfg"
    path.write_text(section)
    with pytest.raises(Exception) as info:
        Printer.from_config(str(path), backend=object())
    assert str(info.value).startswith(f"{path}: [gcode_macro X] {problem}")


def test_parameter_helpers_name_the_parameter_and_what_is_allowed():
    gcmd = GCodeCommand(GCodeDispatch(), parse_line("CMD MODE=Fast AT=1,2.5 BAD=1,x THREE=1,2 INF=1,inf"))
    at_range = {"minval": 0, "maxval": 10}
    assert gcmd.get_choice("MODE", ("slow", "fast")) == "fast"
    assert gcmd.get_choice("OTHER", ("slow", "fast"), None) is None
    assert gcmd.get_floatlist("AT", **at_range) == [1.0, 2.5]
    assert gcmd.get_floatlist("NONE_GIVEN", None, count=2, **at_range) is None
    for call, message in [
        (lambda: gcmd.get_choice("MODE", ("slow", "medium")), "MODE must be one of slow, medium, not 'Fast'"),
        (lambda: gcmd.get_choice("OTHER", ("slow",)), "missing OTHER"),
        (lambda: gcmd.get_floatlist("BAD", **at_range), "unable to parse 'x' in BAD (expected comma-separated numbers)"),
        (lambda: gcmd.get_floatlist("THREE", count=3, **at_range), "THREE needs exactly 3 comma-separated numbers, got 2"),
        (lambda: gcmd.get_floatlist("INF", **at_range), "unable to parse 'inf' in INF (expected comma-separated numbers)"),
        (lambda: gcmd.get_floatlist("AT", minval=2, maxval=10), "AT must have minimum of 2 (allowed: 2 to 10)"),
        (lambda: gcmd.get_floatlist("OTHER", **at_range), "missing OTHER"),
    ]:
        with pytest.raises(GCodeError) as info:
            call()
        assert str(info.value) == f"Error on '{gcmd.commandline}': {message}"
