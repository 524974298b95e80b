/* app.c - the emulator image: runs the generated scenarios through the
 * unchanged core (hx71x_*, tc_sos_filter_*, tc_trigger_*) with a software
 * HX71x behind struct tc_hal, checks every result against what the host library
 * computed, measures, and reports over semihosting.
 *
 * Output lines (parsed by emu.py): "PASS name", "FAIL name: what", and
 * "M key 0xVALUE" measurements. The exit status is the number of failures.
 *
 * Contexts as on a real board: the data-ready interrupt reads the chip and calls
 * tc_trigger_sample(); the watchdog-timer interrupt (higher priority) calls
 * tc_trigger_check_watchdog(); main() configures, arms and waits in WFI.
 */
#include "board.h"
#include "hx71x.h"
#include "load_cell_trigger.h"
#include "scenario.h"
#include "semihost.h"
#include "soft_hx71x.h"
#include "startup.h"

/* What one scenario run saw; written by the interrupts, read by main. */
struct run {
    const struct scenario *sc;
    volatile uint8_t done;
    volatile uint8_t armed;
    uint8_t settling_seen;
    uint8_t end;                 /* enum scenario_end as it happened */
    uint8_t event;
    uint16_t fed;
    int32_t first_mismatch;      /* sample whose filtered value differs, or -1 */
    int32_t mismatch_got;
    uint32_t event_ready_ticks;  /* data-ready time of the ending sample or frame */
    uint32_t ready_to_event_ticks;
    uint32_t watchdog_now_ticks;
};

static struct tc_trigger trigger;
static struct hx71x sensor;
static struct soft_hx71x chip;
static struct tc_hal chip_hal;
static struct run run;
static unsigned failures;

/* Read by the rp2040js runner to file tc_trigger_sample calls by phase. */
volatile uint32_t app_phase;
enum { PHASE_OTHER = 0, PHASE_COST_ARMED = 1, PHASE_COST_IDLE = 2 };

static void finish(uint8_t end, uint8_t event, uint32_t ready_ticks)
{
    run.end = end;
    run.event = event;
    run.event_ready_ticks = ready_ticks;
    run.done = 1;
}

void app_data_ready(uint32_t ready_ticks)
{
    if (run.done)
        return;
    if (!soft_hx71x_convert(&chip)) {
        board_data_ready_stop();         /* the chip went silent */
        return;
    }
    int32_t counts;
    enum hx71x_status status = hx71x_read(&sensor, ready_ticks, &counts);
    if (status == HX71X_SETTLING) {
        run.settling_seen++;
        return;
    }
    if (!run.armed)
        return;
    if (status != HX71X_OK) {
        tc_trigger_abort(&trigger, (int)status, ready_ticks);
        run.ready_to_event_ticks = board_now_ticks() - ready_ticks;
        finish(END_ABORT, TC_EVENT_ERROR, ready_ticks);
        return;
    }
    int event = tc_trigger_sample(&trigger, counts, ready_ticks);
    uint32_t after = board_now_ticks();
    const struct scenario *sc = run.sc;
    if (run.fed < sc->n_fed && trigger.filtered_q != sc->filtered_q[run.fed] && run.first_mismatch < 0) {
        run.first_mismatch = run.fed;
        run.mismatch_got = trigger.filtered_q;
    }
    run.fed++;
    if (event != TC_EVENT_NONE) {
        run.ready_to_event_ticks = after - ready_ticks;
        finish(END_SAMPLE, (uint8_t)event, ready_ticks);
    }
}

void app_watchdog_tick(uint32_t now_ticks)
{
    if (run.done || !run.armed)
        return;
    if (tc_trigger_check_watchdog(&trigger, now_ticks) == TC_ERR_WATCHDOG_TIMEOUT) {
        run.watchdog_now_ticks = now_ticks;
        finish(END_WATCHDOG, TC_EVENT_ERROR, 0);
    }
}

static void fail(const char *name, const char *what, uint32_t expected, uint32_t got)
{
    failures++;
    semihost_puts("FAIL ");
    semihost_puts(name);
    semihost_puts(": ");
    semihost_puts(what);
    semihost_put_hex(" expected", expected);
    semihost_put_hex("  got", got);
}

static int check(const char *name, const char *what, uint32_t expected, uint32_t got)
{
    if (expected != got)
        fail(name, what, expected, got);
    return expected == got;
}

