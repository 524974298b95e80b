"""Klipper-format config files: sections, includes, typed getters, SAVE_CONFIG.

A config file is a list of sections (`[printer]`, `[load_cell probe]`), each
with `key: value` or `key = value` options.  Indented lines continue the value
above them (G-code templates are written that way).  `#` and `;` start a
comment at the start of a line or after whitespace.  `[include pattern]` pulls
in other files (globs, relative to the including file).  The trailing `#*#`
block is what SAVE_CONFIG wrote; its values override the ones above it.

Modules read their options through `ConfigSection` getters.  Every read is
remembered, so that after loading `ConfigFile.check_unused_options()` can
reject options that nothing understood (usually a typo).

Every problem raises `ConfigError`, whose message names the file, section,
option, the value and what is allowed, e.g.
`printer.cfg: [load_cell_probe] trigger_force = 300: must be at most 250`.
"""

from __future__ import annotations

import glob
import math
import os
import re
import stat
import tempfile
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping, Sequence

from tapcell.files import FileRefused, read_limited


class ConfigError(Exception):
    """A problem with a config file, explained for the user who wrote it."""

    def __init__(self, message: str, *, file: str | None = None, section: str | None = None,
                 option: str | None = None, value: str | None = None):
        super().__init__(message)
        self.file = file
        self.section = section
        self.option = option
        self.value = value


class _Required:
    """Sentinel default: the option must be present."""

    def __repr__(self) -> str:
        return "REQUIRED"


REQUIRED: Any = _Required()

SAVE_CONFIG_MARKER = "#*# <---------------------- SAVE_CONFIG ---------------------->"
_SAVE_CONFIG_NOTE = "#*# # This block is rewritten by SAVE_CONFIG; its values override the ones above."
_AUTOSAVE_PREFIX = "#*#"

# Limits on what [include] can pull in: a chain of includes deeper than this is a mistake
# (real configs nest two or three levels), and the file count stops a diamond of includes
# (each file including the next one twice) from reading the same files millions of times.
MAX_INCLUDE_DEPTH = 20
MAX_CONFIG_FILES = 1000
# A printer.cfg with every macro and a few mesh profiles is well under 1 MB.
MAX_CONFIG_FILE_BYTES = 16 * 1024 * 1024

_TRUE_WORDS = ("true", "yes", "on", "1")
_FALSE_WORDS = ("false", "no", "off", "0")


@dataclass
class OptionValue:
    """One option as written: its text and where it came from."""

    text: str
    file: str
    line: int


@dataclass
class _Section:
    name: str
    file: str  # where the section header was first seen
    line: int
    options: dict[str, OptionValue] = field(default_factory=dict)


def format_number(number: float) -> str:
    """50.0 -> '50', 0.25 -> '0.25' (limits read naturally in messages)."""
    if isinstance(number, float) and number.is_integer() and abs(number) < 1e15:
        return str(int(number))
    return str(number)


def require_range(name: str, minval=None, maxval=None, above=None, below=None) -> None:
    """Every number has a range: a getter called without both ends of one is a programming error."""
    if (minval is None and above is None) or (maxval is None and below is None):
        raise TypeError(f"{name}: a numeric option or parameter must declare its range "
                        "(minval or above, and maxval or below)")


def describe_range(minval=None, maxval=None, above=None, below=None) -> str:
    """The allowed range in words: '10 to 250', 'above 0 and at most 50', 'at least 0 and below 1'."""
    if minval is not None and maxval is not None:
        return f"{format_number(minval)} to {format_number(maxval)}"
    parts = []
    if minval is not None:
        parts.append(f"at least {format_number(minval)}")
    if above is not None:
        parts.append(f"above {format_number(above)}")
    if maxval is not None:
        parts.append(f"at most {format_number(maxval)}")
    if below is not None:
        parts.append(f"below {format_number(below)}")
    return " and ".join(parts)


# How a violated bound is worded: config messages say 'must be at least 10', G-code
# messages keep Klipper's 'must have minimum of 10'.
CONFIG_WORDS = {"minval": "must be at least", "maxval": "must be at most", "above": "must be above",
                "below": "must be below"}
