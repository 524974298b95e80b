"""The one Jinja2 environment of the host: `[gcode_macro]` and the probe's G-code templates
(activate_gcode, deactivate_gcode, nozzle_scrubber_gcode) are compiled by it at config load.

Klipper's delimiters: `{ expression }`, `{% statement %}`, `{# comment #}`; so
`G1 Z{params.LIFT}` renders the parameter. An undefined name is an error, not an empty string.

A template is a program the config file holds, so what it may build is bounded: the environment
is Jinja2's sandbox (no `_private` attributes, `range()` of at most 100,000 items), `*` and `**`
are checked before they run (`{"a" * 10**9}` would take gigabytes; Jinja2 would even fold that
constant at config load), and a render stops past MAX_RENDERED_CHARS of G-code.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, Iterator

import jinja2
import jinja2.sandbox

from tapcell.host.config import ConfigSection
from tapcell.host.gcode import GCodeError

MAX_RENDERED_CHARS = 1_000_000  # G-code one render may produce (a PRINT_START is a few kB)
MAX_BUILT_ITEMS = 1_000_000  # characters or items one `*` may build (a string, a list)
MAX_POWER_BITS = 4096  # bits of an integer `**` may build


class TemplateTooLarge(Exception):
    """What a template builds is over a limit (the message says which)."""


def _length(value: Any) -> int | None:
    return len(value) if isinstance(value, (str, list, tuple, bytes)) else None


class _BoundedEnvironment(jinja2.sandbox.SandboxedEnvironment):
    """The sandbox, with `*` and `**` checked against the limits before they build anything."""

    intercepted_binops = frozenset(["*", "**"])

    def call_binop(self, context, operator, left, right):
        if operator == "*":
            for sequence, count in ((left, right), (right, left)):
                size = _length(sequence)
                if size is not None and isinstance(count, int) and size * count > MAX_BUILT_ITEMS:
                    raise TemplateTooLarge(f"repeating {size:,} items {count:,} times builds more than "
                                           f"{MAX_BUILT_ITEMS:,} (the limit)")
        elif operator == "**" and isinstance(left, int) and isinstance(right, int) and abs(left) > 1:
            if right * abs(left).bit_length() > MAX_POWER_BITS:
                raise TemplateTooLarge(f"{left}**{right} has more than {MAX_POWER_BITS} bits (the limit)")
        return super().call_binop(context, operator, left, right)


ENVIRONMENT = _BoundedEnvironment(
    block_start_string="{%", block_end_string="%}",
    variable_start_string="{", variable_end_string="}",
    comment_start_string="{#", comment_end_string="#}",
    undefined=jinja2.StrictUndefined,
    extensions=["jinja2.ext.do"],
)


# Status fields that Klipper gives as coordinates: macros read them as `position.z`, `axis_maximum.x`.
COORDINATE_FIELDS = frozenset(("position", "gcode_position", "homing_origin", "axis_minimum", "axis_maximum",
                               "live_position", "last_probe_position"))


class Coord(list):
    """A position list that also answers `.x`, `.y`, `.z` and `.e` (as Klipper's Coord does in templates)."""

    x = property(lambda self: self[0])
    y = property(lambda self: self[1])
    z = property(lambda self: self[2])
    e = property(lambda self: self[3])


def _with_coordinates(status: dict) -> dict:
    return {key: Coord(value) if key in COORDINATE_FIELDS and isinstance(value, list | tuple) and 3 <= len(value) <= 4
            else value for key, value in status.items()}


class StatusView(Mapping):
    """`printer` inside a template: each object's status, fetched once per render."""

    def __init__(self, printer: Any):
        self._printer = printer
        self._cache: dict[str, dict] = {}

    def __getitem__(self, name: str) -> dict:
        if name not in self._cache:
            obj = self._printer.lookup_object(name, None)
            if obj is None or not hasattr(obj, "get_status"):
                raise KeyError(name)
            self._cache[name] = _with_coordinates(obj.get_status(self._printer.get_time()))
        return self._cache[name]

    def __iter__(self) -> Iterator[str]:
        return iter(name for name, obj in self._printer.objects.items() if hasattr(obj, "get_status"))

    def __len__(self) -> int:
        return sum(1 for _ in self)


class GCodeTemplate:
    """A G-code template compiled at config load; `label` names it in errors ("macro SHOW_FORCE")."""

    def __init__(self, template: jinja2.Template, label: str):
        self.template = template
        self.label = label

    def render(self, context: dict[str, Any]) -> str:
        """The G-code text; an error inside the template is a GCodeError naming it."""
        try:
            return self._render_bounded(context)
        except GCodeError:
            raise
        except (jinja2.TemplateError, TemplateTooLarge) as exc:
            raise GCodeError(f"Error in {self.label}: {exc}") from None
        except Exception as exc:  # e.g. a type error inside an expression the user wrote
            raise GCodeError(f"Error in {self.label}: {type(exc).__name__}: {exc}") from None


    def _render_bounded(self, context: dict[str, Any]) -> str:
        """The rendered text, refused as soon as it passes MAX_RENDERED_CHARS."""
        pieces, size = [], 0
        for piece in self.template.generate(context):
            size += len(piece)
            if size > MAX_RENDERED_CHARS:
                raise TemplateTooLarge(f"the G-code it renders is over {MAX_RENDERED_CHARS:,} characters (the limit)")
            pieces.append(piece)
        return "".join(pieces)


def compile_template(section: ConfigSection, option: str, label: str) -> GCodeTemplate:
    """The template in `option` of `section`; a syntax error is a config error naming the option."""
    try:
        return GCodeTemplate(ENVIRONMENT.from_string(section.get(option)), label)
    except jinja2.TemplateSyntaxError as exc:
        raise section.error(option, f"template error on line {exc.lineno} of the template: {exc.message}") from None
    except (TemplateTooLarge, OverflowError) as exc:  # a constant the compiler would fold (Jinja2 folds `{2**3}`)
        raise section.error(option, f"template error: {exc}") from None
