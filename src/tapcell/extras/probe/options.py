"""Probe options: one table per option group drives both the config reader and the G-code overrides.

Every probe option can be overridden on a probing command by its upper-case name (plus the
classic aliases such as PROBE_SPEED for `speed`). Describing each option once (type, default,
range, G-code names) keeps the config check and the G-code check identical.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

from tapcell.extras.probe.patterns import MAX_CIRCLE_RETRIES
from tapcell.extras.probe.stats import SAMPLES_RESULT_CHOICES


@dataclass(frozen=True)
class OptionSpec:
    """One option: its config name, dataclass field, type, default and limits."""

    option: str
    field: str
    kind: str  # "float" | "optfloat" (G-code NONE/OFF gives None) | "int" | "choice" | "str" | "floatlist"
    default: Any = None
    minval: float | None = None
    maxval: float | None = None
    above: float | None = None
    below: float | None = None
    choices: tuple[str, ...] = ()
    aliases: tuple[str, ...] = ()  # extra G-code parameter names besides OPTION.upper()

    @property
    def gcode_names(self) -> tuple[str, ...]:
        return (self.option.upper(), *self.aliases)

    def limits(self) -> dict:
        return {k: v for k, v in (("minval", self.minval), ("maxval", self.maxval),
                                  ("above", self.above), ("below", self.below)) if v is not None}


DISABLE_WORDS = ("none", "off")  # G-code value that switches an optional option (e.g. a filter) off


def read_section_values(section, specs: tuple[OptionSpec, ...]) -> dict[str, Any]:
    """Read every option of the table from a config section (typed getters check the ranges)."""
    values: dict[str, Any] = {}
    for spec in specs:
        if spec.kind in ("float", "optfloat"):
            values[spec.field] = section.getfloat(spec.option, spec.default, **spec.limits())
        elif spec.kind == "str":
            values[spec.field] = section.get(spec.option, spec.default).strip()
        elif spec.kind == "int":
            values[spec.field] = section.getint(spec.option, spec.default, **spec.limits())
        elif spec.kind == "choice":
            values[spec.field] = section.getchoice(spec.option, list(spec.choices), spec.default)
        elif spec.kind == "floatlist":
            values[spec.field] = _tuple_or_none(section.getfloatlist(spec.option, spec.default, **spec.limits()))
        else:
            raise AssertionError(f"unknown option kind {spec.kind}")
    return values


def _tuple_or_none(value) -> tuple[float, ...] | None:
    return None if value is None else tuple(float(v) for v in value)


def gcode_override_values(gcmd, specs: tuple[OptionSpec, ...], current) -> dict[str, Any]:
    """The options a G-code command overrides, typed and range-checked by the G-code layer."""
    if gcmd is None:
        return {}
    changed: dict[str, Any] = {}
    for spec in specs:
        # has() (not the whole parameter list): a parameter no spec names stays unknown, and is warned about.
        name = next((n for n in spec.gcode_names if gcmd.has(n)), None)
        if name is None:
            continue
        default = getattr(current, spec.field)
        if spec.kind == "optfloat" and gcmd.get(name).strip().lower() in DISABLE_WORDS:
            changed[spec.field] = None
        elif spec.kind in ("float", "optfloat"):
            changed[spec.field] = gcmd.get_float(name, default, **spec.limits())
        elif spec.kind == "int":
            changed[spec.field] = gcmd.get_int(name, default, **spec.limits())
        elif spec.kind == "str":
            changed[spec.field] = gcmd.get(name).strip()
        elif spec.kind == "choice":
            changed[spec.field] = gcmd.get_choice(name, spec.choices)
        elif spec.kind == "floatlist":
            raw = gcmd.get(name).strip()
            if raw.lower() in DISABLE_WORDS:
                changed[spec.field] = None
                continue
            changed[spec.field] = tuple(gcmd.get_floatlist(name, **spec.limits()))
    return changed


def with_overrides(options, specs: tuple[OptionSpec, ...], gcmd):
    """A copy of a frozen options dataclass with the G-code overrides applied."""
    changed = gcode_override_values(gcmd, specs, options)
    return dataclasses.replace(options, **changed) if changed else options


BAD_PROBE_STRATEGIES = ("fail", "ignore", "retry", "circle")


@dataclass(frozen=True)
class ProbeOptions:
    """The `[probe]` options of a probe (lift/retry speed None = same as speed)."""

    z_offset_mm: float
    x_offset_mm: float = 0.0
    y_offset_mm: float = 0.0
    speed_mm_s: float = 5.0
    lift_speed_mm_s: float | None = None
    samples: int = 1
    sample_retract_dist_mm: float = 2.0
    samples_result: str = "average"
    samples_tolerance_mm: float = 0.1
    samples_tolerance_retries: int = 0
    bad_probe_strategy: str = "retry"
    bad_probe_retries: int = 6
    retry_speed_mm_s: float | None = None
    pattern_spacing_mm: float = 2.0
    scrubbing_frequency: int = 0
    templates: dict = field(default_factory=dict, compare=False)  # option -> compiled GCodeTemplate (host.templates)

    @property
    def effective_lift_speed_mm_s(self) -> float:
        return self.lift_speed_mm_s if self.lift_speed_mm_s is not None else self.speed_mm_s

    @property
    def effective_retry_speed_mm_s(self) -> float:
        return self.retry_speed_mm_s if self.retry_speed_mm_s is not None else self.speed_mm_s


# Ranges of the probe options. Probing slower than PROBE_SPEED_MM_S[0] gets no more accurate
# (at 320 sps 0.5 mm/s is already 1.6 µm per sample) but a tap takes seconds of real time;
# more than MAX_SAMPLES taps per point or retries per tap is a mistake, not a measurement.
PROBE_SPEED_MM_S = (0.5, 100.0)
LIFT_SPEED_MM_S = (0.5, 500.0)
MAX_PROBE_OFFSET_MM = 500.0
MAX_Z_OFFSET_MM = 50.0
MAX_SAMPLES = 100
MAX_RETRIES = 100
MAX_RETRACT_MM = 50.0

PROBE_OPTION_SPECS: tuple[OptionSpec, ...] = (
    OptionSpec("x_offset", "x_offset_mm", "float", 0.0, minval=-MAX_PROBE_OFFSET_MM, maxval=MAX_PROBE_OFFSET_MM),
    OptionSpec("y_offset", "y_offset_mm", "float", 0.0, minval=-MAX_PROBE_OFFSET_MM, maxval=MAX_PROBE_OFFSET_MM),
    OptionSpec("speed", "speed_mm_s", "float", 5.0, minval=PROBE_SPEED_MM_S[0], maxval=PROBE_SPEED_MM_S[1],
               aliases=("PROBE_SPEED",)),
    OptionSpec("lift_speed", "lift_speed_mm_s", "float", None, minval=LIFT_SPEED_MM_S[0],
               maxval=LIFT_SPEED_MM_S[1]),
    OptionSpec("samples", "samples", "int", 1, minval=1, maxval=MAX_SAMPLES),
    OptionSpec("sample_retract_dist", "sample_retract_dist_mm", "float", 2.0, above=0.0, maxval=MAX_RETRACT_MM),
    OptionSpec("samples_result", "samples_result", "choice", "average", choices=SAMPLES_RESULT_CHOICES),
    OptionSpec("samples_tolerance", "samples_tolerance_mm", "float", 0.1, minval=0.0, maxval=10.0),
    OptionSpec("samples_tolerance_retries", "samples_tolerance_retries", "int", 0, minval=0, maxval=MAX_RETRIES),
    # STRATEGY= is how the load-cell guide spells it ("BED_MESH STRATEGY=CIRCLE").
    OptionSpec("bad_probe_strategy", "bad_probe_strategy", "choice", "retry", choices=BAD_PROBE_STRATEGIES,
               aliases=("STRATEGY",)),
    OptionSpec("bad_probe_retries", "bad_probe_retries", "int", 6, minval=0, maxval=MAX_RETRIES),
    OptionSpec("retry_speed", "retry_speed_mm_s", "float", None, minval=PROBE_SPEED_MM_S[0],
               maxval=PROBE_SPEED_MM_S[1]),
    OptionSpec("pattern_spacing", "pattern_spacing_mm", "float", 2.0, above=0.0, maxval=20.0),
    OptionSpec("scrubbing_frequency", "scrubbing_frequency", "int", 0, minval=0, maxval=MAX_RETRIES),
)

PROBE_TEMPLATE_OPTIONS = ("activate_gcode", "deactivate_gcode", "nozzle_scrubber_gcode")


def check_probe_options(options: ProbeOptions) -> str | None:
    """Cross-option rules the per-option ranges cannot express; returns the problem or None."""
    if options.bad_probe_strategy == "circle" and options.bad_probe_retries > MAX_CIRCLE_RETRIES:
        return (f"bad_probe_retries = {options.bad_probe_retries}: must be at most {MAX_CIRCLE_RETRIES} "
                "with bad_probe_strategy circle (the hexagonal pattern has 18 places around a point)")
    return None


def read_probe_options(section, templates: dict) -> ProbeOptions:
    """`[probe]` options of a section (z_offset is required)."""
    values = read_section_values(section, PROBE_OPTION_SPECS)
    z_offset_mm = section.getfloat("z_offset", minval=-MAX_Z_OFFSET_MM, maxval=MAX_Z_OFFSET_MM)
    options = ProbeOptions(z_offset_mm=z_offset_mm, templates=templates, **values)
    problem = check_probe_options(options)
    if problem is not None:
        raise section.error("bad_probe_retries", problem.split(": ", 1)[1])
    return options
