/* hal.h - the only way the sensor drivers touch hardware.
 *
 * A driver never calls GPIO, SPI or timer code directly. It calls the function
 * pointers in a `struct tc_hal` that the caller owns and fills in:
 *   - a board port points them at its pin, SPI and timer code;
 *   - the host tests point them at a simulated chip, so the exact same driver
 *     code is exercised bit by bit on the PC.
 * `ctx` is handed back unchanged on every call (the board's or the simulator's
 * state), so there are no hidden globals anywhere.
 */
#ifndef TAPCELL_HAL_H
#define TAPCELL_HAL_H

#include <stdint.h>

struct tc_hal {
    void *ctx;
    /* Drive an output pin low (0) or high (1). */
    void (*pin_write)(void *ctx, uint16_t pin, uint8_t level);
    /* Sample an input pin: 0 or 1. */
    uint8_t (*pin_read)(void *ctx, uint16_t pin);
    /* Busy-wait for at least `ns` nanoseconds (sub-microsecond up to ~1 ms). */
    void (*delay_ns)(void *ctx, uint32_t ns);
    /* Free-running time in timer ticks; wraps at 2^32, so always compare
     * with unsigned subtraction (later - earlier). */
    uint32_t (*time_now_ticks)(void *ctx);
    /* Full-duplex SPI exchange in place: data[i] is sent, then replaced by
     * the byte received at the same time. Chip select is driven by the
     * driver through pin_write, because one command must stay in one
     * CS-low window. */
    void (*spi_transfer)(void *ctx, uint8_t *data, uint8_t len);
    /* Disable interrupts and return the previous state; restore it. Used
     * around each bit-bang clock pulse, where an interrupt stretching the
     * pulse could put a chip into power-down. */
    uint32_t (*irq_save)(void *ctx);
    void (*irq_restore)(void *ctx, uint32_t saved_state);
};

/* Critical-section hook for state shared between contexts (the load-cell
 * trigger's state changes; see load_cell_trigger.h, "Calling contexts").
 * tc_irq_save() masks interrupts and returns the previous mask;
 * tc_irq_restore() puts it back. Both are compiler barriers. On Cortex-M they
 * use PRIMASK (the whole sequence is 3 instructions). A port with other needs
 * (an RTOS lock, a multi-core part) names a header in TC_PORT_HEADER that
 * defines TC_IRQ_SAVE() and TC_IRQ_RESTORE(saved); the C tests use this to
 * play a timer interrupt inside the critical section. The host library the
 * Python host loads is built with TC_SINGLE_THREADED: no-ops. Any other
 * architecture is a build error, never silently unmasked. */
#ifdef TC_PORT_HEADER
#include TC_PORT_HEADER
#endif
#if defined(TC_IRQ_SAVE)
static inline uint32_t tc_irq_save(void) { return TC_IRQ_SAVE(); }
static inline void tc_irq_restore(uint32_t saved) { TC_IRQ_RESTORE(saved); }
#elif defined(__ARM_ARCH_6M__) || defined(__ARM_ARCH_7M__) || defined(__ARM_ARCH_7EM__) \
    || defined(__ARM_ARCH_8M_BASE__) || defined(__ARM_ARCH_8M_MAIN__)
static inline uint32_t tc_irq_save(void)
{
    uint32_t primask;
    __asm__ volatile("mrs %0, primask\n\tcpsid i" : "=r"(primask) : : "memory");
    return primask;
}
static inline void tc_irq_restore(uint32_t saved)
{
    __asm__ volatile("msr primask, %0" : : "r"(saved) : "memory");
}
#elif defined(TC_SINGLE_THREADED)
/* Host builds (the cffi library, the benchmarks' x86 harness): one thread, no interrupts. */
static inline uint32_t tc_irq_save(void) { return 0; }
static inline void tc_irq_restore(uint32_t saved) { (void)saved; }
#else
#error "hal.h: no critical section for this architecture: define TC_PORT_HEADER (TC_IRQ_SAVE/TC_IRQ_RESTORE), or TC_SINGLE_THREADED for a build without interrupts"
#endif

/* Both 24-bit ADCs deliver two's-complement words MSB first. Flipping the
 * sign bit maps the word onto 0..2^24-1 in order; subtracting 2^23 then gives
 * the signed value without any implementation-defined shift of a negative. */
static inline int32_t tc_sign_extend_24(uint32_t word24)
{
    return (int32_t)((word24 ^ 0x800000u) & 0xFFFFFFu) - 0x800000;
}

#endif
