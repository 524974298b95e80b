"""The virtual ADS131M02/M04 on the wire: frames with a CRC, checked by the firmware's reader.

The other virtual chips hand the MCU their counts; a bit flipped on a long cable then reaches
the host as a wrong sample (the `glitchy` scenario). An ADS131M0x sends each sample in a frame
with a CRC word, and the MCU's reader (firmware/src/ads131m0x.c, through tapcell.mcu.ads131m0x)
refuses a frame whose CRC does not hold: the corrupted sample becomes a sensor error instead of
a force. Only the frames that were hit are built and checked (the others cannot fail). A
`chip_reset` fault makes the chip set the RESET bit in its next frame after the gap: the reader
then refuses every frame (sticky) until FIRMWARE_RESTART builds the printer again.
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
        self.crc_errors = 0
        self.reset_seen = False  # the reader saw a frame with the RESET bit: it refuses every frame since

    def error_note(self) -> str:
        """Why this chip's samples were refused, for the host's error message ('' when none were)."""
        name = self.chip.upper()
        if self.reset_seen:
            return (f"the {name} reported a reset (a brown-out on its supply): its settings are gone and its "
                    f"frames are refused until FIRMWARE_RESTART sets it up again")
        if self.crc_errors:
            return (f"the {name}'s frames failed their CRC ({self.crc_errors} so far): check the SPI wiring, "
                    f"its grounding and the cable length")
        return ""

    def after_reset(self, counts: np.ndarray, t_ready_s: np.ndarray, reset_s: list[float]) -> np.ndarray:
        """The samples the reader refuses because the chip reset at one of `reset_s` (a chip_reset
        fault's end of gap): the first frame after it carries the RESET bit, and from then on the
        reader refuses every frame (ERR_RESET is sticky; only decoding the first one is needed)."""
        refused = np.zeros(counts.shape, dtype=bool)
        if self.reset_seen:
            refused[:] = True
            return refused
        after = np.flatnonzero(np.any([t_ready_s >= t for t in reset_s], axis=0)) if reset_s else np.zeros(0, int)
        if after.size == 0:
            return refused
        first = int(after[0])
        frame = ads131m0x.encode_frames(self.chip, counts[first:first + 1], self.channel, reset=np.array([True]))
        _, status = self.reader.decode(frame)
        if status[0] == ads131m0x.ERR_RESET:
            self.reset_seen = True
            refused[first:] = True
        return refused

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
        self.crc_errors += int(np.count_nonzero(status == ads131m0x.ERR_CRC))
        return refused
