/* Host-only batch entry points: the Python host (tapcell.mcu) runs a whole tap through
 * the firmware in one call. They are built into the host library and the C tests, never
 * into the MCU image, so the Cortex-M0+ sizes count only what ships on the toolhead. */
#include "load_cell_trigger.h"
#include "sos_filter.h"

size_t tc_sos_filter_run(struct tc_sos_filter *f, const int32_t *x, int32_t *y, size_t n)
{
    size_t first_overflow = n;
    for (size_t i = 0; i < n; i++) {
        y[i] = tc_sos_filter_apply(f, x[i]);
        if (f->overflowed && first_overflow == n)
            first_overflow = i;
    }
    return first_overflow;
}

size_t tc_trigger_feed(struct tc_trigger *t, const int32_t *counts, const uint32_t *ticks,
                       size_t n, int32_t *filtered_q, int *event)
{
    for (size_t i = 0; i < n; i++) {
        *event = tc_trigger_sample(t, counts[i], ticks[i]);
        if (filtered_q)
            filtered_q[i] = t->filtered_q;
        if (*event != TC_EVENT_NONE)
            return i;
    }
    *event = TC_EVENT_NONE;
    return n;
}

size_t tc_trigger_struct_size(void)
{
    return sizeof(struct tc_trigger);
}
