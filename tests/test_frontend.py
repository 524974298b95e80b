"""tapcell run / tapcell console (front ends over the printer's G-code dispatcher)."""

from __future__ import annotations

import pytest

from tapcell.tools import cli, frontend
from tapcell.host.printer import Printer

CONFIG = """\
[gcode_macro HELLO]
description: Say hello
gcode:
  {action_respond_info("hello " ~ params.NAME|default("world"))}
[gcode_macro BOOM]
gcode:
  {action_raise_error("boom at " ~ params.AT)}
"""


@pytest.fixture
def files(tmp_path):
    config = tmp_path / "printer.cfg"
    config.write_text(CONFIG)
    script = tmp_path / "script.gcode"
    return config, script


def run(capsys, *args):
    status = cli.main(["run", *map(str, args)])
    out, err = capsys.readouterr()
    return status, out.splitlines(), err


def test_run_prints_every_response(capsys, files):
    config, script = files
    script.write_text("; a comment\nHELLO\n\nhello name=tapcell ; inline comment\n")
    status, out, err = run(capsys, script, "--config", config)
    assert (status, out, err) == (0, ["// hello world", "// hello tapcell"], "")


def test_run_stops_at_the_first_error(capsys, files):
    config, script = files
    script.write_text("HELLO\nBOOM AT=2\nHELLO NAME=never\n")
    status, out, err = run(capsys, script, "--config", config)
    assert status == 1
    assert out == ["// hello world", "!! boom at 2"]
    assert err == f"tapcell run: {script}:2: stopped at the first error (use --keep-going to run the rest)\n"


def test_keep_going_runs_everything_but_still_fails(capsys, files):
    config, script = files
    script.write_text("BOOM AT=1\nNOPE\nHELLO NAME=end\n")
    status, out, err = run(capsys, script, "--config", config, "--keep-going", "--echo")
    assert status == 1
    # An unknown command is answered as Klipper answers it in a print file, and the file goes on.
    assert out == ["> BOOM AT=1", "!! boom at 1", "> NOPE", '// Unknown command:"NOPE"', "> HELLO NAME=end",
                   "// hello end"]
    assert err == ""


def test_run_reports_bad_files_without_traceback(capsys, files, tmp_path):
    config, script = files
    status, out, err = run(capsys, tmp_path / "missing.gcode", "--config", config)
    assert (status, out, err) == (2, [], f"tapcell run: script '{tmp_path / 'missing.gcode'}' does not exist\n")
    status, out, err = run(capsys, "/dev/zero", "--config", config)   # exists, but is no file to read
    assert (status, err.splitlines()[-1]) == (2, "tapcell run: cannot read script '/dev/zero': is a character device")
    script.write_text("HELLO\n")
    status, out, err = run(capsys, script, "--config", tmp_path / "nope.cfg")
    assert (status, err) == (1, f"tapcell run: config file '{tmp_path / 'nope.cfg'}' does not exist\n")
    config.write_text("[gcode_macro X]\ngcode: G28\nspeed: 5\n")
    status, out, err = run(capsys, script, "--config", config)
    assert (status, err) == (1, f"tapcell run: config error: {config}: [gcode_macro X] speed = 5: "
                                "Option 'speed' is not valid in section 'gcode_macro X'\n")
    script.write_bytes(b"HELLO \xff\n")
    config.write_text(CONFIG)
    status, out, err = run(capsys, script, "--config", config)
    assert status == 2 and err.startswith(f"tapcell run: script '{script}' is not UTF-8 text:")
    printer = Printer.from_config(str(config), responses=[])
    assert frontend.run_script_file(printer, "/dev/zero", keep_going=False, echo=False) == 2
    assert capsys.readouterr().err == "tapcell run: cannot read script '/dev/zero': is a character device\n"


def test_console_loop_runs_lines_until_eof(capsys, files):
    config, _ = files
    printer = Printer.from_config(str(config), responses=frontend._print_line)
    lines = iter(["HELLO NAME=a", "BOOM AT=3", "   ", "HELLO NAME=b"])

    def read_line(prompt):
        assert prompt == "tapcell> "
        try:
            return next(lines)
        except StopIteration:
            raise EOFError from None

    frontend.console_loop(printer, read_line)
    assert capsys.readouterr().out.splitlines() == ["// hello a", "!! boom at 3", "// hello b", ""]


def test_console_quits_on_exit_and_survives_ctrl_c(capsys, files):
    config, _ = files
    printer = Printer.from_config(str(config), responses=frontend._print_line)
    printer.gcode.register_command("SLOW", lambda gcmd: (_ for _ in ()).throw(KeyboardInterrupt))
    events = iter([KeyboardInterrupt, "SLOW", "HELLO", "exit", "HELLO NAME=never"])

    def read_line(prompt):
        event = next(events)
        if event is KeyboardInterrupt:
            raise KeyboardInterrupt
        return event

    frontend.console_loop(printer, read_line)
    assert capsys.readouterr().out.splitlines() == ["", "!! Interrupted", "// hello world"]


def test_console_main_with_piped_input(capsys, files, monkeypatch):
    config, _ = files
    monkeypatch.setattr("sys.stdin", _Lines(["HELLO NAME=pipe\n"]))
    assert cli.main(["console", "--config", str(config)]) == 0
    out = capsys.readouterr().out
    assert "// Printer is ready. Type HELP for the commands, exit to quit." in out
    assert "// hello pipe" in out


class _Lines:
    """A non-terminal stdin for input()."""

    def __init__(self, lines):
        self._lines = list(lines)

    def isatty(self):
        return False

    def readline(self):
        return self._lines.pop(0) if self._lines else ""


def test_default_config_is_the_shipped_example():
    assert frontend.DEFAULT_CONFIG.name == "virtual-printer.cfg"
    assert frontend.DEFAULT_CONFIG.is_file()
    assert frontend.main(["bogus"]) == 2
