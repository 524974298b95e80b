"""Plain data of the tap analysis: the tap as recorded, the options, and the result.

A `TapData` is what a reader or the probe hands to `analyze_tap`; a `TapAnalysis`
is what comes back. Both are plain dataclasses; `TapAnalysis.to_json()` gives the
JSON-ready dict used by `tapcell analyze --json` and by tap logs.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np

from tapcell.tap import native

# Error codes of the spec ("Tap Validation Error Codes" and "Tap Quality Error Codes").
TAP_CHRONOLOGY = "TAP_CHRONOLOGY"
TAP_SHAPE_INVALID = "TAP_SHAPE_INVALID"
TAP_BREAK_CONTACT_TOO_EARLY = "TAP_BREAK_CONTACT_TOO_EARLY"
TAP_BREAK_CONTACT_TOO_LATE = "TAP_BREAK_CONTACT_TOO_LATE"
TAP_PULLBACK_TOO_SHORT = "TAP_PULLBACK_TOO_SHORT"
COASTING_MOVE_ACCELERATION = "COASTING_MOVE_ACCELERATION"
TOO_FEW_PROBING_MOVES = "TOO_FEW_PROBING_MOVES"
TOO_MANY_PROBING_MOVES = "TOO_MANY_PROBING_MOVES"
LOW_COMPRESSION_FORCE = "LOW_COMPRESSION_FORCE"
LOW_TAP_QUALITY = "LOW_TAP_QUALITY"
LOW_DECOMPRESSION_FORCE = "LOW_DECOMPRESSION_FORCE"
# Codes of our own (documented in docs/tap-analysis.md).
TAP_DATA_INSUFFICIENT = "TAP_DATA_INSUFFICIENT"  # a phase window holds too few samples to fit
TAP_MOTION_INVALID = "TAP_MOTION_INVALID"  # the motion has no approach/halt/pullback to analyse
TAP_CONTACT_MISMATCH = "TAP_CONTACT_MISMATCH"  # contact on the way down above break contact on the way up
TAP_ADHESION = "TAP_ADHESION"  # (toe model) the force dips below free air after break contact (a thread pulling)
TAP_TWO_STAGE_CONTACT = "TAP_TWO_STAGE_CONTACT"  # (toe model) a soft stage pressed above the contact (sheet, springs)
TAP_SENSOR_SATURATED = "TAP_SENSOR_SATURATED"  # the force held flat at its extreme: the sensor's ADC at its limit


class TapFileError(Exception):
    """A tap file could not be read; names the file and the problem."""

    def __init__(self, path: str, problem: str):
        self.path = str(path)
        self.problem = problem
        super().__init__(f"{self.path}: {problem}")


@dataclass
class Move:
    """One trapezoid segment of toolhead Z motion (tap-format `moves`)."""

    print_time: float  # s, same clock as the samples
    move_t: float  # s
    start_v: float  # mm/s, >= 0
    accel: float  # mm/s², signed
    start_z: float  # mm
    z_r: float  # direction of Z travel: -1, 0 or 1

    @classmethod
    def from_record(cls, record: Mapping[str, Any]) -> Move:
        """A move from a dict holding the tap-format keys (others ignored), e.g. a simulator move."""
        return cls(**{f.name: float(record[f.name]) for f in dataclasses.fields(cls)})

    def z_at(self, t_s: np.ndarray | float) -> np.ndarray:
        tau_s = np.clip(np.asarray(t_s, dtype=float) - self.print_time, 0.0, self.move_t)
        return self.start_z + self.z_r * (self.start_v + 0.5 * self.accel * tau_s) * tau_s

    @property
    def end_time(self) -> float:
        return self.print_time + self.move_t


@dataclass
class TapData:
    """One tap: force samples plus the motion that produced them."""

    time_s: np.ndarray
    force_g: np.ndarray
    z_mm: np.ndarray | None = None
    moves: list[Move] = field(default_factory=list)
    sample_rate_sps: float | None = None
    events: dict[str, float] = field(default_factory=dict)
    probe: dict[str, Any] = field(default_factory=dict)
    truth: dict[str, Any] = field(default_factory=dict)
    meta: dict[str, Any] = field(default_factory=dict)


def _parse_bool(text: str) -> bool:
    lowered = text.strip().lower()
    if lowered in ("1", "true", "yes", "on"):
        return True
    if lowered in ("0", "false", "no", "off"):
        return False
    raise ValueError("expected true or false")


class Range(NamedTuple):
    """The values a numeric analysis option allows. (A NamedTuple, as immutable as a frozen dataclass
    and ~6x cheaper to make at import, which every `tapcell analyze` pays.)"""

    low: float
    high: float
    exclusive: bool = False  # the ends themselves are not allowed

    def __contains__(self, value: float) -> bool:
        if self.exclusive:
            return self.low < value < self.high
        return self.low <= value <= self.high

    def describe(self) -> str:
        return f"between {self.low:g} and {self.high:g}" + (" (exclusive)" if self.exclusive else "")

    def limits(self) -> dict[str, float]:
        """The range as the keywords of a Klipper-family config or G-code getter (getfloat, get_float)."""
        return {"above": self.low, "below": self.high} if self.exclusive else {"minval": self.low, "maxval": self.high}


# The one table of tap-analysis ranges; the defaults are AnalysisOptions' own. `tapcell analyze
# --set` checks against it, and `[load_cell_probe]` takes its classifier options from both.
ANALYSIS_RANGES: dict[str, Range] = {
    "sensor_delay_s": Range(0.0, 1.0),
    "sensor_integration_s": Range(0.0, 1.0),
    "contact_onset_um": Range(0.0, 100.0),
    "z_step_um": Range(0.0, 100.0),
    "trigger_force_g": Range(0.0, 100000.0),
    "min_tap_quality": Range(0.0, 100.0),
    "decompression_angle": Range(0.0, 90.0, exclusive=True),
    "max_approach_force": Range(0.0, 100.0),
    "max_departure_force": Range(0.0, 100.0),
    "max_baseline_force_delta": Range(0.0, 100.0),
    "max_dwell_force_drop": Range(0.0, 100.0),
    "max_stiffness_mismatch": Range(0.0, 100.0),
    "max_model_misfit": Range(0.0, 100.0),
    "outlier_sigma": Range(2.0, 1000.0),
}

# The analysis options a printer's config takes ([load_cell_probe]; Kalico's with `tap_classifier: tapcell`)
# and a probing command overrides by the upper-case name: the spec's names, which are the analysis's own,
# with AnalysisOptions' defaults and ANALYSIS_RANGES' ranges. The printer sets trigger_force_g (from its
# trigger_force) and mains_hz (from its notch filter) itself. contact_onset_um unset: not calibrated.
CONFIG_OPTIONS = ("tap_classifier", "min_tap_quality", "decompression_angle", "max_approach_force",
                  "max_departure_force", "max_baseline_force_delta", "max_dwell_force_drop", "contact_model",
                  "contact_onset_um")


@dataclass
class AnalysisOptions:
    """Everything the analysis can be told. None means: from the tap file, else the default.

    sensor_delay_s: pipeline delay of the sensor beyond its conversion window (s); None: tap
        meta `sensor_delay_s`, else "halt". "halt": from the halt (P2's time minus the motion's
        halt is the whole lag, tapcell.tap.toe). "auto": estimated from the tap (contact vs break
        contact).
    contact_model: "toe" (the contact's toe width and shape marginalised per tap, the drift taken
        from the approach, tapcell.tap.toe) or "sharp" (a hinge, with `contact_onset_um`'s
        parabola). A known onset (`contact_onset_um` calibrated, or `fit_contact_onset`) leaves no
        toe to marginalise: the sharp model with that onset is used (`uses_toe_model`).
    sensor_integration_s: conversion (averaging) window of one sample (s); None: tap meta
        `sensor_integration_s`, else one sample period (a continuously converting ADC).
    z_step_um: Z distance of one (micro)step; None: tap meta `z_step_um`, else 2.5 µm. The
        force over the pullback is a staircase of these steps; the misfit allows for it.
    contact_onset_um: calibrated width of the gradual contact onset (soft/textured sheet);
        None: a sharp contact, or fitted per tap when fit_contact_onset.
    mains_hz: mains hum to fit and subtract before the analysis (tapcell.tap.hum): a tuple of
        frequencies (Hz), "auto" (50 or 60 Hz, whichever the tap clearly holds, else none),
        () for none (`--set mains_hz=none`), or None: tap meta `mains_hz` (the printer records
        its choice, "auto" without a notch filter, so its taps give one answer wherever analysed),
        else none.
    """

    sensor_delay_s: float | str | None = None
    sensor_integration_s: float | None = None
    trigger_force_g: float | None = None
    tap_classifier: str = "tap_quality"
    min_tap_quality: float = 40.0
    decompression_angle: float | None = None
    max_approach_force: float = 50.0
    max_departure_force: float = 25.0
    max_baseline_force_delta: float = 25.0
    max_dwell_force_drop: float = 75.0
    max_stiffness_mismatch: float = 50.0
    max_model_misfit: float = 50.0
    contact_onset_um: float | None = None
    z_step_um: float | None = None
    fit_contact_onset: bool = False
    outlier_sigma: float = 8.0
    mains_hz: tuple[float, ...] | str | None = None
    contact_model: str = "toe"

    # Options that may be reset to None ("from the tap file / default") with `--set key=none`.
    _OPTIONAL = frozenset(
        ("sensor_delay_s", "sensor_integration_s", "trigger_force_g", "contact_onset_um", "z_step_um",
         "decompression_angle")
    )

    @property
    def uses_toe_model(self) -> bool:
        """The toe model reads Z: chosen, and the onset is neither calibrated nor fitted per tap."""
        return self.contact_model == "toe" and self.contact_onset_um is None and not self.fit_contact_onset

    def with_mains_hz(self, mains_hz: tuple[float, ...] | str) -> AnalysisOptions:
        """A copy that removes this mains hum (`auto`, or frequencies in Hz)."""
        return dataclasses.replace(self, mains_hz=mains_hz)

    def with_overrides(self, overrides: dict[str, str]) -> AnalysisOptions:
        """A copy with `--set key=value` strings parsed; ValueError names key, value and what is allowed."""
        fields = {f.name: f for f in dataclasses.fields(self) if not f.name.startswith("_")}
        changes: dict[str, Any] = {}
        for key, text in overrides.items():
            if key not in fields:
                raise ValueError(f"unknown option '{key}'; allowed: {', '.join(sorted(fields))}")
            changes[key] = self._parse_value(key, str(text))
        return dataclasses.replace(self, **changes)

    def _parse_value(self, key: str, text: str) -> Any:
        if key == "contact_model":
            if text.strip() not in CONTACT_MODELS:
                raise ValueError(f"option 'contact_model' = '{text}': one of {', '.join(CONTACT_MODELS)}")
            return text.strip()
        if key == "tap_classifier":
            if not text.strip():
                raise ValueError("option 'tap_classifier' needs a classifier name")
            return text.strip()
        if key == "fit_contact_onset":
            try:
                return _parse_bool(text)
            except ValueError:
                raise ValueError(f"option '{key}' = '{text}': expected true or false") from None
        if key in self._OPTIONAL and text.strip().lower() in ("none", ""):
            return None
        if key == "mains_hz":
            return _parse_mains_hz(text)
        if key == "sensor_delay_s" and text.strip().lower() in ("auto", "halt"):
            return text.strip().lower()
        try:
            value = float(text)
        except ValueError:
            raise ValueError(f"option '{key}' = '{text}': expected a number") from None
        if not math.isfinite(value):
            raise ValueError(f"option '{key}' = '{text}': expected a finite number")
        allowed = ANALYSIS_RANGES[key]
        if value not in allowed:
            raise ValueError(f"option '{key}' = '{text}': must be {allowed.describe()}")
        return value


MAINS_HZ_RANGE = (1.0, 10000.0)
CONTACT_MODELS = ("sharp", "toe")


def _parse_mains_hz(text: str) -> tuple[float, ...] | str:
    """'auto', 'none' (no hum removal: an empty tuple) or comma-separated frequencies in Hz ('50', '50,100')."""
    if text.strip().lower() == "auto":
        return "auto"
    if text.strip().lower() in ("none", "off"):
        return ()
    low, high = MAINS_HZ_RANGE
    frequencies = []
    for part in text.split(","):
        try:
            value = float(part)
        except ValueError:
            raise ValueError(f"option 'mains_hz' = '{text}': expected auto, none or frequencies in Hz "
                             "separated by commas (e.g. 50 or 50,100)") from None
        if not low <= value <= high:
            raise ValueError(f"option 'mains_hz' = '{text}': each frequency must be between {low:g} and {high:g} Hz")
        frequencies.append(value)
    return tuple(frequencies)


def _round_num(value: float | None, digits: int = 9) -> float | None:
    """A number as the JSON output holds it: rounded to `digits` decimals, None for None, NaN and infinity."""
    if value is None or not math.isfinite(value):
        return None
    return round(float(value), digits)


# The same in C (c/output.c, bit for bit): round's correctly rounded decimal is half of what writing
# a tap's result costs (tests/tap/test_native_output.py holds it to _round_num).
_C = native.load("output")
_num = _round_num if _C is None else _C.json_number


@dataclass(eq=False, repr=False)  # its arrays have no equality to compare by, nor a short repr
class PullbackFit:
    """The pullback's samples as the sharp contact model read them (window low edge and span, µm
    above the halt; force, g) and its contact height, stiffness and onset (tapcell.tap.pool)."""

    x_min_um: np.ndarray
    span_um: np.ndarray
    force_g: np.ndarray
    contact_um: float
    stiffness_g_um: float
    onset_um: float
    pullback_speed_mm_s: float
    delay_s: float  # the sensor delay the heights were read with


# Slots: 41 fields outgrow the key table Python shares between instances' dicts (under 30 keys),
# so without them each result builds a dict of its own and takes twice as long to construct.
# weakref_slot keeps a result weakly referable (`tapcell analyze` frees each one once written).
@dataclass(slots=True, weakref_slot=True)
class TapAnalysis:
    """The result of analysing one tap. Times in the tap's own clock, forces in the tap's polarity."""

    valid: bool
    error: str | None = None
    message: str = ""
    z_mm: float | None = None  # commanded Z where the nozzle just touches the bed
    z_sigma_um: float | None = None  # 1 sigma of z_mm from the fit
    z_line_mm: float | None = None  # Z at P4 = decompression ∩ departure, delay-corrected
    z_method: str = "none"  # "contact_model", "lines" or "none"
    quality: float | None = None  # 0..100 when a quality classifier scored the tap
    points: list[tuple[float, float]] = field(default_factory=list)  # 6 × (time_s, force_g)
    lines: list[tuple[float, float]] = field(default_factory=list)  # 5 × (slope g/s, intercept g)
    angles_deg: list[float] = field(default_factory=list)  # 4 angles between consecutive lines
    elapsed_ms: float = 0.0  # wall time of analyze_tap (Klipper's `elapsed`)
    cpu_ms: float = 0.0  # the process's CPU time over the same call (what speed targets compare)
    polarity: int = 0  # +1: contact drives force up, -1: down, 0: unknown
    compression_force_g: float | None = None
    break_contact_time_s: float | None = None
    sensor_delay_s: float | None = None  # delay removed from the timing
    sensor_integration_s: float | None = None
    sensor_delay_estimate_s: float | None = None  # estimated from this tap, when the data allows
    contact_onset_um: float | None = None  # width of the gradual contact onset
    stiffness_compression_g_um: float | None = None
    stiffness_decompression_g_um: float | None = None
    compression_samples: int = 0  # samples wholly in contact before the halt (stiffness needs 2)
    outliers: int = 0  # corrupted single samples repaired before fitting
    stale_readings: int = 0  # readings that repeated the one before while the force moved on, dropped
    noise_sigma_g: float | None = None  # sensor noise, from the analysed window's second differences
    fit_residual_sigma_g: float | None = None  # contact-model residual over the pullback near contact
    step_sigma_g: float | None = None  # the Z-step staircase in force, as the sensor averages it
    quality_components: dict[str, float] = field(default_factory=dict)
    classifier: str | None = None
    hum: dict[str, Any] | None = None  # the mains hum removed before the analysis (HumFit.to_json)
    # The toe fit's grid and the Z (mm) of its contact height 0, for pooling taps at one spot
    # (tapcell.tap.pool); not part of the JSON.
    toe_grid: Any = field(default=None, repr=False, compare=False)
    toe_z_origin_mm: float | None = field(default=None, repr=False, compare=False)
    pullback_fit: PullbackFit | None = field(default=None, repr=False, compare=False)
    z_sharp_mm: float | None = field(default=None, repr=False, compare=False)  # the sharp model's Z
    z_sharp_sigma_um: float | None = field(default=None, repr=False, compare=False)
    # What z_sigma_um was made of (tapcell.tap.uncertainty.ZSigmaParts; `python -m bench tap_sigma`).
    z_sigma_parts: Any = field(default=None, repr=False, compare=False)
    # Under a narrow toe, the first touch of two stages the analysis could not name, µm from the
    # toe's contact (tapcell.tap.stage.unnamed_stage_um): z_sigma_um's stage part.
    unnamed_stage_um: float = field(default=0.0, repr=False, compare=False)
    z_pooled_mm: float | None = None  # Z with the toe shared by the taps at one spot (tapcell.tap.pool)
    z_pooled_sigma_um: float | None = None
    # The share of the approach's force change that the departure shows to be a drift in proportion
    # to Z (a cable, a bowden): the quality classifier's approach component leaves it out.
    approach_drift_share: float = field(default=0.0, repr=False, compare=False)
    # The decompression line's stiffness over the compression line's, when the compression stiffness
    # is measured (the quality classifier's stiffness component).
    line_stiffness_ratio: float | None = field(default=None, repr=False, compare=False)
    # The variance of the ringing the dwell shows (g², tapcell.tap.stage.dwell_ringing; 0 when none):
    # a gantry ringing on into the pullback is noise to the contact model, which the quality
    # classifier's misfit allows for.
    dwell_ringing_var_g2: float = field(default=0.0, repr=False, compare=False)
    # The larger of the dip and the pull below free air after break contact that the adhesion check
    # let pass (g, 0 when none): where a hum nobody removed set the noise they were judged against,
    # `analyze_tap` looks again.
    passed_film_g: float = field(default=0.0, repr=False, compare=False)

    def to_json(self) -> dict[str, Any]:
        return {
            "valid": bool(self.valid),
            "error": self.error,
            "message": self.message,
            "z": _num(self.z_mm),
            "z_sigma_um": _num(self.z_sigma_um, 4),
            "z_line": _num(self.z_line_mm),
            "z_method": self.z_method,
            "quality": _num(self.quality, 2),
            "points": [{"time": _num(t), "force": _num(f, 4)} for t, f in self.points],
            "lines": [{"slope": _num(s, 4), "intercept": _num(i, 4)} for s, i in self.lines],
            "angles": [_num(a, 3) for a in self.angles_deg],
            "elapsed_ms": _num(self.elapsed_ms, 4),
            "cpu_ms": _num(self.cpu_ms, 4),
            "polarity": self.polarity,
            "compression_force": _num(self.compression_force_g, 4),
            "break_contact_time": _num(self.break_contact_time_s),
            "sensor_delay_s": _num(self.sensor_delay_s),
            "sensor_integration_s": _num(self.sensor_integration_s),
            "sensor_delay_estimate_s": _num(self.sensor_delay_estimate_s),
            "contact_onset_um": _num(self.contact_onset_um, 4),
            "stiffness_compression_g_um": _num(self.stiffness_compression_g_um, 4),
            "stiffness_decompression_g_um": _num(self.stiffness_decompression_g_um, 4),
            "compression_samples": self.compression_samples,
            "outliers": self.outliers,
            "noise_sigma_g": _num(self.noise_sigma_g, 4),
            "fit_residual_sigma_g": _num(self.fit_residual_sigma_g, 4),
            "step_sigma_g": _num(self.step_sigma_g, 4),
            "quality_components": {k: _num(v, 6) for k, v in self.quality_components.items()},
            "classifier": self.classifier,
            "hum": self.hum,
            **({"stale_readings": self.stale_readings} if self.stale_readings else {}),
            **({} if self.z_pooled_mm is None else {"z_pooled": _num(self.z_pooled_mm),
                                                   "z_pooled_sigma_um": _num(self.z_pooled_sigma_um, 4)}),
        }
