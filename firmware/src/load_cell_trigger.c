/* load_cell_trigger.c - the load-cell endstop; behaviour documented in load_cell_trigger.h. */
#include "load_cell_trigger.h"

/* Change the state `from` -> `to`, setting the error code and stamping
 * `*ticks_out`, unless the state already left `from` (the watchdog or an
 * abort got there first: their verdict stands). Returns 1 when changed. */
static int commit(struct tc_trigger *t, uint8_t from, uint8_t to, int error_code, uint32_t *ticks_out,
                  uint32_t ticks)
{
    uint32_t saved = tc_irq_save();
    int changed = t->state == from;
    if (changed) {
        *ticks_out = ticks;
        t->error = (uint8_t)error_code;
        t->state = to;
    }
    tc_irq_restore(saved);
    return changed;
}

static int fail(struct tc_trigger *t, uint8_t from, int error_code, uint32_t ticks)
{
    commit(t, from, TC_TRIGGER_ERROR, error_code, &t->error_ticks, ticks);
    return TC_EVENT_ERROR;
}

/* Samples are processed while armed, and while triggered when a release level
 * makes the trigger a state that can end (hysteresis). Callers read the state
 * once and decide on that copy. */
static int listening(const struct tc_trigger *t, uint8_t state)
{
    return state == TC_TRIGGER_ARMED || (state == TC_TRIGGER_TRIGGERED && t->cfg.release_q);
}

int tc_trigger_configure(struct tc_trigger *t, const struct tc_trigger_config *cfg)
{
    /* Not masked as a whole: it runs idle (disarm first), and no other context
     * acts on an idle trigger. */
    int32_t edge;
    /* Unsigned compares fold each "lo <= v <= hi" range into one test. */
    if ((cfg->force_limit_counts | cfg->drift_limit_counts) < 0 || cfg->scale == 0
        || __builtin_add_overflow(cfg->reference_tare_counts, cfg->force_limit_counts, &edge)
        || __builtin_sub_overflow(cfg->reference_tare_counts, cfg->force_limit_counts, &edge)
        || cfg->scale_frac_bits - 1u > 30u || cfg->trigger_q <= 0
        || (uint32_t)cfg->release_q >= (uint32_t)cfg->trigger_q    /* also rejects release_q < 0 */
        || cfg->sample_period_ticks - 1u >= TC_TRIGGER_MAX_PERIOD_TICKS - 1u
        || cfg->watchdog_periods - 1u >= TC_TRIGGER_MAX_WATCHDOG_PERIODS
        || cfg->stuck_samples == 1u || cfg->stuck_samples > TC_TRIGGER_MAX_STUCK_SAMPLES)
        return TC_ERR_BAD_CONFIG;
    tc_trigger_disarm(t);
    t->cfg = *cfg;
    t->watchdog_ticks = cfg->watchdog_periods * cfg->sample_period_ticks;
    t->stuck_repeats = cfg->stuck_samples - 1u;   /* 0 (off) wraps to UINT32_MAX: never reached */
    t->scale_round = (uint32_t)1 << (cfg->scale_frac_bits - 1);
    t->trigger_bias = (uint32_t)cfg->trigger_q - 1u;
    return TC_OK;
}

/* The window (larger - limit) .. (smaller + limit): the intersection of
 * larger +- limit and smaller +- limit, as low .. low + span compared modulo
 * 2^32. A limit of 0 allows everything. */
static void set_window(uint32_t *low, uint32_t *span, int32_t larger, int32_t smaller, int32_t limit)
{
    *low = (uint32_t)larger - (uint32_t)limit;
    *span = limit ? 2u * (uint32_t)limit - ((uint32_t)larger - (uint32_t)smaller) : UINT32_MAX;
}

int tc_trigger_arm(struct tc_trigger *t, int32_t tare_counts, uint32_t arm_ticks)
{
    /* configure() guarantees trigger_q > 0; a zeroed, never-configured trigger
     * would otherwise arm with a scale shift of 0 (a 32-bit shift on M0+). */
    if (t->cfg.trigger_q <= 0)
        return TC_ERR_BAD_CONFIG;
    const int32_t reference = t->cfg.reference_tare_counts, limit = t->cfg.force_limit_counts;
    const int32_t drift = t->cfg.drift_limit_counts;
    int status = TC_OK;
    uint32_t saved = tc_irq_save();
    tc_sos_filter_reset(&t->filter);
    t->tare_counts = tare_counts;
    t->arm_ticks = arm_ticks;
    t->last_sample_ticks = arm_ticks;
    t->last_counts = INT32_MIN;   /* no 24-bit sensor value: the first sample starts a run */
    t->repeats = 0;
    t->glitches = 0;
    t->glitch_held = 0;
    t->filtered_q = 0;
    t->error = TC_OK;
    t->state = TC_TRIGGER_ARMED;
    set_window(&t->drift_low, &t->drift_span, tare_counts, tare_counts, drift);
    /* Force window: reference +- limit intersected with tare +- limit. It exists
     * when the two centres are at most limit apart (the tare check); it fits
     * int32 because reference +- limit does (configure). */
    int32_t larger = tare_counts > reference ? tare_counts : reference;
    int32_t smaller = tare_counts > reference ? reference : tare_counts;
    uint32_t apart = (uint32_t)larger - (uint32_t)smaller;
    set_window(&t->force_low, &t->force_span, larger, smaller, limit);
    if (limit && apart > (uint32_t)limit) {
        t->error_ticks = arm_ticks;
        t->error = TC_ERR_FORCE_SAFETY;
        t->state = TC_TRIGGER_ERROR;
        status = TC_ERR_FORCE_SAFETY;
    }
    tc_irq_restore(saved);
    return status;
}

