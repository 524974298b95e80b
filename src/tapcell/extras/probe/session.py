"""The generic probe: probing sessions, PROBE / PROBE_ACCURACY / QUERY_PROBE, G28 Z, status `probe`.

A probe here is anything that can *tap*: make one probing move at the current XY and say
where the bed is and whether it trusts that answer. The load-cell probe is one
(`tapcell.extras.load_cell_probe.device`). This module adds what every probe needs around a tap:

* several samples per point with `samples_result` and `samples_tolerance` (+ retries);
* taps at one spot pooled (`Tapper.pooled_z_shifts_mm`): PROBE_ACCURACY and `SAMPLES=` report each
  tap's Z with what the taps share (the load cell's contact toe, stiffness and lag) estimated
  jointly, when the device can; a device that cannot leaves each tap's own Z;
* bad taps handled by `bad_probe_strategy`: `fail`, `ignore`, `retry` in place, or
  `circle` to the nearest spot of a hexagonal pattern that keeps clear of every place
  where a bad tap happened during the same command (a fouled spot stays avoided);
* the scrubber G-code every `scrubbing_frequency` bad taps;
* `activate_gcode` / `deactivate_gcode` once per session.

`ProbeSession` is the API for many points (BED_MESH_CALIBRATE): open it with the command's
G-code parameters (the overrides), call `probe_point(x, y)` per point, close it.
"""

from __future__ import annotations

import contextlib
import dataclasses
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from tapcell.host.gcode import GCodeError
from tapcell.extras.probe.advice import advised
from tapcell.extras.probe.options import MAX_SAMPLES, PROBE_OPTION_SPECS, ProbeOptions, check_probe_options, with_overrides
from tapcell.extras.probe.patterns import next_clean_spot
from tapcell.extras.probe.stats import (AccuracyStats, accuracy_stats, combine_samples, format_accuracy,
                                       format_single_tap_accuracy, spread_mm)

# BAD_PROBE_STRATEGY and its aliases (STRATEGY=): a command that names one keeps its own choice.
STRATEGY_SPEC = next(spec for spec in PROBE_OPTION_SPECS if spec.field == "bad_probe_strategy")


class ProbeError(GCodeError):
    """A probing failure reported to the user (the G-code layer prints it as `!! message`)."""


@dataclass
class TapOutcome:
    """One tap as the tapping device reports it."""

    z_mm: float  # toolhead Z at which the nozzle touches the bed (before z_offset)
    valid: bool
    error_code: str | None = None  # validation code of a bad tap (TAP_SHAPE_INVALID, LOW_TAP_QUALITY, ...)
    message: str = ""
    analysis: Any = None  # tapcell.tap.TapAnalysis, None for trigger-only taps
    explained: bool = False  # the message already ends with the likely cause and the fix


@dataclass
class ProbeResult:
    """The result at one probed point."""

    z_mm: float  # bed height at the point: combined sample Z minus z_offset
    valid: bool  # False only when bad_probe_strategy=ignore accepted a bad tap
    tap_analysis: Any  # analysis of the last tap
    x_mm: float  # the point asked for (probe coordinates)
    y_mm: float
    attempts: int  # taps made, good and bad
    samples_z_mm: tuple[float, ...] = ()  # the samples combined into z_mm (pooled when `pooled`)
    tapped_x_mm: float = 0.0  # where the nozzle tapped last (differs from x_mm under CIRCLE)
    tapped_y_mm: float = 0.0
    pooled: bool = False  # samples_z_mm are the taps' pooled Zs (Tapper.pooled_z_shifts_mm)
    single_z_mm: tuple[float, ...] = ()  # each sample's own Z (the same as samples_z_mm when not pooled)

    def to_json(self) -> dict:
        out = dataclasses.asdict(self)
        out["tap_analysis"] = None if self.tap_analysis is None else self.tap_analysis.to_json()
        return out


