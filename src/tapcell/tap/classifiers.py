"""Tap classifiers: the registry, the built-ins `tap_quality` and `empty`, and plugins.

A classifier is made by a factory called with the `AnalysisOptions`; its
`classify(analysis, context)` sees a tap that passed validation and may
- return a `Classification` with a quality score and/or replacement lines (in the tap's
  polarity; points and Z are then recomputed from them and validated again),
- raise `TapRejected(code, message)` to mark the tap invalid.
Plugins register factories under the Python entry-point group `tapcell.tap_classifiers`, or are
named by module path (`my_printer.taps`, `my_printer.taps:Factory`, or a file `/path/taps.py`),
whose `TapClassifier` is the factory.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Any, Callable, Protocol

from tapcell.tap.angles import line_angles_deg, slope_angle_deg
from tapcell.tap.context import AnalysisContext, recompute_points
from tapcell.tap.model import (
    LOW_COMPRESSION_FORCE,
    LOW_DECOMPRESSION_FORCE,
    LOW_TAP_QUALITY,
    AnalysisOptions,
    TapAnalysis,
)
from tapcell.tap.validate import TapInvalid, check_break_contact, check_points

ENTRY_POINT_GROUP = "tapcell.tap_classifiers"
# A clean tap's residual scatters around the noise sigma by ~±15 % (both are estimates):
# residuals up to 1.25 × the noise cost nothing.
MISFIT_TOLERANCE = 1.25
# LOW_DECOMPRESSION_FORCE (the guide's figure 2: the sheet or plastic under the nozzle gave way
# during the dwell, so little force is left to release on the pullback): the force released
# between the end of the dwell and break contact, over the trigger force. Over taplab and the
# outside reference archives (../shared/data) the valid clean taps release at least 0.979 x the
# trigger force (a fast ADS1220 stops just past it, a soft sheet then relaxes); 0.9 leaves that
# worst case an 8 % margin (`python -m bench decompression_force`, docs/tap-analysis.md).
MIN_DECOMPRESSION_TO_TRIGGER = 0.9


# LOW_COMPRESSION_FORCE compares the trigger force with what the probe can have seen when it
# triggered: the compression, plus the force the approach added since the tare (a bowden or cable
# pulling in proportion to Z: reference bowden taps add up to 20 g, one read compression 100.7 g
# under a 106 g trigger), plus TRIGGER_NOISE_SIGMAS of the noise (the trigger fires on one sample;
# a noisy-mains tap triggered on a hum swing at 60.1 g of compression under 65 g). Margins over
# taplab seeds 1 and 2 and the reference set (1,960 taps): clean taps reach at least 1.05 x the
# trigger force that way (reference ADS1220 2000 sps); the one fouled tap it rejects 0.97 x, heavy
# ooze down to 0.73 x (reference; the others rejected by earlier checks).
TRIGGER_NOISE_SIGMAS = 3.0


def force_at_trigger_g(analysis: TapAnalysis) -> float:
    """The most force the probe can have measured above its tare when it triggered: the compression,
    the approach line's change toward the contact (drift since the tare) and TRIGGER_NOISE_SIGMAS noise."""
    compression = analysis.compression_force_g or 0.0
    added_g = 0.0
    if len(analysis.points) == 6:
        added_g = max((analysis.polarity or 1) * (analysis.points[1][1] - analysis.points[0][1]), 0.0)
    return compression + added_g + TRIGGER_NOISE_SIGMAS * (analysis.noise_sigma_g or 0.0)


class TapRejected(Exception):
    """Raised by a classifier to reject a tap with a code."""

    def __init__(self, code: str, message: str, quality: float | None = None,
                 components: dict[str, float] | None = None):
        self.code = code
        self.message = message
        self.quality = quality  # the score, when the rejection is for quality
        self.components = components or {}
        super().__init__(f"{code}: {message}")


class UnknownClassifierError(ValueError):
    pass


@dataclass
class Classification:
    """A classifier's verdict on a valid tap: its quality score (0..100), lines it refitted (None:
    keep the analysis's) and the score's components by name."""

    quality: float | None = None
    lines: list[tuple[float, float]] | None = None
    components: dict[str, float] = field(default_factory=dict)


class TapClassifier(Protocol):
    def classify(self, analysis: TapAnalysis, context: AnalysisContext) -> Classification | None: ...


ClassifierFactory = Callable[[AnalysisOptions], TapClassifier]


