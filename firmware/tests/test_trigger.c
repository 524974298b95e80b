/* Load-cell trigger: threshold, safety limits, stuck sensor, watchdog, glitch
 * quarantine, hysteresis, timestamps, critical sections. Scale: 128 counts per
 * gram, so 1 count = 256 LSB of Q16.15 exactly and every expected value below
 * is exact. */
#include "unit.h"
#include "load_cell_trigger.h"
#include "test_port.h"

#define GRAM 32768
#define CPG 128                       /* counts per gram */
#define REF_TARE 1000
#define PERIOD 100                    /* ticks per sample */

static struct tc_trigger_config base_config(void)
{
    struct tc_trigger_config c = {
        .reference_tare_counts = REF_TARE,
        .force_limit_counts = 2000 * CPG,
        .drift_limit_counts = 1000 * CPG,
        .scale = 256 << 16,           /* 32768 / 128 = 256, 16 fraction bits */
        .scale_frac_bits = 16,
        .trigger_q = 75 * GRAM,
        .release_q = 0,
        .sample_period_ticks = PERIOD,
        .watchdog_periods = 2,
        .stuck_samples = 0,
    };
    return c;
}

static void setup(struct tc_trigger *t, const struct tc_trigger_config *c)
{
    tc_sos_filter_configure(&t->filter, NULL, 0, 30);
    tc_trigger_configure(t, c);
}

static int32_t counts_for_g(int32_t tare, double grams) { return tare + (int32_t)(grams * CPG); }

/* A watchdog check by the timer, long after the last sample. */
static void timer_interrupt(void *trigger)
{
    tc_trigger_check_watchdog(trigger, 999);
}

TEST(trigger_fires_on_first_sample_at_threshold)
{
    struct tc_trigger t;
    struct tc_trigger_config c = base_config();
    setup(&t, &c);
    CHECK_EQ_INT(t.state, TC_TRIGGER_IDLE);
    CHECK_EQ_INT(tc_trigger_arm(&t, 5000, 1000), TC_OK);
    CHECK_EQ_INT(t.state, TC_TRIGGER_ARMED);
    CHECK_EQ_INT(tc_trigger_sample(&t, 5000 + 75 * CPG - 1, 1100), TC_EVENT_NONE);
    CHECK_EQ_INT(t.filtered_q, (75 * CPG - 1) * 256);
    CHECK_EQ_INT(tc_trigger_sample(&t, 5000 + 75 * CPG, 1200), TC_EVENT_TRIGGER);
    CHECK_EQ_INT(t.trigger_ticks, 1200);
    CHECK_EQ_INT(t.state, TC_TRIGGER_TRIGGERED);
    /* latched: later samples are ignored, the watchdog is off */
    CHECK_EQ_INT(tc_trigger_sample(&t, 5000, 1300), TC_EVENT_NONE);
    CHECK_EQ_INT(t.filtered_q, 75 * CPG * 256);
    CHECK_EQ_INT(tc_trigger_check_watchdog(&t, 99999), TC_OK);
    CHECK_EQ_INT(t.state, TC_TRIGGER_TRIGGERED);
}

TEST(trigger_negative_force_and_inverted_orientation)
{
    struct tc_trigger t;
    struct tc_trigger_config c = base_config();
    setup(&t, &c);
    tc_trigger_arm(&t, 0, 0);
    CHECK_EQ_INT(tc_trigger_sample(&t, -75 * CPG, 10), TC_EVENT_TRIGGER);
    c.scale = -c.scale;
    setup(&t, &c);
    tc_trigger_arm(&t, 0, 0);
    CHECK_EQ_INT(tc_trigger_sample(&t, 10 * CPG, 10), TC_EVENT_NONE);
    CHECK_EQ_INT(t.filtered_q, -10 * GRAM);
}

TEST(trigger_scale_rounds_half_up)
{
    /* 3 fraction bits, scale 0.5 LSB per count (value 4): 1 count -> 0.5 -> 1, -1 -> 0 */
    struct tc_trigger t;
    struct tc_trigger_config c = base_config();
    c.scale = 4;
    c.scale_frac_bits = 3;
    setup(&t, &c);
    tc_trigger_arm(&t, 0, 0);
    tc_trigger_sample(&t, 1, 10);
    CHECK_EQ_INT(t.filtered_q, 1);
    tc_trigger_sample(&t, -1, 20);
    CHECK_EQ_INT(t.filtered_q, 0);
    tc_trigger_sample(&t, -3, 30);
    CHECK_EQ_INT(t.filtered_q, -1);
}

