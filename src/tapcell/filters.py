"""Continuous-tare filter for the MCU trigger: design, validation, quantization, reference.

Design (SciPy) follows the ``[load_cell_probe]`` options, sections in this order:
drift high-pass Butterworth (order = ``drift_filter_delay``), buzz low-pass Butterworth
(order = ``buzz_filter_delay``), then one ``iirnotch`` section per notch frequency.
Orders 1 and 2 are one biquad each, so at most 1 + 1 + 2 = 4 sections.

Quantization targets the firmware's formats (firmware/include/sos_filter.h): values are
int32 Q16.15 grams; coefficients int32 with one fraction-bit count for the cascade.
``reference_sosfilt_q`` is the bit-exact model of the firmware arithmetic (64-bit
products and states, one round-half-up per section output with error feedback,
saturation on overflow).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

Q1615_ONE_G = 1 << 15  # 1 g in Q16.15
INT32_MIN, INT32_MAX = -(1 << 31), (1 << 31) - 1
INT64_MIN, INT64_MAX = -(1 << 63), (1 << 63) - 1
MAX_SECTIONS = 4
MIN_FRAC_BITS, MAX_FRAC_BITS = 1, 30

DRIFT_CUTOFF_MIN_HZ, DRIFT_CUTOFF_MAX_HZ = 0.1, 20.0
BUZZ_CUTOFF_FLOOR_HZ = 80.0
# The config reference: "Minimum value is 0.5 and maximum is 3.0".
NOTCH_QUALITY_MIN, NOTCH_QUALITY_MAX = 0.5, 3.0
MAX_NOTCHES = 2
FILTER_ORDERS = (1, 2)


class FilterDesignError(ValueError):
    """A filter option value is not allowed; names the option, the value and what is allowed."""

    def __init__(self, option: str, value: object, allowed: str):
        self.option = option
        self.value = value
        self.allowed = allowed
        super().__init__(f"{option}: {value!r} is not allowed; allowed: {allowed}")


@dataclass(frozen=True)
class FilterOptions:
    """The ``[load_cell_probe]`` filter options (None / empty = that filter is off)."""

    sample_rate_sps: float
    drift_filter_cutoff_frequency: float | None = None
    drift_filter_delay: int = 2
    buzz_filter_cutoff_frequency: float | None = None
    buzz_filter_delay: int = 2
    notch_filter_frequencies: Sequence[float] = ()
    notch_filter_quality: float = 2.0


@dataclass(frozen=True)
class QuantizedSos:
    """A cascade in the firmware's fixed point.

    coeff: int32 array (n_sections, 5) with columns b0, b1, b2, a1, a2 (a0 = 1 is implied);
    frac_bits: fraction bits of every coefficient (30 = Q1.30).
    """

    coeff: np.ndarray
    frac_bits: int

    @property
    def n_sections(self) -> int:
        return int(self.coeff.shape[0])


def _finite_number(option: str, value: object, allowed: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise FilterDesignError(option, value, allowed)
    if not math.isfinite(float(value)):
        raise FilterDesignError(option, value, allowed)
    return float(value)


def _order(option: str, value: object) -> int:
    allowed = "1 or 2 (the Butterworth order)"
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value not in FILTER_ORDERS:
        raise FilterDesignError(option, value, allowed)
    return int(value)


def half_rate_hz(sample_rate_sps: float) -> int:
    """floor(sps / 2): the upper limit the buzz and notch options are checked against."""
    return math.floor(sample_rate_sps / 2)


def buzz_cutoff_minimum_hz(sample_rate_sps: float) -> float:
    """The buzz cutoff must be strictly above min(80, floor(sps/2) - 1)."""
    return min(BUZZ_CUTOFF_FLOOR_HZ, half_rate_hz(sample_rate_sps) - 1)


def validate_filter_options(opts: FilterOptions) -> None:
    """Check every option against its allowed range; raise FilterDesignError for the first bad one."""
    sps = _finite_number("sample_rate_sps", opts.sample_rate_sps, "a positive sample rate")
    if sps <= 0:
        raise FilterDesignError("sample_rate_sps", opts.sample_rate_sps, "a positive sample rate")
    nyquist = half_rate_hz(sps)
    drift = opts.drift_filter_cutoff_frequency
    if drift is not None:
        drift_max = min(DRIFT_CUTOFF_MAX_HZ, sps / 2)
        allowed = (f"{DRIFT_CUTOFF_MIN_HZ:g} to {DRIFT_CUTOFF_MAX_HZ:g} Hz"
                   + ("" if drift_max == DRIFT_CUTOFF_MAX_HZ else f", below {sps / 2:g} Hz (half of {sps:g} sps)"))
        value = _finite_number("drift_filter_cutoff_frequency", drift, allowed)
        if not (DRIFT_CUTOFF_MIN_HZ <= value <= DRIFT_CUTOFF_MAX_HZ) or value >= sps / 2:
            raise FilterDesignError("drift_filter_cutoff_frequency", drift, allowed)
    _order("drift_filter_delay", opts.drift_filter_delay)
    buzz = opts.buzz_filter_cutoff_frequency
    if buzz is not None:
        low = buzz_cutoff_minimum_hz(sps)
        allowed = f"above {low:g} Hz and below {nyquist:g} Hz at {sps:g} sps"
        value = _finite_number("buzz_filter_cutoff_frequency", buzz, allowed)
        if not (low < value < nyquist):
            raise FilterDesignError("buzz_filter_cutoff_frequency", buzz, allowed)
    _order("buzz_filter_delay", opts.buzz_filter_delay)
    notches = opts.notch_filter_frequencies
    if isinstance(notches, (str, bytes)) or not isinstance(notches, Sequence):
        raise FilterDesignError("notch_filter_frequencies", notches, f"a list of at most {MAX_NOTCHES} frequencies")
    if len(notches) > MAX_NOTCHES:
        raise FilterDesignError("notch_filter_frequencies", list(notches),
                                f"at most {MAX_NOTCHES} frequencies")
    low_name = f"the drift cutoff {float(drift):g} Hz" if drift is not None else "0 Hz"
    high = float(buzz) if buzz is not None else float(nyquist)
    high_name = f"the buzz cutoff {high:g} Hz" if buzz is not None else f"{nyquist:g} Hz (half of {sps:g} sps)"
    allowed = f"each above {low_name} and below {high_name}"
    low = float(drift) if drift is not None else 0.0
    for f0 in notches:
        value = _finite_number("notch_filter_frequencies", f0, allowed)
        if not (low < value < high):
            raise FilterDesignError("notch_filter_frequencies", f0, allowed)
    allowed = f"{NOTCH_QUALITY_MIN:g} to {NOTCH_QUALITY_MAX:g}"
    q = _finite_number("notch_filter_quality", opts.notch_filter_quality, allowed)
    if not (NOTCH_QUALITY_MIN <= q <= NOTCH_QUALITY_MAX):
        raise FilterDesignError("notch_filter_quality", opts.notch_filter_quality, allowed)
    # A notch's width is f0 / Q; at half the sample rate or wider the design degenerates
    # (scipy's iirnotch divides by zero there and returns coefficients of ~1e16).
    for f0 in notches:
        if float(f0) / q >= sps / 2.0:
            raise FilterDesignError(
                "notch_filter_quality", opts.notch_filter_quality,
                f"above {2.0 * float(f0) / sps:g} for a notch at {float(f0):g} Hz (its width, frequency / quality, "
                f"must stay below half of {sps:g} sps)")


def design_sos(opts: FilterOptions) -> np.ndarray:
    """Float64 second-order sections (n, 6) for the options; (0, 6) when no filter is on."""
    validate_filter_options(opts)
    sections = []
    sps = float(opts.sample_rate_sps)
    if opts.drift_filter_cutoff_frequency is not None or opts.buzz_filter_cutoff_frequency is not None \
            or len(opts.notch_filter_frequencies):
        from scipy import signal  # SciPy only when a filter is configured
        if opts.drift_filter_cutoff_frequency is not None:
            sections.append(signal.butter(opts.drift_filter_delay, float(opts.drift_filter_cutoff_frequency),
                                          btype="highpass", fs=sps, output="sos"))
        if opts.buzz_filter_cutoff_frequency is not None:
            sections.append(signal.butter(opts.buzz_filter_delay, float(opts.buzz_filter_cutoff_frequency),
                                          btype="lowpass", fs=sps, output="sos"))
        for f0 in opts.notch_filter_frequencies:
            b, a = signal.iirnotch(float(f0), float(opts.notch_filter_quality), fs=sps)
            sections.append(np.concatenate([b, a])[np.newaxis, :] / a[0])  # one biquad already
    if not sections:
        return np.zeros((0, 6))
    return np.vstack(sections)


def choose_frac_bits(max_abs: float, max_bits: int = MAX_FRAC_BITS) -> int:
    """Most fraction bits f <= max_bits with round(max_abs * 2^f) still inside int32."""
    if max_abs == 0:
        return max_bits
    frac_bits = min(max_bits, 31 - int(max_abs).bit_length())
    while frac_bits >= 1 and math.floor(max_abs * 2.0 ** frac_bits + 0.5) > INT32_MAX:
        frac_bits -= 1
    return frac_bits


def _fixed_sections(coeff: np.ndarray, frac_bits: int) -> np.ndarray:
    """Round (n, 5) float coefficients to int64 at frac_bits, keeping each numerator's sum.

    b1 takes up the rounding of b0 + b1 + b2, so a high-pass section's zero at z = 1
    stays exact. Rounding the three b's on their own leaves B(1) up to 1.5 LSB, and a
    drift high-pass has A(1) ~ 1e-4 (0.8 Hz at 660 sps), so its DC gain would be
    ~1e-5: 0.03 g of a 2 kg offset leaking through, 0.3 g at 0.1 Hz and 2000 sps.
    """
    scale = 2.0 ** frac_bits
    fixed = np.floor(coeff * scale + 0.5).astype(np.int64)
    numerator_sum = np.floor(coeff[:, :3].sum(axis=1) * scale + 0.5).astype(np.int64)
    fixed[:, 1] = numerator_sum - fixed[:, 0] - fixed[:, 2]
    return fixed


def quantize_sos(sos: np.ndarray) -> QuantizedSos:
    """Convert float sections (n, 6) with a0 = 1 to the firmware's int32 coefficients."""
    sos = np.asarray(sos, dtype=np.float64)
    if sos.ndim != 2 or sos.shape[1] != 6 or sos.shape[0] > MAX_SECTIONS:
        raise FilterDesignError("sos", f"array of shape {sos.shape}", f"shape (n, 6) with n <= {MAX_SECTIONS}")
    if not np.all(np.isfinite(sos)) or not np.allclose(sos[:, 3], 1.0, rtol=0, atol=1e-12):
        raise FilterDesignError("sos", "a0 column", "finite sections normalised to a0 = 1")
    coeff = sos[:, [0, 1, 2, 4, 5]]
    max_abs = float(np.max(np.abs(coeff))) if coeff.size else 0.0
    frac_bits = choose_frac_bits(max_abs)
    fixed = _fixed_sections(coeff, frac_bits)
    # The firmware refuses INT32_MIN (it keeps every section's sums inside int64).
    while frac_bits >= MIN_FRAC_BITS and fixed.size and (fixed.min() <= INT32_MIN or fixed.max() > INT32_MAX):
        frac_bits -= 1  # the adjusted b1 stepped past int32
        fixed = _fixed_sections(coeff, frac_bits)
    if frac_bits < MIN_FRAC_BITS:
        raise FilterDesignError("sos", f"coefficient magnitude {max_abs:g}", "coefficients below 2^30")
    return QuantizedSos(coeff=fixed.astype(np.int32), frac_bits=frac_bits)


