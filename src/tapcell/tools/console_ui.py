"""What `tapcell console` adds on a terminal, beside the plain loop in `tapcell.tools.frontend`:

- TAB completion of command names, their parameters and the values a command's help lists
  (`METHOD=tap|two_pass|prusa`), with line editing and history (prompt_toolkit);
- errors in red and warnings in yellow, where the terminal shows colours (not with NO_COLOR,
  TERM=dumb or output to a file or pipe);
- a progress line on stderr while a mesh or PROBE_ACCURACY runs: points done and the time
  left, wiped before each response line;
- a check before a line runs: a parameter that looks like a misspelt one the command knows
  (`METOD=` for `METHOD=`) is named and the line is not run; the same line sent again runs as is.

Each piece is plain and testable without a terminal: the completer works on prompt_toolkit
Documents, the line check on text, the progress line on any stream with any clock.
"""

from __future__ import annotations

import difflib
import os
import re
import sys
import time
from typing import Callable, Iterable, TextIO

from tapcell.host.gcode import GCodeError, parse_line
from tapcell.tools.progress import InPlaceLine

PARAMETER_IN_HELP = re.compile(r"\b([A-Z][A-Z0-9_]*)=([A-Za-z0-9_.|]*)")
# A misspelling is this close to a known name (difflib's ratio): METOD/METHOD 0.91, SAMPLS/SAMPLES 0.92,
# while real parameters of one command stay apart (SAMPLES/SAMPLE_RETRACT_DIST 0.46).
MISSPELT_RATIO = 0.8
REDRAW_EVERY_S = 0.1
RED, YELLOW, RESET = "\033[31m", "\033[33m", "\033[0m"


# -- what a command takes -----------------------------------------------------------------------

def help_parameters(help_text: str) -> dict[str, tuple[str, ...]]:
    """The NAME= parameters a help text shows, each with the values it lists as a|b|c (else none)."""
    found: dict[str, tuple[str, ...]] = {}
    for name, values in PARAMETER_IN_HELP.findall(help_text):
        choices = tuple(v for v in values.split("|") if v) if "|" in values else ()
        found[name] = tuple(dict.fromkeys(found.get(name, ()) + choices))
    return found


def known_parameters(gcode, command: str) -> dict[str, tuple[str, ...]]:
    """A command's parameters: those its help shows, and those it has read in this session."""
    known = help_parameters(gcode.get_command_help().get(command, ""))
    for name in gcode.known_parameters(command):
        known.setdefault(name, ())
    return known


def misspelt_parameter(gcode, line: str) -> str | None:
    """The warning for a line whose parameter looks like a misspelt known one, else None.

    Only names close to a known parameter count: a command reads some parameters only on some
    paths, so an unknown name alone is left to the dispatcher's warning after the run."""
    try:
        parsed = parse_line(line)
    except GCodeError:
        return None  # the dispatcher says what is wrong with the line
    if parsed is None or parsed.command not in gcode.get_command_help():
        return None
    known = known_parameters(gcode, parsed.command)
    for name in parsed.params:
        if name in known or len(name) == 1:  # classic G-code letters are the command's own business
            continue
        close = difflib.get_close_matches(name, sorted(known), n=1, cutoff=MISSPELT_RATIO)
        if close:
            return (f"{parsed.command}: unknown parameter {name} (did you mean {close[0]}?): not run; "
                    "send the line again to run it as it is")
    return None


class LineChecker:
    """Reads lines through `read_line`, holding back a line `misspelt_parameter` warns about
    unless it is sent again right away."""

    def __init__(self, gcode, read_line: Callable[[str], str], say: Callable[[str], None]):
        self.gcode = gcode
        self.read_line = read_line
        self.say = say
        self._held: str | None = None

    def __call__(self, prompt: str) -> str:
        while True:
            line = self.read_line(prompt)
            if line == self._held:
                self._held = None
                return line
            warning = misspelt_parameter(self.gcode, line)
            if warning is None:
                self._held = None
                return line
            self._held = line
            self.say(f"!! {warning}")


# -- TAB completion -----------------------------------------------------------------------------

def completions(gcode, text_before_cursor: str) -> list[tuple[str, int]]:
    """(completion, start position relative to the cursor) for the text typed so far: command
    names for the first word, then the command's NAME= parameters, then a parameter's values."""
    words = text_before_cursor.split(" ")
    word = words[-1]
    if len(words) == 1:
        prefix = word.upper()
        return [(name, -len(word)) for name in sorted(gcode.get_command_help()) if name.startswith(prefix)]
    command = words[0].upper()
    known = known_parameters(gcode, command)
    if "=" in word:
        name, _, typed = word.partition("=")
        return [(value, -len(typed)) for value in known.get(name.upper(), ()) if value.startswith(typed)]
    used = {w.partition("=")[0].upper() for w in words[1:-1]}
    prefix = word.upper()
    return [(f"{name}=", -len(word)) for name in sorted(known) if name.startswith(prefix) and name not in used]


def make_completer(gcode):
    """A prompt_toolkit Completer over `completions`."""
    from prompt_toolkit.completion import Completer, Completion

    class GCodeCompleter(Completer):
        def get_completions(self, document, complete_event) -> Iterable[Completion]:
            for text, start in completions(gcode, document.text_before_cursor):
                yield Completion(text, start_position=start)

    return GCodeCompleter()


