/* sim_chips.h - simulated HX711/HX717 and ADS1220 behind a struct tc_hal.
 *
 * Host tests hand the driver a HAL whose functions act on one of these
 * structs, so the driver's real pin toggling and SPI frames are checked
 * against a model of the chip. Time is simulated: 1 tick = 1 ns, advanced only
 * by delay_ns() and by the test itself.
 */
#ifndef TAPCELL_SIM_CHIPS_H
#define TAPCELL_SIM_CHIPS_H

#include <stdint.h>
#include "hal.h"

#define SIM_TICKS_PER_S 1000000000u

/* ---- HX711 / HX717 ---------------------------------------------------- */
struct sim_hx71x {
    uint16_t sclk_pin, dout_pin;
    uint32_t now_ticks;
    uint8_t sclk;               /* level the driver last wrote */
    uint8_t dout;               /* level the chip drives */
    uint32_t conversion;        /* 24-bit word being shifted out */
    uint8_t pulses_seen;        /* rising edges counted in the current frame */
    uint8_t last_frame_pulses;  /* pulses of the previous frame = gain selected */
    uint32_t sclk_rise_ticks;
    uint32_t longest_high_ns;   /* longest SCLK high phase seen (excl. power-down) */
    uint32_t shortest_low_ns;   /* shortest SCLK low phase between pulses */
    uint32_t sclk_fall_ticks;
    uint8_t power_cycles;       /* power-down + power-up sequences seen */
    uint8_t irq_disabled;
    uint8_t irq_max_nesting;
    uint8_t reads_with_irq_on;  /* SCLK edges made with interrupts enabled */
    /* Faults: rising edges the chip will miss (noise on SCLK), and extra
     * ticks each pin_read costs (an interrupt stretching the read). */
    uint8_t missed_edges;
    uint32_t ticks_per_pin_read;
};

void sim_hx71x_init(struct sim_hx71x *sim, struct tc_hal *hal,
                    uint16_t sclk_pin, uint16_t dout_pin, uint32_t now_ticks);
/* The chip finishes a conversion: latch `counts` (24-bit two's complement)
 * and pull DOUT low. */
void sim_hx71x_convert(struct sim_hx71x *sim, int32_t counts);

/* ---- ADS1220 ---------------------------------------------------------- */
struct sim_ads1220 {
    uint16_t cs_pin;
    uint8_t cs;                 /* chip-select level */
    uint8_t registers[4];
    uint8_t reset_state[4];     /* what RESET loads (0 on a healthy chip) */
    uint8_t stuck_low[4];       /* register bits that cannot be set (fault) */
    uint8_t started;
    uint8_t resets;
    int32_t conversion;         /* value clocked out by a data read */
    uint16_t protocol_errors;   /* transfers with CS high, unknown commands, bad lengths */
    uint32_t ns_since_reset;    /* delay after RESET before the next command */
    uint8_t command_too_soon;   /* command sent before the reset wait elapsed */
};

void sim_ads1220_init(struct sim_ads1220 *sim, struct tc_hal *hal, uint16_t cs_pin);

#endif