static void measure(const char *name, const char *key, uint32_t value)
{
    semihost_puts("M ");
    semihost_puts(name);
    semihost_puts(".");
    semihost_put_hex(key, value);
}

static int setup_trigger(struct tc_trigger *t, const struct tc_trigger_config *config,
                         const int32_t coeff[TC_SOS_MAX_SECTIONS][TC_SOS_NCOEFF], uint8_t n_sections,
                         uint8_t frac_bits)
{
    if (tc_sos_filter_configure(&t->filter, coeff, n_sections, frac_bits) != TC_OK)
        return -1;
    return tc_trigger_configure(t, config);
}

static void run_scenario(const struct scenario *sc)
{
    const char *name = sc->name;
    unsigned failures_before = failures;
    run = (struct run){.sc = sc, .first_mismatch = -1};
    if (!check(name, "trigger configure", TC_OK, (uint32_t)setup_trigger(&trigger, &sc->config, sc->coeff,
                                                                          sc->n_sections, sc->frac_bits)))
        return;
    const struct hx71x_config sensor_config = {
        .chip = sc->chip, .gain = sc->gain, .sample_rate_sps = sc->sample_rate_sps,
        .ticks_per_s = board_ticks_per_s, .sclk_pin = SOFT_HX71X_SCLK_PIN, .dout_pin = SOFT_HX71X_DOUT_PIN,
    };
    soft_hx71x_hal(&chip_hal, &chip);
    if (!check(name, "hx71x_init", HX71X_OK, hx71x_init(&sensor, &chip_hal, &sensor_config)))
        return;
    check(name, "sample period ticks", sc->config.sample_period_ticks, sensor.sample_period_ticks);
    soft_hx71x_load(&chip, sc->frames, sc->n_frames, hx71x_frame_pulses(sc->chip, sc->gain));
    hx71x_start(&sensor);
    uint32_t period = sc->config.sample_period_ticks;
    board_data_ready_start(board_now_ticks() + period, period);
    while (run.settling_seen < HX71X_SETTLING_SAMPLES)
        board_sleep();
    /* Armed between two conversions, as the host's arm command would be. */
    check(name, "arm", TC_OK, (uint32_t)tc_trigger_arm(&trigger, sc->tare_counts, board_now_ticks()));
    run.armed = 1;
    board_watchdog_start(sc->watchdog_check_ticks);
    while (!run.done)
        board_sleep();
    board_data_ready_stop();
    board_watchdog_stop();

    check(name, "end", sc->end, run.end);
    check(name, "event", sc->event, run.event);
    check(name, "samples fed", sc->n_fed, run.fed);
    if (run.first_mismatch >= 0)
        fail(name, "filtered_q differs at sample", (uint32_t)sc->filtered_q[run.first_mismatch],
             (uint32_t)run.mismatch_got);
    check(name, "state", sc->state, trigger.state);
    check(name, "error", sc->error, trigger.error);
    check(name, "glitches", sc->glitches, trigger.glitches);
    if (run.end == END_WATCHDOG) {
        /* The rule: more than the watchdog span after the last sample; the
         * latency past that deadline is bounded by the check interrupt's period. */
        uint32_t deadline = trigger.last_sample_ticks + trigger.watchdog_ticks;
        uint32_t latency = trigger.error_ticks - deadline;
        check(name, "error ticks = watchdog check time", run.watchdog_now_ticks, trigger.error_ticks);
        if ((int32_t)latency <= 0 || latency > sc->watchdog_latency_max_ticks)
            fail(name, "watchdog latency past the deadline out of range", sc->watchdog_latency_max_ticks, latency);
        measure(name, "detect_latency_ticks", latency);
        measure(name, "after_last_sample_ticks", trigger.error_ticks - trigger.last_sample_ticks);
    } else {
        uint32_t stamped = run.event == TC_EVENT_TRIGGER ? trigger.trigger_ticks : trigger.error_ticks;
        check(name, "event timestamp = data-ready time", run.event_ready_ticks, stamped);
        measure(name, "ready_to_event_ticks", run.ready_to_event_ticks);
    }
    if (failures == failures_before) {
        semihost_puts("PASS ");
        semihost_puts(name);
        semihost_puts("\n");
    }
}

