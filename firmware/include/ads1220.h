/* ads1220.h - TI ADS1220 24-bit ADC on SPI (mode 1).
 *
 * Set-up, done on every start of measurement:
 *   1. RESET (0x06), then wait for the chip to come back.
 *   2. Read the four configuration registers: all must be 0x00, the datasheet's
 *      power-on/reset value. Anything else means the chip is absent, the bus is
 *      miswired, or the RESET was not seen.
 *   3. Write the four registers computed by ads1220_registers(), read them back
 *      and compare.
 *   4. START/SYNC (0x08): continuous conversion begins.
 * Then, each time DRDY goes low, ads1220_read() clocks out the 24-bit result.
 *
 * Register layout written:
 *   reg0 = MUX[7:4] | GAIN[3:1] (log2 gain) | PGA_BYPASS[0]
 *   reg1 = DR[7:5] | MODE[4:3] (00 normal, 10 turbo) | CM[2] = 1 (continuous)
 *   reg2 = VREF[7:6]; FIR 50/60 Hz rejection, low-side switch, IDACs off
 *   reg3 = 0 (IDAC routing off, DRDY on its own pin)
 *
 * Rate 90 sps is in both the normal and the turbo list; it is taken as normal
 * mode (DR = 2), see docs/sensors.md.
 */
#ifndef TAPCELL_ADS1220_H
#define TAPCELL_ADS1220_H

#include <stdint.h>
#include "hal.h"

/* Input multiplexer: the datasheet's MUX[3:0] codes. */
enum ads1220_mux {
    ADS1220_MUX_AIN0_AIN1 = 0,
    ADS1220_MUX_AIN0_AIN2 = 1,
    ADS1220_MUX_AIN0_AIN3 = 2,
    ADS1220_MUX_AIN1_AIN2 = 3,
    ADS1220_MUX_AIN1_AIN3 = 4,
    ADS1220_MUX_AIN2_AIN3 = 5,
    ADS1220_MUX_AIN1_AIN0 = 6,
    ADS1220_MUX_AIN3_AIN2 = 7,
    ADS1220_MUX_AIN0_AVSS = 8,
    ADS1220_MUX_AIN1_AVSS = 9,
    ADS1220_MUX_AIN2_AVSS = 10,
    ADS1220_MUX_AIN3_AVSS = 11
};

/* Voltage reference: the datasheet's VREF[1:0] codes. */
enum ads1220_vref {
    ADS1220_VREF_INTERNAL = 0,      /* internal 2.048 V */
    ADS1220_VREF_REF0 = 1,          /* REFP0 / REFN0 pins */
    ADS1220_VREF_REF1 = 2,          /* REFP1 / REFN1, shared with AIN0 / AIN3 */
    ADS1220_VREF_ANALOG_SUPPLY = 3  /* AVDD - AVSS */
};

/* Result codes: 0 is success; distinct from the trigger's and the HX71x's. */
enum ads1220_status {
    ADS1220_OK = 0,
    ADS1220_ERR_BAD_GAIN = 121,           /* not 1, 2, 4, ..., 128 */
    ADS1220_ERR_BAD_SAMPLE_RATE = 122,    /* not in the normal or turbo list */
    ADS1220_ERR_BAD_INPUT_MUX = 123,      /* not 0..11 */
    ADS1220_ERR_BAD_VREF = 124,           /* not 0..3 */
    ADS1220_ERR_REF1_PIN_CONFLICT = 125,  /* vref REF1 with a mux using AIN0 or AIN3 */
    ADS1220_ERR_AVSS_NEEDS_LOW_GAIN = 126,/* AINx_AVSS needs the PGA bypassed, so gain 1, 2 or 4 */
    ADS1220_ERR_RESET_STATE = 127,        /* registers not all 0x00 after RESET (sticky) */
    ADS1220_ERR_READBACK_MISMATCH = 128,  /* a register read back differently (sticky) */
    ADS1220_ERR_NOT_STARTED = 129         /* read before a successful ads1220_start() */
};

#define ADS1220_CMD_RESET 0x06u
#define ADS1220_CMD_START 0x08u
#define ADS1220_CMD_RREG 0x20u  /* | first_reg << 2 | (count - 1) */
#define ADS1220_CMD_WREG 0x40u  /* | first_reg << 2 | (count - 1) */
#define ADS1220_REGISTER_COUNT 4u
/* After RESET the chip needs 50 us + 32 periods of its 4.096 MHz clock
 * (about 58 us) before it accepts commands. */
#define ADS1220_RESET_WAIT_NS 60000u

struct ads1220_config {
    uint8_t gain;              /* 1, 2, 4, 8, 16, 32, 64, 128 */
    uint8_t pga_bypass;        /* nonzero: bypass the PGA (effective for gains 1, 2, 4 only) */
    uint16_t sample_rate_sps;  /* normal 20..1000 or turbo 40..2000 */
    uint8_t input_mux;         /* enum ads1220_mux */
    uint8_t vref;              /* enum ads1220_vref */
};

/* Driver state; the caller owns it. */
struct ads1220 {
    const struct tc_hal *hal;
    uint16_t cs_pin;
    uint8_t registers[ADS1220_REGISTER_COUNT]; /* what start() writes */
    uint8_t registers_read[ADS1220_REGISTER_COUNT]; /* last read: reset state or readback */
    enum ads1220_status error; /* sticky; ADS1220_OK once started */
};

/* Compute the four configuration registers. Pure; validates every option. */
enum ads1220_status ads1220_registers(const struct ads1220_config *config,
                                      uint8_t registers[ADS1220_REGISTER_COUNT]);

/* 1 if the PGA ends up bypassed: asked for, or forced by an AINx_AVSS input,
 * and only where the chip can bypass it (gains 1, 2, 4). */
uint8_t ads1220_pga_bypassed(uint8_t gain, uint8_t pga_bypass, uint8_t input_mux);

/* 1 if the rate is a turbo-mode rate (after the 90 sps decision), else 0. */
uint8_t ads1220_rate_is_turbo(uint16_t sample_rate_sps);

/* Validate the config and fill `dev`; the chip is not touched yet. */
enum ads1220_status ads1220_init(struct ads1220 *dev, const struct tc_hal *hal,
                                 uint16_t cs_pin, const struct ads1220_config *config);

/* Reset, check the reset state, write and verify the registers, start
 * continuous conversion. A failure is kept in dev->error until the next start. */
enum ads1220_status ads1220_start(struct ads1220 *dev);

/* Read one conversion after DRDY went low: 24 bits, sign-extended. */
enum ads1220_status ads1220_read(struct ads1220 *dev, int32_t *counts);

#endif