TEST(trigger_force_safety_at_arm)
{
    struct tc_trigger t;
    struct tc_trigger_config c = base_config();
    setup(&t, &c);
    CHECK_EQ_INT(tc_trigger_arm(&t, REF_TARE + 2000 * CPG, 0), TC_OK);      /* boundary inside */
    CHECK_EQ_INT(tc_trigger_arm(&t, REF_TARE - 2000 * CPG, 0), TC_OK);
    CHECK_EQ_INT(tc_trigger_arm(&t, REF_TARE + 2000 * CPG + 1, 0), TC_ERR_FORCE_SAFETY);
    CHECK_EQ_INT(t.state, TC_TRIGGER_ERROR);
    CHECK_EQ_INT(t.error, TC_ERR_FORCE_SAFETY);
    CHECK_EQ_INT(tc_trigger_sample(&t, 0, 10), TC_EVENT_NONE);              /* sticky */
    CHECK_EQ_INT(tc_trigger_check_watchdog(&t, 10000), TC_ERR_FORCE_SAFETY);
    CHECK_EQ_INT(tc_trigger_arm(&t, REF_TARE - 2000 * CPG - 1, 0), TC_ERR_FORCE_SAFETY);
    c.force_limit_counts = 0;                                               /* disabled */
    setup(&t, &c);
    CHECK_EQ_INT(tc_trigger_arm(&t, 8000000, 0), TC_OK);
}

TEST(trigger_drift_safety_two_samples_outside)
{
    struct tc_trigger t;
    struct tc_trigger_config c = base_config();
    setup(&t, &c);
    tc_trigger_arm(&t, 0, 0);
    CHECK_EQ_INT(tc_trigger_sample(&t, 1000 * CPG, 100), TC_EVENT_TRIGGER);  /* edge is inside */
    c.trigger_q = 2000 * GRAM;
    setup(&t, &c);
    tc_trigger_arm(&t, 0, 0);
    CHECK_EQ_INT(tc_trigger_sample(&t, 1000 * CPG + 1, 100), TC_EVENT_NONE); /* held */
    CHECK_EQ_INT(tc_trigger_sample(&t, -1000 * CPG - 1, 200), TC_EVENT_ERROR);
    CHECK_EQ_INT(t.error, TC_ERR_DRIFT_SAFETY);
    CHECK_EQ_INT(t.error_ticks, 200);
    CHECK_EQ_INT(t.glitches, 0);
    CHECK_EQ_INT(tc_trigger_sample(&t, 0, 300), TC_EVENT_NONE);              /* sticky */
    CHECK_EQ_INT(t.state, TC_TRIGGER_ERROR);
    CHECK_EQ_INT(tc_trigger_arm(&t, 0, 400), TC_OK);                         /* re-arm clears */
    CHECK_EQ_INT(t.error, TC_OK);
    c.drift_limit_counts = 0;                                                /* disabled */
    setup(&t, &c);
    tc_trigger_arm(&t, 0, 0);
    CHECK_EQ_INT(tc_trigger_sample(&t, 1500 * CPG, 100), TC_EVENT_NONE);
    CHECK_EQ_INT(tc_trigger_sample(&t, 1500 * CPG, 200), TC_EVENT_NONE);
    CHECK_EQ_INT(t.filtered_q, 1500 * GRAM);
}

TEST(trigger_glitch_quarantine_drops_single_sample)
{
    struct tc_trigger t;
    struct tc_trigger_config c = base_config();
    setup(&t, &c);
    tc_trigger_arm(&t, 500, 0);
    tc_trigger_sample(&t, counts_for_g(500, 10), 100);
    CHECK_EQ_INT(t.filtered_q, 10 * GRAM);
    /* a corrupted frame outside the drift window (and far above trigger_force) but
     * inside the force window: held back */
    CHECK_EQ_INT(tc_trigger_sample(&t, counts_for_g(500, 1500), 200), TC_EVENT_NONE);
    CHECK_EQ_INT(t.filtered_q, 10 * GRAM);                                   /* held */
    CHECK_EQ_INT(t.glitches, 0);
    CHECK_EQ_INT(tc_trigger_sample(&t, counts_for_g(500, 11), 300), TC_EVENT_NONE);
    CHECK_EQ_INT(t.glitches, 1);
    CHECK_EQ_INT(t.filtered_q, 11 * GRAM);
    CHECK_EQ_INT(t.state, TC_TRIGGER_ARMED);
    /* a second isolated glitch later is counted too; a triggering neighbour still triggers */
    tc_trigger_sample(&t, counts_for_g(500, -1500), 400);
    CHECK_EQ_INT(tc_trigger_sample(&t, counts_for_g(500, 80), 500), TC_EVENT_TRIGGER);
    CHECK_EQ_INT(t.glitches, 2);
    CHECK_EQ_INT(t.trigger_ticks, 500);
}

