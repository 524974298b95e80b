/* startup.c - reset, vector table and stack painting for ARMv6-M (both targets).
 *
 * The linker script provides __data_load, __data_start, __data_end, __bss_start,
 * __bss_end, __stack_limit and __stack_top. The stack is painted with
 * STACK_PAINT up to the reset handler's own frame, so app.c can report the
 * stack high-water mark. A board names its interrupts by defining
 * irq_handler_N (N = the NVIC line); the others fall to unexpected_handler.
 */
#include <stdint.h>
#include "semihost.h"
#include "startup.h"

extern uint32_t __data_load[], __data_start[], __data_end[], __bss_start[], __bss_end[];
extern uint32_t __stack_limit[], __stack_top[];
int main(void);

void reset_handler(void)
{
    const uint32_t *from = __data_load;
    for (uint32_t *to = __data_start; to < __data_end; )
        *to++ = *from++;
    for (uint32_t *to = __bss_start; to < __bss_end; )
        *to++ = 0;
    uint32_t *sp;
    __asm__ volatile("mov %0, sp" : "=r"(sp));
    for (uint32_t *word = __stack_limit; word < sp - 8; word++)
        *word = STACK_PAINT;
    semihost_exit(main() ? 1u : 0u);
}

uint32_t stack_high_water_bytes(void)
{
    const uint32_t *word = __stack_limit;
    while (word < __stack_top && *word == STACK_PAINT)
        word++;
    return (uint32_t)((const char *)__stack_top - (const char *)word);
}

uint32_t stack_size_bytes(void)
{
    return (uint32_t)((const char *)__stack_top - (const char *)__stack_limit);
}

static void unexpected_handler(void)
{
    semihost_puts("FAIL unexpected exception or interrupt\n");
    semihost_exit(2);
}

#define WEAK_HANDLER(name) void name(void) __attribute__((weak, alias("unexpected_handler")))
WEAK_HANDLER(nmi_handler);
WEAK_HANDLER(hard_fault_handler);
WEAK_HANDLER(svc_handler);
WEAK_HANDLER(pendsv_handler);
WEAK_HANDLER(systick_handler);
WEAK_HANDLER(irq_handler_0);  WEAK_HANDLER(irq_handler_1);  WEAK_HANDLER(irq_handler_2);
WEAK_HANDLER(irq_handler_3);  WEAK_HANDLER(irq_handler_4);  WEAK_HANDLER(irq_handler_5);
WEAK_HANDLER(irq_handler_6);  WEAK_HANDLER(irq_handler_7);  WEAK_HANDLER(irq_handler_8);
WEAK_HANDLER(irq_handler_9);  WEAK_HANDLER(irq_handler_10); WEAK_HANDLER(irq_handler_11);
WEAK_HANDLER(irq_handler_12); WEAK_HANDLER(irq_handler_13); WEAK_HANDLER(irq_handler_14);
WEAK_HANDLER(irq_handler_15); WEAK_HANDLER(irq_handler_16); WEAK_HANDLER(irq_handler_17);
WEAK_HANDLER(irq_handler_18); WEAK_HANDLER(irq_handler_19); WEAK_HANDLER(irq_handler_20);
WEAK_HANDLER(irq_handler_21); WEAK_HANDLER(irq_handler_22); WEAK_HANDLER(irq_handler_23);
WEAK_HANDLER(irq_handler_24); WEAK_HANDLER(irq_handler_25); WEAK_HANDLER(irq_handler_26);
WEAK_HANDLER(irq_handler_27); WEAK_HANDLER(irq_handler_28); WEAK_HANDLER(irq_handler_29);
WEAK_HANDLER(irq_handler_30); WEAK_HANDLER(irq_handler_31);

typedef void (*vector_t)(void);

/* ARMv6-M vector table: initial SP, 15 system exceptions (reserved slots 0), 32 IRQs. */
__attribute__((section(".vectors"), used))
const vector_t vector_table[48] = {
    (vector_t)(uintptr_t)__stack_top, reset_handler, nmi_handler, hard_fault_handler,
    0, 0, 0, 0, 0, 0, 0, svc_handler, 0, 0, pendsv_handler, systick_handler,
    irq_handler_0,  irq_handler_1,  irq_handler_2,  irq_handler_3,  irq_handler_4,  irq_handler_5,
    irq_handler_6,  irq_handler_7,  irq_handler_8,  irq_handler_9,  irq_handler_10, irq_handler_11,
    irq_handler_12, irq_handler_13, irq_handler_14, irq_handler_15, irq_handler_16, irq_handler_17,
    irq_handler_18, irq_handler_19, irq_handler_20, irq_handler_21, irq_handler_22, irq_handler_23,
    irq_handler_24, irq_handler_25, irq_handler_26, irq_handler_27, irq_handler_28, irq_handler_29,
    irq_handler_30, irq_handler_31,
};
