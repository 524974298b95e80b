/* hx71x.h - HX711 / HX717 24-bit load-cell ADCs, read by bit-banging SCLK/DOUT.
 *
 * Protocol (both chips):
 *   - DOUT low means a conversion is ready.
 *   - The MCU clocks 24 + g pulses on SCLK. The first 24 shift out the value,
 *     MSB first, two's complement. The chip drives DOUT high from the 25th
 *     pulse on, so the g trailing bits must all read 1; anything else means the
 *     chip and the MCU disagree about the pulse count (a desync).
 *   - g (1..4) selects channel and gain of the *next* conversion.
 *   - SCLK held high for more than 60 us powers the chip down; pulling it low
 *     again powers it up and resets it to channel A, gain 128.
 *
 * Errors found while reading (desync, late read) are sticky: every later read
 * returns the same code until hx71x_start() restarts the chip, so a probe never
 * runs on a sensor whose frames can no longer be trusted.
 */
#ifndef TAPCELL_HX71X_H
#define TAPCELL_HX71X_H

#include <stddef.h>
#include <stdint.h>
#include "hal.h"

enum hx71x_chip {
    HX71X_CHIP_HX711 = 0,
    HX71X_CHIP_HX717 = 1
};

/* Channel and gain of the next conversion. Not every chip has every one. */
enum hx71x_gain {
    HX71X_GAIN_A_128 = 0, /* both chips: 25 pulses */
    HX71X_GAIN_B_32 = 1,  /* HX711: 26 pulses */
    HX71X_GAIN_A_64 = 2,  /* both chips: 27 pulses */
    HX71X_GAIN_B_64 = 3,  /* HX717: 26 pulses */
    HX71X_GAIN_B_8 = 4    /* HX717: 28 pulses */
};

/* Result codes. 0 is success; the numbers are distinct from the trigger's
 * codes (tc_errors.h) and the ADS1220's, so one log line identifies the source. */
enum hx71x_status {
    HX71X_OK = 0,
    HX71X_SETTLING = 1,            /* sample read but discarded: chip still settling after start */
    HX71X_ERR_BAD_CHIP = 101,      /* chip is not hx711/hx717 */
    HX71X_ERR_BAD_GAIN = 102,      /* gain/channel not offered by this chip */
    HX71X_ERR_BAD_SAMPLE_RATE = 103, /* hx711: 10, 80; hx717: 10, 20, 80, 320 */
    HX71X_ERR_BAD_TICK_RATE = 104, /* timer too slow to express one sample period */
    HX71X_ERR_NOT_READY = 105,     /* read called while DOUT is high; nothing clocked */
    HX71X_ERR_NOT_STARTED = 106,   /* read before hx71x_start() (sticky) */
    HX71X_ERR_DESYNC = 107,        /* a trailing bit read 0 (sticky) */
    HX71X_ERR_LATE_READ = 108,     /* read finished a full sample period or more after
                                      data-ready: the next conversion was due (sticky) */
    HX71X_ERR_BAD_FRAME_LENGTH = 109 /* decode asked for a frame other than 24..28 bits */
};

#define HX71X_DATA_BITS 24
/* Datasheet timing: SCLK high and low each at least 0.2 us, and SCLK high for
 * more than 60 us means power-down (we hold it 100 us to be sure). */
#define HX71X_PULSE_NS 200u
#define HX71X_POWER_DOWN_NS 100000u
/* The datasheet's output settling time after power-up is 4 conversions; the
 * first of them also still uses the power-on gain, not ours. */
#define HX71X_SETTLING_SAMPLES 4u

struct hx71x_config {
    uint8_t chip;              /* enum hx71x_chip */
    uint8_t gain;              /* enum hx71x_gain */
    uint16_t sample_rate_sps;  /* must match the chip's RATE strapping */
    uint32_t ticks_per_s;      /* rate of hal->time_now_ticks */
    uint16_t sclk_pin;
    uint16_t dout_pin;
};

/* Driver state; the caller owns it (no allocation, no globals). */
struct hx71x {
    const struct tc_hal *hal;
    uint16_t sclk_pin;
    uint16_t dout_pin;
    uint8_t frame_pulses;          /* 25..28 */
    uint8_t settling_left;         /* samples still to discard after start */
    uint32_t sample_period_ticks;
    enum hx71x_status error;       /* sticky error, HX71X_OK when healthy */
};

/* Total clock pulses per frame (25..28) for a chip and gain, 0 if the chip
 * does not offer that gain (or the chip is unknown). */
uint8_t hx71x_frame_pulses(uint8_t chip, uint8_t gain);

/* HX71X_OK if the chip can be strapped for this rate. */
enum hx71x_status hx71x_check_sample_rate(uint8_t chip, uint16_t sample_rate_sps);

/* Pure decode of one frame: the `frame_pulses` bits shifted in MSB first
 * (24 data bits followed by frame_pulses-24 trailing bits, which must all be 1).
 * frame_pulses == 24 decodes a bare 24-bit word. Bits above the frame are
 * ignored. Writes *counts only on success. */
enum hx71x_status hx71x_decode_frame(uint32_t frame_bits, uint8_t frame_pulses,
                                     int32_t *counts);

/* Batch decode for the host. Decodes frames in order until one fails;
 * *decoded_count says how many entries of counts_out were filled (the index of
 * the failing frame). Returns HX71X_OK when all `count` decode, otherwise the
 * failing frame's status. */
enum hx71x_status hx71x_decode_frames(const uint32_t *frames, size_t count,
                                      uint8_t frame_pulses, int32_t *counts_out,
                                      size_t *decoded_count);

/* Validate the config and fill `dev`. The chip is left untouched and reads
 * return HX71X_ERR_NOT_STARTED until hx71x_start(). */
enum hx71x_status hx71x_init(struct hx71x *dev, const struct tc_hal *hal,
                             const struct hx71x_config *config);

/* (Re)start measurement: power-cycle the chip (SCLK high for 100 us, then
 * low), clear the sticky error and begin discarding the settling samples. */
void hx71x_start(struct hx71x *dev);

/* 1 when DOUT is low, i.e. a conversion is waiting to be read. */
uint8_t hx71x_is_ready(const struct hx71x *dev);

/* Clock one frame out. `ready_ticks` is when DOUT was seen low; the read is
 * late if it ends a sample period or more after that. Returns HX71X_OK with
 * *counts set, HX71X_SETTLING (frame clocked, value discarded), or an error. */
enum hx71x_status hx71x_read(struct hx71x *dev, uint32_t ready_ticks,
                             int32_t *counts);

#endif