class EmptyClassifier:
    """Accepts every tap that passed validation; no score."""

    def __init__(self, options: AnalysisOptions):
        self.options = options

    def classify(self, analysis: TapAnalysis, context: AnalysisContext) -> Classification:
        return Classification()


def quality_components(points: list[tuple[float, float]], decompression_slope_g_s: float,
                       stiffness_ratio: float | None, decompression_angle: float | None,
                       noise_to_residual: float | None = None, approach_drift_share: float = 0.0) -> dict[str, float]:
    """The ratios of the quality score (fractions, not percent). Needs a nonzero compression force.
    `approach_drift_share`: the share of the approach's force change the departure shows to be a
    cable's drift (TapAnalysis.approach_drift_share), left out of the approach component."""
    f0, f1, f2, f3, f4, f5 = points[0][1], points[1][1], points[2][1], points[3][1], points[4][1], points[5][1]
    compression = abs(f2 - f1)
    components = {
        "approach": (1.0 - approach_drift_share) * abs(f1 - f0) / compression,
        "departure": abs(f5 - f4) / compression,
        "baseline": abs(f1 - f4) / compression,
        "dwell_drop": abs(f2 - f3) / compression,
    }
    if decompression_angle is not None:
        angle = abs(slope_angle_deg(decompression_slope_g_s))
        components["angle"] = abs(angle - decompression_angle) / decompression_angle
    if stiffness_ratio is not None:
        components["stiffness"] = abs(1.0 - stiffness_ratio)
    if noise_to_residual is not None:
        components["misfit"] = max(0.0, 1.0 - MISFIT_TOLERANCE * noise_to_residual)
    return components


def limiting_component(components: dict[str, float], cutoffs_percent: dict[str, float]) -> str:
    """The component that sank the score: the one furthest over its cutoff (any over it makes the
    score 0), else the largest ratio."""
    over = {name: ratio / (cutoffs_percent[name] / 100.0) for name, ratio in components.items()
            if cutoffs_percent.get(name) is not None and ratio > cutoffs_percent[name] / 100.0}
    pool = over or components
    return max(pool, key=pool.get)


def quality_score(components: dict[str, float], cutoffs_percent: dict[str, float]) -> float:
    """100 × Π(1 - ratio); a ratio over its cutoff makes the score 0. Clamped to 0..100."""
    score = 100.0
    get = cutoffs_percent.get
    for name, ratio in components.items():
        cutoff = get(name)
        if cutoff is not None and ratio > cutoff / 100.0:
            return 0.0
        score *= 1.0 - ratio
    return min(100.0, max(0.0, score))


def quality_cutoffs(options: AnalysisOptions) -> dict[str, float]:
    """Each quality component's cutoff in percent (the max_* options)."""
    return {
        "approach": options.max_approach_force,
        "departure": options.max_departure_force,
        "baseline": options.max_baseline_force_delta,
        "dwell_drop": options.max_dwell_force_drop,
        "stiffness": options.max_stiffness_mismatch,
        "misfit": options.max_model_misfit,
    }


DEFAULT_QUALITY_CUTOFFS = quality_cutoffs(AnalysisOptions())


