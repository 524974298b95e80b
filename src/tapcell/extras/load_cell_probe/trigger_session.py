"""The MCU trigger of `[load_cell_probe]`: its parameters for one move, arming it, its errors.

Every move that runs with the firmware trigger armed (a tap, a homing tap, a threshold probe,
LOAD_CELL_TEST_TAP, a move of the nozzle watch) builds the trigger here: the calibration
(counts_per_gram, reference_tare_counts, orientation, the ADC's range), the command's options
(trigger force, safety limits, filter, stuck-sensor run) and the move's own changes.
"""

from __future__ import annotations

from tapcell.extras.load_cell_probe.options import ERROR_PREFIX, TapOptions, TapSettings, trigger_error_message
from tapcell.extras.probe.session import ProbeError
from tapcell.mcu.trigger import FirmwareTrigger, TriggerConfigError, TriggerError, TriggerParams


class TriggerSession:
    """Builds and arms the firmware trigger of one probe cell."""

    def __init__(self, load_cell, inverted: bool, sample_rate_sps: float, default_stuck_samples: int, clock):
        self.load_cell = load_cell
        self.inverted = inverted
        self.sample_rate_sps = sample_rate_sps
        # A live sensor of this type, gain and rate never repeats one value this often (docs/firmware.md).
        self.default_stuck_samples = default_stuck_samples
        self.clock = clock  # the backend: now_s is the arm time

    def stuck_samples(self, options: TapOptions) -> int:
        """The firmware's stuck-sensor run: the option, else the sensor's default (0: off)."""
        return self.default_stuck_samples if options.stuck_sensor_samples is None else options.stuck_sensor_samples

    def params(self, options: TapOptions, sos, trigger_force_g: float, release_force_g: float = 0.0,
               drift_safety_limit_g: float | None = None) -> TriggerParams:
        """The firmware endstop's parameters for one probing move (every probing mode builds them here)."""
        return TriggerParams(
            counts_per_gram=self.load_cell.counts_per_gram,
            reference_tare_counts=self.load_cell.reference_tare_counts,
            trigger_force_g=trigger_force_g,
            release_force_g=release_force_g,
            sample_rate_sps=self.sample_rate_sps,
            force_safety_limit_g=options.force_safety_limit_g,
            drift_safety_limit_g=options.drift_safety_limit_g if drift_safety_limit_g is None else drift_safety_limit_g,
            inverted=self.inverted,
            sos=sos,
            stuck_samples=self.stuck_samples(options),
            counts_range=(self.load_cell.counts_range.min_counts, self.load_cell.counts_range.max_counts),
        )

    def error_message(self, error: TriggerError, options: TapOptions) -> str:
        """What the user reads when the firmware endstop stopped a move with `error`."""
        return trigger_error_message(error, options.force_safety_limit_g, self.stuck_samples(options))

    def move_params(self, settings: TapSettings, *, trigger_force_g: float | None = None, release_force_g: float = 0.0,
                    drift_safety_limit_g: float | None = None) -> TriggerParams:
        """The trigger of one probing move: a tap uses the command's options; threshold probing
        (`threshold.ThresholdProber`) gives its own trigger force, the hysteresis release force
        and, for fast passes, its own drift limit (0 disables it)."""
        options = settings.options
        force_g = options.trigger_force_g if trigger_force_g is None else trigger_force_g
        return self.params(options, settings.sos, force_g, release_force_g, drift_safety_limit_g)

    def arm(self, settings: TapSettings, tare_counts: float, **trigger) -> FirmwareTrigger:
        """The firmware trigger armed on `tare_counts` for one probing move (ProbeError if it refuses);
        the one place a trigger is armed. `trigger`: the keywords of `move_params`."""
        params = self.move_params(settings, **trigger)
        self.refuse_an_unreadable_trigger(params)
        try:
            firmware = FirmwareTrigger(params)
        except TriggerConfigError as exc:  # a calibration or option the firmware cannot represent
            raise ProbeError(ERROR_PREFIX + f"the probe's trigger cannot be set up: {exc}") from None
        error = firmware.arm(int(round(tare_counts)), self.clock.now_s)
        if error != TriggerError.NONE:
            raise ProbeError(self.error_message(error, settings.options))
        return firmware

    def refuse_an_unreadable_trigger(self, params: TriggerParams) -> None:
        """ProbeError when the trigger force lies beyond what the ADC can read from the calibration
        zero at this counts_per_gram (the move could never trigger: only the rails would stop it)."""
        low, high = params.counts_range
        readable_g = min(high - params.reference_tare_counts, params.reference_tare_counts - low) / params.counts_per_gram
        if params.trigger_force_g >= readable_g:
            raise ProbeError(ERROR_PREFIX + f"the trigger force ({params.trigger_force_g:g}g) is beyond what the load cell "
                             f"can read: at counts_per_gram {params.counts_per_gram:g} the ADC's range ends "
                             f"{max(readable_g, 0.0):.3g}g from the calibration zero; check counts_per_gram "
                             "(LOAD_CELL_CALIBRATE) and the sensor's gain")
