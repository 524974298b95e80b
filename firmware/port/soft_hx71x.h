/* soft_hx71x.h - a software HX711/HX717 behind struct tc_hal.
 *
 * It plays the chip's side of the two-wire protocol (hx71x.h) from a list of
 * frames the host generated: soft_hx71x_convert() (called by the board's
 * data-ready interrupt) completes the next conversion and pulls DOUT low; each
 * rising SCLK edge then puts the next frame bit on DOUT, MSB first, trailing
 * bits included (a frame with a trailing 0 is a desync). After the frame DOUT
 * stays high until the next conversion. The unchanged driver (hx71x.c) reads it
 * through the same struct tc_hal a board's GPIO code would fill in.
 */
#ifndef TAPCELL_PORT_SOFT_HX71X_H
#define TAPCELL_PORT_SOFT_HX71X_H

#include <stdint.h>
#include "hal.h"

#define SOFT_HX71X_SCLK_PIN 1u
#define SOFT_HX71X_DOUT_PIN 2u

struct soft_hx71x {
    const uint32_t *frames;
    uint16_t n_frames;
    uint16_t next;          /* frames already converted */
    uint8_t frame_pulses;   /* 25..28: bits in each frame */
    uint8_t bits_left;      /* bits of the current frame not yet shifted out */
    uint8_t dout;
    uint32_t shifting;      /* the current frame */
};

void soft_hx71x_load(struct soft_hx71x *chip, const uint32_t *frames, uint16_t n_frames, uint8_t frame_pulses);
/* The next conversion completes: 1, or 0 when the list is exhausted (the chip went silent). */
int soft_hx71x_convert(struct soft_hx71x *chip);
/* A tc_hal whose pins are this chip and whose time and delays are the board's. */
void soft_hx71x_hal(struct tc_hal *hal, struct soft_hx71x *chip);

#endif