class TapQualityClassifier:
    """The spec's Tap Quality Classifier plus a stiffness-consistency component.

    Components are ratios to the compression force (approach, departure, baseline, dwell
    drop), the normalized decompression angle when `decompression_angle` is calibrated,
    and `stiffness`: |1 - k_decompression / k_compression| with both stiffnesses in g/µm
    (`stiffness_ratio`: the models' fits and the lines' slopes over speed, whichever mismatch is
    smaller, so that the softening shows in both). Unlike the angle it does not saturate near 90°: ooze or a
    loose sheet that halves the decompression stiffness costs 50 %, whatever the speeds.
    And `misfit`: 1 - 1.25 × noise sigma / contact-model residual sigma over the pullback. A clean
    decompression is explained to the noise (misfit ≈ 0); a film of ooze or a string pulling
    on departure bends the curve (residual 3-4 × the noise) and shifts Z by several µm. The noise
    here holds the Z staircase and a ringing the dwell shows (a gantry rung at the pullback's start,
    a mains hum nobody removed): the contact model cannot follow either, and neither bends Z.
    """

    def __init__(self, options: AnalysisOptions):
        self.options = options
        self.cutoffs = quality_cutoffs(options)

    def classify(self, analysis: TapAnalysis, context: AnalysisContext) -> Classification:
        compression = analysis.compression_force_g or 0.0
        trigger = self.options.trigger_force_g
        if trigger is None:
            trigger = _number(context.tap.probe.get("trigger_force"))
        if trigger is not None:
            at_trigger = force_at_trigger_g(analysis)
            if at_trigger < trigger:
                raise TapRejected(LOW_COMPRESSION_FORCE,
                                  f"compression force {compression:.1f} g (with what the approach added since the "
                                  f"tare and {TRIGGER_NOISE_SIGMAS:g} x the {analysis.noise_sigma_g or 0.0:.2f} g noise: "
                                  f"{at_trigger:.1f} g) is below the trigger force {trigger:.1f} g")
        if compression <= 0:
            raise TapRejected(LOW_COMPRESSION_FORCE, "no compression force")
        if trigger is not None and len(analysis.points) == 6:
            decompression = abs(analysis.points[3][1] - analysis.points[4][1])
            if decompression < MIN_DECOMPRESSION_TO_TRIGGER * trigger:
                raise TapRejected(LOW_DECOMPRESSION_FORCE,
                                  f"decompression force {decompression:.1f} g is below "
                                  f"{MIN_DECOMPRESSION_TO_TRIGGER:g} x the trigger force {trigger:.1f} g: the "
                                  f"force fell away during the dwell")
        ratio = stiffness_ratio(analysis)
        noise_to_residual = None
        if analysis.fit_residual_sigma_g:
            noise_g, step_g = analysis.noise_sigma_g or 0.0, analysis.step_sigma_g or 0.0
            explained_g = math.sqrt(noise_g * noise_g + step_g * step_g + analysis.dwell_ringing_var_g2)
            noise_to_residual = explained_g / analysis.fit_residual_sigma_g
        components = quality_components(analysis.points, analysis.lines[3][0], ratio,
                                        self.options.decompression_angle, noise_to_residual,
                                        analysis.approach_drift_share)
        quality = quality_score(components, self.cutoffs)
        if quality < self.options.min_tap_quality:
            worst = limiting_component(components, self.cutoffs)
            cutoff = self.cutoffs.get(worst)
            if cutoff is not None and components[worst] > cutoff / 100.0:
                why = f"{worst} {100 * components[worst]:.1f}% is over its cutoff {cutoff:g}%"
            else:
                why = f"largest component: {worst} {100 * components[worst]:.1f}%"
            raise TapRejected(LOW_TAP_QUALITY,
                              f"tap quality {quality:.1f}% is below min_tap_quality {self.options.min_tap_quality:g}% "
                              f"({why})", quality, components)
        return Classification(quality=quality, components=components)


def stiffness_ratio(analysis: TapAnalysis) -> float | None:
    """k_decompression / k_compression as both estimators see it, the models' fits and the lines'
    slopes (`TapAnalysis.line_stiffness_ratio`): the one nearer 1. A film or a loose sheet that
    softens the decompression shows in both; what one estimator alone shows is that estimator's
    error. Under a mains hum nobody removed the models parted by 55-70 % where the lines agreed within
    13 % (reference noisy mains, 2 of 80 clean taps LOW_TAP_QUALITY), and the lines by 39 % where the
    models agreed within 16 % (a virtual bowden tap with hum, `bench tap_safety`)."""
    lines = analysis.line_stiffness_ratio
    compression, decompression = analysis.stiffness_compression_g_um, analysis.stiffness_decompression_g_um
    if not (compression and decompression):
        return lines
    models = decompression / compression
    # The lines' unless the models' is strictly nearer 1 (a tie or a NaN keeps the lines', which come first).
    return models if lines is None or abs(1.0 - models) < abs(1.0 - lines) else lines


def _number(value: Any) -> float | None:
    # A tuple of types, not `int | float`: that expression builds a union object on every call.
    return float(value) if isinstance(value, (int, float)) and math.isfinite(value) else None


BUILTIN_CLASSIFIERS: dict[str, ClassifierFactory] = {
    "tap_quality": TapQualityClassifier,
    "empty": EmptyClassifier,
}


def entry_points(group: str) -> list:
    """Installed plugins' entry points in `group`. importlib.metadata is imported here, when a
    plugin is asked for: it costs as much as the rest of the analysis' imports together."""
    from importlib import metadata

    return list(metadata.entry_points(group=group))


def available_classifiers() -> dict[str, ClassifierFactory | Any]:
    """Built-ins plus the (not yet loaded) entry points of installed plugins."""
    found: dict[str, Any] = dict(BUILTIN_CLASSIFIERS)
    for entry in entry_points(group=ENTRY_POINT_GROUP):
        found.setdefault(entry.name, entry)
    return found


