"""Sensor facts and the firmware's sensor code, for the host.

Two things live here:

* the allowed-value tables of the supported ADC chips (sample rates, gains,
  input multiplexer and reference names), so the config layer validates with
  the same facts the firmware uses;
* thin wrappers around the firmware's sensor drivers (firmware/src/hx71x.c,
  ads1220.c), called through cffi: the ADS1220 register computation, the
  HX71x pulse count per gain, and a batch decoder of HX71x frames.

Every rule (which rate maps to which register bits, which option combinations
are refused) is decided in C, so the host and the MCU cannot disagree; Python
only maps names to the firmware's codes and turns its status codes into
`SensorConfigError`s that name the option, the value and what is allowed.
"""

from __future__ import annotations

import math
from functools import cache

import numpy as np

from tapcell.mcu import _lib

# ---------------------------------------------------------------------------
# Facts (mirrors of the firmware's tables; tests check they agree with C)

HX71X_CHIPS = ("hx711", "hx717")

# Channel/gain names per chip; the first is the default. Each selects the
# channel and gain of the *next* conversion by the number of clock pulses.
HX71X_GAINS: dict[str, tuple[str, ...]] = {
    "hx711": ("A-128", "B-32", "A-64"),
    "hx717": ("A-128", "B-64", "A-64", "B-8"),
}

ADS1220_GAINS = (1, 2, 4, 8, 16, 32, 64, 128)
ADS1220_NORMAL_SAMPLE_RATES_SPS = (20, 45, 90, 175, 330, 600, 1000)
ADS1220_TURBO_SAMPLE_RATES_SPS = (40, 90, 180, 350, 660, 1200, 2000)
# Datasheet multiplexer order: index = MUX[3:0] code.
ADS1220_INPUT_MUXES = (
    "AIN0_AIN1", "AIN0_AIN2", "AIN0_AIN3", "AIN1_AIN2", "AIN1_AIN3", "AIN2_AIN3",
    "AIN1_AIN0", "AIN3_AIN2", "AIN0_AVSS", "AIN1_AVSS", "AIN2_AVSS", "AIN3_AVSS",
)
# Datasheet reference order: index = VREF[1:0] code.
ADS1220_VREFS = ("internal", "REF0", "REF1", "analog_supply")
# SPI clock the chip's interface is run at, by operating mode.
ADS1220_SPI_SPEED_HZ = {"normal": 256000, "turbo": 512000}

# Sample rates each chip can run at (HX71x: pin-strapped; ADS1220: both modes,
# 90 once), and the defaults of the spec.
SAMPLE_RATES_SPS: dict[str, tuple[int, ...]] = {
    "hx711": (10, 80),
    "hx717": (10, 20, 80, 320),
    "ads1220": tuple(sorted(set(ADS1220_NORMAL_SAMPLE_RATES_SPS) | set(ADS1220_TURBO_SAMPLE_RATES_SPS))),
}
DEFAULT_SAMPLE_RATE_SPS = {"hx711": 80, "hx717": 320, "ads1220": 660}

HX71X_DATA_BITS = 24

# ---------------------------------------------------------------------------
# Noise floor: the least noise a live chip shows, and the stuck-sensor run length
#
# The firmware calls a run of `stuck_samples` identical raw samples a stuck sensor
# (TC_ERR_STUCK_SENSOR). A live chip's own noise changes its reading from sample to
# sample; with Gaussian noise of sigma counts RMS (rounded to whole counts), n samples in
# a row are all equal with probability about (2 pi sigma^2)^(-(n-1)/2) / sqrt(n). The
# default run length keeps that below STUCK_FALSE_STOPS_PER_ARMED_HOUR at the chip's
# lowest possible noise, from its datasheet:
#   HX711 (HX717 taken alike): input noise 50 nV RMS at 10 sps, 90 nV at 80 sps (gain 128),
#     assumed no lower at the smaller gains or higher rates; one count is AVDD / gain / 2^24,
#     largest at the highest AVDD (5.5 V): 19.5 counts RMS at A-128 and 10 sps, 1.2 at B-8.
#   ADS1220: at most 20 bits of effective resolution in any mode, so at least 2^(24-20) = 16
#     counts RMS whatever the gain, rate or reference.
# Real boards (lower AVDD, the bridge's own noise) are noisier, which only makes a false
# stop rarer.
#   ADS131M02/M04: taken as the ADS1220 (16 counts RMS at most 20 effective bits); its datasheet
#     noise at gain 128 is above that at every OSR, so the run length errs long, never short.
ADS1220_LIKE_FLOOR = ("ads1220", "ads131m02", "ads131m04")
HX71X_INPUT_NOISE_V = {"slow": 50e-9, "fast": 90e-9}   # fast: 80 sps and above
HX71X_AVDD_MAX_V = 5.5
ADS1220_MAX_EFFECTIVE_BITS = 20
ADC_BITS = 24
GENERIC_NOISE_FLOOR_COUNTS = 2.0 ** (ADC_BITS - ADS1220_MAX_EFFECTIVE_BITS)   # 16: for an unnamed sensor
STUCK_FALSE_STOPS_PER_ARMED_HOUR = 1e-6

