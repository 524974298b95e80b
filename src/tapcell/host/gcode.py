"""The G-code layer: parsing, the command registry, typed parameters, responses.

Two kinds of lines are understood, as in Klipper:

* classic commands, a letter and a number followed by letter+number
  parameters: `G1 Z5 F300`, `M104 S140`, `G1X10Y20`;
* extended commands, a name followed by `KEY=value` parameters:
  `LOAD_CELL_CALIBRATE`, `CALIBRATE GRAMS=500`, `RESPOND MSG="two words"`.

Command names and parameter names are case-insensitive (stored upper case);
values keep their case.  `;` starts a comment (outside quotes), `N123` line
numbers and `*71` checksums are dropped, blank lines do nothing.

Handlers get a `GCodeCommand` and read typed parameters from it; a bad or
missing parameter raises `GCodeError` naming the parameter, e.g.
`Error on 'CALIBRATE GRAMS=10': GRAMS must have minimum of 50`.
Responses go to a sink (a list or a callable) one line at a time:
`// text` for information, `!! text` for errors.
"""

from __future__ import annotations

import difflib
import math
import re
from dataclasses import dataclass, field
from collections.abc import Sequence
from typing import Any, Callable

from tapcell.host.backend import DeviceError, EmergencyStopError
from tapcell.host.config import GCODE_WORDS, ConfigError, check_range, require_range, underflow_problem


class GCodeError(Exception):
    """A command failed; the message is what the user sees after `!! `."""


class UnknownCommandError(GCodeError):
    """No handler for the command. Klipper answers `// Unknown command:"M205"` and goes on with a
    print file or a macro; the console and scripts stop on it (a typo must not pass for success)."""

    def __init__(self, command: str):
        super().__init__(f'Unknown command:"{command}"')
        self.command = command


class ShutdownError(GCodeError):
    """The printer was shut down (an emergency stop) while the command ran: it and the rest of its
    script end with the shutdown message, as Klipper's do."""


class _Required:
    def __repr__(self) -> str:
        return "REQUIRED"


REQUIRED: Any = _Required()

# Commands may run commands (macros, probe templates); a chain this deep is a mistake.
MAX_NESTING = 32

Handler = Callable[["GCodeCommand"], None]
ResponseSink = Callable[[str], None] | list


# ---------------------------------------------------------------------------
# Parsing (pure functions)


@dataclass(frozen=True)
class ParsedLine:
    """One G-code line, parsed: `command` and `params` are upper-case names."""

    command: str
    params: dict[str, str]
    commandline: str  # the line without comment, line number and checksum
    rawparams: str  # everything after the command name, as typed


# Classic commands whose parameters are free text (`M117 Printing 20%`), as in Klipper.
RAW_TEXT_COMMANDS = ("M117", "M118")
# Turning off a heater or fan the printer does not have is not worth a warning (Klipper's rule):
# when nothing registered these commands, they do nothing if their S (this default when absent) is 0.
SILENT_WHEN_ABSENT = {"M104": "0", "M140": "0", "M106": "1", "M107": "0"}
# Kalico's spelling of a parameter where it differs from tapcell's: (command, Kalico's name) -> ours.
KALICO_SPELLINGS: dict[tuple[str, str], str] = {
    ("LOAD_CELL_TEST_TAP", "TAPS"): "COUNT",
}

_CLASSIC_RE = re.compile(r"^([A-Za-z])\s*(\d+(?:\.\d+)?)")
_LINE_NUMBER_RE = re.compile(r"^[Nn]\d+\s*")
_CHECKSUM_RE = re.compile(r"\*\d+\s*$")
_EXTENDED_PARAM_RE = re.compile(r"""([^\s=]+)=("[^"]*"|'[^']*'|[^\s"']*)(?=\s|$)""")


def strip_comment(line: str) -> str:
    """Drop a `;` comment unless the `;` is inside quotes."""
    quote = None
    for index, char in enumerate(line):
        if quote:
            if char == quote:
                quote = None
        elif char in "\"'":
            quote = char
        elif char == ";":
            return line[:index]
    return line


