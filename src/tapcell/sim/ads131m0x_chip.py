"""The virtual ADS131M02/M04 on the wire: frames with a CRC, checked by the firmware's reader.

The other virtual chips hand the MCU their counts; a bit flipped on a long cable then reaches
the host as a wrong sample (the `glitchy` scenario). An ADS131M0x sends each sample in a frame
with a CRC word, and the MCU's reader (firmware/src/ads131m0x.c, through tapcell.mcu.ads131m0x)
refuses a frame whose CRC does not hold: the corrupted sample becomes a sensor error instead of
a force. Only the frames that were hit are built and checked (the others cannot fail).
"""

from __future__ import annotations

import numpy as np

from tapcell.mcu import ads131m0x

WORD_BITS = 24


class VirtualADS131M0x:
    def __init__(self, chip: str, channel: int = 0):
        self.chip = chip
        self.channel = channel
        self.reader = ads131m0x.FrameReader(chip, channel)

    def corrupted_frames(self, counts: np.ndarray, hit: np.ndarray, bits: np.ndarray) -> np.ndarray:
        """Which of the samples marked `hit` (bit `bits` flipped in their channel word on the wire)
        the reader refuses: their mask over `counts`."""
        refused = np.zeros(counts.shape, dtype=bool)
        index = np.flatnonzero(hit)
        if index.size == 0:
            return refused
        frames = bytearray(ads131m0x.encode_frames(self.chip, counts[index], self.channel))
        size = self.reader.frame_bytes
        for k, bit in enumerate(np.asarray(bits)[index] % WORD_BITS):
            byte = size * k + 3 * (1 + self.channel) + (WORD_BITS - 1 - int(bit)) // 8
            frames[byte] ^= 1 << (int(bit) % 8)
        _, status = self.reader.decode(bytes(frames))
        refused[index] = status != ads131m0x.OK
        return refused
