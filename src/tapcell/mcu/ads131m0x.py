"""The ADS131M02 / ADS131M04 for the host: rate choice, register words and frame decoding.

The chips run from an external clock (`clock_freq`, or a `[static_pwm_clock]` output) and
convert at fclk / (2 x OSR), or fclk / (2 x (chop_delay + 3 x OSR)) with global chop, for
OSR 64 (turbo), 128, 256, ..., 16384. `choose_osr` picks the OSR whose rate is closest to the
asked sample_rate and refuses a request 50 % or more away from anything the clock can do.
Register words and frame decoding are the firmware's (firmware/src/ads131m0x.c) through cffi,
so the host and the MCU cannot disagree: a frame is checked by its CRC and the sticky RESET
bit before its sample is taken.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache

import numpy as np

from tapcell.mcu import _lib
from tapcell.mcu.sensors import SensorConfigError

CHANNELS = {"ads131m02": 2, "ads131m04": 4}
OSRS = (64, 128, 256, 512, 1024, 2048, 4096, 8192, 16384)
GAINS = (1, 2, 4, 8, 16, 32, 64, 128)
CHOP_DELAYS = tuple(2 ** k for k in range(1, 17))  # 2 .. 65536 modulator clocks
CLOCK_HZ_RANGE = (300_000, 8_400_000)
DEFAULT_SAMPLE_RATE_SPS = 500.0
DEFAULT_SPI_SPEED_HZ = 4_000_000
MAX_RATE_MISS = 0.5  # a rate this far (relative) from the asked one is refused

# Firmware status codes (ads131m0x.h).
OK = 0
ERR_CRC = 141
ERR_RESET = 142
STATUS_NAMES = {OK: "ok", ERR_CRC: "CRC mismatch", ERR_RESET: "chip reset"}

_CDEF = """
struct ads131m0x_reader { uint8_t channels; uint8_t channel; uint8_t reset_seen; };
struct ads131m0x_registers { uint16_t mode; uint16_t clock; uint16_t gain1; uint16_t cfg; };
uint16_t ads131m0x_crc16(const uint8_t *data, size_t len);
uint8_t ads131m0x_frame_bytes(uint8_t channels);
int ads131m0x_reader_init(struct ads131m0x_reader *reader, uint8_t channels, uint8_t channel);
void ads131m0x_reader_restart(struct ads131m0x_reader *reader);
size_t ads131m0x_decode_frames(struct ads131m0x_reader *reader, const uint8_t *frames, size_t count,
                               int32_t *counts_out, uint8_t *status_out);
int ads131m0x_register_words(uint8_t channels, uint8_t channel, uint16_t osr, uint8_t gain,
                             uint8_t global_chop, uint32_t chop_delay, struct ads131m0x_registers *out);
"""


@cache
def _firmware():
    return _lib.load(_CDEF)


def conversion_rate_sps(clock_hz: float, osr: int, chop_delay: int | None = None) -> float:
    """The chip's data rate at this clock and OSR (with global chop: its delay counts too)."""
    if chop_delay is None:
        return clock_hz / (2.0 * osr)
    return clock_hz / (2.0 * (chop_delay + 3.0 * osr))


def choose_osr(clock_hz: float, sample_rate_sps: float, chop_delay: int | None = None) -> tuple[int, float]:
    """(OSR, achieved rate) closest to the asked rate; SensorConfigError when the best is 50 % or
    more away (the clock cannot run the chip anywhere near it)."""
    rates = {osr: conversion_rate_sps(clock_hz, osr, chop_delay) for osr in OSRS}
    osr = min(rates, key=lambda o: abs(rates[o] - sample_rate_sps))
    if abs(rates[osr] - sample_rate_sps) >= MAX_RATE_MISS * sample_rate_sps:
        possible = ", ".join(f"{rate:.6g}" for rate in sorted(rates.values()))
        raise SensorConfigError("sample_rate", f"{sample_rate_sps:g}",
                                f"within 50 % of a rate this clock ({clock_hz:g} Hz) gives: {possible}")
    return osr, rates[osr]


