"""The firmware load-cell trigger and filter (firmware/src/load_cell_trigger.c, sos_filter.c) from Python.

`FirmwareTrigger` runs the real C endstop: the host part here only converts the
user's units (grams, seconds, counts per gram) into the firmware's fixed point
(Q16.15 grams, a scale with its own fraction bits, timer ticks) and back. A batch
of samples costs one C call, which stops at the first trigger, release or error.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

import numpy as np

from tapcell.filters import INT32_MAX, INT32_MIN, Q1615_ONE_G, QuantizedSos, choose_frac_bits
from tapcell.mcu import _lib
from tapcell.mcu.sensors import GENERIC_NOISE_FLOOR_COUNTS, stuck_sample_count

_CDEF = """
struct tc_sos_filter {
    int64_t state[4][2];
    int64_t round_half;
    int32_t coeff[4][5];
    uint8_t n_sections;
    uint8_t frac_bits;
    uint8_t overflowed;
};
struct tc_trigger_config {
    int32_t reference_tare_counts;
    int32_t force_limit_counts;
    int32_t drift_limit_counts;
    int32_t scale;
    uint32_t scale_frac_bits;
    int32_t trigger_q;
    int32_t release_q;
    uint32_t sample_period_ticks;
    uint32_t watchdog_periods;
    uint32_t stuck_samples;
};
struct tc_trigger {
    uint8_t state;
    uint8_t error;
    uint8_t glitch_held;
    uint32_t last_sample_ticks;
    uint32_t force_low;
    uint32_t force_span;
    int32_t last_counts;
    uint32_t repeats;
    uint32_t drift_low;
    uint32_t drift_span;
    int32_t tare_counts;
    int32_t filtered_q;
    uint32_t glitches;
    uint32_t arm_ticks;
    uint32_t trigger_ticks;
    uint32_t release_ticks;
    uint32_t error_ticks;
    uint32_t watchdog_ticks;
    uint32_t stuck_repeats;
    uint32_t scale_round;
    uint32_t trigger_bias;
    struct tc_trigger_config cfg;
    struct tc_sos_filter filter;
};
int tc_sos_filter_configure(struct tc_sos_filter *f, const int32_t coeff[][5],
                            unsigned n_sections, unsigned frac_bits);
size_t tc_sos_filter_run(struct tc_sos_filter *f, const int32_t *x, int32_t *y, size_t n);
int tc_trigger_configure(struct tc_trigger *t, const struct tc_trigger_config *cfg);
int tc_trigger_arm(struct tc_trigger *t, int32_t tare_counts, uint32_t arm_ticks);
int tc_trigger_check_watchdog(struct tc_trigger *t, uint32_t now_ticks);
void tc_trigger_abort(struct tc_trigger *t, int error_code, uint32_t now_ticks);
void tc_trigger_disarm(struct tc_trigger *t);
size_t tc_trigger_feed(struct tc_trigger *t, const int32_t *counts, const uint32_t *ticks,
                       size_t n, int32_t *filtered_q, int *event);
size_t tc_trigger_struct_size(void);
"""

# Mirrors of firmware/include/load_cell_trigger.h (tests check them against the headers).
MAX_PERIOD_TICKS = 1 << 27
MAX_WATCHDOG_PERIODS = 15
MAX_STUCK_SAMPLES = 65535
_EVENT_NONE, _EVENT_TRIGGER, _EVENT_RELEASE, _EVENT_ERROR = 0, 1, 2, 3
_STATE_NAMES = ("idle", "armed", "triggered", "error")


class TriggerError(enum.IntEnum):
    """Error codes of firmware/include/tc_errors.h; SENSOR stands for any sensor driver's own code."""

    NONE = 0
    FORCE_SAFETY = 1
    DRIFT_SAFETY = 2
    WATCHDOG_TIMEOUT = 3
    FILTER_OVERFLOW = 4
    SCALE_OVERFLOW = 5
    BAD_CONFIG = 6
    STUCK_SENSOR = 7
    SENSOR = 100


class TriggerConfigError(ValueError):
    """A TriggerParams value the firmware cannot represent; names the parameter."""