/* ---------------------------------------------------------------- cost */

typedef int (*sample_fn)(struct tc_trigger *, int32_t, uint32_t);

/* The same call with an empty body (movs r0, #0; bx lr): the loop's own cost. */
__attribute__((noinline)) static int null_sample(struct tc_trigger *t, int32_t counts, uint32_t ticks)
{
    (void)t;
    (void)counts;
    (void)ticks;
    return 0;
}

static sample_fn volatile selected_fn;   /* volatile: one loop body for every function */
static int32_t cost_out[1024];

__attribute__((noinline)) static uint32_t timed_pass(struct tc_trigger *t, const struct cost_case *c)
{
    sample_fn fn = selected_fn;
    uint32_t start = board_now_ticks();
    for (uint32_t i = 0; i < c->n_samples; i++) {
        fn(t, c->counts[i], c->ticks[i]);
        cost_out[i] = t->filtered_q;
    }
    return board_now_ticks() - start;
}

#define COST_PASSES 8u

static uint32_t timed_passes(struct tc_trigger *t, const struct cost_case *c, sample_fn fn, int arm)
{
    uint32_t total = 0;
    selected_fn = fn;
    for (uint32_t pass = 0; pass < COST_PASSES; pass++) {
        if (arm)
            tc_trigger_arm(t, c->tare_counts, 0);
        total += timed_pass(t, c);
    }
    return total;
}

static void run_cost(const struct cost_case *c)
{
    const char *name = "cost";
    unsigned failures_before = failures;
    if (!check(name, "configure", TC_OK,
               (uint32_t)setup_trigger(&trigger, &c->config, c->coeff, c->n_sections, c->frac_bits)))
        return;
    board_disable_irq();
    uint32_t null_ticks = timed_passes(&trigger, c, null_sample, 1);
    app_phase = PHASE_COST_ARMED;
    uint32_t armed_ticks = timed_passes(&trigger, c, tc_trigger_sample, 1);
    app_phase = PHASE_OTHER;
    for (uint32_t i = 0; i < c->n_samples; i++) {
        if (cost_out[i] != c->filtered_q[i]) {
            fail(name, "filtered_q differs from the host library at a sample", (uint32_t)c->filtered_q[i],
                 (uint32_t)cost_out[i]);
            break;
        }
    }
    check(name, "state after the cost run (never triggers)", TC_TRIGGER_ARMED, trigger.state);
    tc_trigger_disarm(&trigger);
    app_phase = PHASE_COST_IDLE;
    uint32_t idle_ticks = timed_passes(&trigger, c, tc_trigger_sample, 0);
    app_phase = PHASE_OTHER;
    board_enable_irq();
    measure(name, "samples", COST_PASSES * c->n_samples);
    measure(name, "null_loop_ticks", null_ticks);
    measure(name, "armed_loop_ticks", armed_ticks);
    measure(name, "idle_loop_ticks", idle_ticks);
    if (failures == failures_before)
        semihost_puts("PASS cost (bench/firmware_cost's 4-section case, bit-exact)\n");
}

/* A never-configured trigger (all zero, as static storage starts) refuses to arm
 * and ignores samples. */
static void run_unconfigured(void)
{
    static struct tc_trigger fresh;
    const char *name = "unconfigured";
    unsigned failures_before = failures;
    check(name, "arm refused", TC_ERR_BAD_CONFIG, (uint32_t)tc_trigger_arm(&fresh, 0, 0));
    check(name, "sample ignored", TC_EVENT_NONE, (uint32_t)tc_trigger_sample(&fresh, 12345, 10));
    check(name, "state", TC_TRIGGER_IDLE, fresh.state);
    if (failures == failures_before)
        semihost_puts("PASS unconfigured\n");
}

int main(void)
{
    board_init();
    board_enable_irq();
    semihost_puts("BOARD ");
    semihost_puts(board_name);
    semihost_puts("\n");
    measure("board", "ticks_per_s", board_ticks_per_s);
    run_unconfigured();
    for (unsigned i = 0; i < n_scenarios; i++)
        run_scenario(&scenarios[i]);
    run_cost(&cost_case);
    measure("stack", "high_water_bytes", stack_high_water_bytes());
    measure("stack", "size_bytes", stack_size_bytes());
    semihost_put_hex("FAILURES", failures);
    return (int)failures;
}
