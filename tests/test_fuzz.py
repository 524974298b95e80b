"""Issue 10: hostile input never reaches a traceback, a hang or an "Internal error".

Seeded random mutations of tap files (JSON, JSONL, CSV), config files (values, lines,
sections, includes) and G-code lines (every registered command, its parameters with random
values) on the virtual printer. Each case either works or raises the documented user error
(TapFileError, ConfigError, GCodeError) whose message says what is wrong; any other exception,
or a case that takes more than a few seconds, fails the test and names the case.
"""

from __future__ import annotations

import copy
import json
import os
import random
import re
import signal
import socket
import time
from contextlib import contextmanager
from pathlib import Path

import pytest
from probe.probe_vprinter import make_printer, printer_text

from tapcell.extras.load_cell_probe.options import ANALYSIS_OPTION_SPECS, TAP_OPTION_SPECS
from tapcell.extras.probe.options import PROBE_OPTION_SPECS
from tapcell.host.config import ConfigError, ConfigSection, describe_range
from tapcell.host.gcode import GCodeCommand, GCodeError
from tapcell.host.printer import Printer
from tapcell.sim.params import PARAM_FIELDS
from tapcell.tap import TapFileError, analyze_tap, read_tap_file, tap_to_json_dict
from tapcell.tap.synth import synth_tap

CASES = 150  # tap files and config files each; they take milliseconds
GCODE_CASES = 100  # a G-code line may probe (0.1-0.2 s per tap)
MONITOR_CASES = 60  # each analyses up to two taps (0.1 s each)
CASE_LIMIT_S = 20  # a case that runs longer is a hang (a refusal takes milliseconds, a mesh seconds)


@contextmanager
def time_limit(what: str):
    def expire(signum, frame):
        raise TimeoutError(f"{what}: still running after {CASE_LIMIT_S} s")

    previous = signal.signal(signal.SIGALRM, expire)
    signal.alarm(CASE_LIMIT_S)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)


# Values a hostile user might type: junk, the edges of every float, huge integers, lists.
WORDS = ["", "abc", "nan", "inf", "-inf", "1e308", "-1e308", "1e-300", "1e999", "99999999999", "9" * 40,
         "-5", "0", "-0", "1", "2", "3", "5", "10.5", "2e3", "1e12", "3,3", "1,2,3", "NONE", "yes", "{", "[x]",
         "0x10", "1_000", "\u00e9", "'quoted'",
         # valid words for the parameters that choose (NAME=, DIRECTION=, ...), so the numbers after them are read
         "corrupt_frame", "chip_reset", "weight", "stuck", "mcu_reset", "contact", "+X", "-Y", "Z", "CONTACT_ONSET",
         "PULLBACK_DISTANCE", "DECOMPRESSION_ANGLE", "default", "PARK", "height", "circle", "fail", "median"]
JSON_VALUES = [None, True, False, "x", "", [], {}, [[1.0]], 10 ** 30, -1, 0, 1e308, float("nan"), float("inf"),
               [1.0, 2.0], {"a": 1}, "1.5", [None] * 20, -1e-300]


def json_value(rng: random.Random) -> object:
    return copy.deepcopy(rng.choice(JSON_VALUES))  # a fresh list or dict: never shared between documents


def failure(kind: str, case: str, exc: BaseException) -> str:
    return f"{kind} case {case!r}: {type(exc).__name__}: {exc}"


# -- tap files ------------------------------------------------------------------------------


def mutate_document(rng: random.Random, document: dict) -> object:
    doc = copy.deepcopy(document)
    targets = [doc, *doc.get("moves", [])[:3], doc.get("probe", {}), doc.get("meta", {}), doc.get("events", {})]
    for _ in range(rng.randint(1, 3)):
        target = rng.choice([t for t in targets if isinstance(t, dict)] or [doc])
        keys = list(target) or ["time"]
        key = rng.choice(keys)
        action = rng.randrange(6)
        if action == 0:
            target.pop(key, None)
        elif action == 1:
            target[key] = json_value(rng)
        elif action == 2 and isinstance(target.get(key), list) and target[key]:
            target[key][rng.randrange(len(target[key]))] = json_value(rng)
        elif action == 3 and isinstance(target.get(key), list):
            del target[key][rng.randrange(len(target[key]) + 1):]
        elif action == 4 and isinstance(target.get(key), list):
            target[key] = list(reversed(target[key]))
        else:
            target[rng.choice(["x", "z_r", "sample_rate", "trigger_force", "mains_hz", "format"])] = \
                json_value(rng)
    wrap = rng.randrange(8)
    if wrap == 0:
        return [doc]
    if wrap == 1:
        return {"tap": doc}
    return doc


