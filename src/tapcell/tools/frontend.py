"""`tapcell console` (interactive) and `tapcell run` (batch): G-code on the virtual printer.

Both build a `Printer` from a config file (default: examples/virtual-printer.cfg)
and print every response line as soon as it is produced. The console never rewrites a
file git tracks: it works on a copy in the user's folder (`tapcell.tools.workspace`).
"""

from __future__ import annotations

import argparse
import contextlib
import os
import signal
import sys
import threading
from pathlib import Path

from tapcell.files import FileRefused, read_limited, why_missing
from tapcell.package_files import example_config
from tapcell.host.config import ConfigError
from tapcell.host.gcode import GCodeError, UnknownCommandError
from tapcell.host.printer import Printer
from tapcell.tools.progress import ProgressBar
from tapcell.tools.workspace import ScenarioError, set_scenario, working_config

SUBCOMMANDS = ("console", "run")

DEFAULT_CONFIG = example_config("virtual-printer.cfg")
HISTORY_FILE = Path("~/.tapcell_history").expanduser()  # readline's format
CONSOLE_HISTORY_FILE = Path("~/.tapcell_console_history").expanduser()  # prompt_toolkit's format
HISTORY_LENGTH = 1000
PROMPT = "tapcell> "
CONSOLE_STOP_REASON = "Shutdown due to console stop (Ctrl-C)"
MAX_SCRIPT_BYTES = 256 * 1024 * 1024  # a G-code file for the virtual printer; read whole, so bounded


def _print_line(line: str) -> None:
    print(line, flush=True)


def _build_printer(config_path: str, program: str, notices_to=None) -> Printer | None:
    """The printer of `config_path`; the start-up notices go to `notices_to` (stdout by default)."""
    if not os.path.exists(config_path):
        print(f"{program}: config file '{config_path}' {why_missing(config_path)}", file=sys.stderr)
        return None
    try:
        printer = Printer.from_config(config_path, responses=_print_line)
    except ConfigError as exc:
        print(f"{program}: config error: {exc}", file=sys.stderr)
        return None
    for notice in printer.notices:
        for line in notice.split("\n"):
            print(f"// {line}", file=notices_to or sys.stdout, flush=True)
    for warning in printer.warnings:
        print(f"// Warning: {warning}", flush=True)
    return printer


EXIT_OK, EXIT_FAILED, EXIT_UNREADABLE, EXIT_SKIPPED_IN_MACROS = 0, 1, 2, 3


def run_script_file(printer: Printer, script_path: str, *, keep_going: bool, echo: bool,
                    progress: bool | None = False) -> int:
    """Run a G-code file line by line like a print. The exit status: 0 if every line succeeded,
    1 if a line failed, 2 if the file cannot be read, 3 if it ran to the end but a macro skipped
    an unknown command (a PRINT_START that left out its mesh is not a success).
    `progress`: a progress bar on stderr (None: when stderr is a terminal).

    An unknown command is answered as Klipper answers it in a print (`// Unknown command:"M205"`)
    and the file goes on; inside a macro too (see GCodeDispatch.run_macro_script); any other
    error stops it (unless keep_going).
    """
    try:
        lines = read_limited(script_path, MAX_SCRIPT_BYTES).decode("utf-8").splitlines()
    except (OSError, FileRefused) as exc:
        print(f"tapcell run: cannot read script '{script_path}': {exc}", file=sys.stderr)
        return EXIT_UNREADABLE
    except UnicodeDecodeError as exc:
        print(f"tapcell run: script '{script_path}' is not UTF-8 text: {exc}", file=sys.stderr)
        return EXIT_UNREADABLE
    bar = ProgressBar(len(lines), enabled=progress)
    gcode = printer.gcode

    def show(line: str) -> None:
        bar.clear()
        print(line, flush=True)

    gcode.set_response_sink(show)
    # Ctrl-C is an emergency stop, as in the console: the line running fails with the shutdown
    # message and so does every later one (the file stops there unless --keep-going).
    with ctrl_c_stops(printer):
        return _run_lines(printer, lines, bar, show, script_path, keep_going=keep_going, echo=echo)


