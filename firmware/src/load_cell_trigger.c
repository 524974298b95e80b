/* load_cell_trigger.c - the load-cell endstop; behaviour documented in load_cell_trigger.h. */
#include "load_cell_trigger.h"

/* True when value lies within centre +- half_width (half_width >= 0). The
 * difference is taken modulo 2^32 and shifted by half_width, so one unsigned
 * compare covers both sides; exact while |value - centre| < 2^31, which holds
 * for every 24-bit sensor. */
static int within(int32_t value, int32_t centre, int32_t half_width)
{
    return (uint32_t)value - (uint32_t)centre + (uint32_t)half_width <= 2u * (uint32_t)half_width;
}

int tc_trigger_configure(struct tc_trigger *t, const struct tc_trigger_config *cfg)
{
    /* Unsigned compares fold each "lo <= v <= hi" range into one test. */
    if ((cfg->force_limit_counts | cfg->drift_limit_counts) < 0 || cfg->scale == 0
        || cfg->scale_frac_bits - 1u > 30u || cfg->trigger_q <= 0
        || (uint32_t)cfg->release_q >= (uint32_t)cfg->trigger_q    /* also rejects release_q < 0 */
        || cfg->sample_period_ticks - 1u >= TC_TRIGGER_MAX_PERIOD_TICKS - 1u
        || cfg->watchdog_periods - 1u >= TC_TRIGGER_MAX_WATCHDOG_PERIODS)
        return TC_ERR_BAD_CONFIG;
    t->cfg = *cfg;
    t->watchdog_ticks = cfg->watchdog_periods * cfg->sample_period_ticks;
    tc_trigger_disarm(t);
    return TC_OK;
}

static int fail(struct tc_trigger *t, int error_code, uint32_t ticks)
{
    t->state = TC_TRIGGER_ERROR;
    t->error = (uint8_t)error_code;
    t->error_ticks = ticks;
    return TC_EVENT_ERROR;
}

int tc_trigger_arm(struct tc_trigger *t, int32_t tare_counts, uint32_t arm_ticks)
{
    tc_sos_filter_reset(&t->filter);
    t->tare_counts = tare_counts;
    t->arm_ticks = arm_ticks;
    t->last_sample_ticks = arm_ticks;
    t->glitches = 0;
    t->glitch_held = 0;
    t->filtered_q = 0;
    t->error = TC_OK;
    t->state = TC_TRIGGER_ARMED;
    if (t->cfg.force_limit_counts
        && !within(tare_counts, t->cfg.reference_tare_counts, t->cfg.force_limit_counts)) {
        fail(t, TC_ERR_FORCE_SAFETY, arm_ticks);
        return TC_ERR_FORCE_SAFETY;
    }
    return TC_OK;
}

/* Samples are processed while armed, and while triggered when a release level
 * makes the trigger a state that can end (hysteresis). */
static int listening(const struct tc_trigger *t)
{
    return t->state == TC_TRIGGER_ARMED
        || (t->state == TC_TRIGGER_TRIGGERED && t->cfg.release_q);
}

int tc_trigger_sample(struct tc_trigger *t, int32_t counts, uint32_t sample_ticks)
{
    if (!listening(t) || (int32_t)(sample_ticks - t->arm_ticks) < 0)
        return TC_EVENT_NONE;
    if ((int32_t)(sample_ticks - t->last_sample_ticks) > (int32_t)t->watchdog_ticks)
        return fail(t, TC_ERR_WATCHDOG_TIMEOUT, sample_ticks);
    t->last_sample_ticks = sample_ticks;

    if (t->cfg.drift_limit_counts && !within(counts, t->tare_counts, t->cfg.drift_limit_counts)) {
        if (t->glitch_held)
            return fail(t, TC_ERR_DRIFT_SAFETY, sample_ticks);
        t->glitch_held = 1;     /* quarantined: wait for the neighbour's verdict */
        return TC_EVENT_NONE;
    }
    if (t->glitch_held) {       /* neighbour back inside: it was a single bad frame */
        t->glitch_held = 0;
        t->glitches++;
    }

    uint8_t bad = 0;
    int32_t offset_counts;
    if (__builtin_sub_overflow(counts, t->tare_counts, &offset_counts))
        return fail(t, TC_ERR_SCALE_OVERFLOW, sample_ticks);
    int64_t acc = (uint32_t)1 << (t->cfg.scale_frac_bits - 1);   /* round half up */
    int32_t grams_q = tc_mul_add_shift(offset_counts, t->cfg.scale, &acc, t->cfg.scale_frac_bits, &bad);
    if (bad)
        return fail(t, TC_ERR_SCALE_OVERFLOW, sample_ticks);
    int32_t force_q = tc_sos_filter_apply(&t->filter, grams_q);
    if (t->filter.overflowed)
        return fail(t, TC_ERR_FILTER_OVERFLOW, sample_ticks);
    t->filtered_q = force_q;

    /* |force| >= trigger  <=>  force outside 0 +- (trigger - 1) LSB */
    if (t->state == TC_TRIGGER_ARMED) {
        if (!within(force_q, 0, t->cfg.trigger_q - 1)) {
            t->state = TC_TRIGGER_TRIGGERED;
            t->trigger_ticks = sample_ticks;
            return TC_EVENT_TRIGGER;
        }
    } else if (within(force_q, 0, t->cfg.release_q - 1)) {
        t->state = TC_TRIGGER_ARMED;
        t->release_ticks = sample_ticks;
        return TC_EVENT_RELEASE;
    }
    return TC_EVENT_NONE;
}

int tc_trigger_check_watchdog(struct tc_trigger *t, uint32_t now_ticks)
{
    if (listening(t) && (int32_t)(now_ticks - t->last_sample_ticks) > (int32_t)t->watchdog_ticks)
        fail(t, TC_ERR_WATCHDOG_TIMEOUT, now_ticks);
    return t->error;
}

void tc_trigger_abort(struct tc_trigger *t, int error_code, uint32_t now_ticks)
{
    if (listening(t))
        fail(t, error_code, now_ticks);
}

void tc_trigger_disarm(struct tc_trigger *t)
{
    t->state = TC_TRIGGER_IDLE;
    t->error = TC_OK;
    t->glitch_held = 0;
}