# ---------------------------------------------------------------------------
# Errors


class SensorConfigError(ValueError):
    """A sensor option (or combination of options) the chip cannot do."""

    def __init__(self, option: str, value: object, allowed: str):
        self.option = option
        self.value = value
        self.allowed = allowed
        super().__init__(f"{option} = {value} is not allowed; allowed: {allowed}")


class SensorFrameError(ValueError):
    """A frame (or raw word) that cannot be decoded; names its index in the batch."""

    def __init__(self, index: int, frame: int, problem: str):
        self.index = index
        self.frame = frame
        super().__init__(f"frame {index} (0x{frame:x}): {problem}")


# ---------------------------------------------------------------------------
# The firmware binding

_CDEF = """
uint8_t hx71x_frame_pulses(uint8_t chip, uint8_t gain);
int hx71x_check_sample_rate(uint8_t chip, uint16_t sample_rate_sps);
int hx71x_decode_frames(const uint32_t *frames, size_t count, uint8_t frame_pulses,
                        int32_t *counts_out, size_t *decoded_count);

struct ads1220_config {
    uint8_t gain;
    uint8_t pga_bypass;
    uint16_t sample_rate_sps;
    uint8_t input_mux;
    uint8_t vref;
};
int ads1220_registers(const struct ads1220_config *config, uint8_t registers[4]);
uint8_t ads1220_pga_bypassed(uint8_t gain, uint8_t pga_bypass, uint8_t input_mux);
uint8_t ads1220_rate_is_turbo(uint16_t sample_rate_sps);
"""

# Firmware status codes (hx71x.h, ads1220.h) the host can meet.
HX71X_OK = 0
HX71X_ERR_DESYNC = 107
ADS1220_OK = 0
ADS1220_ERR_REF1_PIN_CONFLICT = 125
ADS1220_ERR_AVSS_NEEDS_LOW_GAIN = 126

# Index of each gain name in the firmware's enum hx71x_gain.
_HX71X_GAIN_CODES = {"A-128": 0, "B-32": 1, "A-64": 2, "B-64": 3, "B-8": 4}


@cache
def _firmware():
    """(ffi, lib) of the firmware host library, built and loaded on first use."""
    return _lib.load(_CDEF)


def _join(values) -> str:
    return ", ".join(str(v) for v in values)


# ---------------------------------------------------------------------------
# HX711 / HX717


def _hx71x_chip_code(chip: str) -> int:
    if chip not in HX71X_CHIPS:
        raise SensorConfigError("sensor_type", chip, _join(HX71X_CHIPS))
    return HX71X_CHIPS.index(chip)


def hx71x_pulses(chip: str, gain_channel: str) -> int:
    """Clock pulses per frame (25..28) that select `gain_channel` on `chip`:
    24 data bits plus 1..4 pulses choosing the next conversion's channel and gain."""
    chip_code = _hx71x_chip_code(chip)
    allowed = _join(HX71X_GAINS[chip])
    if not isinstance(gain_channel, str) or gain_channel not in _HX71X_GAIN_CODES:
        raise SensorConfigError("gain", gain_channel, allowed)
    _, lib = _firmware()
    pulses = lib.hx71x_frame_pulses(chip_code, _HX71X_GAIN_CODES[gain_channel])
    if pulses == 0:
        raise SensorConfigError("gain", gain_channel, allowed)
    return int(pulses)


def hx71x_check_sample_rate(chip: str, sample_rate: int) -> int:
    """`sample_rate` as an int if `chip` can be strapped for it (the rate is set by
    the chip's RATE pin, not by software), else SensorConfigError."""
    chip_code = _hx71x_chip_code(chip)
    allowed = _join(SAMPLE_RATES_SPS[chip])
    if isinstance(sample_rate, bool) or sample_rate not in SAMPLE_RATES_SPS[chip]:
        raise SensorConfigError("sample_rate", sample_rate, allowed)
    _, lib = _firmware()
    if lib.hx71x_check_sample_rate(chip_code, int(sample_rate)) != HX71X_OK:
        raise SensorConfigError("sample_rate", sample_rate, allowed)
    return int(sample_rate)