@dataclass(frozen=True)
class RegisterWords:
    mode: int
    clock: int
    gain1: int
    cfg: int


def register_words(chip: str, channel: int, osr: int, gain: int, chop_delay: int | None) -> RegisterWords:
    """The MODE, CLOCK, GAIN1 and CFG words the firmware writes (and reads back) at start-up."""
    ffi, lib = _firmware()
    out = ffi.new("struct ads131m0x_registers *")
    status = lib.ads131m0x_register_words(CHANNELS[chip], channel, osr, gain, chop_delay is not None,
                                          chop_delay or 0, out)
    if status != OK:
        raise SensorConfigError("adc_channel" if status in (143, 144) else "gain" if status == 145
                                else "sample_rate", (channel, osr, gain, chop_delay), f"firmware status {status}")
    return RegisterWords(out.mode, out.clock, out.gain1, out.cfg)


def crc16(data: bytes) -> int:
    ffi, lib = _firmware()
    return int(lib.ads131m0x_crc16(ffi.from_buffer("uint8_t[]", data), len(data)))


def encode_frames(chip: str, counts: np.ndarray, channel: int, reset: np.ndarray | None = None) -> bytes:
    """Frames as the chip sends them: STATUS (RESET bit where `reset`), the load cell's counts on
    `channel` (the other channels read 0) and the CRC. For the virtual chip and the tests."""
    channels = CHANNELS[chip]
    counts = np.asarray(counts, dtype=np.int64)
    words = np.zeros((counts.size, channels + 2), dtype=np.int64)
    words[:, 0] = 0x0100 << 8 | 0  # STATUS: 24-bit words; its 16 bits sit in the upper two bytes
    words[:, 0] |= ((1 << channels) - 1) << 8  # DRDY of every channel
    if reset is not None:
        words[np.asarray(reset, dtype=bool), 0] |= 1 << 18  # RESET is status bit 10
    words[:, 1 + channel] = counts & 0xFFFFFF
    raw = np.zeros((counts.size, 3 * (channels + 2)), dtype=np.uint8)
    for word in range(channels + 1):
        for byte in range(3):
            raw[:, 3 * word + byte] = (words[:, word] >> (16 - 8 * byte)) & 0xFF
    covered = 3 * (channels + 1)
    for i in range(counts.size):
        crc = crc16(raw[i, :covered].tobytes())
        raw[i, covered], raw[i, covered + 1] = crc >> 8, crc & 0xFF
    return raw.tobytes()


class FrameReader:
    """The MCU's reader of one chip's frames (sticky reset included), for a stream of batches."""

    def __init__(self, chip: str, channel: int):
        if chip not in CHANNELS:
            raise SensorConfigError("sensor_type", chip, ", ".join(CHANNELS))
        ffi, lib = _firmware()
        self.chip = chip
        self.frame_bytes = int(lib.ads131m0x_frame_bytes(CHANNELS[chip]))
        self._reader = ffi.new("struct ads131m0x_reader *")
        status = lib.ads131m0x_reader_init(self._reader, CHANNELS[chip], channel)
        if status != OK:
            raise SensorConfigError("adc_channel", channel, f"0 .. {CHANNELS[chip] - 1}")

    def restart(self) -> None:
        _, lib = _firmware()
        lib.ads131m0x_reader_restart(self._reader)

    def decode(self, frames: bytes) -> tuple[np.ndarray, np.ndarray]:
        """(counts, status) per frame; a frame's counts are 0 where its status is not OK."""
        if len(frames) % self.frame_bytes:
            raise ValueError(f"{len(frames)} bytes is not a whole number of {self.frame_bytes}-byte frames")
        count = len(frames) // self.frame_bytes
        counts = np.zeros(count, dtype=np.int32)
        status = np.zeros(count, dtype=np.uint8)
        if count:
            ffi, lib = _firmware()
            lib.ads131m0x_decode_frames(self._reader, ffi.from_buffer("uint8_t[]", frames), count,
                                        ffi.from_buffer("int32_t[]", counts), ffi.from_buffer("uint8_t[]", status))
        return counts, status