GCODE_WORDS = {**CONFIG_WORDS, "minval": "must have minimum of", "maxval": "must have maximum of"}


def check_range(value: float, minval=None, maxval=None, above=None, below=None,
                words: Mapping[str, str] = CONFIG_WORDS) -> str | None:
    """The problem with `value` against the limits ('must be at most 250 (allowed: 10 to 250)'), or None."""
    if minval is not None and value < minval:
        bound, limit = "minval", minval
    elif maxval is not None and value > maxval:
        bound, limit = "maxval", maxval
    elif above is not None and value <= above:
        bound, limit = "above", above
    elif below is not None and value >= below:
        bound, limit = "below", below
    else:
        return None
    return f"{words[bound]} {format_number(limit)} (allowed: {describe_range(minval, maxval, above, below)})"


# ---------------------------------------------------------------------------
# Parsing


def _strip_comment(line: str) -> str:
    """Drop a `#`/`;` comment: whole-line, or inline after whitespace."""
    stripped = line.lstrip()
    if stripped.startswith(("#", ";")):
        return ""
    for index, char in enumerate(line):
        if char in "#;" and index > 0 and line[index - 1].isspace():
            return line[:index].rstrip()
    return line.rstrip()


_SECTION_RE = re.compile(r"^\[([^\[\]]*)\]$")


class _Parser:
    """Reads a main file and its includes into an ordered dict of sections."""

    def __init__(self) -> None:
        self.sections: dict[str, _Section] = {}
        self.autosave_sections: dict[str, _Section] = {}
        self.files_read = 0

    def parse_file(self, path: str, include_stack: tuple[str, ...] = (), *, is_main: bool,
                   included_at: str | None = None) -> None:
        """Parse `path`; `included_at` ('printer.cfg:12') is where an [include] named it."""
        real = os.path.realpath(path)
        if real in include_stack:
            chain = " -> ".join(os.path.basename(p) for p in (*include_stack, real))
            raise ConfigError(f"{path}: include cycle: {chain}", file=path)
        if len(include_stack) > MAX_INCLUDE_DEPTH:
            raise ConfigError(f"{path}: includes are nested more than {MAX_INCLUDE_DEPTH} deep "
                              f"(included from {include_stack[-1]})", file=path)
        self.files_read += 1
        if self.files_read > MAX_CONFIG_FILES:
            raise ConfigError(f"{path}: more than {MAX_CONFIG_FILES} config files read through [include]",
                              file=path)
        text = read_config_text(path, included_at)
        body_lines, autosave_lines, autosave_start = split_autosave(text, path)
        self._parse_lines(body_lines, path, 1, (*include_stack, real), self.sections, allow_include=True)
        if autosave_lines:
            if not is_main:
                raise ConfigError(
                    f"{path}:{autosave_start}: a SAVE_CONFIG block is only allowed in the main config file",
                    file=path)
            self._parse_lines(autosave_lines, path, autosave_start, (), self.autosave_sections,
                              allow_include=False)

    def _parse_lines(self, lines: Sequence[str], path: str, first_line: int, include_stack: tuple[str, ...],
                     target: dict[str, _Section], *, allow_include: bool) -> None:
        section: _Section | None = None
        last_option: OptionValue | None = None
        for offset, raw in enumerate(lines):
            line_no = first_line + offset
            line = _strip_comment(raw)
            if not line.strip():
                continue  # blank lines do not end an indented value
            where = f"{path}:{line_no}"
            if raw[0].isspace():
                if last_option is None:
                    raise ConfigError(f"{where}: indented line {raw.strip()!r} does not continue an option",
                                      file=path, section=section.name if section else None)
                last_option.text = f"{last_option.text}\n{line.strip()}" if last_option.text else line.strip()
                continue
            header = _SECTION_RE.match(line)
            if header:
                name = " ".join(header.group(1).split())
                last_option = None
                if not name:
                    raise ConfigError(f"{where}: empty section name '[]'", file=path)
                if name.split()[0] == "include":
                    if not allow_include:
                        raise ConfigError(f"{where}: [{name}] is not allowed in the SAVE_CONFIG block", file=path)
                    section = None
                    self._include(name[len("include"):].strip(), path, where, include_stack)
                    continue
                section = target.get(name)
                if section is None:
                    section = target[name] = _Section(name, path, line_no)
                continue
            if line.startswith("["):
                raise ConfigError(f"{where}: malformed section header {line!r} (expected '[name]')", file=path)
            separator = min((i for i in (line.find(":"), line.find("=")) if i >= 0), default=-1)
            if separator <= 0:
                raise ConfigError(f"{where}: expected 'option: value' or 'option = value', got {line!r}",
                                  file=path, section=section.name if section else None)
            if section is None:
                raise ConfigError(f"{where}: option {line!r} is outside of any section", file=path)
            key = line[:separator].strip().lower()
            last_option = OptionValue(line[separator + 1:].strip(), path, line_no)
            section.options[key] = last_option

    def _include(self, pattern: str, path: str, where: str, include_stack: tuple[str, ...]) -> None:
        if not pattern:
            raise ConfigError(f"{where}: [include] needs a file name or glob, e.g. [include macros/*.cfg]",
                              file=path)
        full_pattern = os.path.join(os.path.dirname(path), pattern)
        matches = sorted(glob.glob(full_pattern))
        if not matches and not glob.has_magic(pattern):
            raise ConfigError(f"{where}: include file '{full_pattern}' does not exist", file=path)
        for match in matches:
            self.parse_file(match, include_stack, is_main=False, included_at=where)


