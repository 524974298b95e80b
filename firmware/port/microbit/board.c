/* microbit/board.c - BBC micro:bit v1 (nRF51822, Cortex-M0) as QEMU's `microbit` machine models it.
 *
 * Time base: TIMER0, 32-bit at 16 MHz, read with a capture task (CC[3]).
 * Data-ready: TIMER0 compare CC[0] (IRQ 8, priority 2), re-armed one period on.
 * Watchdog: TIMER1 compare CC[0] (IRQ 9, priority 1: it preempts data-ready).
 * Run under -icount shift=0, one instruction is one nanosecond of virtual time,
 * so a 16 MHz tick is 62.5 instructions.
 */
#include "../board.h"

#define TIMER0 0x40008000u
#define TIMER1 0x40009000u
#define TASKS_START 0x000u
#define TASKS_CLEAR 0x00Cu
#define TASKS_CAPTURE(n) (0x040u + 4u * (n))
#define EVENTS_COMPARE(n) (0x140u + 4u * (n))
#define INTENSET 0x304u
#define INTENCLR 0x308u
#define MODE 0x504u
#define BITMODE 0x508u
#define PRESCALER 0x510u
#define CC(n) (0x540u + 4u * (n))
#define INT_COMPARE0 (1u << 16)
#define IRQ_TIMER0 8u
#define IRQ_TIMER1 9u
#define PRIORITY_DATA_READY 2u
#define PRIORITY_WATCHDOG 1u

#define REG(timer, offset) (*(volatile uint32_t *)((timer) + (offset)))

const uint32_t board_ticks_per_s = 16000000u;
const char board_name[] = "qemu-microbit";

static uint32_t data_ready_period, watchdog_period;

static void timer_init(uint32_t timer)
{
    REG(timer, MODE) = 0;        /* timer, not counter */
    REG(timer, BITMODE) = 3;     /* 32 bit */
    REG(timer, PRESCALER) = 0;   /* 16 MHz */
    REG(timer, TASKS_CLEAR) = 1;
    REG(timer, TASKS_START) = 1;
}

static uint32_t timer_now(uint32_t timer)
{
    REG(timer, TASKS_CAPTURE(3)) = 1;
    return REG(timer, CC(3));
}

void board_init(void)
{
    timer_init(TIMER0);
    timer_init(TIMER1);
}

uint32_t board_now_ticks(void)
{
    return timer_now(TIMER0);
}

/* Compare CC[0] of `timer` at `at_ticks` (its own count), interrupting at `priority`. */
static void compare_start(uint32_t timer, unsigned irq, unsigned priority, uint32_t at_ticks)
{
    REG(timer, CC(0)) = at_ticks;
    REG(timer, EVENTS_COMPARE(0)) = 0;
    REG(timer, INTENSET) = INT_COMPARE0;
    board_nvic_enable(irq, priority);
}

static void compare_stop(uint32_t timer, unsigned irq)
{
    REG(timer, INTENCLR) = INT_COMPARE0;
    board_nvic_disable(irq);
}

void board_data_ready_start(uint32_t first_ticks, uint32_t period_ticks)
{
    data_ready_period = period_ticks;
    compare_start(TIMER0, IRQ_TIMER0, PRIORITY_DATA_READY, first_ticks);
}

void board_data_ready_stop(void)
{
    compare_stop(TIMER0, IRQ_TIMER0);
}

void board_watchdog_start(uint32_t period_ticks)
{
    watchdog_period = period_ticks;
    compare_start(TIMER1, IRQ_TIMER1, PRIORITY_WATCHDOG, timer_now(TIMER1) + period_ticks);
}

void board_watchdog_stop(void)
{
    compare_stop(TIMER1, IRQ_TIMER1);
}

void board_sleep(void)
{
    __asm__ volatile("wfi");
}

void board_delay_ns(uint32_t ns)
{
    board_delay_loops((ns >> 1) + 1u);   /* 2 instructions = 2 ns per loop */
}

/* TIMER0: the ADC finished a conversion at CC[0]. The compare moves on BEFORE
 * the event is cleared: QEMU's model re-raises a 32-bit compare whose CC still
 * equals the counter on its next update (the clear is one), which would run this
 * handler a second time at once. */
void irq_handler_8(void)
{
    uint32_t ready = REG(TIMER0, CC(0));
    REG(TIMER0, CC(0)) = ready + data_ready_period;
    REG(TIMER0, EVENTS_COMPARE(0)) = 0;
    app_data_ready(ready);
}

/* TIMER1: the periodic watchdog check. */
void irq_handler_9(void)
{
    REG(TIMER1, CC(0)) += watchdog_period;   /* before the clear, as above */
    REG(TIMER1, EVENTS_COMPARE(0)) = 0;
    app_watchdog_tick(board_now_ticks());
}