def mutate_text(rng: random.Random, text: str) -> str:
    action = rng.randrange(5)
    if action == 0:
        return text[:rng.randrange(len(text) + 1)]
    if action == 1:
        at = rng.randrange(len(text) + 1)
        return text[:at] + rng.choice(["\x00", "}", "]", ",", "\n", "\"", "1e999", "-", "[" * 5000]) + text[at:]
    if action == 2:
        lines = text.splitlines()
        rng.shuffle(lines)
        return "\n".join(lines)
    if action == 3:
        return text * rng.randint(2, 3)
    return text


def tap_case(rng: random.Random, tmp_path: Path, index: int, document: dict) -> tuple[Path, str]:
    kind = rng.choice(["json", "jsonl", "csv"])
    if kind == "csv":
        tap = synth_tap(seed=1)
        rows = [rng.choice(["time,force,z", "time,force", "Time, Force, Z, extra", ""])]
        rows += [f"{t!r},{f!r},{z!r}" for t, f, z in zip(tap.time_s, tap.force_g, tap.z_mm)]
        for _ in range(rng.randint(0, 3)):
            row = rng.randrange(len(rows))
            rows[row] = rng.choice([",".join(rng.choice(WORDS) for _ in range(3)), "", "1,2", rows[row] * 2])
        text = "\n".join(rows)
    else:
        documents = [mutate_document(rng, document) for _ in range(1 if kind == "json" else rng.randint(1, 3))]
        text = "\n".join(json.dumps(d) for d in documents)
    path = tmp_path / f"tap{index}.{kind}"
    path.write_text(mutate_text(rng, text))
    return path, path.read_text()[:120]


def special_files(folder: Path) -> list[Path]:
    """Things at a path that are not files to read: a FIFO (opening it blocks until a writer
    comes), a socket, a directory, a device (issue 20)."""
    fifo, sock, directory = folder / "fifo.json", folder / "sock.json", folder / "dir.json"
    os.mkfifo(fifo)
    listener = socket.socket(socket.AF_UNIX)
    listener.bind(str(sock))
    listener.close()  # the socket file stays
    directory.mkdir()
    return [fifo, sock, directory, Path("/dev/zero")]


