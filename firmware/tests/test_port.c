/* The C tests' port hooks (test_port.h): counted critical sections with an
 * optional interrupt played at the moment of masking. */
#include "test_port.h"

struct test_irq test_irq;

uint32_t test_irq_save(void)
{
    test_irq.saves++;
    if (test_irq.pending) {            /* the interrupt got in just before the mask */
        void (*isr)(void *) = test_irq.pending;
        test_irq.pending = 0;
        isr(test_irq.arg);
    }
    return test_irq.depth++;
}

void test_irq_restore(uint32_t saved)
{
    test_irq.depth = saved;
}