def pin_mcu(pin: str) -> str:
    """The MCU a Klipper pin names: `toolboard:PB3` -> toolboard; a pin without a prefix (`^!PC0`)
    is on the main MCU, `mcu`."""
    name = pin.strip().lstrip("^~!").strip()
    return name.split(":", 1)[0].strip() if ":" in name else "mcu"


def read_config_text(path: str, included_at: str | None = None) -> str:
    """The file's text; a problem names the file (and the [include] that named it, if any)."""
    where = path if included_at is None else f"{included_at}: include file {path}"
    try:
        return read_limited(path, MAX_CONFIG_FILE_BYTES).decode("utf-8")
    except FileNotFoundError:
        raise ConfigError(f"{where}: config file does not exist", file=path) from None
    except FileRefused as exc:
        raise ConfigError(f"{where}: {exc}, not a config file", file=path) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{where}: unable to read config file: {exc}", file=path) from None


def split_autosave(text: str, path: str) -> tuple[list[str], list[str], int]:
    """Split file text into (body lines, SAVE_CONFIG lines without '#*#', first block line number)."""
    lines = text.splitlines()
    for index, line in enumerate(lines):
        if line.startswith(_AUTOSAVE_PREFIX) and "SAVE_CONFIG" in line:
            block = []
            for block_index in range(index + 1, len(lines)):
                block_line = lines[block_index]
                if not block_line.strip():
                    block.append("")
                    continue
                if not block_line.startswith(_AUTOSAVE_PREFIX):
                    raise ConfigError(
                        f"{path}:{block_index + 1}: line {block_line.strip()!r} comes after the SAVE_CONFIG "
                        f"block; the block must be the end of the file", file=path)
                content = block_line[len(_AUTOSAVE_PREFIX):]
                block.append(content[1:] if content.startswith(" ") else content)
            return lines[:index], block, index + 2
    return lines, [], 0


# ---------------------------------------------------------------------------
# Reading values