def prompt_reader(gcode, history_file, *, input=None, output=None) -> Callable[[str], str]:
    """read_line(prompt) through prompt_toolkit: editing, history in `history_file`, TAB completion."""
    from prompt_toolkit import PromptSession
    from prompt_toolkit.history import FileHistory, InMemoryHistory

    history = FileHistory(str(history_file)) if history_file is not None else InMemoryHistory()
    session = PromptSession(history=history, completer=make_completer(gcode), complete_while_typing=False,
                            input=input, output=output)
    return session.prompt


# -- colours ------------------------------------------------------------------------------------

def shows_colours(stream: TextIO) -> bool:
    """Whether to colour lines on `stream` (https://no-color.org, a dumb terminal, a file)."""
    if os.environ.get("NO_COLOR") or os.environ.get("TERM") == "dumb":
        return False
    return hasattr(stream, "isatty") and stream.isatty()


def coloured(line: str) -> str:
    """A response line with its colour: errors red, warnings yellow, the rest as is."""
    if line.startswith("!!"):
        return f"{RED}{line}{RESET}"
    if line.startswith("// Warning") or line.startswith("// WARNING"):
        return f"{YELLOW}{line}{RESET}"
    return line


# -- the progress line --------------------------------------------------------------------------

ACCURACY_START = re.compile(r"^// PROBE_ACCURACY at .*\(samples=(\d+) ")
ACCURACY_POINT = re.compile(r"^// probe at ")
ACCURACY_END = re.compile(r"^// probe accuracy results:")


def progress_text(what: str, done: int, total: int, elapsed_s: float) -> str:
    """`probing 12/49 points, about 20 s left` (the rate so far; no estimate before a point is done)."""
    text = f"{what} {done}/{total} points"
    if 0 < done < total:
        text += f", about {elapsed_s / done * (total - done):.0f} s left"
    return text


class ProgressLine:
    """One line on `stream`, rewritten in place, while a mesh (bed_mesh progress events) or
    PROBE_ACCURACY (its response lines) runs."""

    def __init__(self, stream: TextIO = sys.stderr, clock: Callable[[], float] = time.monotonic):
        self.clock = clock
        self._line = InPlaceLine(stream)
        self._what = ""
        self._started_s = 0.0
        self._total = 0
        self._done = 0
        self._last_draw_s = -float("inf")

    def start(self, what: str, total: int) -> None:
        self._what, self._total, self._done, self._started_s = what, total, 0, self.clock()
        self._draw(force=True)

    def advance(self, done: int, total: int | None = None) -> None:
        if total is not None and (not self._what or total != self._total):
            self.start("mesh", total)
        self._done = done
        if self._done >= self._total:
            self.stop()
        else:
            self._draw()

    def stop(self) -> None:
        self.clear()
        self._what = ""

    def on_mesh_progress(self, done: int, total: int) -> None:
        self.advance(done, total)

    def on_response(self, line: str) -> None:
        """Follow PROBE_ACCURACY through its lines (it sends no progress events)."""
        started = ACCURACY_START.match(line)
        if started:
            self.start("PROBE_ACCURACY", int(started.group(1)))
        elif self._what == "PROBE_ACCURACY" and ACCURACY_POINT.match(line):
            self.advance(self._done + 1)
        elif ACCURACY_END.match(line):
            self.stop()

    def _draw(self, force: bool = False) -> None:
        now = self.clock()
        if not self._what or (not force and now - self._last_draw_s < REDRAW_EVERY_S):
            return
        self._last_draw_s = now
        self._line.show(f"  {progress_text(self._what, self._done, self._total, now - self._started_s)}")

    def clear(self) -> None:
        """Wipe the line (before a response line is printed)."""
        self._line.wipe()

    def redraw(self) -> None:
        """Draw the line again after a response was printed."""
        self._draw(force=True)


# -- putting it together ------------------------------------------------------------------------

class TerminalConsole:
    """The console's response sink and reader on a terminal: colours, progress, completion, checks."""

    def __init__(self, printer, *, out: TextIO = sys.stdout, progress_stream: TextIO = sys.stderr,
                 colours: bool | None = None, clock: Callable[[], float] = time.monotonic):
        self.printer = printer
        self.out = out
        self.colours = shows_colours(out) if colours is None else colours
        self.progress = ProgressLine(progress_stream, clock)
        self._bed_mesh = None
        printer.gcode.set_response_sink(self.show)
        self.follow_the_mesh()

    def follow_the_mesh(self) -> None:
        """Listen to the mesh's progress (again after a RESTART rebuilt the printer)."""
        from tapcell.extras.bed_mesh import PROGRESS_EVENT

        bed_mesh = self.printer.lookup_object("bed_mesh", None)
        if bed_mesh is not None and bed_mesh is not self._bed_mesh:
            self.printer.register_event_handler(PROGRESS_EVENT, self.progress.on_mesh_progress)
        self._bed_mesh = bed_mesh

    def show(self, line: str) -> None:
        self.progress.clear()
        print(coloured(line) if self.colours else line, file=self.out, flush=True)
        self.progress.on_response(line)
        self.progress.redraw()

    def reader(self, read_line: Callable[[str], str]) -> Callable[[str], str]:
        """`read_line` with the line check, re-following the mesh before each line."""
        checker = LineChecker(self.printer.gcode, read_line, self.show)

        def read(prompt: str) -> str:
            self.progress.stop()
            self.follow_the_mesh()
            return checker(prompt)

        return read
