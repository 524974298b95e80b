"""Issue 20: hostile files, templates and macros: a one-line error or a warning, never a hang,
a traceback or gigabytes."""

from __future__ import annotations

import os
import json
import re
import resource
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from tapcell.files import FileRefused, check_appendable, open_append, read_limited
from tapcell.host import templates
from tapcell.host.config import ConfigError, ConfigFile
from tapcell.host.gcode import GCodeError
from tapcell.host.printer import Printer
from tapcell.tap import TapFileError, read_tap_file, tap_to_json_dict
from tapcell.tap.synth import synth_tap
from tapcell.tools import cli

READ_DEADLINE_S = 20.0  # a refusal takes microseconds; a hang is caught, then freed, after this


def finishes(function, fifo: Path | None = None):
    """function()'s result or exception; a call still blocked after READ_DEADLINE_S fails the test
    (after opening the FIFO's other end so that the thread can end)."""
    outcome: dict = {}

    def call():
        try:
            outcome["value"] = function()
        except BaseException as exc:  # handed to the test
            outcome["error"] = exc

    thread = threading.Thread(target=call, daemon=True)
    thread.start()
    thread.join(READ_DEADLINE_S)
    if thread.is_alive():
        if fifo is not None:
            os.close(os.open(fifo, os.O_RDWR))  # a writer for a reader stuck in open()
        pytest.fail(f"{function} was still blocked after {READ_DEADLINE_S} s")
    if "error" in outcome:
        raise outcome["error"]
    return outcome.get("value")


@pytest.fixture
def fifo(tmp_path) -> Path:
    path = tmp_path / "pipe.json"
    os.mkfifo(path)
    return path


def test_a_fifo_is_refused_at_once_by_every_reader_naming_it(tmp_path, fifo):
    with pytest.raises(FileRefused, match=r"^is a FIFO \(named pipe\)$"):
        finishes(lambda: read_limited(fifo, 1000), fifo)
    with pytest.raises(TapFileError, match=rf"^{fifo}: is a FIFO \(named pipe\), not a tap file$"):
        finishes(lambda: read_tap_file(str(fifo)), fifo)
    with pytest.raises(ConfigError, match=rf"^{fifo}: is a FIFO \(named pipe\), not a config file$"):
        finishes(lambda: ConfigFile.read(fifo), fifo)
    main = tmp_path / "printer.cfg"
    main.write_text(f"[include {fifo.name}]\n")
    with pytest.raises(ConfigError, match=rf"printer.cfg:1: include file {fifo}: is a FIFO \(named pipe\), "
                                          r"not a config file$"):
        finishes(lambda: ConfigFile.read(main), fifo)


def test_a_directory_and_a_socket_are_named_as_what_they_are(tmp_path):
    import socket
    with pytest.raises(FileRefused, match=r"^is a directory$"):
        read_limited(tmp_path, 1000)
    path = tmp_path / "s.sock"
    listener = socket.socket(socket.AF_UNIX)
    listener.bind(str(path))
    try:
        with pytest.raises(FileRefused, match=r"^is a socket$"):
            read_limited(path, 1000)
    finally:
        listener.close()


def test_a_log_target_is_checked_without_blocking(tmp_path, fifo):
    # A FIFO nobody reads would block open() for writing; a directory cannot take lines.
    assert finishes(lambda: check_appendable(fifo), fifo) == "is a FIFO (named pipe)"
    assert check_appendable(tmp_path) == "is a directory"
    assert check_appendable(tmp_path / "missing" / "log.jsonl").startswith("cannot be written (No such file")
    log = tmp_path / "log.jsonl"
    assert check_appendable(log) is None
    with open_append(log) as out:
        out.write("one\n")
    with open_append(log) as out:
        out.write("two\n")
    assert log.read_text() == "one\ntwo\n"
    assert oct(log.stat().st_mode & 0o777) == oct(0o666 & ~_umask())


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def test_tapcell_run_refuses_a_fifo_script(tmp_path, fifo, capsys):
    config = tmp_path / "printer.cfg"
    config.write_text("[gcode_macro HELLO]\ngcode:\n  {action_respond_info('hi')}\n")
    status = finishes(lambda: cli.main(["run", "--config", str(config), str(fifo)]), fifo)
    assert status == 2
    assert capsys.readouterr().err.splitlines()[-1] == \
        f"tapcell run: cannot read script '{fifo}': is a FIFO (named pipe)"