# A classifier given as a module (`tap_classifier_module: my_printer.taps`, or a file
# `/home/pi/taps.py`) provides its factory under this name; `module:Name` names another one.
MODULE_FACTORY = "TapClassifier"


def is_module_reference(name: str) -> bool:
    """A module path or a .py file rather than a registered name (names have no '.', '/' or ':')."""
    return any(mark in name for mark in ".:/")


def _module_factory(reference: str) -> ClassifierFactory:
    import importlib
    import importlib.util
    import os

    location, _, attribute = reference.partition(":") if not reference.endswith(".py") else (reference, "", "")
    attribute = attribute or MODULE_FACTORY
    try:
        if location.endswith(".py"):
            path = os.path.expanduser(location)
            if not os.path.isfile(path):
                raise UnknownClassifierError(f"tap classifier file '{location}' does not exist")
            spec = importlib.util.spec_from_file_location(f"tapcell_classifier_{abs(hash(path))}", path)
            module = importlib.util.module_from_spec(spec)
            spec.loader.exec_module(module)
        else:
            module = importlib.import_module(location)
    except ModuleNotFoundError as exc:
        raise UnknownClassifierError(f"tap classifier module '{location}' is not importable ({exc})") from None
    factory = getattr(module, attribute, None)
    if not callable(factory):
        raise UnknownClassifierError(f"tap classifier module '{location}' has no {attribute} (a factory called "
                                     f"with the AnalysisOptions, returning an object with classify())")
    return factory


@lru_cache(maxsize=64)
def _classifier_factory(name: str) -> ClassifierFactory:
    """Built-ins without touching the (slow) package metadata; a module path imported; plugins
    loaded once."""
    if name in BUILTIN_CLASSIFIERS:
        return BUILTIN_CLASSIFIERS[name]
    if is_module_reference(name):
        return _module_factory(name)
    known = available_classifiers()
    if name in known:
        return known[name].load()
    try:  # a top-level module of that name
        return _module_factory(name)
    except UnknownClassifierError as exc:
        raise UnknownClassifierError(f"unknown tap_classifier '{name}'; available: {', '.join(sorted(known))}, or a "
                                     f"module path ({exc})") from None


def get_classifier(name: str, options: AnalysisOptions | None = None) -> TapClassifier:
    """The classifier called `name`, built with `options`; UnknownClassifierError lists the names."""
    return _classifier_factory(name)(options or AnalysisOptions())


def run_classifier(result: TapAnalysis, context: AnalysisContext, classifier: TapClassifier,
                   name: str) -> TapAnalysis:
    """Apply a classifier to a validated tap (invalid taps are returned as they are)."""
    result.classifier = name
    if not result.valid:
        return result
    try:
        verdict = classifier.classify(result, context)
    except TapRejected as rejected:
        result.quality = rejected.quality
        result.quality_components = dict(rejected.components)
        result.valid, result.error, result.message = False, rejected.code, rejected.message
        return result
    if verdict is None:
        return result
    result.quality = verdict.quality
    result.quality_components = dict(verdict.components)
    if verdict.lines is not None:
        _apply_lines(result, context, verdict.lines)
    return result


def _apply_lines(result: TapAnalysis, context: AnalysisContext, lines: list[tuple[float, float]]) -> None:
    """Replace the five lines: recompute points, angles and Z, and validate again."""
    result.lines = [(float(s), float(i)) for s, i in lines]
    result.points = recompute_points(result.lines, result.points[0][0], result.points[5][0])
    result.angles_deg = line_angles_deg(result.lines)
    sign = result.polarity or 1
    motion, timing = context.motion, context.timing
    t_break = result.points[4][0]
    result.break_contact_time_s = t_break
    result.compression_force_g = abs(result.points[2][1] - result.points[1][1])
    try:
        check_points([(t, sign * f) for t, f in result.points], [sign * a for a in result.angles_deg])
        check_break_contact(t_break - result.sensor_delay_s - 0.5 * timing.integration_s, motion,
                            timing.sample_period_s)
    except TapInvalid as invalid:
        result.valid, result.error, result.message = False, invalid.code, invalid.message
        return
    result.z_line_mm = motion.z_at_time_mm(t_break - result.sensor_delay_s - 0.5 * timing.integration_s)
    result.z_mm = result.z_line_mm
    result.z_method = "lines"