@dataclass(frozen=True)
class TriggerParams:
    counts_per_gram: float
    reference_tare_counts: int
    trigger_force_g: float
    sample_rate_sps: float
    force_safety_limit_g: float = 2000.0   # raw window around the reference and the tare, every sample; 0 disables
    drift_safety_limit_g: float = 1000.0   # 0 disables (and with it the glitch quarantine)
    release_force_g: float = 0.0           # hysteresis release level; 0 = latched trigger
    watchdog_periods: int = 2
    inverted: bool = False
    sos: QuantizedSos | None = None
    clock_hz: float = 1e6                  # MCU timer ticks per second used for timestamps
    # Identical raw samples in a row that stop the move as STUCK_SENSOR; 0 disables. None: the
    # run a sensor with 16 counts RMS of noise never shows (sensors.stuck_sample_count); the
    # probe passes its own sensor's value (sensors.noise_floor_counts).
    stuck_samples: int | None = None
    # The sensor's raw range (lowest, highest count). Given, the force window never reaches past
    # it: a window wider than the ADC (force_safety_limit 0, or a limit the scale puts beyond the
    # range) becomes the widest window inside it, so a saturated sample always stops the move.
    counts_range: tuple[int, int] | None = None

    @property
    def effective_stuck_samples(self) -> int:
        if self.stuck_samples is not None:
            return self.stuck_samples
        return stuck_sample_count(GENERIC_NOISE_FLOOR_COUNTS, self.sample_rate_sps, MAX_STUCK_SAMPLES)


@dataclass
class FeedResult:
    trigger_index: int | None        # index in the batch of the triggering sample
    trigger_time_s: float | None     # that sample's own timestamp
    release_index: int | None        # hysteresis: index of the releasing sample
    release_time_s: float | None
    error: TriggerError              # NONE or the sticky error
    error_index: int | None          # index of the sample that caused the error (None: earlier)
    glitches: int                    # quarantined samples dropped since arm
    consumed: int                    # samples the firmware took (stops after an event)
    filtered_g: np.ndarray | None    # filtered force after each consumed sample (when asked)
    sensor_error_code: int | None = None  # the sensor driver's code when error is SENSOR


def _error_from_code(code: int) -> TriggerError:
    try:
        return TriggerError(code)
    except ValueError:
        return TriggerError.SENSOR


def _check(name: str, value: float, ok: bool, allowed: str) -> None:
    if not ok:
        raise TriggerConfigError(f"{name}: {value!r} is not allowed; allowed: {allowed}")


def _finite(value: object) -> bool:
    return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool) \
        and math.isfinite(float(value))


def quantize_scale(counts_per_gram: float, inverted: bool) -> tuple[int, int]:
    """(scale, frac_bits): Q16.15 grams per count, times 2^frac_bits, negative when inverted."""
    grams_q_per_count = Q1615_ONE_G / counts_per_gram
    frac_bits = choose_frac_bits(grams_q_per_count)
    scale = math.floor(grams_q_per_count * 2.0 ** frac_bits + 0.5)
    return (-scale if inverted else scale), frac_bits


def reference_counts_to_q1615(counts: np.ndarray, tare_counts: int, scale: int, frac_bits: int) -> np.ndarray:
    """The firmware's counts -> Q16.15 conversion: ((counts - tare) * scale + 2^(f-1)) >> f."""
    offset = np.asarray(counts, dtype=np.int64) - int(tare_counts)
    return np.array([(int(o) * scale + (1 << (frac_bits - 1))) >> frac_bits for o in offset], dtype=np.int64)


def _limit_counts(name: str, limit_g: float, counts_per_gram: float) -> int:
    _check(name, limit_g, _finite(limit_g) and limit_g >= 0, "0 (disabled) or a positive force in grams")
    if limit_g == 0:
        return 0
    counts = max(1, round(limit_g * counts_per_gram))
    _check(name, limit_g, counts <= INT32_MAX, f"at most {INT32_MAX / counts_per_gram:g} g at this counts_per_gram")
    return counts