TEST(trigger_force_window_is_never_quarantined)
{
    /* The first sample beyond the force limit stops the move on that sample, even
     * though the drift window's quarantine would have held it (issue 10, finding 3). */
    struct tc_trigger t;
    struct tc_trigger_config c = base_config();
    setup(&t, &c);
    tc_trigger_arm(&t, REF_TARE, 0);
    CHECK_EQ_INT(tc_trigger_sample(&t, counts_for_g(REF_TARE, 50), 100), TC_EVENT_NONE);
    CHECK_EQ_INT(tc_trigger_sample(&t, counts_for_g(REF_TARE, 2000.0078125), 200), TC_EVENT_ERROR);
    CHECK_EQ_INT(t.error, TC_ERR_FORCE_SAFETY);
    CHECK_EQ_INT(t.error_ticks, 200);
    CHECK_EQ_INT(t.glitch_held, 0);
    /* a corrupted frame far outside stops the move too: safe, and the host sees why */
    tc_trigger_arm(&t, REF_TARE, 0);
    CHECK_EQ_INT(tc_trigger_sample(&t, 0x7FFFFF, 100), TC_EVENT_ERROR);
    CHECK_EQ_INT(t.error, TC_ERR_FORCE_SAFETY);
    tc_trigger_arm(&t, REF_TARE, 0);
    CHECK_EQ_INT(tc_trigger_sample(&t, -0x800000, 100), TC_EVENT_ERROR);
    /* the window edges are inside */
    tc_trigger_arm(&t, REF_TARE, 0);
    c.trigger_q = 4000 * GRAM;
    c.drift_limit_counts = 0;
    setup(&t, &c);
    tc_trigger_arm(&t, REF_TARE, 0);
    CHECK_EQ_INT(tc_trigger_sample(&t, REF_TARE + 2000 * CPG, 100), TC_EVENT_NONE);
    CHECK_EQ_INT(tc_trigger_sample(&t, REF_TARE - 2000 * CPG, 200), TC_EVENT_NONE);
    CHECK_EQ_INT(tc_trigger_sample(&t, REF_TARE - 2000 * CPG - 1, 300), TC_EVENT_ERROR);
}

TEST(trigger_force_window_is_relative_to_reference_and_tare)
{
    /* Tare 1500 g above the calibration zero (a bowden tube pushing): the move may
     * add only 500 g before reaching 2000 g of true force (reference window), and
     * may not pull more than 2000 g below the tare (tare window). */
    struct tc_trigger t;
    struct tc_trigger_config c = base_config();
    c.trigger_q = 4000 * GRAM;
    c.drift_limit_counts = 0;
    setup(&t, &c);
    const int32_t tare = REF_TARE + 1500 * CPG;
    CHECK_EQ_INT(tc_trigger_arm(&t, tare, 0), TC_OK);
    CHECK_EQ_INT(tc_trigger_sample(&t, REF_TARE + 2000 * CPG, 100), TC_EVENT_NONE);
    CHECK_EQ_INT(tc_trigger_sample(&t, REF_TARE + 2000 * CPG + 1, 200), TC_EVENT_ERROR);
    CHECK_EQ_INT(t.error, TC_ERR_FORCE_SAFETY);
    tc_trigger_arm(&t, tare, 0);
    CHECK_EQ_INT(tc_trigger_sample(&t, tare - 2000 * CPG, 100), TC_EVENT_NONE);   /* -500 g true */
    CHECK_EQ_INT(tc_trigger_sample(&t, tare - 2000 * CPG - 1, 200), TC_EVENT_ERROR);
    /* tare below the reference: mirror image */
    const int32_t low_tare = REF_TARE - 700 * CPG;
    tc_trigger_arm(&t, low_tare, 0);
    CHECK_EQ_INT(tc_trigger_sample(&t, REF_TARE - 2000 * CPG, 100), TC_EVENT_NONE);
    CHECK_EQ_INT(tc_trigger_sample(&t, REF_TARE - 2000 * CPG - 1, 200), TC_EVENT_ERROR);
    tc_trigger_arm(&t, low_tare, 0);
    CHECK_EQ_INT(tc_trigger_sample(&t, low_tare + 2000 * CPG, 100), TC_EVENT_NONE);
    CHECK_EQ_INT(tc_trigger_sample(&t, low_tare + 2000 * CPG + 1, 200), TC_EVENT_ERROR);
    /* a tare exactly at the reference window's edge leaves a window one limit wide */
    tc_trigger_arm(&t, REF_TARE + 2000 * CPG, 0);
    CHECK_EQ_INT(t.force_span, 2000u * CPG);
    CHECK_EQ_INT(tc_trigger_sample(&t, REF_TARE, 100), TC_EVENT_NONE);
    CHECK_EQ_INT(tc_trigger_sample(&t, REF_TARE - 1, 200), TC_EVENT_ERROR);
}