def decode_hx71x_frames(frames, pulses: int = HX71X_DATA_BITS) -> np.ndarray:
    """Decode a batch of HX71x frames in one firmware call.

    `frames` holds unsigned integers. With the default `pulses=24` each is a raw
    24-bit two's-complement word; with `pulses` 25..28 each is a whole frame as
    clocked in (24 data bits, then pulses-24 trailing bits that must all read 1).
    Returns int32 counts of the same shape. A frame with a trailing 0 (the chip
    and MCU disagree on the pulse count) raises SensorFrameError naming it.
    """
    if isinstance(pulses, bool) or pulses not in range(HX71X_DATA_BITS, HX71X_DATA_BITS + 5):
        raise SensorConfigError("pulses", pulses, "24, 25, 26, 27, 28")
    values = np.asarray(frames)
    if values.dtype.kind not in "iu":
        raise TypeError(f"frames must be an integer array, got dtype {values.dtype}")
    flat = values.reshape(-1)
    out_of_range = np.flatnonzero((flat < 0) | (flat >= (1 << pulses)))
    if out_of_range.size:
        index = int(out_of_range[0])
        raise SensorFrameError(index, int(flat[index]) & 0xFFFFFFFFFFFFFFFF,
                               f"does not fit in a {pulses}-bit frame")
    words = np.ascontiguousarray(flat, dtype=np.uint32)
    counts = np.empty(words.shape, dtype=np.int32)
    ffi, lib = _firmware()
    decoded = ffi.new("size_t *")
    status = lib.hx71x_decode_frames(ffi.from_buffer("uint32_t[]", words), words.size, pulses,
                                     ffi.from_buffer("int32_t[]", counts), decoded)
    if status == HX71X_ERR_DESYNC:
        index = int(decoded[0])
        trailing = pulses - HX71X_DATA_BITS
        tail = int(words[index]) & ((1 << trailing) - 1)
        raise SensorFrameError(index, int(words[index]),
                               f"trailing bits 0b{tail:0{trailing}b} must all be 1 (desync)")
    return counts.reshape(values.shape)


# ---------------------------------------------------------------------------
# ADS1220


def ads1220_is_turbo(sample_rate: int) -> bool:
    """True for the turbo-mode rates. 90 sps is in both lists and runs in normal mode."""
    if isinstance(sample_rate, bool) or sample_rate not in SAMPLE_RATES_SPS["ads1220"]:
        raise SensorConfigError("sample_rate", sample_rate, _join(SAMPLE_RATES_SPS["ads1220"]))
    _, lib = _firmware()
    return bool(lib.ads1220_rate_is_turbo(int(sample_rate)))


def ads1220_spi_speed_hz(sample_rate: int) -> int:
    """The SPI clock for `sample_rate`: 512000 in turbo mode, 256000 in normal mode."""
    return ADS1220_SPI_SPEED_HZ["turbo" if ads1220_is_turbo(sample_rate) else "normal"]


def _ads1220_codes(gain, sample_rate, input_mux, vref) -> tuple[int, int, int, int]:
    """Checks each option alone against the tables; returns the firmware codes."""
    if isinstance(gain, bool) or gain not in ADS1220_GAINS:
        raise SensorConfigError("gain", gain, _join(ADS1220_GAINS))
    if isinstance(sample_rate, bool) or sample_rate not in SAMPLE_RATES_SPS["ads1220"]:
        raise SensorConfigError(
            "sample_rate", sample_rate,
            f"normal {_join(ADS1220_NORMAL_SAMPLE_RATES_SPS)}; turbo {_join(ADS1220_TURBO_SAMPLE_RATES_SPS)}",
        )
    if input_mux not in ADS1220_INPUT_MUXES:
        raise SensorConfigError("input_mux", input_mux, _join(ADS1220_INPUT_MUXES))
    if vref not in ADS1220_VREFS:
        raise SensorConfigError("vref", vref, _join(ADS1220_VREFS))
    return int(gain), int(sample_rate), ADS1220_INPUT_MUXES.index(input_mux), ADS1220_VREFS.index(vref)