class Tapper(Protocol):
    """What a probe device provides to the probe session."""

    def command_settings(self, gcmd) -> Any: ...  # per-command settings (overrides applied once)

    def tap(self, settings, z_min_mm: float, speed_mm_s: float) -> TapOutcome: ...

    def home_tap(self, settings, z_min_mm: float, speed_mm_s: float) -> float: ...

    def guarded(self) -> contextlib.AbstractContextManager: ...  # around a probing command: lift after an error

    # Taps made at one spot (their TapOutcome.analysis): what to add to each tap's Z for its pooled Z (the
    # part the taps share estimated jointly), or None when this device does not pool these taps.
    def pooled_z_shifts_mm(self, analyses: list[Any]) -> list[float] | None: ...


class Motion(Protocol):
    """The few toolhead services a probe needs."""

    def get_position(self) -> tuple[float, float, float]: ...

    def move_to(self, x: float | None = None, y: float | None = None, z: float | None = None,
                speed_mm_s: float = ...) -> None: ...

    def z_position_min(self) -> float: ...

    def z_travel_mm(self) -> float: ...  # the longest Z move possible (for homing from anywhere)

    def set_z_position(self, z_mm: float) -> None: ...  # re-base Z (homing)

    def is_z_homed(self) -> bool: ...


class ProbeSession:
    """Probing several points with one command's options; fouled places are remembered."""

    def __init__(self, probe: Probe, gcmd=None, *, force_strategy: str | None = None):
        self.probe = probe
        options = with_overrides(probe.options, PROBE_OPTION_SPECS, gcmd)
        strategy_given = gcmd is not None and any(gcmd.has(name) for name in STRATEGY_SPEC.gcode_names)
        if force_strategy is not None and not strategy_given:
            options = dataclasses.replace(options, bad_probe_strategy=force_strategy)
        problem = check_probe_options(options)
        if problem is not None:
            raise ProbeError(problem)
        self.options = options
        self.tap_settings = probe.tapper.command_settings(gcmd)
        self.fouled_xy_mm: list[tuple[float, float]] = []
        self._active = False

    def __enter__(self) -> ProbeSession:
        with contextlib.ExitStack() as stack:
            stack.callback(self.end)
            # Entered after `end` so that after an error the nozzle is lifted before deactivate_gcode.
            stack.enter_context(self.probe.tapper.guarded())
            self.start()
            self._exit_stack = stack.pop_all()
        return self

    def __exit__(self, *exc) -> None:
        self._exit_stack.__exit__(*exc)

    def start(self) -> None:
        if not self.probe.motion.is_z_homed():
            raise ProbeError("Must home before probe (run G28)")
        self.probe.run_template("activate_gcode", {})
        self._active = True

    def end(self) -> None:
        if self._active:
            self._active = False
            self.probe.run_template("deactivate_gcode", {})

    # -- one point ---------------------------------------------------------------------------
    def probe_point(self, x_mm: float, y_mm: float) -> ProbeResult:
        """Probe the bed at (x, y) (probe coordinates), from the current Z height."""
        opts = self.options
        tolerance_retries = 0
        attempts = 0
        while True:
            samples: list[float] = []
            analyses: list[Any] = []
            spots: list[tuple[float, float]] = []
            outcome = None
            tapped = (x_mm, y_mm)
            valid = True
            while len(samples) < opts.samples:
                outcome, tapped, taps = self._tap_until_good(x_mm, y_mm)
                attempts += taps
                valid = valid and outcome.valid
                samples.append(outcome.z_mm)
                analyses.append(outcome.analysis)
                spots.append(tapped)
                if spread_mm(np.array(samples)) > opts.samples_tolerance_mm:
                    break
                if len(samples) < opts.samples:
                    self._retract(outcome.z_mm)
            if spread_mm(np.array(samples)) <= opts.samples_tolerance_mm:
                break
            if tolerance_retries >= opts.samples_tolerance_retries:
                raise ProbeError("Probe samples exceed samples_tolerance")
            tolerance_retries += 1
            self.probe.respond_info("Probe samples exceed tolerance. Retrying...")
            self._retract(outcome.z_mm)
        pooled = self._pooled(samples, analyses, spots)
        combined = samples if pooled is None else pooled
        z_mm = combine_samples(np.array(combined), opts.samples_result) - opts.z_offset_mm
        result = ProbeResult(
            z_mm=z_mm, valid=valid, tap_analysis=outcome.analysis, x_mm=x_mm, y_mm=y_mm,
            attempts=attempts, samples_z_mm=tuple(combined), tapped_x_mm=tapped[0], tapped_y_mm=tapped[1],
            pooled=pooled is not None, single_z_mm=tuple(samples),
        )
        self.probe.last_result = result
        return result

    def _pooled(self, z_mm: list[float], analyses: list[Any], spots: list[tuple[float, float]]) -> list[float] | None:
        """The taps' pooled Zs (in order), or None: one tap, taps at more than one spot (CIRCLE moved
        away from a fouled one), or the device does not pool them."""
        if len(z_mm) < 2 or len(set(spots)) != 1:
            return None
        shifts = self.probe.tapper.pooled_z_shifts_mm(analyses)
        return None if shifts is None else [z + shift for z, shift in zip(z_mm, shifts)]

    def pooled_results(self, results: list[ProbeResult]) -> list[float] | None:
        """The pooled Zs (bed heights, as ProbeResult.z_mm) of single-sample results (PROBE_ACCURACY's),
        or None when they are not pooled."""
        return self._pooled([r.z_mm for r in results], [r.tap_analysis for r in results],
                            [(r.tapped_x_mm, r.tapped_y_mm) for r in results])

    def probe_repeatedly(self, x_mm: float, y_mm: float, count: int) -> Iterator[ProbeResult]:
        """Probe one point `count` times, one sample each, lifting sample_retract_dist in between.

        For PROBE_ACCURACY and the calibrations: each result is yielded before the lift, so the
        caller can look at that tap (e.g. the device's last recorded tap) while it is the latest.
        """
        self.options = dataclasses.replace(self.options, samples=1)
        for index in range(count):
            result = self.probe_point(x_mm, y_mm)
            yield result
            if index < count - 1:
                self._retract(result.z_mm + self.options.z_offset_mm)

    def _tap_until_good(self, x_mm: float, y_mm: float) -> tuple[TapOutcome, tuple[float, float], int]:
        """Tap, then follow bad_probe_strategy until a tap is accepted; returns (outcome, where, taps)."""
        opts = self.options
        motion = self.probe.motion
        bad_here: list[TapOutcome] = []
        taps = 0
        speed = opts.speed_mm_s
        while True:
            where = self._tap_position(x_mm, y_mm)
            nozzle_x, nozzle_y = where[0] - opts.x_offset_mm, where[1] - opts.y_offset_mm
            x_now, y_now, _ = motion.get_position()
            if abs(x_now - nozzle_x) > 1e-6 or abs(y_now - nozzle_y) > 1e-6:
                motion.move_to(x=nozzle_x, y=nozzle_y, speed_mm_s=opts.effective_retry_speed_mm_s)
            outcome = self.probe.tapper.tap(self.tap_settings, motion.z_position_min(), speed)
            taps += 1
            self.probe.respond_info(f"probe at {where[0]:.3f},{where[1]:.3f} is z={outcome.z_mm:.6f}")
            if outcome.valid:
                return outcome, where, taps
            reason = f"{outcome.error_code} - {outcome.message}" if outcome.message else str(outcome.error_code)
            if opts.bad_probe_strategy == "ignore":
                self.probe.respond_info(f"Bad probe ignored (bad_probe_strategy=ignore): {reason}")
                return outcome, where, taps
            if opts.bad_probe_strategy == "fail":
                raise ProbeError(advised(f"Probe failed because it was deemed bad quality: {reason}", [outcome],
                                         motion.z_position_min()))
            self.fouled_xy_mm.append(where)
            bad_here.append(outcome)
            if len(bad_here) > opts.bad_probe_retries:
                raise ProbeError(advised(f"Probing failed after {len(bad_here)} bad probes (last: {reason})", bad_here,
                                         motion.z_position_min()))
            self.probe.respond_info(self._retry_message(reason, bad_here, opts.bad_probe_retries,
                                                        motion.z_position_min()))
            self._retract(outcome.z_mm)
            if opts.scrubbing_frequency and len(bad_here) % opts.scrubbing_frequency == 0:
                self.probe.run_template("nozzle_scrubber_gcode",
                                        {"ATTEMPT": len(bad_here), "RETRIES": opts.bad_probe_retries})
            speed = opts.effective_retry_speed_mm_s

    @staticmethod
    def _retry_message(reason: str, bad_here: list[TapOutcome], retries: int, position_min_mm: float) -> str:
        """The line after a bad tap that is retried. The first tap failing with a code carries the
        likely cause and the fix (the user reads the first failure, which may be the only one)."""
        line = f"Bad probe detected: {reason}. Retrying ({len(bad_here)}/{retries})..."
        latest = bad_here[-1]
        if [tap.error_code for tap in bad_here].count(latest.error_code) == 1:
            advice = advised("", [latest], position_min_mm).strip(" .")
            if advice:
                line += f" {advice}."
        return line

    def _tap_position(self, x_mm: float, y_mm: float) -> tuple[float, float]:
        if self.options.bad_probe_strategy != "circle":
            return (x_mm, y_mm)
        spot = next_clean_spot(x_mm, y_mm, self.options.pattern_spacing_mm, np.array(self.fouled_xy_mm))
        if spot is None:
            raise ProbeError(f"Probing failed: every place within {2 * self.options.pattern_spacing_mm:.1f}mm "
                             f"of {x_mm:.3f},{y_mm:.3f} is fouled")
        return spot

    def _retract(self, contact_z_mm: float) -> None:
        """Lift sample_retract_dist above the contact (never down)."""
        motion = self.probe.motion
        target = contact_z_mm + self.options.sample_retract_dist_mm
        if target > motion.get_position()[2]:
            motion.move_to(z=target, speed_mm_s=self.options.effective_lift_speed_mm_s)