TEST(trigger_force_window_catches_what_the_filter_hides)
{
    /* Issue 10, finding 2: a drift high-pass with the drift check off lets a slow
     * press reach kilograms under the trigger. Here a filter that outputs nothing
     * at all stands for it: the raw window still stops the move. */
    struct tc_trigger t;
    struct tc_trigger_config c = base_config();
    c.drift_limit_counts = 0;
    setup(&t, &c);
    const int32_t silent[1][TC_SOS_NCOEFF] = {{0, 0, 0, 0, 0}};
    tc_sos_filter_configure(&t.filter, silent, 1, 30);
    tc_trigger_arm(&t, REF_TARE, 0);
    int event = TC_EVENT_NONE;
    uint32_t i;
    for (i = 1; i <= 4000 && event == TC_EVENT_NONE; i++)
        event = tc_trigger_sample(&t, counts_for_g(REF_TARE, i), i * PERIOD);   /* 1 g per sample */
    CHECK_EQ_INT(event, TC_EVENT_ERROR);
    CHECK_EQ_INT(t.error, TC_ERR_FORCE_SAFETY);
    CHECK_EQ_INT(i - 1, 2001);                                               /* the first sample past 2000 g */
    CHECK_EQ_INT(t.filtered_q, 0);
    c.force_limit_counts = 0;                                                /* off: nothing stops it */
    setup(&t, &c);
    tc_sos_filter_configure(&t.filter, silent, 1, 30);
    tc_trigger_arm(&t, REF_TARE, 0);
    for (i = 1; i <= 4000; i++)
        CHECK_EQ_INT(tc_trigger_sample(&t, counts_for_g(REF_TARE, i), i * PERIOD), TC_EVENT_NONE);
}

TEST(trigger_stuck_sensor_after_n_identical_samples)
{
    struct tc_trigger t;
    struct tc_trigger_config c = base_config();
    c.stuck_samples = 4;
    setup(&t, &c);
    tc_trigger_arm(&t, REF_TARE, 0);
    const int32_t v = REF_TARE + 3;
    /* three in a row, then a change: alive */
    const int32_t alive[] = {v, v, v, v + 1, v + 1, v + 1, v, v};
    for (uint32_t i = 0; i < 8; i++)
        CHECK_EQ_INT(tc_trigger_sample(&t, alive[i], (i + 1) * PERIOD), TC_EVENT_NONE);
    CHECK_EQ_INT(t.repeats, 1);
    CHECK_EQ_INT(tc_trigger_sample(&t, v, 900), TC_EVENT_NONE);              /* third v in a row */
    CHECK_EQ_INT(tc_trigger_sample(&t, v, 1000), TC_EVENT_ERROR);            /* fourth */
    CHECK_EQ_INT(t.error, TC_ERR_STUCK_SENSOR);
    CHECK_EQ_INT(t.error_ticks, 1000);
    CHECK_EQ_INT(t.state, TC_TRIGGER_ERROR);
    /* the run starts with the first sample after arming, whatever came before */
    tc_trigger_arm(&t, v, 2000);
    CHECK_EQ_INT(t.repeats, 0);
    for (uint32_t i = 1; i <= 3; i++)
        CHECK_EQ_INT(tc_trigger_sample(&t, v, 2000 + i * PERIOD), TC_EVENT_NONE);
    CHECK_EQ_INT(tc_trigger_sample(&t, v, 2400), TC_EVENT_ERROR);
    /* quarantined samples are raw samples too: a sensor stuck outside the drift
     * window is reported as stuck, not as a drift error, when the run is shorter */
    c.stuck_samples = 2;
    setup(&t, &c);
    tc_trigger_arm(&t, REF_TARE, 0);
    CHECK_EQ_INT(tc_trigger_sample(&t, counts_for_g(REF_TARE, 1500), 100), TC_EVENT_NONE);
    CHECK_EQ_INT(tc_trigger_sample(&t, counts_for_g(REF_TARE, 1500), 200), TC_EVENT_ERROR);
    CHECK_EQ_INT(t.error, TC_ERR_STUCK_SENSOR);
    /* 0: off */
    c.stuck_samples = 0;
    setup(&t, &c);
    tc_trigger_arm(&t, REF_TARE, 0);
    for (uint32_t i = 1; i <= 1000; i++)
        CHECK_EQ_INT(tc_trigger_sample(&t, v, i * PERIOD), TC_EVENT_NONE);
}