class ConfigSection:
    """One section, as handed to a module's `load_config(section, printer)`."""

    def __init__(self, config: ConfigFile, name: str):
        self.config = config
        self.name = name

    def get_name(self) -> str:
        """The full section name: 'load_cell', 'load_cell my_cell', 'gcode_macro PARK'."""
        return self.name

    def get_prefix(self) -> str:
        """The first word of the name ('load_cell' for [load_cell my_cell])."""
        return self.name.split()[0]

    def get_instance_name(self) -> str | None:
        """The rest of the name after the first word, or None for a plain [name]."""
        parts = self.name.split(None, 1)
        return parts[1] if len(parts) > 1 else None

    def getsection(self, name: str) -> ConfigSection:
        return self.config.getsection(name)

    def has_option(self, option: str) -> bool:
        return self.config._lookup(self.name, option) is not None

    def get_option_names(self, prefix: str = "") -> list[str]:
        """Option names in this section starting with `prefix` (e.g. 'variable_')."""
        return [o for o in self.config._option_names(self.name) if o.startswith(prefix)]

    # -- the getters -------------------------------------------------------

    def _where(self, option: str, stored: OptionValue | None) -> str:
        file = stored.file if stored else self.config.section_file(self.name)
        if stored is None:
            return f"{file}: [{self.name}] {option}"
        shown = stored.text if "\n" not in stored.text else stored.text.split("\n")[0] + " ..."
        return f"{file}: [{self.name}] {option} = {shown}"

    def error(self, option: str, problem: str) -> ConfigError:
        """A ConfigError about `option` of this section (for checks modules do themselves)."""
        stored = self.config._lookup(self.name, option)
        return ConfigError(f"{self._where(option, stored)}: {problem}",
                           file=stored.file if stored else self.config.section_file(self.name),
                           section=self.name, option=option,
                           value=stored.text if stored else None)

    def _get_parsed(self, option: str, default: Any, parse: Callable[[str], Any], expected: str) -> Any:
        stored = self.config._lookup(self.name, option)
        self.config._note_read(self.name, option)
        if stored is None:
            if default is REQUIRED:
                raise ConfigError(f"{self._where(option, None)}: must be specified ({expected})",
                                  file=self.config.section_file(self.name), section=self.name, option=option)
            return default
        try:
            return parse(stored.text)
        except (ValueError, TypeError, SyntaxError) as exc:
            detail = str(exc) if isinstance(exc, _ValueProblem) else f"expected {expected}"
            raise self.error(option, detail) from None

    def _checked_number(self, option: str, default: Any, parse: Callable[[str], Any], kind: str,
                        minval=None, maxval=None, above=None, below=None) -> Any:
        require_range(f"[{self.name}] {option}", minval, maxval, above, below)
        expected = f"{kind}, {describe_range(minval, maxval, above, below)}"

        def parse_and_check(text: str):
            value = parse(text)
            problem = check_range(value, minval, maxval, above, below)
            if problem:
                raise _ValueProblem(problem)
            return value

        return self._get_parsed(option, default, parse_and_check, expected)

    def get(self, option: str, default: Any = REQUIRED) -> Any:
        """The option's text (multi-line values keep their newlines)."""
        return self._get_parsed(option, default, str, "a value")

    def getint(self, option: str, default: Any = REQUIRED, *, minval: int | None = None,
               maxval: int | None = None) -> Any:
        """An integer within the declared range (every numeric getter must declare one)."""
        return self._checked_number(option, default, _parse_int, "an integer", minval, maxval)

    def getfloat(self, option: str, default: Any = REQUIRED, *, minval: float | None = None,
                 maxval: float | None = None, above: float | None = None, below: float | None = None) -> Any:
        """A finite number within the declared range."""
        return self._checked_number(option, default, _parse_float, "a number", minval, maxval, above, below)

    def getboolean(self, option: str, default: Any = REQUIRED) -> Any:
        return self._get_parsed(option, default, _parse_bool, "True or False")

    def getchoice(self, option: str, choices: Sequence[Any] | Mapping[Any, Any], default: Any = REQUIRED) -> Any:
        """One of `choices`; for a mapping, the value the chosen key maps to.

        Integer choices (e.g. ADS1220 gains) are compared as integers.
        """
        keys = list(choices)
        allowed = "one of: " + ", ".join(str(k) for k in keys)

        def parse_choice(text: str):
            if all(isinstance(k, int) for k in keys):
                try:
                    key: Any = int(text)
                except ValueError:
                    raise _ValueProblem(f"must be {allowed}") from None
            else:
                key = text
            if key not in keys:
                raise _ValueProblem(f"must be {allowed}")
            return choices[key] if isinstance(choices, Mapping) else key

        return self._get_parsed(option, default, parse_choice, allowed)

    def getlist(self, option: str, default: Any = REQUIRED, sep: str = ",", count: int | None = None) -> Any:
        return self._getlist(option, default, sep, count, str, "a list")

    def getintlist(self, option: str, default: Any = REQUIRED, sep: str = ",", count: int | None = None, *,
                   minval: int | None = None, maxval: int | None = None) -> Any:
        """Integers, each within the declared range."""
        return self._getlist(option, default, sep, count, _parse_int, "a list of integers", minval, maxval)

    def getfloatlist(self, option: str, default: Any = REQUIRED, sep: str = ",", count: int | None = None, *,
                     minval: float | None = None, maxval: float | None = None, above: float | None = None,
                     below: float | None = None) -> Any:
        """Finite numbers, each within the declared range."""
        return self._getlist(option, default, sep, count, _parse_float, "a list of numbers",
                             minval, maxval, above, below)

    def _getlist(self, option, default, sep, count, parse_item, kind, *limits):
        separator = "newline" if sep == "\n" else repr(sep)
        expected = f"{kind} separated by {separator}" + (f", exactly {count} items" if count else "")
        if parse_item is not str:
            require_range(f"[{self.name}] {option}", *limits)
            expected += f", each {describe_range(*limits)}"

        def parse_list(text: str):
            items = [item.strip() for item in text.split(sep)]
            if items and not items[-1]:
                items.pop()  # a trailing separator is harmless
            if any(not item for item in items) or not items:
                raise _ValueProblem(f"has an empty item (expected {expected})")
            if count is not None and len(items) != count:
                raise _ValueProblem(f"has {len(items)} items, expected exactly {count}")
            values = []
            for item in items:
                try:
                    values.append(parse_item(item))
                except ValueError:
                    raise _ValueProblem(f"item {item!r} is not valid (expected {expected})") from None
                problem = check_range(values[-1], *limits) if parse_item is not str else None
                if problem:
                    raise _ValueProblem(f"item {item!r} {problem}")
            return values

        return self._get_parsed(option, default, parse_list, expected)