def _limits_inside_range(p: TriggerParams) -> tuple[int, int]:
    """(force, drift) window half widths in counts when the sensor's range is known: the force
    window at most the widest one around reference_tare_counts that stays off both rails (also
    when force_safety_limit is 0: the last line that nothing turns off), the drift window at most
    the whole range (a wider one can never be left)."""
    low, high = (int(v) for v in p.counts_range)
    _check("force_safety_limit_g", p.force_safety_limit_g, _finite(p.force_safety_limit_g) and p.force_safety_limit_g >= 0,
           "0 (disabled) or a positive force in grams")
    _check("drift_safety_limit_g", p.drift_safety_limit_g, _finite(p.drift_safety_limit_g) and p.drift_safety_limit_g >= 0,
           "0 (disabled) or a positive force in grams")
    inside_rails = max(1, min(high - 1 - p.reference_tare_counts, p.reference_tare_counts - 1 - low))
    force = max(1, round(p.force_safety_limit_g * p.counts_per_gram)) if p.force_safety_limit_g else inside_rails
    drift = max(1, round(p.drift_safety_limit_g * p.counts_per_gram)) if p.drift_safety_limit_g else 0
    return min(force, inside_rails), min(drift, high - low)


def _config_values(p: TriggerParams) -> dict:
    _check("counts_per_gram", p.counts_per_gram, _finite(p.counts_per_gram) and 1e-4 < p.counts_per_gram < 1e9,
           "a positive number of counts per gram (1e-4 .. 1e9)")
    _check("reference_tare_counts", p.reference_tare_counts,
           isinstance(p.reference_tare_counts, (int, np.integer)) and INT32_MIN <= p.reference_tare_counts <= INT32_MAX,
           "an integer count within int32")
    _check("trigger_force_g", p.trigger_force_g, _finite(p.trigger_force_g) and 0 < p.trigger_force_g < 65536,
           "above 0 and below 65536 g")
    _check("release_force_g", p.release_force_g,
           _finite(p.release_force_g) and 0 <= p.release_force_g < p.trigger_force_g,
           f"0 (latched trigger) or above 0 and below trigger_force_g ({p.trigger_force_g:g} g)")
    _check("clock_hz", p.clock_hz, _finite(p.clock_hz) and p.clock_hz > 0, "a positive tick rate in Hz")
    _check("sample_rate_sps", p.sample_rate_sps, _finite(p.sample_rate_sps) and p.sample_rate_sps > 0,
           "a positive sample rate")
    period_ticks = round(p.clock_hz / p.sample_rate_sps)
    _check("sample_rate_sps", p.sample_rate_sps, 1 <= period_ticks < MAX_PERIOD_TICKS,
           f"a sample period of 1 .. {MAX_PERIOD_TICKS - 1} ticks at clock_hz {p.clock_hz:g}")
    _check("watchdog_periods", p.watchdog_periods,
           isinstance(p.watchdog_periods, (int, np.integer)) and 1 <= p.watchdog_periods <= MAX_WATCHDOG_PERIODS,
           f"an integer 1 .. {MAX_WATCHDOG_PERIODS}")
    stuck = p.effective_stuck_samples
    _check("stuck_samples", p.stuck_samples,
           isinstance(stuck, (int, np.integer)) and (stuck == 0 or 2 <= stuck <= MAX_STUCK_SAMPLES),
           f"0 (disabled) or an integer 2 .. {MAX_STUCK_SAMPLES}")
    scale, scale_frac_bits = quantize_scale(p.counts_per_gram, bool(p.inverted))
    if p.counts_range is None:
        force_limit_counts = _limit_counts("force_safety_limit_g", p.force_safety_limit_g, p.counts_per_gram)
        drift_limit_counts = _limit_counts("drift_safety_limit_g", p.drift_safety_limit_g, p.counts_per_gram)
    else:
        force_limit_counts, drift_limit_counts = _limits_inside_range(p)
    _check("force_safety_limit_g", p.force_safety_limit_g,
           INT32_MIN <= p.reference_tare_counts - force_limit_counts
           and p.reference_tare_counts + force_limit_counts <= INT32_MAX,
           "a window reference_tare_counts +- limit within int32")
    return {
        "reference_tare_counts": int(p.reference_tare_counts),
        "force_limit_counts": force_limit_counts,
        "drift_limit_counts": drift_limit_counts,
        "scale": scale,
        "scale_frac_bits": scale_frac_bits,
        "trigger_q": max(1, round(p.trigger_force_g * Q1615_ONE_G)),
        "release_q": round(p.release_force_g * Q1615_ONE_G),
        "sample_period_ticks": period_ticks,
        "watchdog_periods": int(p.watchdog_periods),
        "stuck_samples": int(stuck),
    }


