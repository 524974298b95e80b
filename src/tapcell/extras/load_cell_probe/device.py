"""`[load_cell_probe]`: the nozzle taps the bed through a load cell.

One tap, step by step (`LoadCellProbe.tap`):

1. check the cell is calibrated;
2. tare: average `tare_time` of samples taken at rest (no settle wait: the virtual printer's
   toolhead is at rest as soon as the previous move ends);
3. refuse to move when that tare is more than `force_safety_limit` from `reference_tare_counts`;
4. arm the firmware trigger (the real C code) with this tap's tare, trigger force, safety limits
   and the filters designed for *this command* (G-code filter overrides are redesigned and used);
5. probing move toward `position_min`; the MCU halts Z on the triggering sample;
6. dwell just long enough for the dwell line of the analysis, then pull back
   `pullback_distance` at `pullback_speed` (default 1 µm per sample);
7. collect the samples to the end of the pullback, build a `TapData` (force in grams, the
   recorded moves, events, probe info; never simulator truth) and analyse it;
8. report: Z at break contact when the tap is valid, otherwise the trigger Z and the
   validation code for the probe's bad_probe_strategy.

Its commands are in `commands.py`, next to the [load_cell] commands and the generic probe
commands of `tapcell.extras.probe.session`. Status: `load_cell_probe` (and `probe`).
"""

from __future__ import annotations

import collections
import contextlib
import dataclasses
import functools
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from tapcell.files import check_appendable, open_append
from tapcell.host.backend import Backend
from tapcell.host.config import pin_mcu
from tapcell.filters import FilterDesignError, FilterOptions, design_firmware_filter
from tapcell.extras.load_cell import LoadCell, read_load_cell_options, sensor_error_note
from tapcell.mcu import sensors
from tapcell.mcu.trigger import MAX_STUCK_SAMPLES, TriggerError
from tapcell.extras.probe.approach import NO_CONTACT_DEPTH_MM, BedHeightMemory, approach_height_mm, no_contact_message
from tapcell.extras.probe.session import ProbeError, TapOutcome
from tapcell.extras.load_cell_probe.options import (
    ERROR_PREFIX,
    NOT_CALIBRATED,
    QUIET_PART_OF_TRIGGER,
    CorruptFrameBudget,
    check_stuck_sensor_samples,
    classifier_option,
    lone_frame,
    preload_refusal,
    read_tap_options,
    replace_tap_options,
    tap_analysis_options,
    tap_options_with_overrides,
    TapOptions,
    TapSettings,
    default_pullback_speed_mm_s,
    dwell_sample_count,
    force_beyond_safety_limit_g,
    robust_tare_counts,
    tare_sample_count,
    too_fast_explanation,
    too_fast_for_analysis,
)
from tapcell.extras.load_cell_probe import safety
from tapcell.extras.load_cell_probe.speed_guard import SpeedGuard
from tapcell.extras.load_cell_probe.trigger_session import TriggerSession
from tapcell.extras.load_cell_probe.overrides import disabled_protections, refuse_loosening, \
    refuse_misspelled_safety_parameters, refuse_unknown_parameters
from tapcell.extras.load_cell_probe.threshold import commanded_z_mm, z_at_time_mm
from tapcell.scale import counts_to_grams
from tapcell.tap import Move, TapData, analyze_tap, get_classifier, tap_to_json_dict
from tapcell.tap.pool import apply_pool

BREAK_CLEAR_SAMPLES = 4  # after break contact: one conversion window plus margin before free-air samples
KEEP_LAST_TAPS = 16
HISTORY_S = 1.0  # samples kept between taps (the tare looks back at most tare_time)
TARE_TIMEOUT_S = 1.0  # no sample for this long: the sensor is gone
# Bad-tap codes a too-fast probing move can cause (the compression between two samples, a
# deep over-travel; TAP_DATA_INSUFFICIENT where the analysis names it: too few samples for the
# speed). A low quality score is the classifier's verdict, not explained by speed.
SPEED_SENSITIVE_CODES = ("TAP_CHRONOLOGY", "TAP_SHAPE_INVALID", "TAP_PULLBACK_TOO_SHORT", "TAP_BREAK_CONTACT_TOO_LATE",
                         "TAP_DATA_INSUFFICIENT")
# The bad-tap code a bed too stiff for the speed causes (the compression is a few um: contact breaks
# as the pullback starts): such a tap tells the force guard the bed's stiffness from its pullback.
# Other codes (a touch, a tug, ooze) leave pullbacks that do not measure the bed.
STIFF_BED_CODES = ("TAP_BREAK_CONTACT_TOO_EARLY",)
BAD_TAP_AGREEMENT = 1.5  # two bad taps' pullback stiffness agree within this factor
RELEASE_CHECK_S = 0.05  # LOAD_CELL_TEST_TAP looks at the force this often while waiting for a release
TARE_FRESH_MARGIN_SAMPLES = 4  # the tare window may reach back this many periods beyond tare_time
SAVE_CONFIG_NOTE = ("The SAVE_CONFIG command will update the printer config file with the above and restart "
                    "the printer.")
# G28 Z: the taps after the first come from this far above the last halt, at most this fast,
# and at most this many taps in all look for two that agree.
HOME_BACKOFF_MM = 0.5
HOME_CONFIRM_SPEED_MM_S = 2.0
HOME_TAPS = 4
# max_bed_stiffness (g/um): the stiffest bed the force guard assumes until taps measure it.
MAX_BED_STIFFNESS_RANGE = (1.0, 1000.0)


