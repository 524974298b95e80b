/* Load-cell trigger: threshold, safety limits, watchdog, glitch quarantine,
 * hysteresis, timestamps. Scale: 128 counts per gram, so 1 count = 256 LSB of
 * Q16.15 exactly and every expected value below is exact. */
#include "unit.h"
#include "load_cell_trigger.h"

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
    };
    return c;
}

static void setup(struct tc_trigger *t, const struct tc_trigger_config *c)
{
    tc_sos_filter_configure(&t->filter, NULL, 0, 30);
    tc_trigger_configure(t, c);
}

static int32_t counts_for_g(int32_t tare, double grams) { return tare + (int32_t)(grams * CPG); }

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
    /* a corrupted frame far outside the window (and far above trigger_force) */
    CHECK_EQ_INT(tc_trigger_sample(&t, 0x7FFFFF, 200), TC_EVENT_NONE);
    CHECK_EQ_INT(t.filtered_q, 10 * GRAM);                                   /* held */
    CHECK_EQ_INT(t.glitches, 0);
    CHECK_EQ_INT(tc_trigger_sample(&t, counts_for_g(500, 11), 300), TC_EVENT_NONE);
    CHECK_EQ_INT(t.glitches, 1);
    CHECK_EQ_INT(t.filtered_q, 11 * GRAM);
    CHECK_EQ_INT(t.state, TC_TRIGGER_ARMED);
    /* a second isolated glitch later is counted too; a triggering neighbour still triggers */
    tc_trigger_sample(&t, -0x800000, 400);
    CHECK_EQ_INT(tc_trigger_sample(&t, counts_for_g(500, 80), 500), TC_EVENT_TRIGGER);
    CHECK_EQ_INT(t.glitches, 2);
    CHECK_EQ_INT(t.trigger_ticks, 500);
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
#undef BAD
    CHECK_EQ_INT(t.cfg.trigger_q, 75 * GRAM);                                /* nothing stored */
    c = good;
    c.watchdog_periods = TC_TRIGGER_MAX_WATCHDOG_PERIODS;
    c.sample_period_ticks = TC_TRIGGER_MAX_PERIOD_TICKS - 1;
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