class Probe:
    """PROBE, PROBE_ACCURACY, QUERY_PROBE, the z virtual endstop (G28 Z) and status `probe`."""

    def __init__(self, name: str, options: ProbeOptions, tapper: Tapper, motion: Motion, gcode,
                 template_runner=None):
        self.name = name
        self.options = options
        self.tapper = tapper
        self.motion = motion
        self.gcode = gcode
        self.template_runner = template_runner  # callable(option_name, template, params) or None
        self.last_result: ProbeResult | None = None
        self.last_accuracy: AccuracyStats | None = None  # of the last PROBE_ACCURACY (pooled Zs when pooled)
        self.last_accuracy_single: AccuracyStats | None = None  # of its taps' own Zs
        self.last_accuracy_pooled = False
        self.last_z_result = 0.0
        self.last_query = False

    # -- plumbing ---------------------------------------------------------------------------
    def respond_info(self, message: str) -> None:
        self.gcode.respond_info(message)

    def run_template(self, option: str, params: dict) -> None:
        template = self.options.templates.get(option)
        if template is not None and self.template_runner is not None:
            self.template_runner(option, template, params)

    def register_commands(self) -> None:
        g = self.gcode
        g.register_command("PROBE", self.cmd_PROBE, desc="Probe the bed at the current position (HOME=Z sets Z)")
        g.register_command("PROBE_ACCURACY", self.cmd_PROBE_ACCURACY, desc="Probe repeatedly and report statistics")
        g.register_command("QUERY_PROBE", self.cmd_QUERY_PROBE, desc="Report the probe state")

    def session(self, gcmd=None, *, force_strategy: str | None = None) -> ProbeSession:
        """A probing session for a command (the overrides come from its parameters)."""
        return ProbeSession(self, gcmd, force_strategy=force_strategy)

    def probe_point(self, x_mm: float, y_mm: float, overrides=None) -> ProbeResult:
        """Probe one point in its own session (`overrides`: a G-code command or None)."""
        with self.session(overrides) as session:
            return session.probe_point(x_mm, y_mm)

    def current_probe_xy(self) -> tuple[float, float]:
        x, y, _ = self.motion.get_position()
        return x + self.options.x_offset_mm, y + self.options.y_offset_mm

    # -- commands ---------------------------------------------------------------------------
    def cmd_PROBE(self, gcmd) -> None:
        home = gcmd.get("HOME", "").strip().upper()
        if home not in ("", "Z"):
            raise gcmd.param_error(f"HOME must be Z, not '{home}'")
        x, y = self.current_probe_xy()
        result = self.probe_point(x, y, gcmd)
        self.last_z_result = result.z_mm
        self.respond_info(f"Result is z={result.z_mm:.6f}")
        if home == "Z":
            # The bed is at result.z_mm in the old frame; make it Z = 0 (the accurate datum).
            z_now = self.motion.get_position()[2]
            self.motion.set_z_position(z_now - result.z_mm)
            self.respond_info(f"Z homed by probing: toolhead Z is now {z_now - result.z_mm:.6f}")

    def cmd_PROBE_ACCURACY(self, gcmd) -> None:
        samples = gcmd.get_int("SAMPLES", 10, minval=1, maxval=MAX_SAMPLES)
        x, y = self.current_probe_xy()
        z_start = self.motion.get_position()[2]
        # Every tap must be trusted: a bad tap aborts unless the user picked another strategy.
        with self.session(gcmd, force_strategy="fail") as session:
            opts = session.options
            self.respond_info(
                f"PROBE_ACCURACY at X:{x:.3f} Y:{y:.3f} Z:{z_start:.3f} (samples={samples} "
                f"retract={opts.sample_retract_dist_mm:.3f} speed={opts.speed_mm_s:.1f} "
                f"lift_speed={opts.effective_lift_speed_mm_s:.1f})")
            results = list(session.probe_repeatedly(x, y, samples))
            pooled = session.pooled_results(results)
        single = accuracy_stats(np.array([result.z_mm for result in results]))
        self.last_accuracy_single = single
        if pooled is not None:
            # Klipper's line (last, where macros and users read it) shows the pooled Zs; the taps' own beside it.
            self.respond_info(format_single_tap_accuracy(single))
        stats = single if pooled is None else accuracy_stats(np.array(pooled))
        self.last_accuracy = stats
        self.last_accuracy_pooled = pooled is not None
        self.last_z_result = stats.average_mm
        self.respond_info(format_accuracy(stats))

    def cmd_QUERY_PROBE(self, gcmd) -> None:
        # A load cell only senses force while armed for a probing move: at rest it is "open".
        self.last_query = False
        self.respond_info("probe: open")

    # -- homing -----------------------------------------------------------------------------
    def home_z(self, gcmd=None) -> float:
        """G28 Z through probe:z_virtual_endstop: trigger-only tap, Z = z_offset at the trigger.

        Faster but less accurate than PROBE HOME=Z (no pullback, no analysis); returns the
        new toolhead Z after lifting clear of the bed.
        """
        settings = self.tapper.command_settings(gcmd)
        motion = self.motion
        z_now = motion.get_position()[2]
        z_min = z_now - motion.z_travel_mm()
        self.run_template("activate_gcode", {})
        try:
            with self.tapper.guarded():
                trigger_z = self.tapper.home_tap(settings, z_min, self.options.speed_mm_s)
                z_after = motion.get_position()[2] - trigger_z + self.options.z_offset_mm
                motion.set_z_position(z_after)
                motion.move_to(z=z_after + self.options.sample_retract_dist_mm,
                               speed_mm_s=self.options.effective_lift_speed_mm_s)
        finally:
            self.run_template("deactivate_gcode", {})
        return motion.get_position()[2]

    def get_status(self, eventtime=None) -> dict:
        last = self.last_result
        return {
            "name": self.name,
            "last_query": self.last_query,
            "last_z_result": self.last_z_result,
            "last_probe_position": [0.0, 0.0, 0.0] if last is None else [last.x_mm, last.y_mm, last.z_mm],
            "last_probe_valid": None if last is None else last.valid,
            "last_attempts": None if last is None else last.attempts,
        }