# -- templates --------------------------------------------------------------------------------

MACROS = """\
[gcode_macro HUGE_CONSTANT]
gcode:
  {"a" * 10**9}
[gcode_macro HUGE_OUTPUT]
gcode:
  {% for i in range(50000) %}RESPOND MSG={"x" * 30}
  {% endfor %}
[gcode_macro HUGE_POWER]
gcode:
  {10 ** 100000000}
[gcode_macro HUGE_LOOP]
gcode:
  {% for i in range(10**9) %}{% endfor %}
[gcode_macro FINE]
gcode:
  {action_respond_info("ok " ~ ("ab" * 3) ~ " " ~ (2 ** 10))}
[respond]
"""


def _peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def test_templates_that_would_build_gigabytes_are_refused_at_render(tmp_path):
    config = tmp_path / "printer.cfg"
    config.write_text(MACROS)
    before_mb = _peak_rss_mb()
    responses: list[str] = []
    printer = Printer.from_config(str(config), responses=responses)  # Jinja2 folded "a"*10**9 here: 3 GB
    printer.gcode.run_script("FINE")
    assert responses == ["// ok ababab 1024"]
    expected = {
        "HUGE_CONSTANT": "Error in macro HUGE_CONSTANT: repeating 1 items 1,000,000,000 times builds more "
                         "than 1,000,000 (the limit)",
        "HUGE_OUTPUT": "Error in macro HUGE_OUTPUT: the G-code it renders is over 1,000,000 characters (the limit)",
        "HUGE_POWER": "Error in macro HUGE_POWER: 10**100000000 has more than 4096 bits (the limit)",
    }
    for macro, message in expected.items():
        with pytest.raises(GCodeError) as caught:
            printer.gcode.run_script(macro)
        assert str(caught.value) == message
    with pytest.raises(GCodeError, match=r"^Error in macro HUGE_LOOP: OverflowError: Range too big"):
        printer.gcode.run_script("HUGE_LOOP")
    # Nothing above built more than a few MB (the limits are 1 M characters).
    assert _peak_rss_mb() - before_mb < 100


def test_the_render_limit_is_the_documented_one():
    assert templates.MAX_RENDERED_CHARS == 1_000_000
    assert "1,000,000 characters" in (Path(__file__).parents[1] / "docs" / "limits.md").read_text()


# -- unknown commands inside macros --------------------------------------------------------------

PRINT_START = """\
[gcode_macro PRINT_START]
gcode:
  RESPOND MSG=heating
  Z_TILT_ADJUST
  RESPOND MSG=meshing
  NOT_A_COMMAND X=1
  RESPOND MSG=purging
[gcode_macro OUTER]
gcode:
  PRINT_START
  RESPOND MSG=outer-done
[respond]
"""


def test_an_unknown_command_in_a_macro_warns_and_the_macro_goes_on(tmp_path):
    config = tmp_path / "printer.cfg"
    config.write_text(PRINT_START)
    responses: list[str] = []
    printer = Printer.from_config(str(config), responses=responses)
    printer.gcode.run_script("OUTER")
    assert responses == [
        "echo: heating",
        '// Unknown command:"Z_TILT_ADJUST" in macro PRINT_START, skipped',
        "echo: meshing",
        '// Unknown command:"NOT_A_COMMAND" in macro PRINT_START, skipped',
        "echo: purging",
        "echo: outer-done",
    ]
    assert printer.gcode.skipped_in_macros == ["PRINT_START: Z_TILT_ADJUST", "PRINT_START: NOT_A_COMMAND"]
    # At the top level (the console, a script) an unknown command is still an error.
    with pytest.raises(GCodeError, match='^Unknown command:"Z_TILT_ADJUST"$'):
        printer.gcode.run_script("Z_TILT_ADJUST")