TEST(trigger_stuck_sensor_while_triggered_with_release_level)
{
    /* Hysteresis (Prusa style): while TRIGGERED the samples are still checked. */
    struct tc_trigger t;
    struct tc_trigger_config c = base_config();
    c.trigger_q = 125 * GRAM;
    c.release_q = 45 * GRAM;
    c.stuck_samples = 3;
    setup(&t, &c);
    tc_trigger_arm(&t, 0, 0);
    CHECK_EQ_INT(tc_trigger_sample(&t, 200 * CPG, 100), TC_EVENT_TRIGGER);
    CHECK_EQ_INT(tc_trigger_sample(&t, 200 * CPG, 200), TC_EVENT_NONE);
    CHECK_EQ_INT(tc_trigger_sample(&t, 200 * CPG, 300), TC_EVENT_ERROR);
    CHECK_EQ_INT(t.error, TC_ERR_STUCK_SENSOR);
    CHECK_EQ_INT(t.trigger_ticks, 100);
    /* and the force window */
    tc_trigger_arm(&t, 0, 0);
    CHECK_EQ_INT(tc_trigger_sample(&t, 200 * CPG, 100), TC_EVENT_TRIGGER);
    CHECK_EQ_INT(tc_trigger_sample(&t, 2001 * CPG, 200), TC_EVENT_ERROR);
    CHECK_EQ_INT(t.error, TC_ERR_FORCE_SAFETY);
}

TEST(trigger_samples_before_arm_are_ignored)
{
    struct tc_trigger t;
    struct tc_trigger_config c = base_config();
    setup(&t, &c);
    CHECK_EQ_INT(tc_trigger_sample(&t, 100 * CPG, 50), TC_EVENT_NONE);       /* idle */
    tc_trigger_arm(&t, 0, 1000);
    CHECK_EQ_INT(tc_trigger_sample(&t, 100 * CPG, 999), TC_EVENT_NONE);
    CHECK_EQ_INT(tc_trigger_sample(&t, 5000 * CPG, 900), TC_EVENT_NONE);     /* not even a drift error */
    CHECK_EQ_INT(t.state, TC_TRIGGER_ARMED);
    CHECK_EQ_INT(t.filtered_q, 0);
    CHECK_EQ_INT(tc_trigger_sample(&t, 100 * CPG, 1000), TC_EVENT_TRIGGER);  /* at the arm time: counts */
}

TEST(trigger_watchdog_after_exactly_n_periods)
{
    struct tc_trigger t;
    struct tc_trigger_config c = base_config();
    setup(&t, &c);
    tc_trigger_arm(&t, 0, 1000);
    CHECK_EQ_INT(tc_trigger_check_watchdog(&t, 1000 + 2 * PERIOD), TC_OK);
    CHECK_EQ_INT(tc_trigger_sample(&t, 0, 1150), TC_EVENT_NONE);
    CHECK_EQ_INT(tc_trigger_check_watchdog(&t, 1150 + 2 * PERIOD), TC_OK);
    CHECK_EQ_INT(tc_trigger_check_watchdog(&t, 1150 + 2 * PERIOD + 1), TC_ERR_WATCHDOG_TIMEOUT);
    CHECK_EQ_INT(t.state, TC_TRIGGER_ERROR);
    CHECK_EQ_INT(t.error_ticks, 1351);
    CHECK_EQ_INT(tc_trigger_sample(&t, 0, 1352), TC_EVENT_NONE);             /* sticky */
    /* three periods configured */
    c.watchdog_periods = 3;
    setup(&t, &c);
    tc_trigger_arm(&t, 0, 0);
    CHECK_EQ_INT(tc_trigger_check_watchdog(&t, 300), TC_OK);
    CHECK_EQ_INT(tc_trigger_check_watchdog(&t, 301), TC_ERR_WATCHDOG_TIMEOUT);
    /* an idle trigger has no watchdog */
    tc_trigger_disarm(&t);
    CHECK_EQ_INT(tc_trigger_check_watchdog(&t, 100000), TC_OK);
}

TEST(trigger_late_sample_is_a_watchdog_timeout)
{
    struct tc_trigger t;
    struct tc_trigger_config c = base_config();
    setup(&t, &c);
    tc_trigger_arm(&t, 0, 0);
    CHECK_EQ_INT(tc_trigger_sample(&t, 0, 200), TC_EVENT_NONE);              /* exactly 2 periods */
    CHECK_EQ_INT(tc_trigger_sample(&t, 0, 401), TC_EVENT_ERROR);
    CHECK_EQ_INT(t.error, TC_ERR_WATCHDOG_TIMEOUT);
    CHECK_EQ_INT(t.error_ticks, 401);
}