def parse_line(line: str) -> ParsedLine | None:
    """Parse one line; None for a blank or comment-only line.  Raises GCodeError if malformed."""
    text = strip_comment(line).strip()
    text = _CHECKSUM_RE.sub("", text)
    text = _LINE_NUMBER_RE.sub("", text).strip()
    if not text:
        return None
    classic = _CLASSIC_RE.match(text)
    tail = text[classic.end():] if classic else ""
    # `G1 Z5` and `G1Z5` are classic; `A1_THING` is an extended command name.
    if classic and (not tail or tail[0].isspace() or tail[0].isalpha()):
        number = classic.group(2)
        # G01 and G1 are the same command.
        integer, _, fraction = number.partition(".")
        number = str(int(integer)) + (f".{fraction}" if fraction else "")
        command = classic.group(1).upper() + number
        rawparams = text[classic.end():].strip()
        if command in RAW_TEXT_COMMANDS:
            return ParsedLine(command, {}, text, rawparams)
        return ParsedLine(command, _parse_classic_params(rawparams, text), text, rawparams)
    name, _, rawparams = text.partition(" ")
    rawparams = rawparams.strip()
    return ParsedLine(name.upper(), _parse_extended_params(rawparams, text), text, rawparams)


def _parse_classic_params(rawparams: str, commandline: str) -> dict[str, str]:
    params: dict[str, str] = {}
    for match in re.finditer(r"\s*(\S)([^\sA-Za-z]*)", rawparams):
        letter, value = match.group(1), match.group(2)
        if not letter.isalpha():
            raise GCodeError(f"Malformed command '{commandline}': expected a letter and a number, "
                             f"got {match.group(0).strip()!r}")
        params[letter.upper()] = value
    return params


def _parse_extended_params(rawparams: str, commandline: str) -> dict[str, str]:
    params: dict[str, str] = {}
    position = 0
    while position < len(rawparams):
        if rawparams[position].isspace():
            position += 1
            continue
        match = _EXTENDED_PARAM_RE.match(rawparams, position)
        if match is None:
            word = rawparams[position:].split()[0]
            if word.count('"') % 2 or word.count("'") % 2:
                problem = "a quoted value is not closed"
            else:
                problem = f"expected NAME=VALUE, got {word!r}"
            raise GCodeError(f"Malformed command '{commandline}': {problem}")
        key, value = match.group(1), match.group(2)
        if len(value) >= 2 and value[0] == value[-1] and value[0] in "\"'":
            value = value[1:-1]
        params[key.upper()] = value
        position = match.end()
    return params


# ---------------------------------------------------------------------------
# A command being run