class SampleHistory:
    """The probe cell's recent samples with their times (the LoadCell keeps counts only).

    Holds the last HISTORY_S seconds, and everything since `keep_from_s` while a tap is
    being recorded; `errors` are remembered with the time of the batch that reported them.
    """

    def __init__(self):
        self._t: list[np.ndarray] = []
        self._counts: list[np.ndarray] = []
        self._errors: list[tuple[float, int]] = []
        self.keep_from_s: float | None = None
        self.newest_s = -np.inf

    def add(self, batch, now_s: float) -> None:
        if batch.errors:
            self._errors.append((now_s, int(batch.errors)))
        if len(batch.t_s):
            self._t.append(np.asarray(batch.t_s, dtype=float))
            self._counts.append(np.asarray(batch.counts, dtype=float))
            self.newest_s = float(self._t[-1][-1])
        oldest_kept_s = self.newest_s - HISTORY_S
        if self.keep_from_s is not None:
            oldest_kept_s = min(oldest_kept_s, self.keep_from_s)
        while self._t and self._t[0][-1] < oldest_kept_s:
            self._t.pop(0)
            self._counts.pop(0)
        self._errors = [e for e in self._errors if e[0] >= oldest_kept_s]

    def between(self, t0_s: float, t1_s: float) -> tuple[np.ndarray, np.ndarray, int]:
        """(times, raw counts, sensor errors reported) of the samples read in [t0, t1]."""
        t_s = np.concatenate(self._t) if self._t else np.zeros(0)
        counts = np.concatenate(self._counts) if self._counts else np.zeros(0)
        inside = (t_s >= t0_s) & (t_s <= t1_s)
        errors = sum(n for when_s, n in self._errors if t0_s <= when_s <= t1_s)
        return t_s[inside], counts[inside], errors


def filter_options(options: TapOptions, sample_rate_sps: float) -> FilterOptions:
    return FilterOptions(
        sample_rate_sps=sample_rate_sps,
        drift_filter_cutoff_frequency=options.drift_filter_cutoff_frequency,
        drift_filter_delay=options.drift_filter_delay,
        buzz_filter_cutoff_frequency=options.buzz_filter_cutoff_frequency,
        buzz_filter_delay=options.buzz_filter_delay,
        notch_filter_frequencies=options.notch_filter_frequencies or (),
        notch_filter_quality=options.notch_filter_quality,
    )


def mains_meta(mains_hz: tuple[float, ...] | str | None) -> list[float] | str | None:
    """AnalysisOptions.mains_hz as tap-file meta (JSON: a list, "auto" or null)."""
    return list(mains_hz) if isinstance(mains_hz, tuple) else mains_hz


@dataclass
class RecordedTap:
    """A tap kept for status, plots and `tapcell analyze`."""

    tap: TapData
    analysis: Any
    z_mm: float
    valid: bool