def test_mutated_tap_files_read_or_give_a_tap_file_error(tmp_path):
    rng = random.Random(10)
    document = tap_to_json_dict(synth_tap(seed=2))
    failures, errors, accepted = [], 0, 0
    specials = special_files(tmp_path)
    for index in range(CASES):
        path, shown = tap_case(rng, tmp_path, index, document)
        if index % 10 == 0:
            path = specials[index // 10 % len(specials)]
            shown = str(path)
        try:
            with time_limit(shown):
                for tap in read_tap_file(path):
                    analyze_tap(tap)  # never raises on data that the reader accepted
            accepted += 1
        except TapFileError as exc:
            errors += 1
            if not (str(exc).startswith(f"{path}: ") and len(str(exc)) > len(f"{path}: ")):
                failures.append(f"{shown!r}: message does not name the file and problem: {exc}")
        except Exception as exc:  # anything else is a bug a tap file can reach
            failures.append(failure("tap", shown, exc))
    assert not failures, "\n".join(failures)
    assert errors > CASES / 3 and accepted > 5  # the mutations reach both outcomes


# -- config files ---------------------------------------------------------------------------

# Every section kind the virtual printer knows, so that every option is a mutation target.
ALL_SECTIONS = """
[extruder]
step_pin: PA0
dir_pin: PA1
rotation_distance: 33.5
microsteps: 16
nozzle_diameter: 0.4
filament_diameter: 1.75
heater_pin: PA2
sensor_type: EPCOS 100K B57560G104F
sensor_pin: PA3
control: pid
pid_kp: 21.5
pid_ki: 1.06
pid_kd: 108.5
min_temp: 0
max_temp: 300

[prusa_probe]

[xy_probe]
pin_x: 225
pin_y: 225
pin_diameter: 6

[z_thermal_adjust]
temp_coeff: -0.00045
sensor_type: temperature_combined
sensor_list: extruder
min_temp: 0
max_temp: 400
max_z_adjustment: 0.1

[gcode_macro PARK]
description: Park the nozzle
variable_height: 10
gcode:
  G1 Z{height} F600

[gcode_macro SHOW]
gcode:
  {action_respond_info("x=%s" % (params.X|default(1)))}

[gcode_macro HUGE_LINE]
gcode:
  {"G4 P0\\n" * 10**9}

[gcode_macro HUGE_OUTPUT]
gcode:
  {% for i in range(99999) %}{"G4 P" ~ "0" * 30}
  {% endfor %}
"""
PROBE_EXTRA = "nozzle_scrubber_gcode: PARK\nscrubbing_frequency: 2"
SIM_EXTRA = "pin_diameter_mm: 6\npin_x_mm: 225\npin_y_mm: 225"


def full_config_text() -> str:
    return printer_text(probe_options=PROBE_EXTRA, virtual_printer=SIM_EXTRA) + ALL_SECTIONS


def mutate_config(rng: random.Random, text: str, tmp_path: Path) -> str:
    lines = text.splitlines()
    option_lines = [i for i, line in enumerate(lines) if line and line[0].isalpha() and ":" in line]
    for _ in range(rng.randint(1, 3)):
        action = rng.randrange(8)
        if action <= 3:  # the most common: a bad value for an existing option
            i = rng.choice(option_lines)
            key = lines[i].split(":", 1)[0]
            lines[i] = f"{key}: {rng.choice(WORDS)}"
        elif action == 4:
            del lines[rng.randrange(len(lines))]
            option_lines = [i for i in option_lines if i < len(lines)]
        elif action == 5:
            lines.insert(rng.randrange(len(lines) + 1),
                         rng.choice(["[include missing.cfg]", "[include /dev/zero]", "[include self.cfg]",
                                     "[include fifo.json]", "[include sock.json]", "[include dir.json]",
                                     "[gcode_macro HUGE]\ngcode: {'a' * 10**9}",
                                     "[include *.cfg]", "[bogus]", "[printer", "  indented: 1", "novalue",
                                     "[gcode_macro BAD]\ngcode: {% if %}", "[gcode_macro X]\ngcode: X",
                                     "[bed_mesh extra]\nversion: 1\npoints: 1,2"]))
        elif action == 6:
            lines.append(rng.choice(["[virtual_printer]\nbed_x_mm: 1e308", "[load_cell_probe]\nspeed: 0",
                                     "[bed_mesh]\nprobe_count: 100000", "[stepper_z]\nposition_max: 1e308"]))
        else:
            i = rng.choice(option_lines)
            lines[i] = lines[i] + rng.choice([", 1", "\x00", " ; comment", "e999", "9" * 30])
    (tmp_path / "self.cfg").write_text("[include self.cfg]\n")
    return "\n".join(lines) + "\n"


def test_mutated_config_files_load_or_give_a_config_error(tmp_path):
    rng = random.Random(10)
    base = full_config_text()
    path = tmp_path / "printer.cfg"
    path.write_text(base)
    Printer.from_config(str(path))  # the unmutated file is valid
    special_files(tmp_path)
    failures, errors = [], 0
    for _ in range(CASES):
        text = mutate_config(rng, base, tmp_path)
        path.write_text(text)
        changed = sorted(set(text.splitlines()) - set(base.splitlines()))[:4]
        try:
            with time_limit(str(changed)):
                Printer.from_config(str(path))
        except ConfigError as exc:
            errors += 1
            if not str(exc).startswith(str(tmp_path)):
                failures.append(f"{changed}: the message does not name the file: {exc}")
        except Exception as exc:
            failures.append(failure("config", str(changed), exc))
    assert not failures, "\n".join(failures)
    assert errors > CASES / 2


# -- G-code ---------------------------------------------------------------------------------

# Commands that take the printer apart (RESTART reloads the config, dropping the calibration;
# M112 halts it) run once at the end instead of at random.
RUN_LAST = ("RESTART", "FIRMWARE_RESTART", "SAVE_CONFIG", "M112")
PROBE_OVERRIDE_COMMANDS = ("PROBE", "PROBE_ACCURACY", "PROBE_CALIBRATE", "NOZZLE_CLEANUP", "BED_MESH_CALIBRATE",
                           "LOAD_CELL_TEST_TAP",
                           "LOAD_CELL_PROBE_CALIBRATE", "G28")
# Lines start with these, so that the defaults (10 taps, a 30 s wait) do not eat the time budget;
# the random parameters after them may still ask for more.
QUICK_START = {"PROBE_ACCURACY": "SAMPLES=2", "Z_THERMAL_CALIBRATE": "SAMPLES=2 TEMP_COLD=30 TEMP_HOT=40",
               "LOAD_CELL_TEST_TAP": "TIMEOUT=1", "LOAD_CELL_PROBE_CALIBRATE": "SAMPLES=3",
               "BED_MESH_CALIBRATE": "PROBE_COUNT=3"}
# A 3 x 3 mesh keeps BED_MESH_CALIBRATE quick.
SMALL_MESH = {"probe_count: 7, 7": "probe_count: 3, 3", "algorithm: bicubic": "algorithm: lagrange"}
OVERRIDE_SPECS = (*PROBE_OPTION_SPECS, *TAP_OPTION_SPECS, *ANALYSIS_OPTION_SPECS)
SPEC_PARAMETERS = sorted({name for spec in OVERRIDE_SPECS for name in spec.gcode_names})


class ParameterRecorder:
    """Which parameters each command reads (so the fuzzer feeds it those), and the range of every
    number read from G-code or the config (so the test can hold docs/limits.md to them)."""

    def __init__(self, monkeypatch):
        self.read: dict[str, set[str]] = {}
        self.gcode_ranges: dict[tuple[str, str], str] = {}
        self.config_ranges: dict[tuple[str, str], str] = {}
        get, get_numbers = GCodeCommand.get, GCodeCommand._get_numbers
        checked_number, getlist = ConfigSection._checked_number, ConfigSection._getlist
        recorder = self

        def recording_get(gcmd, name, *args, **kwargs):
            recorder.read.setdefault(gcmd.command, set()).add(name.upper())
            return get(gcmd, name, *args, **kwargs)

        def recording_get_numbers(gcmd, name, default, parse, kind, limits, **kwargs):
            recorder.read.setdefault(gcmd.command, set()).add(name.upper())
            each = "each " if kwargs.get("many") else ""
            recorder.gcode_ranges[(gcmd.command, name.upper())] = each + describe_range(*limits)
            return get_numbers(gcmd, name, default, parse, kind, limits, **kwargs)

        def recording_checked_number(section, option, default, parse, kind, *limits):
            recorder.config_ranges[(section.get_prefix(), option)] = describe_range(*limits)
            return checked_number(section, option, default, parse, kind, *limits)

        def recording_getlist(section, option, default, sep, count, parse_item, kind, *limits):
            if limits:
                recorder.config_ranges[(section.get_prefix(), option)] = "each " + describe_range(*limits)
            return getlist(section, option, default, sep, count, parse_item, kind, *limits)

        monkeypatch.setattr(GCodeCommand, "get", recording_get)
        monkeypatch.setattr(GCodeCommand, "_get_numbers", recording_get_numbers)
        monkeypatch.setattr(ConfigSection, "_checked_number", recording_checked_number)
        monkeypatch.setattr(ConfigSection, "_getlist", recording_getlist)

    def parameters(self, command: str) -> list[str]:
        return sorted(self.read.get(command, set()))


LIMITS_DOC = Path(__file__).resolve().parents[1] / "docs" / "limits.md"


def documented_ranges() -> tuple[dict[tuple[str, str], str], dict[tuple[str, str], str]]:
    """docs/limits.md's tables: {(section kind, option): range} and {(command, parameter): range}."""
    config, gcode = {}, {}
    sections: list[str] = []
    for line in LIMITS_DOC.read_text().splitlines():
        if line.startswith("### "):
            sections = re.findall(r"`\[(\w+)\]`", line)
        cells = [cell.strip() for cell in line.strip().strip("|").split("|")] if line.startswith("| `") else []
        names = [re.findall(r"`([^`]+)`", cell) for cell in cells]
        if len(cells) == 2 and sections:
            config.update({(section, option): cells[1] for section in sections for option in names[0]})
        elif len(cells) == 3:
            gcode.update({(command, parameter): cells[2] for command in names[0] for parameter in names[1]})
    return config, gcode


def range_problems(recorded: dict, documented: dict, what: str) -> list[str]:
    problems = []
    for key, enforced in sorted(recorded.items()):
        doc = documented.get(key)
        if doc is None:
            problems.append(f"{what} {key}: enforced range {enforced!r} is not in docs/limits.md")
            continue
        stated = re.sub(r"\s*\(.*\)$", "", doc)  # a note in brackets is not the range
        if "`" not in stated and stated != enforced:  # `other_option`: depends on another value
            problems.append(f"{what} {key}: docs/limits.md says {doc!r}, the code enforces {enforced!r}")
    return problems


def probe_override_ranges(config_doc: dict) -> dict[tuple[str, str], str]:
    """A probing command's override of a [load_cell_probe] option (TRIGGER_FORCE=...) has the option's range."""
    return {(command, name): config_doc[("load_cell_probe", spec.option)]
            for command in PROBE_OVERRIDE_COMMANDS for spec in OVERRIDE_SPECS
            for name in spec.gcode_names if ("load_cell_probe", spec.option) in config_doc}


def random_line(rng: random.Random, command: str, known: list[str]) -> str:
    parameters = []
    for _ in range(rng.randint(0, 3)):
        pool = known if known and rng.random() < 0.8 else SPEC_PARAMETERS
        parameters.append(f"{rng.choice(pool)}={rng.choice(WORDS)}")
    if command[0] in "GM" and command[1:].isdigit():  # classic: X10 F600
        return " ".join([command, *(p.split("=")[0][0] + p.split("=")[1] for p in parameters)])
    return " ".join([command, QUICK_START.get(command, ""), *parameters])


def test_random_gcode_on_the_virtual_printer_works_or_gives_a_gcode_error(tmp_path, monkeypatch):
    recorder = ParameterRecorder(monkeypatch)
    printer, _ = make_printer(tmp_path, probe_options=PROBE_EXTRA, virtual_printer=SIM_EXTRA, sections=ALL_SECTIONS,
                              replace=SMALL_MESH)
    for command in sorted(printer.gcode.get_command_help()):  # once without parameters: records what each reads
        if command not in RUN_LAST:
            with time_limit(command):
                printer.gcode.run_script_reporting_errors(f"{command} {QUICK_START.get(command, '')}")
    commands = sorted(name for name in printer.gcode.get_command_help() if name not in RUN_LAST)
    rng = random.Random(10)
    failures, errors = [], 0
    lines = [random_line(rng, command, recorder.parameters(command))
             for command in rng.choices(commands, k=GCODE_CASES)] + list(RUN_LAST)
    for line in lines:
        try:
            with time_limit(line):
                printer.gcode.run_script(line)
        except GCodeError as exc:
            errors += 1
            if not str(exc).strip() or "Internal error" in str(exc):
                failures.append(f"{line!r}: not a message for the user: {exc!r}")
        except Exception as exc:
            failures.append(failure("G-code", line, exc))
    assert not failures, "\n".join(failures)
    # Most random lines are refused. How many depends on the share of commands that take no
    # parameters (QUERY_ENDSTOPS, TURN_OFF_HEATERS, the example's PAUSE/RESUME/CANCEL_PRINT
    # macros and their *_BASE): 44-57 of 100 over seeds 1-6 and 10; a third leaves that margin.
    assert errors > GCODE_CASES / 3
    # Every range the run met is documented as enforced.
    config_doc, gcode_doc = documented_ranges()
    # The simulator's own parameters are listed, with their ranges, by `tapcell scenarios NAME`.
    config_ranges = {key: text for key, text in recorder.config_ranges.items()
                     if not (key[0] == "virtual_printer" and key[1] in PARAM_FIELDS)}
    problems = range_problems(config_ranges, config_doc, "config option")
    problems += range_problems(recorder.gcode_ranges, {**probe_override_ranges(config_doc), **gcode_doc}, "parameter")
    assert not problems, "\n".join(problems)


# -- what a server sends to `tapcell monitor` (issue 20) -----------------------------------------

class _Exhausted(Exception):
    """The fake server has sent everything."""


class _ScriptedSocket:
    def __init__(self, texts: list[str]):
        self.texts = list(texts)

    def recv(self, timeout: float):
        if not self.texts:
            raise _Exhausted
        return self.texts.pop(0)


class _Lines:
    def __init__(self):
        self.said: list[str] = []
        self.rows: list = []

    def say(self, message: str) -> None:
        self.said.append(message)

    def add(self, row) -> None:
        self.rows.append(row)


def test_hostile_server_messages_are_skipped_or_analysed_by_the_monitor(tmp_path):
    from tapcell.tools import monitor as monitor_module

    rng = random.Random(20)
    tap = tap_to_json_dict(synth_tap(seed=3))
    tap.update(tap_pos=[100.0, 100.0, 0.01], is_valid=True, error=None)
    event = {"tap": tap}
    log = tmp_path / "taps.jsonl"
    args = type("Args", (), {"log": str(log), "plot_dir": None, "count": 0, "force": True,
                             "moonraker": "http://printer:7125"})()
    options = monitor_module.analysis_options({}, [])
    failures, skipped = [], 0
    for index in range(MONITOR_CASES):
        kind = rng.randrange(4)
        if kind == 0:  # the tap itself mutated, the printer's result included
            text = json.dumps({"params": mutate_document(rng, copy.deepcopy(event))}, allow_nan=True)
        elif kind == 1:  # the message's shape
            text = json.dumps(rng.choice([{"params": json_value(rng)}, json_value(rng), {"params": {"tap": json_value(rng)}},
                                          {"params": {"data": json_value(rng)}}]), allow_nan=True)
        elif kind == 2:  # not JSON, or too deep for it
            text = rng.choice(["", "{", "nul", '{"params":' + "[" * 5000, "[" * 100000 + "]" * 100000,
                               json.dumps(event)[: rng.randrange(1, 200)]])
        else:
            text = mutate_text(rng, json.dumps({"params": event}))
        display = _Lines()
        bridge = monitor_module.Bridge(_ScriptedSocket([text, json.dumps({"params": event})]))
        lines_before = len(log.read_text().splitlines()) if log.exists() else 0
        try:
            with time_limit(text[:120]):
                monitor_module._follow(bridge, args, options, display, monitor_module.TapCount())
        except _Exhausted:
            pass
        except Exception as exc:  # anything else is a bug a server can reach
            failures.append(failure("monitor", text[:120], exc))
            continue
        skipped += any("skipped" in line for line in display.said)
        logged = log.read_text().splitlines()[lines_before:]
        if not logged or any(json.loads(line)["analysis"] is None for line in logged):
            failures.append(f"{text[:120]!r}: the valid tap after it was not logged: {display.said[-3:]}")
        if len([line for line in display.said if "skipped" in line]) > 1:
            failures.append(f"{text[:120]!r}: more than one line for one bad message: {display.said}")
    assert not failures, "\n".join(failures)
    assert MONITOR_CASES / 4 < skipped < MONITOR_CASES  # the mutations reach both outcomes