class GCodeCommand:
    """What a handler receives: the command, its parameters and a way to answer."""

    def __init__(self, dispatch: GCodeDispatch, parsed: ParsedLine):
        self._dispatch = dispatch
        self.command = parsed.command
        self.commandline = parsed.commandline
        self.rawparams = parsed.rawparams
        self._params = _with_our_spellings(parsed)
        self._read: set[str] = set()  # parameters the handler asked for (the others are unknown to it)

    def get_commandline(self) -> str:
        return self.commandline

    def get_command_parameters(self) -> dict[str, str]:
        """All parameters, upper-case names to their text (the handler takes them all)."""
        self._read.update(self._params)
        return dict(self._params)

    def has(self, name: str) -> bool:
        self._read.add(name.upper())
        return name.upper() in self._params

    def read_parameters(self) -> list[str]:
        """Parameters the handler asked for so far (given or not): the ones it knows."""
        return sorted(self._read)

    def unread_parameters(self) -> list[str]:
        """Parameters given but never asked for: the command does not know them."""
        return [name for name in self._params if name not in self._read]

    def error(self, message: str) -> GCodeError:
        return GCodeError(message)

    def param_error(self, problem: str) -> GCodeError:
        """The error for a bad or missing parameter: `Error on '<the command line>': <problem>`."""
        return GCodeError(f"Error on '{self.commandline}': {problem}")

    def get(self, name: str, default: Any = REQUIRED) -> Any:
        """The parameter's text, `default` when absent (absent and no default: error)."""
        self._read.add(name.upper())
        value = self._params.get(name.upper())
        if value is None:
            if default is REQUIRED:
                raise self.param_error(f"missing {name.upper()}")
            return default
        return value

    def get_int(self, name: str, default: Any = REQUIRED, *, minval: int | None = None,
                maxval: int | None = None) -> Any:
        """An integer parameter within the declared range (every numeric parameter must declare one)."""
        return self._get_numbers(name, default, int, "an integer", (minval, maxval, None, None))

    def get_float(self, name: str, default: Any = REQUIRED, *, minval: float | None = None,
                  maxval: float | None = None, above: float | None = None, below: float | None = None) -> Any:
        """A finite number parameter within the declared range."""
        return self._get_numbers(name, default, _finite_float, "a number", (minval, maxval, above, below))

    def get_intlist(self, name: str, default: Any = REQUIRED, *, count: int | None = None,
                    minval: int | None = None, maxval: int | None = None) -> Any:
        """Comma-separated integers, each within the declared range (`count`: exactly that many)."""
        return self._get_numbers(name, default, int, "integers", (minval, maxval, None, None), many=True, count=count)

    def get_floatlist(self, name: str, default: Any = REQUIRED, *, count: int | None = None,
                      minval: float | None = None, maxval: float | None = None, above: float | None = None,
                      below: float | None = None) -> Any:
        """Comma-separated finite numbers, each within the declared range."""
        return self._get_numbers(name, default, _finite_float, "numbers", (minval, maxval, above, below),
                                 many=True, count=count)

    def _get_numbers(self, name, default, parse, kind, limits, *, many=False, count=None):
        """One number, or with `many` a comma-separated list (of `count` items if given), range-checked."""
        name = name.upper()
        require_range(f"{self.command} {name}", *limits)
        self._read.add(name)
        text = self._params.get(name)
        if text is None:
            return self.get(name, default)  # the default, or the "missing" error
        if not many:
            return self._parse_checked(name, text, parse, f"unable to parse '{text}' for {name} (expected {kind})",
                                       limits)
        items = [item.strip() for item in text.split(",")]
        if count is not None and len(items) != count:
            raise self.param_error(f"{name} needs exactly {count} comma-separated {kind}, got {len(items)}")
        return [self._parse_checked(name, item, parse,
                                    f"unable to parse '{item}' in {name} (expected comma-separated {kind})", limits)
                for item in items]

    def _parse_checked(self, name, text, parse, unparsable, limits):
        try:
            value = parse(text)
        except _Underflow as exc:
            raise self.param_error(f"{name} {exc}") from None
        except ValueError:
            raise self.param_error(unparsable) from None
        problem = check_range(value, *limits, words=GCODE_WORDS)
        if problem:
            raise self.param_error(f"{name} {problem}")
        return value

    def get_choice(self, name: str, choices: Sequence[str], default: Any = REQUIRED) -> Any:
        """One of `choices`, compared case-insensitively and returned as `choices` spells it."""
        text = self.get(name, None)
        if text is None:
            return self.get(name, default)  # the default, or the missing-parameter error
        chosen = {choice.lower(): choice for choice in choices}.get(text.strip().lower())
        if chosen is None:
            raise self.param_error(f"{name.upper()} must be one of {', '.join(choices)}, not '{text.strip()}'")
        return chosen

    def respond_info(self, message: str) -> None:
        self._dispatch.respond_info(message)

    def respond_raw(self, message: str) -> None:
        self._dispatch.respond_raw(message)


def _is_zero(text: str) -> bool:
    try:
        return float(text) == 0.0
    except ValueError:
        return False


def _with_our_spellings(parsed: ParsedLine) -> dict[str, str]:
    """The parameters with Kalico's spellings renamed to ours (both given: an error)."""
    params = dict(parsed.params)
    for (command, kalico_name), our_name in KALICO_SPELLINGS.items():
        if command != parsed.command or kalico_name not in params:
            continue
        if our_name in params:
            raise GCodeError(f"Error on '{parsed.commandline}': {kalico_name} (Kalico's name) and {our_name} "
                             f"are the same parameter; give one")
        params[our_name] = params.pop(kalico_name)
    return params


