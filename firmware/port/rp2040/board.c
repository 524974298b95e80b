/* rp2040/board.c - RP2040 (Cortex-M0+) as rp2040js models it.
 *
 * Time base: the 1 MHz TIMER (TIMERAWL).
 * Data-ready: ALARM0 (IRQ 0 TIMER_IRQ_0, priority 2), re-armed one period on.
 * Watchdog: ALARM1 (IRQ 1 TIMER_IRQ_1, priority 1: it preempts data-ready).
 * clk_sys is rp2040js's 125 MHz. A real board also needs boot2, the clock tree
 * (XOSC, PLL), the TIMER out of reset and the watchdog's tick generator
 * (docs/firmware.md).
 */
#include "../board.h"

#define TIMER 0x40054000u
#define ALARM(n) (0x10u + 4u * (n))
#define TIMERAWL 0x28u
#define INTR 0x34u
#define INTE 0x38u
#define IRQ_DATA_READY 0u   /* TIMER_IRQ_n is alarm n */
#define IRQ_WATCHDOG 1u
#define PRIORITY_DATA_READY 2u
#define PRIORITY_WATCHDOG 1u

#define REG(offset) (*(volatile uint32_t *)(TIMER + (offset)))

const uint32_t board_ticks_per_s = 1000000u;
const char board_name[] = "rp2040js";

static uint32_t data_ready_period, data_ready_next, watchdog_period, watchdog_next;

void board_init(void)
{
}

uint32_t board_now_ticks(void)
{
    return REG(TIMERAWL);
}

/* Alarm n (IRQ n) at `at_ticks`, interrupting at `priority`. */
static void alarm_start(unsigned n, unsigned priority, uint32_t at_ticks)
{
    REG(INTR) = 1u << n;
    REG(INTE) |= 1u << n;
    REG(ALARM(n)) = at_ticks;
    board_nvic_enable(n, priority);
}

static void alarm_stop(unsigned n)
{
    REG(INTE) &= ~(1u << n);
    board_nvic_disable(n);
}

void board_data_ready_start(uint32_t first_ticks, uint32_t period_ticks)
{
    data_ready_period = period_ticks;
    data_ready_next = first_ticks;
    alarm_start(IRQ_DATA_READY, PRIORITY_DATA_READY, first_ticks);
}

void board_data_ready_stop(void)
{
    alarm_stop(IRQ_DATA_READY);
}

void board_watchdog_start(uint32_t period_ticks)
{
    watchdog_period = period_ticks;
    watchdog_next = board_now_ticks() + period_ticks;
    alarm_start(IRQ_WATCHDOG, PRIORITY_WATCHDOG, watchdog_next);
}

void board_watchdog_stop(void)
{
    alarm_stop(IRQ_WATCHDOG);
}

void board_sleep(void)
{
    __asm__ volatile("wfi");
}

void board_delay_ns(uint32_t ns)
{
    board_delay_loops((ns >> 4) + 1u);   /* 3 cycles = 24 ns per loop at 125 MHz */
}

/* ALARM0: the ADC finished a conversion. */
void irq_handler_0(void)
{
    REG(INTR) = 1u << 0;
    uint32_t ready = data_ready_next;
    data_ready_next = ready + data_ready_period;
    REG(ALARM(0)) = data_ready_next;
    app_data_ready(ready);
}

/* ALARM1: the periodic watchdog check. */
void irq_handler_1(void)
{
    REG(INTR) = 1u << 1;
    watchdog_next += watchdog_period;
    REG(ALARM(1)) = watchdog_next;
    app_watchdog_tick(board_now_ticks());
}
