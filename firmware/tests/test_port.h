/* Port hooks for the C tests: the trigger's critical sections count themselves
 * and can run a "pending interrupt" at the moment interrupts get masked - what
 * a timer interrupt that fired just before the mask would have done - so the
 * tests can check the order of events of a preempted tc_trigger_sample(). */
#ifndef TAPCELL_TEST_PORT_H
#define TAPCELL_TEST_PORT_H

#include <stdint.h>

struct test_irq {
    void (*pending)(void *arg);   /* run once, at the next mask; NULL: none */
    void *arg;
    uint32_t saves;               /* critical sections entered */
    uint32_t depth;               /* currently masked (0 when balanced) */
};
extern struct test_irq test_irq;

uint32_t test_irq_save(void);
void test_irq_restore(uint32_t saved);

#define TC_IRQ_SAVE() test_irq_save()
#define TC_IRQ_RESTORE(saved) test_irq_restore(saved)

#endif