def _run_lines(printer: Printer, lines: list[str], bar: ProgressBar, show, script_path: str, *,
               keep_going: bool, echo: bool) -> int:
    gcode = printer.gcode
    failed = False
    try:
        for line_number, line in enumerate(lines, start=1):
            if echo and line.strip():
                show(f"> {line.strip()}")
            try:
                gcode.run_line(line)
            except UnknownCommandError as exc:
                gcode.respond_info(str(exc))
            except GCodeError as exc:
                gcode.respond_error(str(exc))
                failed = True
                if not keep_going:
                    bar.clear()
                    print(f"tapcell run: {script_path}:{line_number}: stopped at the first error "
                          f"(use --keep-going to run the rest)", file=sys.stderr)
                    return EXIT_FAILED
            bar.update(line_number, printer.get_time())
    finally:
        bar.clear()
        gcode.set_response_sink(_print_line)
    if bar.enabled:
        print(bar.summary(len(lines), printer.get_time()), file=sys.stderr)
    skipped = gcode.skipped_in_macros
    if skipped:
        shown = ", ".join(dict.fromkeys(skipped))  # each macro/command once, in order
        print(f"tapcell run: warning: {len(skipped)} unknown command(s) skipped inside macros ({shown})"
              f"{'' if failed else f'; exit status {EXIT_SKIPPED_IN_MACROS}'}", file=sys.stderr)
    if failed:
        return EXIT_FAILED
    return EXIT_SKIPPED_IN_MACROS if skipped else EXIT_OK


def _config_for_run(config: str) -> str:
    """The config a run works on: the console's working copy of a file git tracks or tapcell installed
    (so a calibration saved in the console holds here), said on stderr; the user's own file in place."""
    if not os.path.exists(config):
        return config  # _build_printer says so
    path, where = working_config(Path(config))
    if path != Path(config):
        print(f"// {where}", file=sys.stderr, flush=True)
    return str(path)


def _main_run(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="tapcell run", description="Run a G-code script on the virtual printer "
                                     "and print every response.")
    parser.add_argument("script", help="G-code file to run, one command per line")
    parser.add_argument("--config", default=str(DEFAULT_CONFIG), help="printer config (default: %(default)s)")
    parser.add_argument("--keep-going", action="store_true", help="run the rest of the script after an error "
                        "(the exit status is still 1)")
    parser.add_argument("--echo", action="store_true", help="print each command (as '> LINE') before its responses")
    parser.add_argument("--progress", choices=("auto", "always", "never"), default="auto",
                        help="progress bar on stderr (auto: when stderr is a terminal)")
    args = parser.parse_args(argv)
    if not os.path.exists(args.script):
        print(f"tapcell run: script '{args.script}' {why_missing(args.script)}", file=sys.stderr)
        return 2
    # In a run the notices are about the session, not responses to the file: they go to stderr.
    printer = _build_printer(_config_for_run(args.config), "tapcell run", notices_to=sys.stderr)
    if printer is None:
        return 1
    return run_script_file(printer, args.script, keep_going=args.keep_going, echo=args.echo,
                           progress={"auto": None, "always": True, "never": False}[args.progress])


def _setup_readline():
    """Line editing and history through readline, when the platform has it."""
    try:
        import readline
    except ImportError:
        return None
    try:
        readline.read_history_file(HISTORY_FILE)
    except OSError:
        pass  # first run: no history yet
    readline.set_history_length(HISTORY_LENGTH)
    return readline


@contextlib.contextmanager
def ctrl_c_stops(printer: Printer):
    """While a command runs, Ctrl-C is the console's emergency stop: the steppers stop at the next
    sample, the command and the rest of the line fail with the shutdown message, the printer is
    shut down until RESTART. A second Ctrl-C interrupts what is not motion (a long template)."""
    if threading.current_thread() is not threading.main_thread():
        yield  # signals reach only the main thread
        return

    def stop(signum, frame):
        if printer.state == "shutdown":
            raise KeyboardInterrupt
        printer.request_emergency_stop(CONSOLE_STOP_REASON)

    previous = signal.signal(signal.SIGINT, stop)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
        printer.finish_shutdown()


