"""The `[load_cell_probe]` commands: LOAD_CELL_TEST_TAP, NOZZLE_CLEANUP and
LOAD_CELL_PROBE_CALIBRATE (CONTACT_ONSET, PULLBACK_DISTANCE, DECOMPRESSION_ANGLE)."""

from __future__ import annotations

import collections

import numpy as np

from tapcell.extras.load_cell_probe.calibration import (
    CALIBRATION_PULLBACK_MM,
    MAX_CALIBRATION_TAPS,
    MIN_ONSET_TAPS,
    break_contact_height_um,
    calibrate_decompression_angle,
    covered_speed_range_mm_s,
    decompression_angle_deg,
    fit_pooled_contact_onset,
    min_usable_taps,
    propose_pullback_distance,
)
from tapcell.extras.load_cell_probe.device import (
    RELEASE_CHECK_S,
    SAVE_CONFIG_NOTE,
    LoadCellProbe,
    RecordedTap,
)
from tapcell.extras.load_cell_probe.hand_tap import HandTap, check_hand_tap
from tapcell.extras.load_cell_probe.options import PULLBACK_LIMITS_MM, TapOptions
from tapcell.extras.probe.advice import advised
from tapcell.extras.probe.options import (LIFT_SPEED_MM_S, MAX_RETRACT_MM, MAX_RETRIES, MAX_SAMPLES,
                                          PROBE_SPEED_MM_S)
from tapcell.extras.probe.patterns import serpentine_pattern
from tapcell.extras.probe.session import Probe, ProbeError
from tapcell.host.toolhead import SPEED_RANGE
from tapcell.mcu.trigger import TriggerError
from tapcell.tap.motion import tap_motion

HAND_RELEASE_S = 2.0  # a tap by hand is released within this; longer, it is checked as it is
HAND_SETTLE_S = 0.1  # after the release, the force over this long is where it came back to
# NOZZLE_CLEANUP's pattern: at most 20 x 20 taps, at most 20 mm apart.
MAX_PATTERN_COUNT = 20
MAX_PATTERN_STEPOVER_MM = 20.0