TEST(trigger_timestamps_wrap)
{
    struct tc_trigger t;
    struct tc_trigger_config c = base_config();
    setup(&t, &c);
    uint32_t arm = 0xFFFFFF80u;
    tc_trigger_arm(&t, 0, arm);
    CHECK_EQ_INT(tc_trigger_sample(&t, 0, 0xFFFFFF00u), TC_EVENT_NONE);      /* before arm */
    CHECK_EQ_INT(tc_trigger_sample(&t, 0, 0xFFFFFFE4u), TC_EVENT_NONE);
    CHECK_EQ_INT(tc_trigger_check_watchdog(&t, 0xFFFFFFE4u + 200u), TC_OK);  /* wraps to 0xAC */
    CHECK_EQ_INT(tc_trigger_sample(&t, 80 * CPG, 0x48u), TC_EVENT_TRIGGER);  /* 100 ticks later */
    CHECK_EQ_INT(t.trigger_ticks, 0x48);
    setup(&t, &c);
    tc_trigger_arm(&t, 0, arm);
    tc_trigger_sample(&t, 0, 0xFFFFFFE4u);
    CHECK_EQ_INT(tc_trigger_check_watchdog(&t, 0xFFFFFFE4u + 201u), TC_ERR_WATCHDOG_TIMEOUT);
}

TEST(trigger_time_is_wrap_safe_however_long_it_stays_armed)
{
    /* Issue 10, finding 4: between 2^31 and 2^32 ticks after arming every sample
     * used to count as "before the arm time" and was dropped. With the longest
     * period the span of 2^32 ticks is 32 samples; none may be dropped. */
    struct tc_trigger t;
    struct tc_trigger_config c = base_config();
    c.sample_period_ticks = TC_TRIGGER_MAX_PERIOD_TICKS - 1;
    c.trigger_q = 4000 * GRAM;
    setup(&t, &c);
    const uint32_t arm = 0x12345678u;
    tc_trigger_arm(&t, 0, arm);
    for (uint32_t i = 1; i <= 80; i++) {
        uint32_t ticks = arm + i * c.sample_period_ticks;                    /* wraps twice */
        CHECK_EQ_INT(tc_trigger_sample(&t, (int32_t)i * CPG, ticks), TC_EVENT_NONE);
        CHECK_EQ_INT(t.filtered_q, (int32_t)i * GRAM);
        CHECK_EQ_INT(t.last_sample_ticks, ticks);
    }
    CHECK_EQ_INT(t.state, TC_TRIGGER_ARMED);
    CHECK_EQ_INT(tc_trigger_check_watchdog(&t, arm + 80 * c.sample_period_ticks + 2 * c.sample_period_ticks),
                 TC_OK);
    /* once a sample is accepted, the base is that sample: an older one is stale */
    CHECK_EQ_INT(tc_trigger_sample(&t, 500 * CPG, arm + 79 * c.sample_period_ticks), TC_EVENT_NONE);
    CHECK_EQ_INT(t.filtered_q, 80 * GRAM);
    CHECK_EQ_INT(tc_trigger_sample(&t, 81 * CPG, arm + 80 * c.sample_period_ticks), TC_EVENT_NONE);
    CHECK_EQ_INT(t.filtered_q, 81 * GRAM);                                   /* same time: accepted */
}

TEST(trigger_a_late_timer_interrupt_wins_over_the_sample_it_preempted)
{
    /* The watchdog fires from a timer interrupt while tc_trigger_sample() is
     * between deciding TRIGGER and committing it: the timeout stands, the trigger
     * time is not written, and the sample reports the error. */
    struct tc_trigger t;
    struct tc_trigger_config c = base_config();
    setup(&t, &c);
    tc_trigger_arm(&t, 0, 0);
    test_irq.saves = 0;
    CHECK_EQ_INT(tc_trigger_sample(&t, 10 * CPG, 100), TC_EVENT_NONE);
    CHECK_EQ_INT(test_irq.saves, 0);                                         /* no mask without an event */
    t.trigger_ticks = 12345;
    test_irq.pending = timer_interrupt;
    test_irq.arg = &t;
    CHECK_EQ_INT(tc_trigger_sample(&t, 80 * CPG, 200), TC_EVENT_ERROR);
    CHECK_EQ_INT(t.error, TC_ERR_WATCHDOG_TIMEOUT);
    CHECK_EQ_INT(t.error_ticks, 999);
    CHECK_EQ_INT(t.trigger_ticks, 12345);
    CHECK_EQ_INT(t.state, TC_TRIGGER_ERROR);
    CHECK_EQ_INT(test_irq.depth, 0);
    /* the same for an error found by the sample: the first verdict stands */
    tc_trigger_arm(&t, 0, 0);
    test_irq.pending = timer_interrupt;
    CHECK_EQ_INT(tc_trigger_sample(&t, 3000 * CPG, 200), TC_EVENT_ERROR);
    CHECK_EQ_INT(t.error, TC_ERR_WATCHDOG_TIMEOUT);
    /* and an abort after the trigger latched changes nothing */
    tc_trigger_arm(&t, 0, 0);
    CHECK_EQ_INT(tc_trigger_sample(&t, 80 * CPG, 100), TC_EVENT_TRIGGER);
    tc_trigger_abort(&t, 107, 150);
    CHECK_EQ_INT(t.state, TC_TRIGGER_TRIGGERED);
    CHECK_EQ_INT(t.error, TC_OK);
    CHECK_EQ_INT(test_irq.depth, 0);
}

