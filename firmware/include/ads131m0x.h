/* ads131m0x.h - TI ADS131M02 / ADS131M04 simultaneous-sampling 24-bit ADCs (SPI mode 1).
 *
 * What the load cell needs from the chip, as pure functions and one small reader state:
 *   - the register words the start-up writes and reads back (MODE, CLOCK, GAIN1, CFG);
 *   - decoding one data frame read after DRDY: in 24-bit word mode a frame is the STATUS
 *     word, one word per channel (2 or 4) and a CRC word, 3 bytes each, MSB first
 *     (12 bytes for the M02, 18 for the M04). 16-bit values (STATUS, CRC) sit in the
 *     upper two bytes of their word.
 *
 * Every frame is checked before its sample is used:
 *   - CRC-16-CCITT (polynomial 0x1021, initial value 0xFFFF) over the STATUS and channel
 *     words must equal the CRC word: a mismatch is ADS131M0X_ERR_CRC for that frame only
 *     (a bit flipped on the wire; the next frame may be good);
 *   - the STATUS RESET bit (bit 10) says the chip reset itself (a brown-out): its settings
 *     are gone, so every later frame is ADS131M0X_ERR_RESET until the reader is restarted
 *     (sticky: measurement must be set up again).
 * A load-cell trigger treats either error as a sensor error and stops the move.
 */
#ifndef TAPCELL_ADS131M0X_H
#define TAPCELL_ADS131M0X_H

#include <stddef.h>
#include <stdint.h>

#define ADS131M0X_WORD_BYTES 3u
#define ADS131M0X_MAX_CHANNELS 4u
#define ADS131M0X_MAX_FRAME_BYTES (ADS131M0X_WORD_BYTES * (ADS131M0X_MAX_CHANNELS + 2u))
#define ADS131M0X_STATUS_RESET_BIT (1u << 10)
#define ADS131M0X_CRC_POLY 0x1021u
#define ADS131M0X_CRC_INIT 0xFFFFu
/* MODE: 24-bit words (WLENGTH = 01b), everything else at its default. */
#define ADS131M0X_MODE_24BIT 0x0100u
/* CLOCK: PWR = 10b (high resolution); TBM selects OSR 64. */
#define ADS131M0X_CLOCK_PWR_HIGH_RESOLUTION 0x0002u
#define ADS131M0X_CLOCK_TBM 0x0020u
#define ADS131M0X_CFG_GC_EN 0x0100u

/* Result codes: 0 is success; distinct from the other drivers' (1xx) and the trigger's. */
enum ads131m0x_status {
    ADS131M0X_OK = 0,
    ADS131M0X_ERR_CRC = 141,           /* the frame's CRC word does not match its contents */
    ADS131M0X_ERR_RESET = 142,         /* the chip reported a reset (sticky until restart) */
    ADS131M0X_ERR_BAD_CHANNELS = 143,  /* channel count not 2 or 4 */
    ADS131M0X_ERR_BAD_CHANNEL = 144,   /* adc channel not below the channel count */
    ADS131M0X_ERR_BAD_GAIN = 145,      /* not 1, 2, 4, ..., 128 */
    ADS131M0X_ERR_BAD_OSR = 146,       /* not 64, 128, ..., 16384 */
    ADS131M0X_ERR_BAD_CHOP_DELAY = 147 /* not 2, 4, ..., 65536 */
};

/* The frame reader of one chip: which channel is the load cell, and the sticky reset. */
struct ads131m0x_reader {
    uint8_t channels;    /* 2 (M02) or 4 (M04) */
    uint8_t channel;     /* the load cell's input, 0 .. channels - 1 */
    uint8_t reset_seen;  /* set by a frame with the RESET bit; cleared by restart */
};

/* CRC-16-CCITT (0x1021, initial 0xFFFF, no reflection, no final xor) over `len` bytes. */
uint16_t ads131m0x_crc16(const uint8_t *data, size_t len);

/* Bytes in one data frame: 3 * (channels + 2). */
uint8_t ads131m0x_frame_bytes(uint8_t channels);

enum ads131m0x_status ads131m0x_reader_init(struct ads131m0x_reader *reader, uint8_t channels,
                                            uint8_t channel);

/* Measurement set up again (after a reset): frames are trusted again. */
void ads131m0x_reader_restart(struct ads131m0x_reader *reader);

/* Check one frame and take the load cell's channel: 24 bits, sign-extended. On an error
 * `counts` is left alone. */
enum ads131m0x_status ads131m0x_decode_frame(struct ads131m0x_reader *reader, const uint8_t *frame,
                                             int32_t *counts);

/* Decode `count` frames laid end to end (the host's batch entry): each frame's status goes
 * to status_out[i] and its counts to counts_out[i] (0 for a bad frame). Returns the number
 * of good frames. */
size_t ads131m0x_decode_frames(struct ads131m0x_reader *reader, const uint8_t *frames, size_t count,
                               int32_t *counts_out, uint8_t *status_out);

/* The register words the start-up writes and reads back. */
struct ads131m0x_registers {
    uint16_t mode;
    uint16_t clock;
    uint16_t gain1;
    uint16_t cfg;
};

/* osr: 64 (turbo) or 128 .. 16384; gain: 1 .. 128 (every channel gets it); global chop with
 * its delay in modulator clocks (2 .. 65536, powers of two) when `global_chop` is nonzero. */
enum ads131m0x_status ads131m0x_register_words(uint8_t channels, uint8_t channel, uint16_t osr,
                                               uint8_t gain, uint8_t global_chop, uint32_t chop_delay,
                                               struct ads131m0x_registers *out);

#endif