def _firmware():
    ffi, lib = _lib.load(_CDEF)
    if ffi.sizeof("struct tc_trigger") != lib.tc_trigger_struct_size():
        raise _lib.FirmwareBuildError("struct tc_trigger in mcu/trigger.py does not match load_cell_trigger.h")
    return ffi, lib


def _configure_filter(ffi, lib, filter_ptr, sos: QuantizedSos | None) -> None:
    if sos is None or sos.n_sections == 0:
        status = lib.tc_sos_filter_configure(filter_ptr, ffi.NULL, 0, 30)
    else:
        coeff = np.ascontiguousarray(sos.coeff, dtype=np.int32)
        status = lib.tc_sos_filter_configure(filter_ptr, ffi.from_buffer("int32_t[][5]", coeff),
                                             sos.n_sections, sos.frac_bits)
    if status != 0:
        raise TriggerConfigError(f"sos: {sos.n_sections} sections with {sos.frac_bits} fraction bits "
                                 "is not allowed; allowed: at most 4 sections, 1 .. 30 fraction bits, "
                                 "no coefficient equal to -2^31")


class Endstop:
    """What the host sees of one firmware endstop: user units in, FeedResult out.

    The conversions (seconds -> wrapping ticks, batch -> first event) live here once;
    a subclass supplies the per-sample machine: FirmwareTrigger (the C code through cffi)
    or tapcell.mcu.trigger_model.TriggerModel (its bit-exact Python model).
    """

    def __init__(self, params: TriggerParams):
        self.params = params
        self.config = _config_values(params)

    # -- the machine (subclasses) -----------------------------------------------------
    def _arm(self, tare_counts: int, arm_ticks: int) -> int:
        raise NotImplementedError

    def _feed(self, counts: np.ndarray, ticks: np.ndarray, filtered: np.ndarray | None) -> tuple[int, int]:
        """tc_trigger_feed: (index of the first event or len, its event); fills `filtered`."""
        raise NotImplementedError

    def _check_watchdog(self, now_ticks: int) -> int:
        raise NotImplementedError

    def _abort(self, error_code: int, now_ticks: int) -> None:
        raise NotImplementedError

    def disarm(self) -> None:
        raise NotImplementedError

    def field(self, name: str) -> int:
        """A member of struct tc_trigger: state, error, glitches, ..."""
        raise NotImplementedError

    # -- host units ---------------------------------------------------------------------
    def ticks(self, t_s: np.ndarray | float) -> np.ndarray:
        """Seconds -> MCU timer ticks (uint32, wrapping)."""
        scaled = np.floor(np.asarray(t_s, dtype=np.float64) * self.params.clock_hz + 0.5)
        return np.mod(scaled, 2.0 ** 32).astype(np.uint32)

    def arm(self, tare_counts: int, t_arm_s: float) -> TriggerError:
        """Start a move; runs the force_safety check on the tare."""
        _check("tare_counts", tare_counts, INT32_MIN <= int(tare_counts) <= INT32_MAX, "an integer count within int32")
        return _error_from_code(self._arm(int(tare_counts), int(self.ticks(t_arm_s))))

    def feed(self, t_s: np.ndarray, counts: np.ndarray, want_filtered: bool = False) -> FeedResult:
        """Run a batch of samples through the endstop; stops after the first event."""
        t_s = np.ascontiguousarray(t_s, dtype=np.float64)
        counts_in = np.asarray(counts)
        if t_s.ndim != 1 or counts_in.shape != t_s.shape:
            raise ValueError(f"feed: t_s and counts must be 1-D arrays of one length, got {t_s.shape} and "
                             f"{counts_in.shape}")
        if counts_in.size and (counts_in.min() < INT32_MIN or counts_in.max() > INT32_MAX):
            raise ValueError("feed: counts must fit int32")
        filtered = np.zeros(t_s.size, dtype=np.int32) if want_filtered else None
        index, event = self._feed(np.ascontiguousarray(counts_in, dtype=np.int32), self.ticks(t_s), filtered)
        hit = None if event == _EVENT_NONE else int(index)
        consumed = t_s.size if hit is None else hit + 1
        error = self.error
        return FeedResult(
            trigger_index=hit if event == _EVENT_TRIGGER else None,
            trigger_time_s=float(t_s[hit]) if event == _EVENT_TRIGGER else None,
            release_index=hit if event == _EVENT_RELEASE else None,
            release_time_s=float(t_s[hit]) if event == _EVENT_RELEASE else None,
            error=error,
            error_index=hit if event == _EVENT_ERROR else None,
            glitches=self.glitches,
            consumed=consumed,
            filtered_g=filtered[:consumed] / Q1615_ONE_G if want_filtered else None,
            sensor_error_code=self.field("error") if error == TriggerError.SENSOR else None,
        )

    def check_watchdog(self, now_s: float) -> TriggerError:
        """The MCU timer's check: WATCHDOG_TIMEOUT after more than watchdog_periods periods without a sample."""
        return _error_from_code(self._check_watchdog(int(self.ticks(now_s))))

    def abort(self, error_code: int, now_s: float) -> None:
        """Stop an active move with an error code (e.g. a sensor driver's code)."""
        _check("error_code", error_code, 1 <= int(error_code) <= 255, "1 .. 255")
        self._abort(int(error_code), int(self.ticks(now_s)))

    @property
    def state(self) -> str:
        """'idle' | 'armed' | 'triggered' | 'error'."""
        return _STATE_NAMES[self.field("state")]

    @property
    def error(self) -> TriggerError:
        return _error_from_code(self.field("error"))

    @property
    def glitches(self) -> int:
        return self.field("glitches")