class LoadCellProbe:
    """The tapping device behind `[load_cell_probe]`."""

    def __init__(self, section, printer):
        self.printer = printer
        self.name = section.get_name()
        self.backend: Backend = printer.backend
        self.cell_options = read_load_cell_options(section)
        self.sample_rate_sps = float(self.cell_options.sample_rate_sps)
        self.options = read_tap_options(section)
        self.tap_log_path = section.get("tap_log", None)
        if self.tap_log_path:  # a FIFO would hang the first tap, a directory fail it: said at load
            problem = check_appendable(self.tap_log_path)
            if problem is not None:
                raise section.error("tap_log", f"{problem}: a tap log must be a file taps can be appended to")
        self._check_classifier(self.options.analysis.tap_classifier,
                               lambda msg: section.error(classifier_option(section), msg))
        check_stuck_sensor_samples(self.options.stuck_sensor_samples,
                                   lambda msg: section.error("stuck_sensor_samples", msg))
        # A live sensor of this type, gain and rate never repeats one value this often (docs/firmware.md).
        self.default_stuck_samples = sensors.stuck_sample_count(
            sensors.noise_floor_counts(self.cell_options.sensor_type, self.cell_options.gain, self.sample_rate_sps),
            self.sample_rate_sps, MAX_STUCK_SAMPLES)
        try:
            self.config_settings = self._design(self.options)
        except FilterDesignError as exc:
            raise section.error(exc.option, f"{exc.value!r} is not allowed; allowed: {exc.allowed}") from None
        self.load_cell = LoadCell(self.name, self.cell_options, printer)
        self.trigger = TriggerSession(self.load_cell, self.cell_options.inverted, self.sample_rate_sps,
                                      self.default_stuck_samples, self.backend)
        # The toolhead implements the probe's Motion protocol (toolhead Z = virtual printer Z + frame offset).
        self.motion = printer.lookup_object("toolhead")
        self.last_taps: collections.deque[RecordedTap] = collections.deque(maxlen=KEEP_LAST_TAPS)
        self.dwell_samples = dwell_sample_count(self.sample_rate_sps)
        # The probe listens to its cell all the time, like the MCU stream of a real printer.
        self.history = SampleHistory()
        self.load_cell.add_client(self._on_samples)
        # Samples from this time on were taken with the nozzle clear of the bed (None: only new ones).
        self._tare_from_s: float | None = -np.inf
        self._tap_clients: list = []  # called with every RecordedTap (the API's dump_taps)
        self.last_trigger_time_s: float | None = None
        self.tare_counts_at_tap: float | None = None
        self.tare_time_s: float | None = None  # when tare_counts_at_tap was taken (the nozzle clear of the bed)
        sensor_pin = self.cell_options.dout_pin or self.cell_options.data_ready_pin
        self.stop_timing = safety.stop_timing(self.cell_options.sensor_type, self.sample_rate_sps,
                                              pin_mcu(sensor_pin), pin_mcu(self.motion.options.axes["z"].step_pin))
        # The stiffest bed a bad tap's pullback showed (the force guard only raises its assumption by it).
        self.bad_tap_stiffness_g_um: float | None = None
        self._unconfirmed_stiffness_g_um: float | None = None  # the last such tap's, until the next agrees
        self.home_stiffness_g_um: float | None = None  # the stiffest bed the last G28 Z that read its backoffs showed
        self.speed_guard = SpeedGuard(self.stop_timing, lambda: self.motion.options.max_z_velocity_mm_s,
                                      self._guard_stiffness_g_um, printer.gcode.respond_info,
                                      section.getfloat("max_bed_stiffness", safety.DEFAULT_STIFFNESS_G_UM,
                                                       minval=MAX_BED_STIFFNESS_RANGE[0],
                                                       maxval=MAX_BED_STIFFNESS_RANGE[1]))
        # Inside a probing command (`guarded`): how deep, the speed notes already given, and the
        # machine Z the last probing move started from (clear of the bed at that XY).
        self._guard_depth = 0
        self._clear_machine_z_mm: float | None = None
        self.bed_heights = BedHeightMemory(self._mesh_height_mm)
        self.nozzle_watch = None  # watch.NozzleWatch, set by load_config (it guards the toolhead's low moves)
        printer.register_event_handler("toolhead:z_homed", self.bed_heights.forget)

    # -- settings per command -----------------------------------------------------------
    @staticmethod
    def _check_classifier(name: str, make_error) -> None:
        try:
            get_classifier(name)
        except (KeyError, ValueError) as exc:
            raise make_error(f"unknown tap classifier '{name}' ({exc})") from None

    def _design(self, options: TapOptions) -> TapSettings:
        sos = design_firmware_filter(filter_options(options, self.sample_rate_sps))
        pullback_speed = options.pullback_speed_mm_s or default_pullback_speed_mm_s(self.sample_rate_sps)
        return TapSettings(options, sos, pullback_speed, tap_analysis_options(options))

    def command_settings(self, gcmd) -> TapSettings:
        """The settings of this command: a new filter design when any option is overridden."""
        refuse_misspelled_safety_parameters(gcmd)
        options = tap_options_with_overrides(self.options, gcmd)
        if options is self.options:
            return self.config_settings
        refuse_loosening(gcmd, self.options, options, self.trigger.stuck_samples(self.options))
        self._check_classifier(options.analysis.tap_classifier, gcmd.error)
        check_stuck_sensor_samples(options.stuck_sensor_samples,
                                   lambda msg: gcmd.param_error(f"STUCK_SENSOR_SAMPLES: {msg}"))
        try:
            return self._design(options)
        except FilterDesignError as exc:
            raise gcmd.param_error(f"{exc.option.upper()}: {exc.value!r} is not allowed; allowed: {exc.allowed}") from None

    def with_options(self, settings: TapSettings, **changes) -> TapSettings:
        """`settings` with some TapOptions (or analysis) fields changed (a calibration's own taps)."""
        return self._design(replace_tap_options(settings.options, **changes))

    def set_calibrated(self, option: str, text: str, **changes) -> None:
        """Use calibrated TapOptions (or analysis) fields from now on and queue `option: text` for SAVE_CONFIG."""
        self.options = replace_tap_options(self.options, **changes)
        self.config_settings = self._design(self.options)
        self.printer.config.set(self.name, option, text)

    # -- the tap ---------------------------------------------------------------------------
    def require_calibrated(self) -> None:
        if not self.load_cell.is_calibrated:
            raise ProbeError(ERROR_PREFIX + NOT_CALIBRATED)

    def _on_samples(self, batch) -> None:
        self.history.add(batch, self.backend.now_s)

    def tare(self, options: TapOptions) -> float:
        """Raw counts at rest: the mean of the last ⌈tare_time·sps⌉ samples, corrupted frames left out.

        The tare overlaps the end of the previous move (the lift after a tap, a travel): every
        sample taken since the nozzle last left the bed counts, so a tap after a retract long
        enough for the tare waits for nothing. Only when too few such samples exist does it wait
        for the rest. Then checks force_safety_limit and sets the cell's tare.
        """
        needed = tare_sample_count(options.tare_time_s, self.sample_rate_sps)
        period_s = 1.0 / self.sample_rate_sps
        deadline_s = self.backend.now_s + TARE_TIMEOUT_S
        while True:
            self.load_cell.pump()
            now_s = self.backend.now_s
            usable_from_s = now_s if self._tare_from_s is None else self._tare_from_s
            # Fresh samples only: a stalled sensor must not tare on what it said long ago.
            oldest_s = max(usable_from_s, now_s - (needed + TARE_FRESH_MARGIN_SAMPLES) * period_s)
            t_s, counts, errors = self.history.between(oldest_s, now_s)
            if errors:
                raise ProbeError(ERROR_PREFIX + f"sensor reported {errors} errors while taring"
                                 f"{sensor_error_note(self.backend)}")
            if len(counts) >= needed:
                break
            if now_s >= deadline_s:
                raise ProbeError(ERROR_PREFIX + "timed out waiting for sensor data")
            self._tare_from_s = usable_from_s
            self.backend.dwell(max(needed - len(counts), 1) * period_s)
        tare_counts = robust_tare_counts(counts[-needed:])
        self.refuse_preload(tare_counts, options)
        self.load_cell.set_tare(tare_counts)
        self.tare_counts_at_tap = tare_counts
        self.tare_time_s = self.backend.now_s
        return tare_counts

    def refuse_preload(self, tare_counts: float, options: TapOptions) -> None:
        """Refuse to move when the force at rest is already past force_safety_limit (ProbeError, with the force)."""
        beyond = force_beyond_safety_limit_g(tare_counts, self.load_cell.reference_tare_counts,
                                             self.load_cell.counts_per_gram, options.force_safety_limit_g)
        if beyond is not None:
            raise ProbeError(preload_refusal(beyond, options.force_safety_limit_g))

    def expect_contact(self) -> None:
        """The nozzle may touch the bed (or a hand the nozzle) from now on: the next tare waits for new samples."""
        self._tare_from_s = None

    def probing_move(self, settings: TapSettings, tare_counts: float, z_min_mm: float, speed_mm_s: float,
                     **trigger):
        """One Z probing move (threshold probing); taps and homing run the same steps through
        `_probing_move`, which checks the speed once, before its lift.

        The speed is capped by [printer] max_z_velocity (said once per command) and refused when
        the worst-case overshoot could press harder than force_safety_limit; then the firmware
        trigger (`trigger`: the keywords of `move_params`) is armed with the tare and Z moves down
        toward z_min_mm (toolhead Z) until it stops. A force_safety_limit stop by one corrupted
        frame in the air is moved on from (CorruptFrameBudget; each retry goes on down from where
        the last stopped). Firmware errors,
        and a sensor that stopped changing or saturated, raise ProbeError naming the cause.
        Returns (move result, the speed used, when the last attempt started); result.triggered is
        False when the move reached z_min_mm without a trigger.
        """
        speed_mm_s = self.speed_guard.check(self.trigger.move_params(settings, **trigger), speed_mm_s)
        result, t_start_s = self._move_at_checked_speed(settings, tare_counts, z_min_mm, speed_mm_s, **trigger)
        return result, speed_mm_s, t_start_s

    def _move_at_checked_speed(self, settings: TapSettings, tare_counts: float, z_min_mm: float, speed_mm_s: float,
                               **trigger):
        """`probing_move` after its speed check: the caller has passed `speed_mm_s` through
        `SpeedGuard.check` with these settings and trigger. Returns (move result, when the
        last attempt started)."""
        options = settings.options
        self._clear_machine_z_mm = float(self.backend.position[2])
        corrupt_frames = CorruptFrameBudget()
        while True:
            firmware = self.trigger.arm(settings, tare_counts, **trigger)
            t_start_s = self.backend.now_s  # the arm time: the firmware sees the samples read from here on
            # Unhomed (G28 Z), z_min is a full axis length below: the machine stops at its own end of travel.
            machine_z_min_mm = max(z_min_mm - self._z_frame_offset_mm(), self.backend.limits["z"][0])
            result = self.backend.probing_move(machine_z_min_mm, speed_mm_s, firmware)
            self.load_cell.pump()
            lone_g = (self.corrupt_frame_that_stopped(firmware.params, result, tare_counts, t_start_s)
                      if result.error == TriggerError.FORCE_SAFETY else None)
            if lone_g is None or not corrupt_frames.allows_another(self.backend.now_s):
                break
            self.printer.gcode.respond_info(f"Load cell: one sample read {lone_g:.0f}g between samples near 0g "
                                            "(a corrupted frame); the move stopped at once, probing again")
        _, counts, _ = self.history.between(t_start_s, self.backend.now_s)
        # The firmware names a stuck sensor itself; with its check off (stuck_sensor_samples: 0), or
        # a saturated sensor, the move's own samples say why it failed (not position_min).
        fault = safety.sensor_fault(counts, self.load_cell.counts_range, self.default_stuck_samples)
        if (fault is not None and result.error != TriggerError.STUCK_SENSOR
                and (result.error != TriggerError.NONE or not result.triggered)):
            raise ProbeError(ERROR_PREFIX + safety.sensor_fault_message(fault, counts, z_min_mm))
        if result.error != TriggerError.NONE:
            message = self.trigger.error_message(result.error, options)
            if result.error == TriggerError.DRIFT_SAFETY:
                message += self._explain_drift(options, tare_counts, t_start_s, speed_mm_s)
            raise ProbeError(message)
        if result.triggered:
            self.last_trigger_time_s = result.trigger_time_s
        return result, t_start_s

    def refuse_a_trigger_past_the_safety_limit(self, section) -> None:
        """Config load: a trigger_force at or above force_safety_limit can never fire first (the
        raw force passes the limit on the way), so every probe would end in the safety error; said
        here, where the cause is, before the drift-filter check blames the filter for it."""
        limit_g, trigger_g = self.options.force_safety_limit_g, self.options.trigger_force_g
        if limit_g > 0 and trigger_g >= limit_g:
            raise section.error("trigger_force", f"must be below force_safety_limit ({limit_g:g}g): the raw force "
                                                 f"would pass the limit and stop every probe before the trigger "
                                                 f"fires; allowed: below {limit_g:g}")

    def refuse_a_hiding_drift_filter(self, section, probe_options) -> None:
        """Config load: a drift filter that hides a tap at the configured speeds (the filtered force
        never reaches trigger_force on a soft bed) is refused unless a safety limit stops the
        nozzle at or below force_safety_limit; the error says the highest cutoff that does not."""
        options = self.options
        if options.drift_filter_cutoff_frequency is None:
            return
        max_z_mm_s = self.motion.options.max_z_velocity_mm_s
        speeds = sorted({min(s, max_z_mm_s) for s in (probe_options.speed_mm_s,
                                                     probe_options.effective_retry_speed_mm_s)})

        def hiding(opts: TapOptions) -> list[float]:
            sos = design_firmware_filter(filter_options(opts, self.sample_rate_sps))
            params = dataclasses.replace(self.trigger.params(opts, sos, opts.trigger_force_g),
                                         counts_per_gram=safety.NOMINAL_COUNTS_PER_GRAM, reference_tare_counts=0)
            return safety.unprotected_hiding_speeds(params, self.stop_timing, speeds)

        hidden = hiding(options)
        if not hidden:
            return
        cutoff_hz = options.drift_filter_cutoff_frequency
        while cutoff_hz > safety.LOWEST_SUGGESTED_CUTOFF_HZ and hiding(
                dataclasses.replace(options, drift_filter_cutoff_frequency=cutoff_hz)):
            cutoff_hz *= safety.CUTOFF_SEARCH_STEP
        raise section.error("drift_filter_cutoff_frequency", safety.hiding_filter_refusal(
            options.drift_filter_cutoff_frequency, hidden[0], options, cutoff_hz))

    @contextlib.contextmanager
    def guarded(self):
        """Around every probing command: after any error the nozzle is lifted clear of the bed
        (to where the last probing move started, at least sample_retract_dist above where it
        stopped) before the error goes on to the user. Nests (the outermost resets the state)."""
        if self._guard_depth == 0:
            self.speed_guard.new_command()
            self._clear_machine_z_mm = None
            refuse_unknown_parameters(self.printer.gcode.innermost_command())
            for warning in disabled_protections(self.options):
                self.printer.gcode.respond_info(f"Warning: {warning}")
        self._guard_depth += 1
        try:
            yield
        except Exception:  # any error, ours or the machine's: lift, then let it go on to the user
            self._lift_clear()
            raise
        finally:
            self._guard_depth -= 1

    def _lift_clear(self) -> None:
        if self._clear_machine_z_mm is None:
            return  # no probing move yet: the nozzle has not gone down toward the bed
        z_now_mm = float(self.backend.position[2])
        target_mm = min(max(self._clear_machine_z_mm, z_now_mm + self.probe.options.sample_retract_dist_mm),
                        self.backend.limits["z"][1])
        if target_mm > z_now_mm:
            self.backend.move_to(z=target_mm, speed_mm_s=self.probe.options.effective_lift_speed_mm_s)
            self.printer.gcode.respond_info(
                f"Lifted the nozzle {target_mm - z_now_mm:.3f} mm, clear of the bed, after the error")

    def _probing_move(self, settings: TapSettings, z_min_mm: float, speed_mm_s: float,
                      expected_z_mm: float | None = None):
        """The speed check of `probing_move`, tare, then the probing move; returns (move result,
        tare, t_start, the speed used).

        `expected_z_mm`: the bed height expected here (a tap): the nozzle lifts first when it is too
        close to reach the speed before it, and the move stops 2 mm below it.
        """
        self.require_calibrated()
        # The force guard of `probing_move`, run once here: an unsafe speed is refused before the lift.
        speed_mm_s = self.speed_guard.check(self.trigger.move_params(settings), speed_mm_s)
        if expected_z_mm is not None:
            self._make_room_to_reach_speed(expected_z_mm, speed_mm_s)
        tare_counts = self.tare(settings.options)
        # Until a pullback completes, the nozzle may be on the bed: the next tare waits for fresh samples.
        self.expect_contact()
        result, t_start_s = self._move_at_checked_speed(settings, tare_counts, z_min_mm, speed_mm_s)
        if not result.triggered and expected_z_mm is not None and z_min_mm > self.motion.z_position_min():
            raise ProbeError(ERROR_PREFIX + no_contact_message(z_min_mm, expected_z_mm))
        if not result.triggered:
            raise ProbeError(ERROR_PREFIX + f"No trigger on probe after full movement (down to Z={z_min_mm:.3f}); "
                             "check that [stepper_z] position_min is negative (e.g. -2) and the nozzle reaches the bed")
        return result, tare_counts, t_start_s, speed_mm_s

    def grams(self, counts, tare_counts: float):
        """Raw counts as force in grams against `tare_counts` (the cell's scale and its 'inverted')."""
        return counts_to_grams(counts, tare_counts, self.load_cell.counts_per_gram, self.cell_options.inverted)

    def _force_between(self, t0_s: float, t1_s: float, tare_counts: float) -> tuple[np.ndarray, np.ndarray]:
        """(sample times, force in grams against `tare_counts`) of the kept samples from t0_s to t1_s."""
        t_s, counts, _ = self.history.between(t0_s, t1_s)
        return t_s, self.grams(counts, tare_counts)

    def corrupt_frame_that_stopped(self, params, result, tare_counts: float, armed_s: float) -> float | None:
        """The force of the corrupted frame that stopped a move armed at `armed_s` with the trigger
        `params`, else None: a force_safety_limit stop on a lone sample past the raw force window
        (its neighbours under the trigger force; waits for the sample after it), or a trigger on a
        lone sample past the trigger force (the samples around it, through the one after the
        triggering sample, under QUIET_PART_OF_TRIGGER of it; the caller has rested after the
        halt). Judged on the samples from the arm on: a frame an earlier attempt moved on from is
        not this stop's."""
        period_s = 1.0 / self.sample_rate_sps
        if result.error == TriggerError.FORCE_SAFETY:
            stop_time_s, quiet_g = None, params.trigger_force_g
            self._wait_for_samples_to(self.backend.now_s + 2.5 * period_s)  # the sample after the stop
        elif result.triggered and result.error == TriggerError.NONE:
            stop_time_s, quiet_g = result.trigger_time_s, QUIET_PART_OF_TRIGGER * params.trigger_force_g
        else:
            return None
        t_s, counts, _ = self.history.between(armed_s - 2.0 * period_s, self.backend.now_s)  # and the one before
        force_g = self.grams(counts, tare_counts)
        if result.error == TriggerError.FORCE_SAFETY:
            # The firmware's window: force_safety_limit around the calibration zero and the tare.
            from_zero_g = self.grams(counts, self.load_cell.reference_tare_counts)
            past = np.maximum(np.abs(force_g), np.abs(from_zero_g)) > params.force_safety_limit_g
        else:
            past = np.abs(force_g) >= params.trigger_force_g
        lone = lone_frame(t_s, force_g, past, armed_s, quiet_g, stop_time_s)
        return None if lone is None else float(force_g[lone])

    def _explain_drift(self, options: TapOptions, tare_counts: float, t_start_s: float, speed_mm_s: float) -> str:
        """' (why)' when the move's samples show the force jumping past the limit within one sample."""
        _, force_g = self._force_between(t_start_s, self.backend.now_s, tare_counts)
        beyond = np.flatnonzero(np.abs(force_g) >= options.drift_safety_limit_g)
        if len(beyond) == 0 or beyond[0] == 0:
            return ""
        first = int(beyond[0])
        why = too_fast_explanation(float(force_g[first - 1]), float(force_g[first]), options.trigger_force_g,
                                   options.drift_safety_limit_g, speed_mm_s, self.sample_rate_sps)
        return "" if why is None else f" ({why})"

    def _z_frame_offset_mm(self) -> float:
        return self.motion.frame_offset_mm["z"]

    def home_tap(self, settings: TapSettings, z_min_mm: float, speed_mm_s: float) -> float:
        """G28 Z: the toolhead Z of the bed from trigger-only taps, once two of them agree.

        A trigger-only tap has no tap shape to judge, and a touch, a tug on the bowden tube, a
        corrupted frame or a jump of the chip's offset in the air triggers like the bed. A trigger
        on one corrupted frame (`corrupt_frame_that_stopped`) is not a tap: probing goes on down
        from its halt (CorruptFrameBudget over the homing). A tap counts only when its force
        holds after the halt like a contact (`contact_holds`),
        and a slower tap from HOME_BACKOFF_MM above the halt, tared afresh, finds the same
        height (`agreement_tolerance_mm`, between the triggering samples); otherwise the newest
        tap is the one to check, up to HOME_TAPS taps. Returns where the confirming (slow) tap
        halted, as a single G28 Z tap did (a whole number of steps: moves land on round Z).
        """
        candidate: tuple[float, float] | None = None  # (trigger Z, speed) of a tap that held
        measured_g_um: list[float] = []  # this homing's backoffs; until one reads, the last homing's value stands
        speed = speed_mm_s
        heights = []
        reversed_g = []  # the force held after taps that held like a contact the wrong way round
        threshold_g = settings.options.trigger_force_g
        corrupt_frames = CorruptFrameBudget()
        while len(heights) < HOME_TAPS:
            result, tare_counts, armed_s, speed = self._probing_move(settings, z_min_mm, speed)
            force_g = self._force_after_halt(tare_counts)
            if self._triggered_by_a_corrupt_frame(settings, result, tare_counts, armed_s, corrupt_frames):
                continue
            z_mm = z_at_time_mm(result.moves, result.trigger_time_s) + self._z_frame_offset_mm()
            heights.append(z_mm)
            if safety.contact_holds(force_g, threshold_g):
                if candidate is not None and abs(z_mm - candidate[0]) <= safety.agreement_tolerance_mm(
                        self.stop_timing, speed, candidate[1]):
                    return float(result.halt_z_mm) + self._z_frame_offset_mm()
                candidate = (z_mm, speed)
            else:
                candidate = None
                if safety.contact_holds(-force_g, threshold_g):
                    reversed_g.append(float(np.median(force_g)))
            backoff_start_s = self.backend.now_s
            self.backend.move_to(z=float(self.backend.position[2]) + HOME_BACKOFF_MM, speed_mm_s=speed)
            if candidate is not None:  # a real contact: its backoff measures the bed for the force guard
                stiffness = self._backoff_stiffness_g_um(tare_counts, backoff_start_s)
                if stiffness is not None:
                    measured_g_um.append(stiffness)
                    self.home_stiffness_g_um = max(measured_g_um)
            speed = min(speed_mm_s, HOME_CONFIRM_SPEED_MM_S)
        found = ", ".join(f"{z:.3f}" for z in heights)
        if len(reversed_g) == HOME_TAPS:
            raise ProbeError(ERROR_PREFIX + self._orientation_hint(reversed_g, found))
        raise ProbeError(ERROR_PREFIX + f"G28 Z: {HOME_TAPS} taps found no bed height twice (triggers at Z={found}): "
                         "something pushes or pulls on the nozzle, or the sensor jumps; check the toolhead and the "
                         "load cell, then home again")

    def _triggered_by_a_corrupt_frame(self, settings: TapSettings, result, tare_counts: float, armed_s: float,
                                      corrupt_frames: CorruptFrameBudget) -> bool:
        """G28 Z, after the rest at the halt: whether the tap's trigger was one corrupted frame in the
        air, within the homing's budget (then says so: the tap does not count)."""
        lone_g = self.corrupt_frame_that_stopped(self.trigger.move_params(settings), result, tare_counts, armed_s)
        if lone_g is None or not corrupt_frames.allows_another(self.backend.now_s):
            return False
        self.printer.gcode.respond_info(f"Load cell: one sample read {lone_g:.0f}g between samples near 0g "
                                        "(a corrupted frame); the probe triggered on it, probing again")
        return True

    def _backoff_stiffness_g_um(self, tare_counts: float, backoff_start_s: float) -> float | None:
        """G28 Z: a tap that held like a contact backs off through its decompression, which shows the
        bed's stiffness (`safety.decompression_stiffness_g_um`, as a bad tap's pullback does; None when
        too few samples show it). The force guard takes the stiffest such measurement of the last
        homing, so only the first tap of the first homing (max_bed_stiffness assumed) must be slow."""
        end_s = self.backend.now_s
        self._wait_for_samples_to(end_s)
        t_s, force_g = self._force_between(backoff_start_s, end_s, tare_counts)
        moves = [Move.from_record(m) for m in self.backend.recorded_moves(backoff_start_s, end_s)
                 if m["print_time"] >= backoff_start_s - 1e-9]
        if not moves:
            return None
        return safety.decompression_stiffness_g_um(t_s, force_g, functools.partial(commanded_z_mm, moves),
                                                   backoff_start_s, end_s)

    def _orientation_hint(self, reversed_g: list[float], found: str) -> str:
        """G28 Z's error when every tap pressed the bed but the cell read it as a pull."""
        now = "inverted" if self.load_cell.options.inverted else "normal"
        other = "normal" if self.load_cell.options.inverted else "inverted"
        held = ", ".join(f"{force:.0f}" for force in reversed_g)
        return (f"G28 Z: the load cell reads the nozzle pressing on the bed as a negative force ({held} g held after "
                f"each tap at Z={found}): sensor_orientation is the wrong way round for this cell. Set "
                f"sensor_orientation: {other} in [{self.name}] (it is {now}), RESTART, then home again")

    def _force_after_halt(self, tare_counts: float) -> np.ndarray:
        """The force over CONTACT_CHECK_SAMPLES samples of rest at the halt."""
        halt_s = self.backend.now_s
        self.backend.dwell(safety.CONTACT_CHECK_SAMPLES / self.sample_rate_sps)
        self.load_cell.pump()
        _, force_g = self._force_between(halt_s, self.backend.now_s, tare_counts)
        return force_g

    def contact_holds_after_halt(self, tare_counts: float, threshold_g: float) -> bool:
        """Rest at the halt for CONTACT_CHECK_SAMPLES samples: whether the force held like a contact."""
        return safety.contact_holds(self._force_after_halt(tare_counts), threshold_g)

    def tap(self, settings: TapSettings, z_min_mm: float, speed_mm_s: float) -> TapOutcome:
        """One full tap at the current XY (see the module docstring)."""
        options = settings.options
        x_mm, y_mm, _ = self.motion.get_position()
        expected_z_mm = self.bed_heights.expected_z_mm(x_mm, y_mm)
        z_min_mm = max(z_min_mm, expected_z_mm - NO_CONTACT_DEPTH_MM)
        self.history.keep_from_s = self.backend.now_s - HISTORY_S  # this tap's samples stay until analysed
        try:
            result, tare_counts, t_start_s, speed_mm_s = self._probing_move(settings, z_min_mm, speed_mm_s,
                                                                            expected_z_mm)
            self.backend.dwell(self.dwell_samples / self.sample_rate_sps)
            pullback_start_s = self.backend.now_s
            self.backend.move_to(z=result.halt_z_mm + options.pullback_distance_mm,
                            speed_mm_s=settings.pullback_speed_mm_s)
            pullback_end_s = self.backend.now_s
            # From here the nozzle is pullback_distance above the halt: clear of the bed for the next tare.
            self._tare_from_s = pullback_end_s
            self._wait_for_samples_to(pullback_end_s)
            tap = self._tap_data(tare_counts, t_start_s, result, pullback_start_s, pullback_end_s,
                                 speed_mm_s, settings)
        finally:
            self.history.keep_from_s = None
        analysis = analyze_tap(tap, settings.analysis)
        valid = bool(analysis.valid) and analysis.z_mm is not None
        if valid:
            # A valid tap proves the nozzle left the bed at break contact: the departure samples
            # (one conversion window plus a margin later) already belong to the next tare.
            clear_s = analysis.break_contact_time_s + BREAK_CLEAR_SAMPLES / self.sample_rate_sps
            self._tare_from_s = min(clear_s, pullback_end_s)
        z_mm = float(analysis.z_mm) if valid else float(result.halt_z_mm) + self._z_frame_offset_mm()
        message = analysis.message
        stuck = None if valid else self._stuck_in_pullback(tap, options)
        why = None if valid or stuck else self._explain_bad_tap(tap, analysis.error, options, speed_mm_s)
        if stuck is not None:
            message, why = stuck, stuck  # the sensor, not the tap: the analysis's advice would mislead
        elif why is not None:
            message = f"{message} ({why})"
        # Kept after the stiffness guess above: a bad tap's stiffness must not explain itself.
        self._record(tap, analysis, z_mm, valid)
        if not valid and analysis.error in STIFF_BED_CODES:
            self._note_bad_tap_stiffness(tap)
        else:
            self._unconfirmed_stiffness_g_um = None
        if valid:
            self.bed_heights.remember(x_mm, y_mm, z_mm)
        if analysis.quality is not None:
            self.printer.gcode.respond_info(f"Tap Quality: {analysis.quality:.1f}%")
        return TapOutcome(z_mm=z_mm, valid=valid, error_code=analysis.error, message=message, analysis=analysis,
                          explained=why is not None)

    def pooled_z_shifts_mm(self, analyses: list) -> list[float] | None:
        """Taps at one spot (their analyses): each tap's pooled Z minus its own (tapcell.tap.pool: the toe,
        stiffness and lag the taps share, estimated jointly), written into the analyses (`z_pooled_mm`).
        None unless every tap is valid and was read by the toe model (a calibrated onset or the sharp
        model has no shared toe to estimate)."""
        if not all(a is not None and a.valid and a.z_mm is not None for a in analyses):
            return None
        apply_pool(analyses)
        if any(a.z_pooled_mm is None for a in analyses):
            return None
        return [a.z_pooled_mm - a.z_mm for a in analyses]

    def _make_room_to_reach_speed(self, expected_z_mm: float, speed_mm_s: float) -> None:
        """Lift first when the nozzle is too close to the bed for the probing move to reach its
        speed before contact (else COASTING_MOVE_ACCELERATION), e.g. right after a pullback."""
        toolhead = self.motion.options
        accel = min(toolhead.max_z_accel_mm_s2, toolhead.max_accel_mm_s2)
        speed = min(speed_mm_s, toolhead.max_z_velocity_mm_s)
        start_z_mm = expected_z_mm + approach_height_mm(speed, accel, self.sample_rate_sps)
        if self.motion.get_position()[2] < start_z_mm:
            self.motion.move_to(z=start_z_mm, speed_mm_s=self.probe.options.effective_lift_speed_mm_s)

    def _mesh_height_mm(self, x_mm: float, y_mm: float) -> float | None:
        bed_mesh = self.printer.lookup_object("bed_mesh", None)
        mesh = getattr(bed_mesh, "mesh", None)
        return None if mesh is None else float(mesh.z_at(x_mm, y_mm))

    def _known_stiffness_g_um(self) -> float | None:
        """The bed's stiffness measured by the kept valid taps (the stiffest), None before any.

        A bad tap's analysis is not trusted: the explanation of a bad tap never uses it, and the force
        guard only takes a bad tap's own pullback when that shows a stiffer bed (`_guard_stiffness_g_um`).
        """
        stiffness = [t.analysis.stiffness_decompression_g_um for t in self.last_taps
                     if t.valid and t.analysis.stiffness_decompression_g_um]
        return max(stiffness) if stiffness else None

    def _note_bad_tap_stiffness(self, tap: TapData) -> None:
        """A bad tap on a bed too stiff for the speed (break contact too early) still shows the bed's
        stiffness in its pullback. When two such taps in a row agree, the force guard takes it (if
        stiffer than what it assumes), so the next tap at that speed is refused with the safe speed
        instead of failing the same way again and again."""
        if not tap.moves:
            return
        stiffness = safety.decompression_stiffness_g_um(tap.time_s, tap.force_g,
                                                        functools.partial(commanded_z_mm, tap.moves),
                                                        tap.events["pullback_start_time"],
                                                        tap.events["pullback_end_time"])
        # Two such taps in a row must agree: one pullback disturbed by a tug or a touch does not count.
        unconfirmed, self._unconfirmed_stiffness_g_um = self._unconfirmed_stiffness_g_um, stiffness
        if stiffness is not None and unconfirmed is not None and \
                max(stiffness, unconfirmed) <= BAD_TAP_AGREEMENT * min(stiffness, unconfirmed):
            self.bad_tap_stiffness_g_um = max(min(stiffness, unconfirmed), self.bad_tap_stiffness_g_um or 0.0)

    def _guard_stiffness_g_um(self) -> float | None:
        """What the force guard takes as measured: the valid taps' and G28 Z's backoffs' stiffness,
        raised by a stiffer bed a bad tap showed. A bad tap's pullback reads a stiff bed low (75 g/um
        read 36-48 on the virtual printer: the decompression falls between samples), so it only ever
        raises the assumption: alone it counts only when stiffer than max_bed_stiffness."""
        measured = [k for k in (self._known_stiffness_g_um(), self.home_stiffness_g_um) if k]
        bad = self.bad_tap_stiffness_g_um
        if measured:
            return max(measured + [bad or 0.0])
        if bad and bad * safety.MEASURED_STIFFNESS_MARGIN > self.speed_guard.max_bed_stiffness_g_um:
            return bad
        return None

    def _stuck_in_pullback(self, tap: TapData, options: TapOptions) -> str | None:
        """The real cause when the sensor stopped changing after the halt: the firmware's stuck
        rule (that many identical samples, which a live sensor never gives) over the samples
        from the pullback's start; the analysis would read the flat force as a nozzle still on
        the bed and advise a longer pullback."""
        run = self.trigger.stuck_samples(options)
        pulled = tap.force_g[tap.time_s >= tap.events.get("pullback_start_time", np.inf)]
        if not run or len(pulled) < run or not np.all(pulled[-run:] == pulled[-1]):
            return None
        different = np.flatnonzero(pulled != pulled[-1])
        same = len(pulled) - (int(different[-1]) + 1 if len(different) else 0)
        return (f"the load cell's readings stopped changing during the pullback ({same} identical samples at "
                f"{pulled[-1]:.0f}g): a stuck sensor, not a short pullback; check the sensor's wiring and "
                f"connector, then LOAD_CELL_DIAGNOSTIC")

    def _explain_bad_tap(self, tap: TapData, error_code: str | None, options: TapOptions,
                         speed_mm_s: float) -> str | None:
        """Why a bad tap may come from probing too fast for the sensor (see too_fast_for_analysis)."""
        if error_code not in SPEED_SENSITIVE_CODES:
            return None
        before_halt = tap.force_g[tap.time_s <= tap.events["home_end_time"]]
        at_trigger = np.flatnonzero(before_halt >= options.trigger_force_g)
        if len(at_trigger) == 0 or at_trigger[0] == 0:
            return None
        first = int(at_trigger[0])
        return too_fast_for_analysis(float(before_halt[first - 1]), float(before_halt[first]),
                                     float(np.max(tap.force_g)), options.trigger_force_g, speed_mm_s,
                                     self.sample_rate_sps, options.pullback_distance_mm,
                                     self._known_stiffness_g_um())

    def _wait_for_samples_to(self, end_s: float) -> None:
        """Make sure the samples up to end_s have arrived (a live sensor has them already).

        The conversion that closed last before end_s is read within a fraction of a period; a
        newest sample older than 1.5 periods means the sensor stalled: wait for it, up to a limit.
        """
        period_s = 1.0 / self.sample_rate_sps
        deadline_s = end_s + TARE_TIMEOUT_S
        while True:
            self.load_cell.pump()
            if self.history.newest_s >= end_s - 1.5 * period_s:
                return
            if self.backend.now_s >= deadline_s:
                raise ProbeError(ERROR_PREFIX + "timed out waiting for sensor data")
            self.backend.dwell(0.25 * period_s)

    def _tap_data(self, tare_counts, t_start_s, result, pullback_start_s, pullback_end_s,
                  speed_mm_s, settings: TapSettings) -> TapData:
        t_s, force_g = self._force_between(t_start_s, pullback_end_s, tare_counts)
        # One Z frame for every report of this tap (console, tap file, plot, tapcell analyze): the
        # toolhead's. The virtual printer's own (machine) frame is kept as a named offset.
        offset = self.motion.frame_offset_mm
        moves = [dataclasses.replace(Move.from_record(m), start_z=m["start_z"] + offset["z"])
                 for m in self.backend.recorded_moves(t_start_s, pullback_end_s)
                 if m["print_time"] >= t_start_s - 1e-9]  # not the move that ended as the tap began
        x, y, _ = self.motion.get_position()
        options = settings.options
        return TapData(
            time_s=t_s, force_g=force_g, moves=moves, sample_rate_sps=self.sample_rate_sps,
            events={"home_end_time": float(result.halt_time_s), "pullback_start_time": pullback_start_s,
                    "pullback_end_time": pullback_end_s},
            probe={"x": float(x), "y": float(y), "speed": speed_mm_s,
                   "pullback_distance": options.pullback_distance_mm,
                   "pullback_speed": settings.pullback_speed_mm_s, "trigger_force": options.trigger_force_g},
            meta={"source": "tapcell load_cell_probe", "sensor_type": self.cell_options.sensor_type,
                  "mains_hz": mains_meta(settings.analysis.mains_hz), "frame": "toolhead",
                  # machine (virtual printer) position = toolhead position - this
                  "machine_offset_mm": [offset["x"], offset["y"], offset["z"]]},
        )

    def add_tap_client(self, callback) -> None:
        """Call `callback(recorded_tap)` after every tap, valid or not."""
        self._tap_clients.append(callback)

    def _record(self, tap: TapData, analysis, z_mm: float, valid: bool) -> None:
        recorded = RecordedTap(tap, analysis, z_mm, valid)
        self.last_taps.append(recorded)
        if self.tap_log_path:
            with open_append(self.tap_log_path) as log:
                log.write(json.dumps(tap_to_json_dict(tap, analysis)) + "\n")
        for callback in self._tap_clients:
            callback(recorded)

    # -- status -------------------------------------------------------------------------------
    def get_status(self, eventtime=None) -> dict:
        status = dict(self.load_cell.get_status(eventtime))
        last = self.last_taps[-1] if self.last_taps else None
        status.update({
            "tare_counts_at_tap": self.tare_counts_at_tap,
            "last_trigger_time": self.last_trigger_time_s,
            "is_last_tap_valid": None if last is None else last.valid,
            "last_tap_z": None if last is None else last.z_mm,
            "last_tap_quality": None if last is None else last.analysis.quality,
            "last_tap_error": None if last is None else last.analysis.error,
            "taps_recorded": len(self.last_taps),
            "trigger_force": self.options.trigger_force_g,
        })
        if self.nozzle_watch is not None:
            status["nozzle_watch"] = self.nozzle_watch.get_status()
        return status

    def write_last_taps(self, path: str | Path) -> int:
        """The kept taps as tapcell.tap.v1 JSON lines (for `tapcell analyze`); returns the count."""
        with open(path, "w", encoding="utf-8") as out:
            for recorded in self.last_taps:
                out.write(json.dumps(tap_to_json_dict(recorded.tap, recorded.analysis)) + "\n")
        return len(self.last_taps)