class LoadCellProbeCommands:
    """LOAD_CELL_TEST_TAP, NOZZLE_CLEANUP (QUERY_ENDSTOPS: tapcell.extras.query_endstops; the probe commands live in tapcell.extras.probe.session)."""

    def __init__(self, device: LoadCellProbe, probe: Probe):
        self.device = device
        self.probe = probe

    def register(self, gcode) -> None:
        gcode.register_command("LOAD_CELL_TEST_TAP", self.cmd_LOAD_CELL_TEST_TAP,
                               desc="Detect taps on the load cell without moving: [COUNT=3] [TIMEOUT=30]")
        gcode.register_command("NOZZLE_CLEANUP", self.cmd_NOZZLE_CLEANUP,
                               desc="Tap a serpentine pattern until SAMPLES good taps in a row")
        gcode.register_command("LOAD_CELL_PROBE_CALIBRATE", self.cmd_LOAD_CELL_PROBE_CALIBRATE,
                               desc="Calibrate the probe: CALIBRATION=CONTACT_ONSET|PULLBACK_DISTANCE|DECOMPRESSION_ANGLE [SAMPLES=10]")

    def cmd_LOAD_CELL_PROBE_CALIBRATE(self, gcmd) -> None:
        """Tap SAMPLES times at the current XY and calibrate one option from the taps.

        CONTACT_ONSET: contact_onset_um from the pooled taps. PULLBACK_DISTANCE: the pullback
        that puts break contact near the middle of the pullback. DECOMPRESSION_ANGLE: the
        median angle of the decompression line, for the quality classifier. The value is used
        at once and written by SAVE_CONFIG; the probing options may be overridden as on PROBE.
        """
        calibrations = {"CONTACT_ONSET": self._calibrate_contact_onset,
                        "PULLBACK_DISTANCE": self._calibrate_pullback_distance,
                        "DECOMPRESSION_ANGLE": self._calibrate_decompression_angle}
        calibrations[gcmd.get_choice("CALIBRATION", list(calibrations))](gcmd)

    def _calibration_taps(self, gcmd, samples: int, strategy: str, **option_changes):
        """SAMPLES taps at the current XY with `strategy` for bad taps; returns (recorded taps, session).

        `option_changes` change this command's TapOptions for its own taps only.
        """
        device = self.device
        x_mm, y_mm = self.probe.current_probe_xy()
        taps: list[RecordedTap] = []
        with self.probe.session(gcmd, force_strategy=strategy) as session:
            if option_changes:
                session.tap_settings = device.with_options(session.tap_settings, **option_changes)
            for _ in session.probe_repeatedly(x_mm, y_mm, samples):
                taps.append(device.last_taps[-1])  # the accepted tap, before the lift
        return taps, session

    def _calibrate_contact_onset(self, gcmd) -> None:
        """Fit the sheet's onset width on the pooled taps (bad taps retried in place)."""
        samples = gcmd.get_int("SAMPLES", 10, minval=MIN_ONSET_TAPS, maxval=MAX_CALIBRATION_TAPS)
        x_mm, y_mm = self.probe.current_probe_xy()
        recorded, session = self._calibration_taps(gcmd, samples, "retry")
        try:
            found = fit_pooled_contact_onset([r.tap for r in recorded], session.tap_settings.analysis)
        except ValueError as exc:
            raise ProbeError(f"LOAD_CELL_PROBE_CALIBRATE: {exc}") from None
        self.device.set_calibrated("contact_onset_um", f"{found.onset_um:.2f}", contact_onset_um=found.onset_um)
        gcmd.respond_info(
            f"Contact onset calibration ({found.taps} taps at X:{x_mm:.3f} Y:{y_mm:.3f}):\n\n"
            f"contact_onset_um: {found.onset_um:.2f}\n\n"
            f"Z reads {found.z_shift_um:+.2f} um against a sharp contact. A calibrated onset selects the sharp "
            f"contact model with this onset (the toe model needs contact_onset_um unset). {SAVE_CONFIG_NOTE}")

    def _calibrate_pullback_distance(self, gcmd) -> None:
        """Tap with a long pullback, measure break contact above the halt, propose pullback_distance.

        A tap counts when it is valid or its only fault is break contact in the first sixth
        (TAP_BREAK_CONTACT_TOO_EARLY: expected with the long pullback, and the timing rule is
        what this calibration sets). The taps use the configured speed (PROBE_SPEED overrides):
        break contact grows with speed, so the result holds for a range of speeds around it.
        """
        samples = gcmd.get_int("SAMPLES", 10, minval=MIN_ONSET_TAPS, maxval=MAX_CALIBRATION_TAPS)
        device = self.device
        shortest_mm, longest_mm = PULLBACK_LIMITS_MM
        long_pullback_mm = gcmd.get_float("PULLBACK_DISTANCE", CALIBRATION_PULLBACK_MM,
                                          minval=shortest_mm, maxval=longest_mm)
        x_mm, y_mm = self.probe.current_probe_xy()
        recorded, session = self._calibration_taps(gcmd, samples, "ignore", pullback_distance_mm=long_pullback_mm)
        usable = [r for r in recorded if r.valid or r.analysis.error == "TAP_BREAK_CONTACT_TOO_EARLY"]
        self._refuse_too_few(recorded, usable, samples, "PULLBACK_DISTANCE", long_pullback_mm)
        heights_um = [break_contact_height_um(r.analysis.break_contact_time_s, r.analysis.sensor_delay_s or 0.0,
                                              r.analysis.sensor_integration_s or 0.0, tap_motion(r.tap))
                      for r in usable]
        speed_mm_s = session.options.speed_mm_s
        try:
            found = propose_pullback_distance(heights_um, speed_mm_s, device.sample_rate_sps)
        except ValueError as exc:
            raise ProbeError(f"LOAD_CELL_PROBE_CALIBRATE: {exc}") from None
        pullback_speed_um_s = session.tap_settings.pullback_speed_mm_s * 1000.0
        stiffness_g_um = float(np.median([abs(r.analysis.lines[3][0]) for r in usable])) / pullback_speed_um_s
        trigger_depth_um = session.tap_settings.options.trigger_force_g / stiffness_g_um
        slowest, fastest = covered_speed_range_mm_s(found, speed_mm_s, device.sample_rate_sps, trigger_depth_um)
        device.set_calibrated("pullback_distance", f"{found.pullback_distance_mm:.3f}",
                              pullback_distance_mm=found.pullback_distance_mm)
        gcmd.respond_info(
            f"Pullback distance calibration ({found.taps} of {samples} taps at X:{x_mm:.3f} Y:{y_mm:.3f}, "
            f"{speed_mm_s:g} mm/s, {long_pullback_mm:g} mm pullback):\n"
            f"break contact {found.break_mean_um:.1f} um above the halt (sigma {found.break_sigma_um:.2f} um, "
            f"{found.break_min_um:.1f}..{found.break_max_um:.1f} um)\n\n"
            f"pullback_distance: {found.pullback_distance_mm:.3f}\n\n"
            f"Break contact now comes at {found.share(found.break_mean_um):.0%} of the pullback "
            f"({found.share(found.break_min_um):.0%}..{found.share(found.break_max_um):.0%}; the spec's middle two "
            f"thirds: 17%..83%). {self._speed_coverage(self.probe.options, slowest, fastest)} "
            f"{SAVE_CONFIG_NOTE}")

    @staticmethod
    def _speed_coverage(probe_options, slowest: float, fastest: float) -> str:
        """Which probing speeds the pullback suits, and which configured speeds fall outside."""
        coverage = f"It suits probing at about {slowest:g}..{fastest:g} mm/s (estimated from this speed)."
        outside = [f"{name} {value:g} mm/s" for name, value in
                   (("speed", probe_options.speed_mm_s), ("retry_speed", probe_options.effective_retry_speed_mm_s))
                   if not slowest <= value <= fastest]
        if outside:
            coverage += (f" Outside that: {', '.join(outside)}; calibrate at the speed you probe at most "
                         "(PROBE_SPEED=) or bring the speeds closer together.")
        return coverage

    def _calibrate_decompression_angle(self, gcmd) -> None:
        """Tap SAMPLES times without the angle term, store the median decompression angle."""
        samples = gcmd.get_int("SAMPLES", 10, minval=MIN_ONSET_TAPS, maxval=MAX_CALIBRATION_TAPS)
        x_mm, y_mm = self.probe.current_probe_xy()
        # An old calibration must not reject the taps that replace it.
        recorded, session = self._calibration_taps(gcmd, samples, "ignore", decompression_angle=None)
        usable = [r for r in recorded if r.valid]
        pullback_mm = session.tap_settings.options.pullback_distance_mm
        self._refuse_too_few(recorded, usable, samples, "DECOMPRESSION_ANGLE", pullback_mm)
        try:
            found = calibrate_decompression_angle([decompression_angle_deg(r.analysis.lines[3][0]) for r in usable])
        except ValueError as exc:
            raise ProbeError(f"LOAD_CELL_PROBE_CALIBRATE: {exc}") from None
        self.device.set_calibrated("decompression_angle", f"{found.angle_deg:.2f}", decompression_angle=found.angle_deg)
        pullback_speed_mm_s = session.tap_settings.pullback_speed_mm_s
        sample_rate_sps = self.device.sample_rate_sps
        gcmd.respond_info(
            f"Decompression angle calibration ({found.taps} of {samples} taps at X:{x_mm:.3f} Y:{y_mm:.3f}):\n"
            f"angles {found.min_deg:.2f}..{found.max_deg:.2f} deg ({found.spread:.1%} from the median)\n\n"
            f"decompression_angle: {found.angle_deg:.2f}\n\n"
            f"The tap quality score now includes the normalized decompression angle. The angle holds for "
            f"pullback_speed {pullback_speed_mm_s:g} mm/s ({pullback_speed_mm_s * 1000 / sample_rate_sps:g} um per "
            f"sample at {sample_rate_sps:g} samples/s) on this bed: calibrate again after changing either. "
            f"{SAVE_CONFIG_NOTE}")

    @staticmethod
    def _refuse_too_few(recorded, usable, samples: int, calibration: str, pullback_mm: float) -> None:
        """Refuse a calibration when fewer than min_usable_taps(samples) taps are usable, saying why."""
        needed = min_usable_taps(samples)
        if len(usable) >= needed:
            return
        usable_ids = {id(r) for r in usable}
        codes = collections.Counter(r.analysis.error for r in recorded if id(r) not in usable_ids)
        found = ", ".join(f"{code} x{count}" for code, count in codes.most_common())
        late = codes["TAP_PULLBACK_TOO_SHORT"] + codes["TAP_BREAK_CONTACT_TOO_LATE"]
        if late and calibration == "PULLBACK_DISTANCE":
            advice = (f"break contact came late in the {pullback_mm:g} mm pullback: run again with "
                      f"PULLBACK_DISTANCE={min(2 * pullback_mm, PULLBACK_LIMITS_MM[1]):g} (or probe slower)")
        elif late:
            advice = "the pullback is too short: run CALIBRATION=PULLBACK_DISTANCE first"
        elif codes["TAP_BREAK_CONTACT_TOO_EARLY"] and calibration != "PULLBACK_DISTANCE":
            advice = "the pullback is too long: run CALIBRATION=PULLBACK_DISTANCE first"
        else:
            advice = ("clean the nozzle (NOZZLE_CLEANUP) and cool it below the ooze point, check the sheet, "
                      "then calibrate again")
        raise ProbeError(f"LOAD_CELL_PROBE_CALIBRATE CALIBRATION={calibration}: only {len(usable)} of {samples} "
                         f"taps were good enough ({found}), at least {needed} are needed; {advice}")

    def cmd_LOAD_CELL_TEST_TAP(self, gcmd) -> None:
        count = gcmd.get_int("COUNT", 3, minval=1, maxval=10)
        timeout_s = gcmd.get_float("TIMEOUT", 30.0, minval=1.0, maxval=120.0)
        device = self.device
        device.require_calibrated()
        settings = device.command_settings(gcmd)
        gcmd.respond_info(f"Tap the load cell {count} times:")
        deadline_s = device.backend.now_s + timeout_s
        good = 0
        for index in range(count):
            self._wait_for_release(settings.options, deadline_s)
            tare_counts = device.tare(settings.options)
            armed_s = device.backend.now_s
            device.history.keep_from_s = armed_s  # the tap's samples stay until checked
            try:
                trigger = device.trigger.arm(settings, tare_counts)
                # A hand is on the nozzle now: the next tare must wait for new samples.
                device.expect_contact()
                result = device.backend.wait_for_trigger(trigger, max(deadline_s - device.backend.now_s, 0.0))
                device.load_cell.pump()
                if result.error != TriggerError.NONE:
                    raise ProbeError(device.trigger.error_message(result.error, settings.options))
                if not result.triggered:
                    raise ProbeError(f"LOAD_CELL_TEST_TAP: no tap detected within {timeout_s:g}s "
                                     f"({index} of {count} taps detected)")
                tap = self._check_hand_tap(settings.options, armed_s, tare_counts)
            finally:
                device.history.keep_from_s = None
            good += tap.problem is None
            gcmd.respond_info(f"Tap Detected! {tap.describe()}")
        gcmd.respond_info(f"Test complete, {count} taps detected ({good} good)")

    def _check_hand_tap(self, options: TapOptions, armed_s: float, tare_counts: float) -> HandTap:
        """Wait for the release (at most HAND_RELEASE_S), let the cell settle, check the tap."""
        device = self.device
        self._wait_for_release(options, device.backend.now_s + HAND_RELEASE_S)
        device.load_cell.collect(HAND_SETTLE_S)
        now_s = device.backend.now_s
        t_s, counts, errors = device.history.between(armed_s, now_s)
        force_g = device.grams(counts, tare_counts)
        settled = force_g[t_s >= now_s - HAND_SETTLE_S]
        after_g = float(np.median(settled)) if len(settled) else float("nan")
        return check_hand_tap(force_g, after_g, options.trigger_force_g, options.analysis.max_baseline_force_delta,
                              errors)

    def _wait_for_release(self, options: TapOptions, deadline_s: float) -> None:
        """Do not tare under a hand still pressing: wait until the force is back near the tare."""
        device = self.device
        while device.backend.now_s < deadline_s:
            batch = device.load_cell.collect(RELEASE_CHECK_S)
            force_g = device.load_cell.counts_to_grams(batch.counts)
            if force_g is None or len(force_g) == 0 or np.max(np.abs(force_g)) < 0.5 * options.trigger_force_g:
                return

    def cmd_NOZZLE_CLEANUP(self, gcmd) -> None:
        probe_opts = self.probe.options
        good_needed = gcmd.get_int("SAMPLES", 3, minval=1, maxval=MAX_SAMPLES)
        stepover_mm = gcmd.get_float("PATTERN_STEPOVER", 2.0, above=0.0, maxval=MAX_PATTERN_STEPOVER_MM)
        count_x = gcmd.get_int("PATTERN_X", 10, minval=1, maxval=MAX_PATTERN_COUNT)
        count_y = gcmd.get_int("PATTERN_Y", 4, minval=1, maxval=MAX_PATTERN_COUNT)
        speed = gcmd.get_float("SPEED", probe_opts.speed_mm_s, minval=PROBE_SPEED_MM_S[0],
                               maxval=PROBE_SPEED_MM_S[1])
        lift_speed = gcmd.get_float("LIFT_SPEED", probe_opts.effective_lift_speed_mm_s, minval=LIFT_SPEED_MM_S[0],
                                    maxval=LIFT_SPEED_MM_S[1])
        horizontal_speed = gcmd.get_float("HORIZONTAL_SPEED", 50.0, **SPEED_RANGE)
        retract_mm = gcmd.get_float("SAMPLE_RETRACT_DIST", probe_opts.sample_retract_dist_mm, above=0.0,
                                    maxval=MAX_RETRACT_MM)
        scrubbing_frequency = gcmd.get_int("SCRUBBING_FREQUENCY", probe_opts.scrubbing_frequency, minval=0,
                                           maxval=MAX_RETRIES)
        motion = self.device.motion
        if not motion.is_z_homed():
            raise ProbeError("Must home before probe (run G28)")
        x0, y0, _ = motion.get_position()
        settings = self.device.command_settings(gcmd)
        positions = serpentine_pattern(x0, y0, count_x, count_y, stepover_mm)
        with self.device.guarded():
            good_in_row = 0
            bad_taps = []
            for index, (x, y) in enumerate(positions):
                if index:
                    motion.move_to(x=float(x), y=float(y), speed_mm_s=horizontal_speed)
                outcome = self.device.tap(settings, motion.z_position_min(), speed)
                motion.move_to(z=outcome.z_mm + retract_mm, speed_mm_s=lift_speed)
                if outcome.valid:
                    good_in_row += 1
                    if good_in_row >= good_needed:
                        gcmd.respond_info(f"NOZZLE_CLEANUP succeeded: {good_needed} good taps in a row "
                                          f"after {index + 1} taps")
                        return
                    continue
                good_in_row = 0
                bad_taps.append(outcome)
                gcmd.respond_info(f"NOZZLE_CLEANUP: bad tap at {x:.3f},{y:.3f}: {outcome.error_code} - {outcome.message}")
                if scrubbing_frequency and len(bad_taps) % scrubbing_frequency == 0:
                    self.probe.run_template("nozzle_scrubber_gcode", {"ATTEMPT": index + 1, "RETRIES": len(positions)})
            raise ProbeError(advised(f"NOZZLE_CLEANUP failed after trying {len(positions)} positions", bad_taps))