TEST(trigger_hysteresis_trigger_and_release)
{
    /* Prusa style: trigger at 125 g, release 80 g lower (below 45 g) */
    struct tc_trigger t;
    struct tc_trigger_config c = base_config();
    c.trigger_q = 125 * GRAM;
    c.release_q = 45 * GRAM;
    setup(&t, &c);
    tc_trigger_arm(&t, 0, 0);
    const double force_g[] = {0, 100, 125, 200, 60, 45, 44.9921875, 30, 130};
    const int want[] = {TC_EVENT_NONE, TC_EVENT_NONE, TC_EVENT_TRIGGER, TC_EVENT_NONE, TC_EVENT_NONE,
                        TC_EVENT_NONE, TC_EVENT_RELEASE, TC_EVENT_NONE, TC_EVENT_TRIGGER};
    for (int i = 0; i < 9; i++)
        CHECK_EQ_INT(tc_trigger_sample(&t, counts_for_g(0, force_g[i]), 100u * (unsigned)(i + 1)), want[i]);
    CHECK_EQ_INT(t.release_ticks, 700);
    CHECK_EQ_INT(t.trigger_ticks, 900);
    CHECK_EQ_INT(t.state, TC_TRIGGER_TRIGGERED);
    /* while triggered the watchdog and the safety window stay active */
    CHECK_EQ_INT(tc_trigger_check_watchdog(&t, 1101), TC_ERR_WATCHDOG_TIMEOUT);
}

TEST(trigger_scale_and_filter_overflow)
{
    struct tc_trigger t;
    struct tc_trigger_config c = base_config();
    c.drift_limit_counts = 0;
    c.force_limit_counts = 0;
    c.trigger_q = 0x7FFFFFFF;
    setup(&t, &c);
    tc_trigger_arm(&t, 0, 0);
    CHECK_EQ_INT(tc_trigger_sample(&t, 65535 * CPG, 100), TC_EVENT_NONE);
    CHECK_EQ_INT(tc_trigger_sample(&t, 65536 * CPG, 200), TC_EVENT_ERROR);   /* 65536 g */
    CHECK_EQ_INT(t.error, TC_ERR_SCALE_OVERFLOW);
    tc_trigger_arm(&t, INT32_MIN + 5, 0);                                    /* counts - tare overflows */
    CHECK_EQ_INT(tc_trigger_sample(&t, 10, 100), TC_EVENT_ERROR);
    CHECK_EQ_INT(t.error, TC_ERR_SCALE_OVERFLOW);
    const int32_t gain_1_5[1][TC_SOS_NCOEFF] = {{3 << 29, 0, 0, 0, 0}};
    tc_sos_filter_configure(&t.filter, gain_1_5, 1, 30);
    tc_trigger_arm(&t, 0, 0);
    CHECK_EQ_INT(tc_trigger_sample(&t, 40000 * CPG, 100), TC_EVENT_NONE);    /* 60000 g */
    CHECK_EQ_INT(t.filtered_q, 60000 * GRAM);
    CHECK_EQ_INT(tc_trigger_sample(&t, 50000 * CPG, 200), TC_EVENT_ERROR);   /* 75000 g */
    CHECK_EQ_INT(t.error, TC_ERR_FILTER_OVERFLOW);
    CHECK_EQ_INT(tc_trigger_arm(&t, 0, 300), TC_OK);                         /* re-arm resets the filter */
    CHECK_EQ_INT(t.filter.overflowed, 0);
}