class _Underflow(ValueError):
    """A number written as non-zero that reads as 0 (its text says why)."""


def _finite_float(text: str) -> float:
    value = float(text)
    if not math.isfinite(value):
        raise ValueError(text)
    problem = underflow_problem(text, value)
    if problem:
        raise _Underflow(problem)
    return value


# ---------------------------------------------------------------------------
# The dispatcher


@dataclass
class _Mux:
    key: str
    handlers: dict[str | None, Handler] = field(default_factory=dict)


class GCodeDispatch:
    """The command registry and the place every response goes through."""

    def __init__(self, responses: ResponseSink | None = None):
        self._responses: ResponseSink | None = responses
        self._handlers: dict[str, Handler] = {}
        self._help: dict[str, str] = {}
        self._mux: dict[str, _Mux] = {}
        # After a shutdown: (commands still allowed, the message every other command gets).
        self._refusal: tuple[tuple[str, ...], str] | None = None
        # Parameters each command has asked for so far, to suggest a spelling for an unknown one.
        self._known_parameters: dict[str, set[str]] = {}
        self._running: list[str] = []  # the commands running now, outermost first
        self._running_commands: list[GCodeCommand] = []  # the same, as commands (callers that are not commands left out)
        # Told when the machine fails under a command; each returns what the user must know more.
        self._device_error_listeners: list[Callable[[DeviceError], str]] = []
        # Unknown commands a macro skipped ("PRINT_START: Z_TILT_ADJUST"), for `tapcell run`'s summary.
        self.skipped_in_macros: list[str] = []
        self._register_builtins()

    # -- responses -----------------------------------------------------------

    def set_response_sink(self, responses: ResponseSink | None) -> None:
        """Where response lines go: a list (appended to) or a callable (called per line)."""
        self._responses = responses

    def _emit(self, line: str) -> None:
        if self._responses is None:
            return
        if isinstance(self._responses, list):
            self._responses.append(line)
        else:
            self._responses(line)

    def respond_raw(self, message: str) -> None:
        for line in str(message).split("\n"):
            self._emit(line)

    def respond_info(self, message: str) -> None:
        for line in str(message).split("\n"):
            self._emit(f"// {line}")

    def respond_error(self, message: str) -> None:
        for line in str(message).split("\n"):
            self._emit(f"!! {line}")

    # -- registration --------------------------------------------------------

    def clear_commands(self) -> None:
        """Forget every command except the built-in HELP (used by RESTART)."""
        self._handlers.clear()
        self._help.clear()
        self._mux.clear()
        self._register_builtins()

    def _register_builtins(self) -> None:
        self.register_command("HELP", self._cmd_help, desc="List the available commands with their help text")

    def on_device_error(self, listener: Callable[[DeviceError], str]) -> None:
        """Call `listener(error)` when the machine fails under any command (e.g. its MCU resets);
        the text it returns is added to the command's error message."""
        self._device_error_listeners.append(listener)

    def set_refusal(self, allowed: tuple[str, ...] | None, message: str = "") -> None:
        """Refuse every command but `allowed` with `message` (a halted printer); None lifts it."""
        self._refusal = None if allowed is None else (allowed, message)

    def is_registered(self, name: str) -> bool:
        return name.upper() in self._handlers

    def register_command(self, name: str, handler: Handler, desc: str | None = None) -> None:
        """Add a command; registering a name twice is an error (unregister first)."""
        name = name.upper()
        if name in self._handlers:
            raise GCodeError(f"Command '{name}' is already registered")
        self._handlers[name] = handler
        if desc:
            self._help[name] = desc

    def replace_command(self, name: str, handler: Handler, desc: str | None = None) -> Handler:
        """Put `handler` in place of a registered command; returns the handler it replaced
        (so [safe_z_home] can wrap G28 and call the original for the actual homing)."""
        name = name.upper()
        if name not in self._handlers:
            raise GCodeError(f"Command '{name}' is not registered, so it cannot be replaced")
        previous = self._handlers[name]
        self._handlers[name] = handler
        if desc:
            self._help[name] = desc
        return previous

    def rename_command(self, name: str, new_name: str) -> None:
        """Move a command to another name (a macro's `rename_existing`), with its help text."""
        name, new_name = name.upper(), new_name.upper()
        if name not in self._handlers:
            raise GCodeError(f"Existing command '{name}' not found in gcode_macro rename")
        if new_name in self._handlers:
            raise GCodeError(f"Command '{new_name}' is already registered")
        self._handlers[new_name] = self._handlers.pop(name)
        self._help[new_name] = self._help.pop(name, f"Renamed builtin of '{name}'")
        if name in self._mux:
            self._mux[new_name] = self._mux.pop(name)

    def unregister_command(self, name: str) -> None:
        """Remove a command (e.g. the temporary TARE/ACCEPT of a calibration)."""
        name = name.upper()
        self._handlers.pop(name, None)
        self._help.pop(name, None)
        self._mux.pop(name, None)

    def register_mux_command(self, cmd: str, key: str, value: str | None, handler: Handler,
                             desc: str | None = None) -> None:
        """Register `cmd` for `KEY=value`; value None is the default when KEY is omitted."""
        cmd, key = cmd.upper(), key.upper()
        mux = self._mux.get(cmd)
        if mux is None:
            if cmd in self._handlers:
                raise GCodeError(f"Command '{cmd}' is already registered")
            mux = self._mux[cmd] = _Mux(key)
            self._handlers[cmd] = lambda gcmd, cmd=cmd: self._run_mux(cmd, gcmd)
            if desc:
                self._help[cmd] = desc
        if mux.key != key:
            raise GCodeError(f"Command '{cmd}' is already selected by {mux.key}=, not {key}=")
        if value in mux.handlers:
            shown = f"{key}={value}" if value is not None else f"without {key}="
            raise GCodeError(f"Command '{cmd}' {shown} is already registered")
        mux.handlers[value] = handler

    def _run_mux(self, cmd: str, gcmd: GCodeCommand) -> None:
        mux = self._mux[cmd]
        value = gcmd.get(mux.key, None)
        handler = mux.handlers.get(value)
        if handler is None:
            named = sorted(v for v in mux.handlers if v is not None)
            if value is None:
                raise gcmd.param_error(f"missing {mux.key} "
                                       f"(one of: {', '.join(named)})")
            raise gcmd.param_error(f"the value '{value}' is not valid for "
                                   f"{mux.key} (one of: {', '.join(named)})")
        handler(gcmd)

    def get_command_help(self) -> dict[str, str]:
        return dict(self._help)

    def known_parameters(self, command: str) -> set[str]:
        """The parameters `command` has read so far in this session (what the unknown-parameter
        warning counts as known)."""
        return set(self._known_parameters.get(command, ()))

    # -- running -------------------------------------------------------------

    def run_script(self, text: str, caller: str | None = None) -> None:
        """Run each line of `text`; the first failure raises GCodeError (the rest is not run).

        `caller` names what runs the script when it is not a command (e.g. a probe's
        nozzle_scrubber_gcode); it shows in the chain of a recursion error.
        """
        if caller is not None:
            self._running.append(caller)
        try:
            for line in text.split("\n"):
                self.run_line(line)
        finally:
            if caller is not None:
                self._running.pop()

    def run_macro_script(self, text: str, macro: str) -> None:
        """Run a macro's rendered lines as Klipper does: an unknown command is answered with
        `// Unknown command:"X" in macro NAME, skipped` and the next line runs (the rest of a
        PRINT_START must not vanish over one command the printer lacks); it is remembered in
        `skipped_in_macros`. Any other failure raises GCodeError as in run_script."""
        for line in text.split("\n"):
            try:
                self.run_line(line)
            except UnknownCommandError as exc:
                parsed = parse_line(line)
                if parsed is None or parsed.command != exc.command:  # raised further in (a probe template)
                    raise
                self.skipped_in_macros.append(f"{macro}: {exc.command}")
                self.respond_info(f"{exc} in macro {macro}, skipped")

    def run_line(self, line: str) -> None:
        """Run one line.  A user error raises GCodeError; any other exception is a bug and propagates."""
        parsed = parse_line(line)
        if parsed is None:
            return
        if self._refusal is not None and parsed.command not in self._refusal[0]:
            raise GCodeError(self._refusal[1])
        handler = self._handlers.get(parsed.command)
        if handler is None:
            if parsed.command in SILENT_WHEN_ABSENT and _is_zero(
                    parsed.params.get("S", SILENT_WHEN_ABSENT[parsed.command])):
                return
            raise UnknownCommandError(parsed.command)
        self._check_nesting(parsed.command)
        gcmd = GCodeCommand(self, parsed)
        self._running.append(parsed.command)
        self._running_commands.append(gcmd)
        try:
            handler(gcmd)
        except ConfigError as exc:  # e.g. SAVE_CONFIG unable to write the file
            raise GCodeError(str(exc)) from exc
        except EmergencyStopError as exc:  # the machine halted under the command: say why, as Klipper does
            raise ShutdownError(self._refusal[1] if self._refusal is not None else str(exc)) from exc
        except DeviceError as exc:  # the machine failed under the command: the user's to know, not a bug
            more = "".join(listener(exc) for listener in self._device_error_listeners)
            raise GCodeError(f"MCU error on '{parsed.commandline}': {exc}{more}") from exc
        finally:
            self._running.pop()
            self._running_commands.pop()
            self._warn_unknown_parameters(gcmd)

    def running_command(self) -> str | None:
        """The command running now, quoted: the innermost line, and the outermost when they
        differ (`'G1 Z-1.5' in 'PROBE'`), for errors that name the command that did it."""
        if not self._running_commands:
            return None
        inner, outer = self._running_commands[-1].commandline, self._running_commands[0].commandline
        return f"'{inner}'" if inner == outer else f"'{inner}' in '{outer}'"

    def innermost_command(self) -> GCodeCommand | None:
        """The command whose handler runs now (None outside any command)."""
        return self._running_commands[-1] if self._running_commands else None

    def _warn_unknown_parameters(self, gcmd: GCodeCommand) -> None:
        """One line per parameter the handler never asked for (a misspelt SAMPLE= silently did nothing)."""
        known = self._known_parameters.setdefault(gcmd.command, set())
        known.update(gcmd._read)
        # A name the command read in another call is known: this call ended before it got to it.
        for name in (name for name in gcmd.unread_parameters() if name not in known):
            close = difflib.get_close_matches(name, sorted(known), n=1)
            hint = f" (did you mean {close[0]}?)" if close else ""
            self.respond_info(f"{gcmd.command}: unknown parameter {name} ignored{hint}")

    def _check_nesting(self, command: str) -> None:
        """Refuse a command that runs inside itself (a macro or probe template calling it again)
        or a chain of commands nested too deep: either would never end."""
        if command in self._running:
            chain = " -> ".join((*self._running[self._running.index(command):], command))
            raise GCodeError(f"{command} called recursively ({chain})")
        if len(self._running) >= MAX_NESTING:
            raise GCodeError(f"{command}: G-code nested more than {MAX_NESTING} commands deep "
                             f"({' -> '.join(self._running[:3])} -> ...)")

    def run_script_reporting_errors(self, text: str) -> bool:
        """Run like a console: a failure becomes a `!! message` response.  True if all succeeded."""
        try:
            self.run_script(text)
        except GCodeError as exc:
            self.respond_error(str(exc))
            return False
        return True

    # -- built-ins -----------------------------------------------------------

    def _cmd_help(self, gcmd: GCodeCommand) -> None:
        lines = ["Available commands:"]
        lines += [f"{name}: {self._help[name]}" for name in sorted(self._help)]
        gcmd.respond_info("\n".join(lines))