def ads1220_effective_pga_bypass(gain: int, pga_bypass: bool, input_mux: str) -> bool:
    """Whether the PGA really is bypassed: forced for AINx_AVSS inputs, and only
    possible at gains 1, 2 and 4 (at 8..128 the chip keeps the PGA on)."""
    gain_code, _, mux_code, _ = _ads1220_codes(gain, DEFAULT_SAMPLE_RATE_SPS["ads1220"], input_mux, "internal")
    _, lib = _firmware()
    return bool(lib.ads1220_pga_bypassed(gain_code, bool(pga_bypass), mux_code))


def ads1220_registers(gain: int, pga_bypass: bool, sample_rate: int, input_mux: str, vref: str) -> bytes:
    """The four ADS1220 configuration registers (reg0..reg3) the firmware writes.

    Raises SensorConfigError naming the option, the value and what is allowed, for
    a bad value or a combination the chip cannot do (REF1 with AIN0/AIN3 inputs,
    an AVSS input above gain 4).
    """
    gain_code, rate, mux_code, vref_code = _ads1220_codes(gain, sample_rate, input_mux, vref)
    ffi, lib = _firmware()
    config = ffi.new("struct ads1220_config *", {
        "gain": gain_code, "pga_bypass": bool(pga_bypass), "sample_rate_sps": rate,
        "input_mux": mux_code, "vref": vref_code,
    })
    registers = ffi.new("uint8_t[4]")
    status = lib.ads1220_registers(config, registers)
    if status == ADS1220_ERR_REF1_PIN_CONFLICT:
        free_muxes = _join(m for m in ADS1220_INPUT_MUXES if "AIN0" not in m and "AIN3" not in m)
        raise SensorConfigError(
            "vref", vref,
            f"internal, REF0, analog_supply with input_mux {input_mux} "
            f"(REF1 shares its pins with AIN0 and AIN3; it works only with {free_muxes})",
        )
    if status == ADS1220_ERR_AVSS_NEEDS_LOW_GAIN:
        raise SensorConfigError(
            "gain", gain,
            f"1, 2, 4 with input_mux {input_mux} (an AVSS input needs the PGA bypassed, "
            f"which the chip can only do up to gain 4)",
        )
    if status != ADS1220_OK:
        # The tables above already refuse every single bad value; reaching this
        # means the tables and the firmware disagree.
        raise RuntimeError(f"ads1220_registers: firmware status {status} for values the tables allow")
    return bytes(registers)


# ---------------------------------------------------------------------------
# Stuck-sensor defaults (see "Noise floor" above)


def noise_floor_counts(sensor_type: str, gain: str | int, sample_rate_sps: float) -> float:
    """The least RMS noise, in counts, a live `sensor_type` shows at this gain and rate."""
    if sensor_type in HX71X_CHIPS:
        if gain not in HX71X_GAINS[sensor_type]:
            raise SensorConfigError("gain", gain, _join(HX71X_GAINS[sensor_type]))
        volts_per_count = HX71X_AVDD_MAX_V / int(str(gain).split("-")[1]) / 2.0 ** ADC_BITS
        return HX71X_INPUT_NOISE_V["fast" if sample_rate_sps >= 80 else "slow"] / volts_per_count
    if sensor_type in ADS1220_LIKE_FLOOR:
        return GENERIC_NOISE_FLOOR_COUNTS
    raise SensorConfigError("sensor_type", sensor_type, _join((*HX71X_CHIPS, *ADS1220_LIKE_FLOOR)))


def identical_run_probability(noise_counts: float, samples: int) -> float:
    """Chance that `samples` readings in a row of a steady input with Gaussian noise of
    `noise_counts` RMS (rounded to whole counts) are all equal: the sum over k of
    P(reading = k)^samples, about (2 pi sigma^2)^(-(samples-1)/2) / sqrt(samples) for
    sigma >= 1 (the noise floors here are all above 1 count)."""
    sigma = max(noise_counts, 1.0)
    return (2.0 * math.pi * sigma * sigma) ** (-(samples - 1) / 2.0) / math.sqrt(samples)


def stuck_sample_count(noise_counts: float, sample_rate_sps: float, max_samples: int) -> int:
    """The shortest run of identical samples (>= 2) that a live sensor with `noise_counts` RMS
    of noise shows less often than STUCK_FALSE_STOPS_PER_ARMED_HOUR; capped at max_samples."""
    budget = STUCK_FALSE_STOPS_PER_ARMED_HOUR / (3600.0 * sample_rate_sps)
    for samples in range(2, max_samples + 1):
        if identical_run_probability(noise_counts, samples) <= budget:
            return samples
    return max_samples