TEST(trigger_abort_with_sensor_code)
{
    struct tc_trigger t;
    struct tc_trigger_config c = base_config();
    setup(&t, &c);
    tc_trigger_abort(&t, 107, 5);                                            /* idle: nothing to abort */
    CHECK_EQ_INT(t.state, TC_TRIGGER_IDLE);
    tc_trigger_arm(&t, 0, 0);
    tc_trigger_abort(&t, 107, 50);
    CHECK_EQ_INT(t.state, TC_TRIGGER_ERROR);
    CHECK_EQ_INT(tc_trigger_check_watchdog(&t, 60), 107);
    CHECK_EQ_INT(t.error_ticks, 50);
    tc_trigger_disarm(&t);
    CHECK_EQ_INT(t.error, TC_OK);
}

TEST(trigger_configure_rejects_bad_values)
{
    struct tc_trigger t;
    struct tc_trigger_config good = base_config(), c;
    setup(&t, &good);
#define BAD(field, value) do { c = good; c.field = value; \
        CHECK_EQ_INT(tc_trigger_configure(&t, &c), TC_ERR_BAD_CONFIG); } while (0)
    BAD(force_limit_counts, -1);
    BAD(drift_limit_counts, -1);
    BAD(scale, 0);
    BAD(scale_frac_bits, 0);
    BAD(scale_frac_bits, 32);
    BAD(trigger_q, 0);
    BAD(release_q, -1);
    BAD(release_q, 75 * GRAM);
    BAD(sample_period_ticks, 0);
    BAD(sample_period_ticks, TC_TRIGGER_MAX_PERIOD_TICKS);
    BAD(watchdog_periods, 0);
    BAD(watchdog_periods, TC_TRIGGER_MAX_WATCHDOG_PERIODS + 1);
    BAD(stuck_samples, 1);
    BAD(stuck_samples, TC_TRIGGER_MAX_STUCK_SAMPLES + 1);
    c = good;                                   /* reference +- force limit must fit int32 */
    c.reference_tare_counts = INT32_MAX - 100;
    c.force_limit_counts = 101;
    CHECK_EQ_INT(tc_trigger_configure(&t, &c), TC_ERR_BAD_CONFIG);
    c.reference_tare_counts = INT32_MIN + 100;
    CHECK_EQ_INT(tc_trigger_configure(&t, &c), TC_ERR_BAD_CONFIG);
    c.force_limit_counts = 100;
    CHECK_EQ_INT(tc_trigger_configure(&t, &c), TC_OK);
    tc_trigger_configure(&t, &good);
#undef BAD
    CHECK_EQ_INT(t.cfg.trigger_q, 75 * GRAM);                                /* nothing stored */
    c = good;
    c.watchdog_periods = TC_TRIGGER_MAX_WATCHDOG_PERIODS;
    c.sample_period_ticks = TC_TRIGGER_MAX_PERIOD_TICKS - 1;
    c.stuck_samples = TC_TRIGGER_MAX_STUCK_SAMPLES;
    CHECK_EQ_INT(tc_trigger_configure(&t, &c), TC_OK);
    c.stuck_samples = 2;
    CHECK_EQ_INT(tc_trigger_configure(&t, &c), TC_OK);
}

TEST(trigger_feed_stops_at_first_event)
{
    struct tc_trigger t;
    struct tc_trigger_config c = base_config();
    setup(&t, &c);
    tc_trigger_arm(&t, 0, 0);
    const int32_t counts[5] = {0, 10 * CPG, 80 * CPG, 90 * CPG, 0};
    const uint32_t ticks[5] = {100, 200, 300, 400, 500};
    int32_t filtered[5] = {-1, -1, -1, -1, -1};
    int event = -1;
    CHECK_EQ_INT(tc_trigger_feed(&t, counts, ticks, 5, filtered, &event), 2);
    CHECK_EQ_INT(event, TC_EVENT_TRIGGER);
    CHECK_EQ_INT(filtered[1], 10 * GRAM);
    CHECK_EQ_INT(filtered[2], 80 * GRAM);
    CHECK_EQ_INT(filtered[3], -1);                                           /* not consumed */
    tc_trigger_arm(&t, 0, 0);
    CHECK_EQ_INT(tc_trigger_feed(&t, counts, ticks, 2, NULL, &event), 2);
    CHECK_EQ_INT(event, TC_EVENT_NONE);
}

TEST(trigger_never_configured_refuses_to_arm)
{
    static struct tc_trigger fresh;   /* zeroed, as static storage starts */
    CHECK_EQ_INT(tc_trigger_arm(&fresh, 1000, 0), TC_ERR_BAD_CONFIG);
    CHECK_EQ_INT(fresh.state, TC_TRIGGER_IDLE);
    CHECK_EQ_INT(tc_trigger_sample(&fresh, 1000, 10), TC_EVENT_NONE);
    CHECK_EQ_INT(tc_trigger_check_watchdog(&fresh, 1u << 30), TC_OK);
    CHECK_EQ_INT(fresh.state, TC_TRIGGER_IDLE);
}