class _ValueProblem(ValueError):
    """A parse failure whose message is already the user-facing problem."""


def _parse_int(text: str) -> int:
    return int(text.strip())


def underflow_problem(text: str, value: float) -> str | None:
    """Why a number written as non-zero but read as 0 (`1e-400` underflows) is refused, else None:
    a limit given that way must not silently become 0, which turns a protection off."""
    mantissa = re.split(r"[eE]", text.strip(), maxsplit=1)[0]
    if value == 0.0 and re.search(r"[1-9]", mantissa):
        return f"'{text.strip()}' is too small to tell from 0 (it would be read as 0); write 0 to mean 0"
    return None


def _parse_float(text: str) -> float:
    value = float(text.strip())
    if not math.isfinite(value):
        raise _ValueProblem("must be a finite number")
    problem = underflow_problem(text, value)
    if problem:
        raise _ValueProblem(problem)
    return value


def _parse_bool(text: str) -> bool:
    word = text.strip().lower()
    if word in _TRUE_WORDS:
        return True
    if word in _FALSE_WORDS:
        return False
    raise ValueError(text)


# ---------------------------------------------------------------------------
# The file


class ConfigFile:
    """A parsed config file (with its includes and SAVE_CONFIG block)."""

    def __init__(self, path: str, sections: dict[str, _Section], autosave: dict[str, _Section]):
        self.path = path
        self._sections = sections
        self._autosave = autosave
        self._read: set[tuple[str, str]] = set()
        self._pending_set: dict[str, dict[str, str]] = {}
        self._pending_remove: set[str] = set()

    @classmethod
    def read(cls, path: str | os.PathLike) -> ConfigFile:
        parser = _Parser()
        parser.parse_file(os.fspath(path), is_main=True)
        return cls(os.fspath(path), parser.sections, parser.autosave_sections)

    # -- sections ------------------------------------------------------------

    def sections(self) -> list[str]:
        """Section names in file order (SAVE_CONFIG-only sections last)."""
        names = list(self._sections)
        names += [n for n in self._autosave if n not in self._sections]
        return names

    def has_section(self, name: str) -> bool:
        return name in self._sections or name in self._autosave

    def getsection(self, name: str) -> ConfigSection:
        """A section's reader; a missing section reads as empty (every option takes its default)."""
        return ConfigSection(self, name)

    def get_prefix_sections(self, prefix: str) -> list[ConfigSection]:
        """Sections whose name starts with `prefix` ('gcode_macro' -> every [gcode_macro X])."""
        return [ConfigSection(self, n) for n in self.sections() if n.startswith(prefix)]

    def section_file(self, name: str) -> str:
        """The file holding the section's header (the main file for a missing section)."""
        section = self._sections.get(name) or self._autosave.get(name)
        return section.file if section else self.path

    def section_options(self, name: str) -> dict[str, str]:
        """The merged option texts of a section (config body overridden by SAVE_CONFIG).

        Counts as reading every option (for modules that parse a whole section themselves).
        """
        self.mark_section_read(name)
        return {option: self._lookup(name, option).text for option in self._option_names(name)}

    def _option_names(self, name: str) -> list[str]:
        names = list(self._sections[name].options) if name in self._sections else []
        if name in self._autosave:
            names += [o for o in self._autosave[name].options if o not in names]
        return names

    def _lookup(self, section: str, option: str) -> OptionValue | None:
        option = option.lower()
        for source in (self._autosave, self._sections):
            if section in source and option in source[section].options:
                return source[section].options[option]
        return None

    def peek(self, section: str, option: str) -> str | None:
        """An option's text without checking or counting it as read (None when absent): for the
        virtual printer, which mirrors the hardware before the modules check their sections."""
        stored = self._lookup(section, option)
        return None if stored is None else stored.text

    def _note_read(self, section: str, option: str) -> None:
        self._read.add((section, option.lower()))

    def mark_section_read(self, name: str) -> None:
        """Treat every option of a section as understood (for sections loaded elsewhere)."""
        for option in self._option_names(name):
            self._note_read(name, option)

    def check_unused_options(self) -> None:
        """Raise for the first option (in file order) that no module read."""
        for name in self.sections():
            for option in self._option_names(name):
                if (name, option) not in self._read:
                    stored = self._lookup(name, option)
                    raise ConfigError(
                        f"{stored.file}: [{name}] {option} = {stored.text.split(chr(10))[0]}: "
                        f"Option '{option}' is not valid in section '{name}'",
                        file=stored.file, section=name, option=option, value=stored.text)

    # -- SAVE_CONFIG ---------------------------------------------------------

    def set(self, section: str, option: str, value: Any) -> None:
        """Queue `option = value` in the SAVE_CONFIG block (written by save())."""
        self._pending_remove.discard(section)
        self._pending_set.setdefault(section, {})[option.lower()] = str(value)

    def remove_section(self, section: str) -> None:
        """Queue removal of a section from the SAVE_CONFIG block."""
        self._pending_set.pop(section, None)
        self._pending_remove.add(section)

    def has_pending_changes(self) -> bool:
        return bool(self._pending_set or self._pending_remove)

    def pending_changes(self) -> dict[str, dict[str, str] | None]:
        """{section: {option: value}} to set, {section: None} to remove."""
        changes: dict[str, dict[str, str] | None] = {name: None for name in sorted(self._pending_remove)}
        changes.update({name: dict(options) for name, options in self._pending_set.items()})
        return changes

    def save(self) -> None:
        """Rewrite the main file's SAVE_CONFIG block with the pending changes, atomically.

        The text above the block is kept byte for byte; the old file is kept
        as `<name>.bak` (see write_atomically: symlinks, mode and owner).  On any
        failure the old file is left untouched.
        """
        text = read_config_text(self.path)
        body_lines, block_lines, block_start = split_autosave(text, self.path)
        parser = _Parser()
        parser._parse_lines(block_lines, self.path, block_start, (), parser.autosave_sections, allow_include=False)
        block = {name: {o: v.text for o, v in s.options.items()} for name, s in parser.autosave_sections.items()}
        for name in self._pending_remove:
            block.pop(name, None)
        for name, options in self._pending_set.items():
            block.setdefault(name, {}).update(options)
        new_text = render_with_autosave("\n".join(body_lines), block)
        write_atomically(self.path, new_text, keep_backup=True)
        self._pending_set.clear()
        self._pending_remove.clear()