/* The per-sample path of a listening trigger (tc_trigger_sample below). Kept out
 * of line so the not-armed return happens before any register is saved. */
__attribute__((noinline)) static int sample_listening(struct tc_trigger *t, uint8_t state, int32_t counts,
                                                      uint32_t sample_ticks)
{
    int error;
    /* Unsigned: a sample older than the base (negative difference) is huge too,
     * so one compare passes every sample in time; the rare others sort here. */
    uint32_t since_last = sample_ticks - t->last_sample_ticks;
    if (since_last > t->watchdog_ticks) {
        if ((int32_t)since_last < 0)
            return TC_EVENT_NONE;                 /* taken before the arm time / last sample */
        error = TC_ERR_WATCHDOG_TIMEOUT;
        goto failed;
    }
    t->last_sample_ticks = sample_ticks;

    /* The force limit: every sample, before anything can hold it back. */
    error = TC_ERR_FORCE_SAFETY;
    if ((uint32_t)counts - t->force_low > t->force_span)
        goto failed;
    error = TC_ERR_STUCK_SENSOR;
    if (counts != t->last_counts) {
        t->last_counts = counts;
        t->repeats = 0;
    } else if (++t->repeats >= t->stuck_repeats) {
        goto failed;
    }

    if ((uint32_t)counts - t->drift_low > t->drift_span) {
        error = TC_ERR_DRIFT_SAFETY;
        if (t->glitch_held)
            goto failed;
        t->glitch_held = 1;     /* quarantined: wait for the neighbour's verdict */
        return TC_EVENT_NONE;
    }
    if (t->glitch_held) {       /* neighbour back inside: it was a single bad frame */
        t->glitch_held = 0;
        t->glitches++;
    }

    uint8_t bad = 0;
    int32_t offset_counts;
    error = TC_ERR_SCALE_OVERFLOW;
    if (__builtin_sub_overflow(counts, t->tare_counts, &offset_counts))
        goto failed;
    const uint32_t round_half = t->scale_round;
#ifdef __OPTIMIZE_SIZE__
    /* Size builds share the filter's out-of-line multiply; its saturating add
     * never saturates here (|product| <= 2^62, plus 2^30), so it is the same. */
    int64_t acc = round_half;
    int32_t grams_q = tc_mul_add_shift(offset_counts, t->cfg.scale, &acc, t->cfg.scale_frac_bits, &bad);
#else
    int32_t grams_q = tc_shift_to_int32(tc_mul_s32(offset_counts, t->cfg.scale) + round_half,
                                        t->cfg.scale_frac_bits, &bad);
#endif
    if (bad)
        goto failed;
    int32_t force_q = tc_sos_filter_apply(&t->filter, grams_q);
    error = TC_ERR_FILTER_OVERFLOW;
    if (t->filter.overflowed)
        goto failed;
    t->filtered_q = force_q;

    /* |force| >= level  <=>  force outside 0 +- (level - 1) LSB */
    if (state == TC_TRIGGER_ARMED) {
        uint32_t bias = t->trigger_bias;
        if ((uint32_t)force_q + bias > 2u * bias)
            return commit(t, state, TC_TRIGGER_TRIGGERED, TC_OK, &t->trigger_ticks, sample_ticks)
                ? TC_EVENT_TRIGGER : TC_EVENT_ERROR;
    } else {
        uint32_t bias = (uint32_t)t->cfg.release_q - 1u;
        if ((uint32_t)force_q + bias <= 2u * bias)
            return commit(t, state, TC_TRIGGER_ARMED, TC_OK, &t->release_ticks, sample_ticks)
                ? TC_EVENT_RELEASE : TC_EVENT_ERROR;
    }
    return TC_EVENT_NONE;

failed:
    return fail(t, state, error, sample_ticks);
}

int tc_trigger_sample(struct tc_trigger *t, int32_t counts, uint32_t sample_ticks)
{
    const uint8_t state = t->state;
    if (!listening(t, state))
        return TC_EVENT_NONE;
    return sample_listening(t, state, counts, sample_ticks);
}

int tc_trigger_check_watchdog(struct tc_trigger *t, uint32_t now_ticks)
{
    const uint8_t state = t->state;
    if (listening(t, state) && (int32_t)(now_ticks - t->last_sample_ticks) > (int32_t)t->watchdog_ticks)
        fail(t, state, TC_ERR_WATCHDOG_TIMEOUT, now_ticks);
    return t->error;
}

void tc_trigger_abort(struct tc_trigger *t, int error_code, uint32_t now_ticks)
{
    const uint8_t state = t->state;
    if (listening(t, state))
        fail(t, state, error_code, now_ticks);
}

void tc_trigger_disarm(struct tc_trigger *t)
{
    uint32_t saved = tc_irq_save();
    t->state = TC_TRIGGER_IDLE;
    t->error = TC_OK;
    t->glitch_held = 0;
    tc_irq_restore(saved);
}