def test_tapcell_run_reports_skipped_commands_in_its_summary_and_exit_status(tmp_path, capsys):
    config = tmp_path / "printer.cfg"
    config.write_text(PRINT_START)
    script = tmp_path / "print.gcode"
    script.write_text("PRINT_START\nM205 X8\n")
    status = cli.main(["run", "--config", str(config), str(script)])
    out, err = capsys.readouterr()
    assert status == 3
    assert out.splitlines()[-1] == '// Unknown command:"M205"'  # a slicer's code at the top: as in Klipper
    assert err.splitlines()[-1] == ("tapcell run: warning: 2 unknown command(s) skipped inside macros "
                                    "(PRINT_START: Z_TILT_ADJUST, PRINT_START: NOT_A_COMMAND); exit status 3")
    script.write_text("M205 X8\nRESPOND MSG=done\n")  # unknown at the top level only: 0, as before
    assert cli.main(["run", "--config", str(config), str(script)]) == 0


# -- the command line's own exits ----------------------------------------------------------------

def test_analyze_into_a_closed_pipe_ends_quietly(tmp_path):
    taps = _write_taps(tmp_path, 3)
    # `tapcell analyze … | head -0`: the reader is gone before the first line is written.
    process = subprocess.Popen([sys.executable, "-m", "tapcell", "analyze", *map(str, taps)],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    process.stdout.close()
    _, err = process.communicate(timeout=120)
    assert b"Traceback" not in err and b"BrokenPipe" not in err, err.decode()[-800:]
    assert process.returncode == cli.EXIT_BROKEN_PIPE


def _write_taps(folder: Path, count: int) -> list[Path]:
    text = json.dumps(tap_to_json_dict(synth_tap()))
    paths = [folder / f"tap{k:03d}.json" for k in range(count)]
    for path in paths:
        path.write_text(text)
    return paths


@pytest.mark.parametrize("text", ["", "  \n\t\n", "# only a comment\n; and another\n"])
def test_an_empty_config_is_refused_not_run_silently(tmp_path, capsys, text):
    config = tmp_path / "printer.cfg"
    config.write_text(text)
    script = tmp_path / "s.gcode"
    script.write_text("STATUS\n")
    assert cli.main(["run", "--config", str(config), str(script)]) == 1
    assert capsys.readouterr().err == (f"tapcell run: config error: {config}: the config file has no sections (it is "
                                       f"empty or only comments): a printer needs at least [printer] and its steppers\n")


def test_a_symlink_loop_is_named_as_such_not_as_missing(tmp_path, capsys):
    (tmp_path / "a.cfg").symlink_to(tmp_path / "b.cfg")
    (tmp_path / "b.cfg").symlink_to(tmp_path / "a.cfg")
    script = tmp_path / "s.gcode"
    script.write_text("STATUS\n")
    assert cli.main(["run", "--config", str(tmp_path / "a.cfg"), str(script)]) == 1
    assert capsys.readouterr().err == (f"tapcell run: config file '{tmp_path / 'a.cfg'}' is a symbolic link that "
                                       f"leads nowhere (a loop, or its target is missing)\n")


def test_a_trigger_force_past_the_safety_limit_is_named_as_the_cause(tmp_path):
    # With a drift filter as well, the refusal used to blame the filter ("0.8 Hz hides a tap").
    example = (Path(__file__).parents[1] / "examples" / "virtual-printer.cfg").read_text()
    config = tmp_path / "printer.cfg"
    config.write_text(example.replace("force_safety_limit: 2000", "force_safety_limit: 100")
                      .replace("trigger_force: 75", "trigger_force: 150")
                      .replace("\nspeed: 5\n", "\nspeed: 5\ndrift_filter_cutoff_frequency: 0.8\n"))
    with pytest.raises(ConfigError) as refused:
        Printer.from_config(str(config), responses=[])
    assert str(refused.value) == (f"{config}: [load_cell_probe] trigger_force = 150: must be below force_safety_limit "
                                  f"(100g): the raw force would pass the limit and stop every probe before the "
                                  f"trigger fires; allowed: below 100")


@pytest.mark.parametrize("kind", ["fifo", "directory"])
def test_a_tap_log_that_cannot_take_taps_is_refused_at_load(tmp_path, kind):
    log = tmp_path / "taps.jsonl"
    if kind == "fifo":
        os.mkfifo(log)
    else:
        log.mkdir()
    example = (Path(__file__).parents[1] / "examples" / "virtual-printer.cfg").read_text()
    config = tmp_path / "printer.cfg"
    config.write_text(example.replace("\nspeed: 5\n", f"\nspeed: 5\ntap_log: {log}\n"))
    with pytest.raises(ConfigError) as refused:
        finishes(lambda: Printer.from_config(str(config), responses=[]), log if kind == "fifo" else None)
    what = "a FIFO (named pipe)" if kind == "fifo" else "a directory"
    assert str(refused.value) == (f"{config}: [load_cell_probe] tap_log = {log}: is {what}: a tap log must be a file "
                                  f"taps can be appended to")


def test_settings_the_firmware_trigger_refuses_are_a_probe_error_not_a_traceback(tmp_path):
    # counts_per_gram at the top of its range: a TriggerConfigError traceback before issue 20.
    example = (Path(__file__).parents[1] / "examples" / "virtual-printer.cfg").read_text()
    config = tmp_path / "printer.cfg"
    config.write_text(example.replace("samples: 1\n", "samples: 1\ncounts_per_gram: 8388607\n"
                                                      "reference_tare_counts: -38000\n", 1))
    printer = Printer.from_config(str(config), responses=[])
    with pytest.raises(GCodeError) as refused:
        printer.gcode.run_script("G28")
    assert str(refused.value).startswith("Load Cell Probe Error: the trigger force (75g) is beyond what the load "
                                         "cell can read: at counts_per_gram 8.38861e+06")


def _calibrated_example(tmp_path, replace: dict[str, str] | None = None) -> Path:
    text = (Path(__file__).parents[1] / "examples" / "virtual-printer.cfg").read_text()
    text = text.replace("samples: 1\n", "samples: 1\ncounts_per_gram: 110\nreference_tare_counts: -38000\n", 1)
    for old, new in (replace or {}).items():
        assert old in text
        text = text.replace(old, new)
    config = tmp_path / "printer.cfg"
    config.write_text(text)
    return config


@pytest.mark.parametrize("case", ["stuck sensor", "short pullback"])
def test_a_sensor_stuck_in_the_pullback_is_named_not_the_pullback(tmp_path, case):
    replace = {"pullback_distance: 0.15": "pullback_distance: 0.01"} if case == "short pullback" else {}
    printer = Printer.from_config(str(_calibrated_example(tmp_path, replace)), responses=[])
    fault = "SIM_FAULT NAME=stuck WHEN=trigger\n" if case == "stuck sensor" else ""
    printer.gcode.run_script("G28\nG1 X110 Y110 F6000\nG1 Z3 F600")
    with pytest.raises(GCodeError) as failed:
        printer.gcode.run_script(fault + "PROBE BAD_PROBE_STRATEGY=fail")
    message = str(failed.value)
    assert message.startswith("Probe failed because it was deemed bad quality: TAP_PULLBACK_TOO_SHORT - ")
    if case == "stuck sensor":
        assert re.search(r"the load cell's readings stopped changing during the pullback \(\d+ identical samples at "
                         r"\d+g\): a stuck sensor, not a short pullback; check the sensor's wiring", message)
        assert "lengthen pullback_distance" not in message
    else:  # the control: a pullback that is really too short is still told so
        assert "stuck" not in message and "Fix: lengthen pullback_distance" in message


def test_the_coasting_fix_fits_the_printers_position_min():
    from tapcell.extras.probe.advice import bad_tap_advice

    already = bad_tap_advice("COASTING_MOVE_ACCELERATION", position_min_mm=-2.0)
    assert already.endswith("Fix: start the probe higher ([stepper_z] position_min is -2 already); if it triggers "
                            "in the air, free the bowden tube or cable chain that pulls on the toolhead.")
    assert "-5" not in already
    at_zero = bad_tap_advice("COASTING_MOVE_ACCELERATION", position_min_mm=0.0)
    assert at_zero.endswith("Fix: give [stepper_z] a negative position_min (it is 0; e.g. -5), so the probing move "
                            "can pass Z=0, and start the probe higher.")
    # The cause covers both ways a move is not at its steady speed (the code is raised for both).
    assert "still speeding up" in at_zero and "already slowing down" in at_zero