def design_firmware_filter(opts: FilterOptions) -> QuantizedSos | None:
    """Design and quantize; None when no filter option is on."""
    sos = design_sos(opts)
    return quantize_sos(sos) if len(sos) else None


def grams_to_q1615(grams: np.ndarray | float) -> np.ndarray:
    """Grams to int32 Q16.15 (round half up); ValueError outside +-65536 g."""
    q = np.floor(np.asarray(grams, dtype=np.float64) * Q1615_ONE_G + 0.5)
    if np.any(~np.isfinite(q)) or np.any(q < INT32_MIN) or np.any(q > INT32_MAX):
        raise ValueError("grams: values must be finite and within -65536 .. 65535.99997 g (Q16.15)")
    return q.astype(np.int32)


def q1615_to_grams(q: np.ndarray | int) -> np.ndarray:
    return np.asarray(q, dtype=np.float64) / Q1615_ONE_G


def _sat(value: int, low: int, high: int) -> tuple[int, bool]:
    if value < low:
        return low, True
    if value > high:
        return high, True
    return value, False


def _wrap_int32(value: int) -> int:
    return ((value + (1 << 31)) & 0xFFFFFFFF) - (1 << 31)


class ReferenceSosFilter:
    """Bit-exact model of one tc_sos_filter, one sample at a time (from zero state).

    Python integers hold the 64-bit intermediate values exactly; saturation and the
    32-bit rounding-error term follow the C code (firmware/include/sos_filter.h).
    `overflowed` is sticky like the C flag. The trigger model (tapcell.mcu.trigger_model)
    steps it sample by sample; reference_sosfilt_q runs it over a whole signal.
    """

    def __init__(self, qsos: QuantizedSos | None):
        sections = [] if qsos is None else [[int(c) for c in row] for row in qsos.coeff]
        if any(c == INT32_MIN for row in sections for c in row):
            raise ValueError("sos: a coefficient of -2^31 is not allowed (the firmware refuses it)")
        self._coeff = sections
        self._shift = 0 if qsos is None else qsos.frac_bits
        self._half = (1 << (self._shift - 1)) if sections else 0
        self.reset()

    def reset(self) -> None:
        self._state = [[self._half, self._half] for _ in self._coeff]
        self.overflowed = False

    def apply(self, value: int) -> int:
        shift, half = self._shift, self._half
        for (b0, b1, b2, a1, a2), z in zip(self._coeff, self._state):
            acc, bad_add = _sat(b0 * value + z[0], INT64_MIN, INT64_MAX)
            y, bad_y = _sat(acc >> shift, INT32_MIN, INT32_MAX)
            err = _wrap_int32(acc - (y << shift) - half)
            z[0], bad_state = _sat(b1 * value - a1 * y + 2 * err + z[1], INT64_MIN, INT64_MAX)
            z[1] = b2 * value - a2 * y + half - err
            self.overflowed |= bad_add or bad_y or bad_state
            value = y
        return value


def reference_sosfilt_q(qsos: QuantizedSos | None, x_q: np.ndarray) -> tuple[np.ndarray, bool]:
    """Bit-exact model of tc_sos_filter_apply over a signal from zero state.

    Returns the int32 outputs and whether any value overflowed (saturated).
    """
    x = np.asarray(x_q)
    if x.size and (x.min() < INT32_MIN or x.max() > INT32_MAX):
        raise ValueError("x_q: values must fit int32 (Q16.15 grams)")
    f = ReferenceSosFilter(qsos)
    out = np.array([f.apply(value) for value in x.tolist()], dtype=np.int32)
    return out, f.overflowed
