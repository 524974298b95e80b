/* board.h - what the emulator app (app.c) needs from a board port.
 *
 * A port supplies a free-running 32-bit time base, a periodic "data-ready"
 * interrupt standing in for the ADC's conversion clock (DOUT falling on a real
 * HX71x), a periodic watchdog-timer interrupt at a HIGHER priority than
 * data-ready (so it can preempt a sample being processed), a calibrated
 * busy-wait and a sleep. Its interrupt handlers call app_data_ready() and
 * app_watchdog_tick(). Output and exit go through semihosting (semihost.h).
 */
#ifndef TAPCELL_PORT_BOARD_H
#define TAPCELL_PORT_BOARD_H

#include <stdint.h>

extern const uint32_t board_ticks_per_s;
extern const char board_name[];

void board_init(void);
uint32_t board_now_ticks(void);
/* First interrupt at `first_ticks` (on the board_now_ticks() scale), then every period. */
void board_data_ready_start(uint32_t first_ticks, uint32_t period_ticks);
void board_data_ready_stop(void);
void board_watchdog_start(uint32_t period_ticks);
void board_watchdog_stop(void);
/* Wait for an interrupt (WFI). */
void board_sleep(void);
/* Busy-wait at least ns nanoseconds of this board's CPU time. */
void board_delay_ns(uint32_t ns);

/* Called from the board's interrupt handlers. ready_ticks is when the
 * conversion completed (the compare value, not when the handler ran). */
void app_data_ready(uint32_t ready_ticks);
void app_watchdog_tick(uint32_t now_ticks);

/* Two-instruction loop ("subs; bhi"): n iterations. */
static inline void board_delay_loops(uint32_t n)
{
    __asm__ volatile(".syntax unified\n1: subs %0, %0, #1\n\tbhi 1b\n\t.syntax divided" : "+l"(n) : : "cc");
}

static inline void board_enable_irq(void) { __asm__ volatile("cpsie i" : : : "memory"); }
static inline void board_disable_irq(void) { __asm__ volatile("cpsid i" : : : "memory"); }

/* ARMv6-M NVIC: enable an interrupt and set its priority (0 = highest of 4 levels,
 * the top two bits of each byte; IPR must be written as words on ARMv6-M). */
static inline void board_nvic_enable(unsigned irq, unsigned priority)
{
    volatile uint32_t *ipr = (volatile uint32_t *)0xE000E400u + (irq >> 2);
    unsigned shift = (irq & 3u) * 8u;
    *ipr = (*ipr & ~(0xFFu << shift)) | ((priority << 6) << shift);
    *(volatile uint32_t *)0xE000E100u = 1u << irq;   /* ISER */
}

static inline void board_nvic_disable(unsigned irq)
{
    *(volatile uint32_t *)0xE000E180u = 1u << irq;   /* ICER */
    *(volatile uint32_t *)0xE000E280u = 1u << irq;   /* ICPR */
}

#endif