def render_with_autosave(body: str, block: Mapping[str, Mapping[str, str]]) -> str:
    """The file text: `body`, then the SAVE_CONFIG block for `block` (if not empty)."""
    body = body.rstrip("\n")
    if not any(block.values()):
        return body + "\n"
    lines = [SAVE_CONFIG_MARKER, _SAVE_CONFIG_NOTE]
    for name, options in block.items():
        if not options:
            continue
        lines += [_AUTOSAVE_PREFIX, f"{_AUTOSAVE_PREFIX} [{name}]"]
        for option, value in options.items():
            first, *rest = value.split("\n")
            lines.append(f"{_AUTOSAVE_PREFIX} {option} = {first}")
            lines += [f"{_AUTOSAVE_PREFIX}     {continuation}" for continuation in rest]
    return body + "\n\n" + "\n".join(lines) + "\n"


def write_atomically(path: str, text: str, *, keep_backup: bool = False) -> None:
    """Replace the file at `path` with `text` so that a crash leaves either the old or the new file.

    A symlink is followed: its target is rewritten and the link stays a link.  The new
    file is written to a temp file next to the target (same filesystem, so the rename is
    atomic), given the old file's mode and owner, flushed and fsynced, then renamed over
    the target.  With `keep_backup`, the old contents first go to `<target>.bak` the same
    way, so the backup is never torn or empty either (an empty old file keeps the
    previous backup).  On any failure the old file is untouched and no temp file is left.
    """
    target = os.path.realpath(path)
    directory = os.path.dirname(target)
    try:
        old = _read_existing(target)
        if keep_backup and old is not None and old[0]:
            _replace_file(target + ".bak", old[0], old[1])
        _replace_file(target, text.encode("utf-8"), old[1] if old else None)
        _fsync_directory(directory)
    except OSError as exc:
        raise ConfigError(f"{path}: unable to write config file (old file left unchanged): {exc}",
                          file=path) from None


def _read_existing(path: str) -> tuple[bytes, os.stat_result] | None:
    """The file's bytes and stat, or None when it does not exist yet."""
    try:
        with open(path, "rb") as handle:
            return handle.read(), os.fstat(handle.fileno())
    except FileNotFoundError:
        return None


def _replace_file(path: str, data: bytes, like: os.stat_result | None) -> None:
    """Atomically put `data` at `path` (temp file + fsync + rename), with the mode and owner of `like`."""
    fd, temp_path = tempfile.mkstemp(dir=os.path.dirname(path), prefix=f".{os.path.basename(path)}.",
                                     suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as handle:
            handle.write(data)
            handle.flush()
            if like is not None:
                os.fchmod(handle.fileno(), stat.S_IMODE(like.st_mode))
                created = os.fstat(handle.fileno())
                if (like.st_uid, like.st_gid) != (created.st_uid, created.st_gid):
                    os.fchown(handle.fileno(), like.st_uid, like.st_gid)
            os.fsync(handle.fileno())
        os.replace(temp_path, path)
    except BaseException:
        os.unlink(temp_path)
        raise


def _fsync_directory(directory: str) -> None:
    """Make the rename itself durable (where the platform allows opening directories)."""
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    finally:
        os.close(fd)