class FirmwareTrigger(Endstop):
    """One instance of the firmware endstop (struct tc_trigger owned by this object)."""

    def __init__(self, params: TriggerParams):
        super().__init__(params)
        self._ffi, self._lib = _firmware()
        self._t = self._ffi.new("struct tc_trigger *")
        _configure_filter(self._ffi, self._lib, self._ffi.addressof(self._t, "filter"), params.sos)
        config = self._ffi.new("struct tc_trigger_config *", self.config)
        if self._lib.tc_trigger_configure(self._t, config) != 0:
            raise TriggerConfigError(f"trigger parameters rejected by the firmware: {self.config}")
        self._event = self._ffi.new("int *")

    def _arm(self, tare_counts: int, arm_ticks: int) -> int:
        return self._lib.tc_trigger_arm(self._t, tare_counts, arm_ticks)

    def _feed(self, counts, ticks, filtered):
        ffi = self._ffi
        index = self._lib.tc_trigger_feed(
            self._t, ffi.from_buffer("int32_t[]", counts), ffi.from_buffer("uint32_t[]", ticks), counts.size,
            ffi.NULL if filtered is None else ffi.from_buffer("int32_t[]", filtered), self._event)
        return int(index), self._event[0]

    def _check_watchdog(self, now_ticks: int) -> int:
        return self._lib.tc_trigger_check_watchdog(self._t, now_ticks)

    def _abort(self, error_code: int, now_ticks: int) -> None:
        self._lib.tc_trigger_abort(self._t, error_code, now_ticks)

    def disarm(self) -> None:
        self._lib.tc_trigger_disarm(self._t)

    def field(self, name: str) -> int:
        return int(getattr(self._t, name))


def sos_filter_run(qsos: QuantizedSos | None, x_q: np.ndarray) -> tuple[np.ndarray, bool]:
    """The C filter over a signal from zero state: (int32 outputs, whether anything overflowed)."""
    ffi, lib = _firmware()
    x = np.asarray(x_q)
    if x.size and (x.min() < INT32_MIN or x.max() > INT32_MAX):
        raise ValueError("x_q: values must fit int32 (Q16.15 grams)")
    x = np.ascontiguousarray(x, dtype=np.int32)
    y = np.empty_like(x)
    f = ffi.new("struct tc_sos_filter *")
    _configure_filter(ffi, lib, f, qsos)
    first_overflow = lib.tc_sos_filter_run(f, ffi.from_buffer("int32_t[]", x), ffi.from_buffer("int32_t[]", y),
                                           x.size)
    return y, bool(first_overflow < x.size)
