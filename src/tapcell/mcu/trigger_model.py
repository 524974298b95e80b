"""A bit-exact Python model of the firmware endstop (firmware/src/load_cell_trigger.c).

Written from the rules in firmware/include/load_cell_trigger.h, with Python integers and
explicit 32-bit wrapping where the C code wraps, and the filter's own model
(tapcell.filters.ReferenceSosFilter). It has the host API of FirmwareTrigger (same
Endstop base), so tests run one random configuration and sample stream through both
and compare every result; it also lets anyone read the per-sample rules in Python.
Single-threaded: the C code's critical sections have nothing to guard here.
"""

from __future__ import annotations

import numpy as np

from tapcell.filters import INT32_MAX, INT32_MIN, MAX_SECTIONS, ReferenceSosFilter
from tapcell.mcu.trigger import (
    _EVENT_ERROR, _EVENT_NONE, _EVENT_RELEASE, _EVENT_TRIGGER, Endstop, TriggerConfigError, TriggerError,
    TriggerParams,
)

U32 = 0xFFFFFFFF
IDLE, ARMED, TRIGGERED, ERROR = 0, 1, 2, 3


def _u32(value: int) -> int:
    return value & U32


def _s32(value: int) -> int:
    value &= U32
    return value - (1 << 32) if value >> 31 else value


class TriggerModel(Endstop):
    """struct tc_trigger and its functions, sample by sample."""

    def __init__(self, params: TriggerParams):
        super().__init__(params)
        sos = params.sos
        if sos is not None and (sos.n_sections > MAX_SECTIONS or not 1 <= sos.frac_bits <= 30
                                or np.any(np.asarray(sos.coeff) == INT32_MIN)):
            raise TriggerConfigError(f"sos: {sos.n_sections} sections with {sos.frac_bits} fraction bits "
                                     "is not allowed; allowed: at most 4 sections, 1 .. 30 fraction bits, "
                                     "no coefficient equal to -2^31")
        self.filter = ReferenceSosFilter(sos)
        c = self.config
        self.watchdog_ticks = c["watchdog_periods"] * c["sample_period_ticks"]
        self.stuck_repeats = _u32(c["stuck_samples"] - 1)      # 0 (off) -> never reached
        self.state_code = IDLE
        self.error_code = 0
        self.glitch_held = False
        self.glitch_count = 0
        self.filtered_q = 0
        self.trigger_ticks = self.release_ticks = self.error_ticks = 0

    # -- the C functions ------------------------------------------------------------
    def _listening(self, state: int) -> bool:
        return state == ARMED or (state == TRIGGERED and self.config["release_q"] != 0)

    def _fail(self, code: int, ticks: int) -> int:
        self.state_code, self.error_code, self.error_ticks = ERROR, code, ticks
        return _EVENT_ERROR

    def _arm(self, tare_counts: int, arm_ticks: int) -> int:
        c = self.config
        self.filter.reset()
        self.tare_counts = tare_counts
        self.last_sample_ticks = arm_ticks
        self.last_counts = INT32_MIN
        self.repeats = 0
        self.glitch_count = 0
        self.glitch_held = False
        self.filtered_q = 0
        self.error_code = 0
        self.state_code = ARMED
        drift = c["drift_limit_counts"]
        self.drift_low = _u32(tare_counts - drift)
        self.drift_span = 2 * drift if drift else U32
        # reference +- limit intersected with tare +- limit
        limit, reference = c["force_limit_counts"], c["reference_tare_counts"]
        larger, smaller = max(tare_counts, reference), min(tare_counts, reference)
        self.force_low = _u32(larger - limit)
        self.force_span = _u32(2 * limit - (larger - smaller)) if limit else U32
        if limit and larger - smaller > limit:
            self._fail(TriggerError.FORCE_SAFETY, arm_ticks)
            return TriggerError.FORCE_SAFETY
        return 0

    def sample(self, counts: int, ticks: int) -> int:
        """tc_trigger_sample: one raw sample at its timestamp; returns the event."""
        c = self.config
        state = self.state_code
        if not self._listening(state):
            return _EVENT_NONE
        since_last = _u32(ticks - self.last_sample_ticks)
        if since_last > self.watchdog_ticks:
            if _s32(since_last) < 0:
                return _EVENT_NONE                                   # before the arm time / last sample
            return self._fail(TriggerError.WATCHDOG_TIMEOUT, ticks)
        self.last_sample_ticks = ticks
        if _u32(counts - self.force_low) > self.force_span:
            return self._fail(TriggerError.FORCE_SAFETY, ticks)
        if counts != self.last_counts:
            self.last_counts, self.repeats = counts, 0
        else:
            self.repeats = _u32(self.repeats + 1)
            if self.repeats >= self.stuck_repeats:
                return self._fail(TriggerError.STUCK_SENSOR, ticks)
        if _u32(counts - self.drift_low) > self.drift_span:
            if self.glitch_held:
                return self._fail(TriggerError.DRIFT_SAFETY, ticks)
            self.glitch_held = True
            return _EVENT_NONE
        if self.glitch_held:
            self.glitch_held = False
            self.glitch_count += 1
        offset = counts - self.tare_counts
        frac = c["scale_frac_bits"]
        grams_q = (offset * c["scale"] + (1 << (frac - 1))) >> frac
        if not (INT32_MIN <= offset <= INT32_MAX and INT32_MIN <= grams_q <= INT32_MAX):
            return self._fail(TriggerError.SCALE_OVERFLOW, ticks)
        force_q = self.filter.apply(grams_q)
        if self.filter.overflowed:
            return self._fail(TriggerError.FILTER_OVERFLOW, ticks)
        self.filtered_q = force_q
        if state == ARMED:
            bias = c["trigger_q"] - 1
            if _u32(force_q + bias) > 2 * bias:
                self.state_code, self.trigger_ticks = TRIGGERED, ticks
                return _EVENT_TRIGGER
        else:
            bias = c["release_q"] - 1
            if _u32(force_q + bias) <= 2 * bias:
                self.state_code, self.release_ticks = ARMED, ticks
                return _EVENT_RELEASE
        return _EVENT_NONE

    def _feed(self, counts, ticks, filtered):
        for i, (value, stamp) in enumerate(zip(counts.tolist(), ticks.tolist())):
            event = self.sample(value, stamp)
            if filtered is not None:
                filtered[i] = self.filtered_q
            if event != _EVENT_NONE:
                return i, event
        return counts.size, _EVENT_NONE

    def _check_watchdog(self, now_ticks: int) -> int:
        if self._listening(self.state_code) and _s32(now_ticks - self.last_sample_ticks) > self.watchdog_ticks:
            self._fail(TriggerError.WATCHDOG_TIMEOUT, now_ticks)
        return self.error_code

    def _abort(self, error_code: int, now_ticks: int) -> None:
        if self._listening(self.state_code):
            self._fail(error_code, now_ticks)

    def disarm(self) -> None:
        self.state_code, self.error_code, self.glitch_held = IDLE, 0, False

    def field(self, name: str) -> int:
        """The value of struct tc_trigger's member `name` (state, error and glitches are named differently here: the base class has properties of those names)."""
        return int(getattr(self, {"state": "state_code", "error": "error_code", "glitches": "glitch_count"}.get(name, name)))