def console_loop(printer: Printer, read_line=input) -> None:
    """Read commands until EOF or 'exit'/'quit'; every response is printed by the printer's sink."""
    while True:
        try:
            line = read_line(PROMPT)
        except EOFError:
            print()
            return
        except KeyboardInterrupt:
            print()
            continue
        if line.strip().lower() in ("exit", "quit"):
            return
        try:
            with ctrl_c_stops(printer):
                printer.gcode.run_script_reporting_errors(line)
        except KeyboardInterrupt:
            # Ctrl-C stops a long command (e.g. a 10 s diagnostic), not the console.
            print("!! Interrupted", flush=True)


def _main_console(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="tapcell console", description="Interactive G-code console on the "
                                     "virtual printer (HELP lists the commands, exit or Ctrl-D quits).")
    parser.add_argument("--config", default=str(DEFAULT_CONFIG),
                        help="printer config (default: %(default)s); a file git tracks is never rewritten: the "
                             "console works on a copy in your folder (TAPCELL_HOME, else ~/.config/tapcell)")
    parser.add_argument("--scenario", metavar="NAME", help="the virtual printer's world, written into the config "
                        "worked on ([virtual_printer] scenario; 'tapcell scenarios' lists them)")
    parser.add_argument("--fresh", action="store_true", help="start your copy again from the tracked config")
    args = parser.parse_args(argv)
    if not os.path.exists(args.config):
        print(f"tapcell console: config file '{args.config}' {why_missing(args.config)}", file=sys.stderr)
        return 1
    config_path, where = working_config(Path(args.config), fresh=args.fresh)
    if args.scenario:
        try:
            set_scenario(config_path, args.scenario)
        except ScenarioError as exc:
            print(f"tapcell console: --scenario: {exc}", file=sys.stderr)
            return 2
        except ConfigError as exc:  # the file could not be rewritten (left as it was)
            print(f"tapcell console: --scenario: {exc}", file=sys.stderr)
            return 1
        where += f"; scenario {args.scenario}"
    print(f"// {where}", flush=True)
    printer = _build_printer(str(config_path), "tapcell console")
    if printer is None:
        return 1
    print(f"// {printer.state_summary()}. Type HELP for the commands, exit to quit.", flush=True)
    read_line, finish = _console_reader(printer, interactive=sys.stdin.isatty())
    try:
        console_loop(printer, read_line)
    finally:
        finish()
    return 0


def _console_reader(printer: Printer, *, interactive: bool):
    """(read_line, finish) for the console. Every line is checked before it runs (a misspelt
    parameter holds it back: `tapcell.tools.console_ui`). On a terminal: prompt_toolkit's editing,
    history and TAB completion, colours and the progress line; readline where prompt_toolkit is
    not installed (it comes with the [tools] extra)."""
    from tapcell.tools import console_ui

    if not interactive:
        return console_ui.LineChecker(printer.gcode, input, _print_line), lambda: None
    terminal = console_ui.TerminalConsole(printer)
    try:
        return terminal.reader(console_ui.prompt_reader(printer.gcode, CONSOLE_HISTORY_FILE)), lambda: None
    except ImportError:
        pass
    readline = _setup_readline()

    def finish() -> None:
        if readline is not None:
            try:
                readline.write_history_file(HISTORY_FILE)
            except OSError as exc:
                print(f"tapcell console: could not save history to {HISTORY_FILE}: {exc}", file=sys.stderr)

    return terminal.reader(input), finish


def main(argv: list[str]) -> int:
    """argv[0] is the subcommand ('console' or 'run'), the rest its arguments."""
    if not argv or argv[0] not in SUBCOMMANDS:
        print(f"tapcell frontend: expected one of {', '.join(SUBCOMMANDS)}", file=sys.stderr)
        return 2
    if argv[0] == "run":
        return _main_run(argv[1:])
    return _main_console(argv[1:])
