/* load_cell_trigger.h - the load-cell endstop: tare, scale, filter, threshold,
 * safety limits, stuck-sensor detection, watchdog, glitch quarantine and
 * optional hysteresis.
 *
 * Per sample (tc_trigger_sample, called by the sensor driver with the raw
 * counts and the sample's own timestamp in MCU timer ticks, uint32, wrapping):
 *   1. ignored unless armed (or triggered with a release level configured);
 *   2. time, by wrap-safe signed difference from the last accepted sample (the
 *      arm time until the first sample is accepted): a sample older than that
 *      is ignored (it was taken before the move); one more than
 *      watchdog_periods sample periods later is a WATCHDOG_TIMEOUT - the rule
 *      the timer applies through tc_trigger_check_watchdog(). Accepted samples
 *      are never further apart than the watchdog span (< 2^31 ticks), so the
 *      comparison stays exact however long the trigger stays armed;
 *   3. force window, on the raw counts, on EVERY sample: counts must stay
 *      within reference_tare_counts +- force_limit_counts (the calibration
 *      zero, as the tare check at arming) AND within tare +- force_limit_counts
 *      (the force this move adds). Both windows are folded into one interval at
 *      arming, so this is one subtraction and one unsigned compare. Outside is
 *      FORCE_SAFETY on that very sample: no quarantine, no filter, no delay;
 *   4. stuck sensor: stuck_samples raw samples in a row with exactly the same
 *      value are STUCK_SENSOR (a live ADC's noise changes the reading from one
 *      sample to the next; a frozen chip, a DOUT line held low or high, or a
 *      driver repeating its last frame does not). The run may start with the
 *      first sample after arming;
 *   5. drift window: counts must stay within tare +- drift_limit_counts.
 *      Glitch quarantine: a single sample outside (but inside the force
 *      window) is held back, not filtered and not able to trigger; if the next
 *      sample is inside again the held one is dropped and counted in
 *      `glitches`, if it is outside too the error is DRIFT_SAFETY (reported at
 *      that second sample). The quarantine only delays the trigger decision;
 *      the force window of step 3 has already seen the sample;
 *   6. grams = (counts - tare) * scale >> scale_frac_bits, rounded half up, as
 *      Q16.15 (SCALE_OVERFLOW beyond +-65536 g); a negative scale inverts the
 *      sensor orientation at no cost;
 *   7. filter (FILTER_OVERFLOW when any filter value saturates);
 *   8. armed: TRIGGER when |filtered| >= trigger_q; the trigger time is this
 *      sample's timestamp. With release_q == 0 the trigger latches: later
 *      samples are ignored until re-armed. With 0 < release_q < trigger_q the
 *      state is TRIGGERED until |filtered| < release_q, then RELEASE (its time
 *      is that sample's timestamp) and armed again. While TRIGGERED with a
 *      release level, steps 2-7 keep running.
 * Errors are sticky (state ERROR, later samples ignored) until the next arm,
 * disarm or configure. The caller owns the struct: no allocation, no globals,
 * no floating point.
 *
 * Calling contexts (a board port must keep to these):
 *   tc_trigger_configure, tc_trigger_arm, tc_trigger_disarm
 *       task context (the host command handler). They must not interrupt a
 *       running tc_trigger_sample() of the same trigger: call them from the
 *       context that runs the sampling, or with it masked.
 *   tc_trigger_sample
 *       the sensor driver's context that reads the conversion: a task, or the
 *       data-ready interrupt.
 *   tc_trigger_check_watchdog
 *       a periodic timer: may be an interrupt that preempts tc_trigger_sample().
 *       It must run at least every 2^31 - watchdog span ticks while armed.
 *   tc_trigger_abort
 *       any context (e.g. the driver's error path in an interrupt).
 * Shared state: the watchdog and abort may change `state`, `error` and
 * `error_ticks` while tc_trigger_sample() runs. Every state change (trigger,
 * release, error) is therefore made inside the critical section of hal.h
 * (tc_irq_save / tc_irq_restore, PRIMASK on Cortex-M) and only from the state
 * the change was decided in: the first error wins, and neither a trigger nor a
 * later error overwrites it. A sample without an event takes no critical
 * section. The 32-bit fields the timer reads (last_sample_ticks) are written
 * with single aligned stores. arm and disarm run masked as a whole; configure
 * disarms first.
 */
#ifndef TAPCELL_LOAD_CELL_TRIGGER_H
#define TAPCELL_LOAD_CELL_TRIGGER_H

#include <stddef.h>
#include <stdint.h>
#include "hal.h"
#include "sos_filter.h"
#include "tc_errors.h"

/* Bounds that keep the watchdog span below 2^31 ticks (signed tick
 * differences): 15 * 2^27 < 2^31. 2^27 ticks is 0.67 s at 200 MHz. */
#define TC_TRIGGER_MAX_PERIOD_TICKS (1u << 27)
#define TC_TRIGGER_MAX_WATCHDOG_PERIODS 15u
/* stuck_samples: 0 (off) or 2..TC_TRIGGER_MAX_STUCK_SAMPLES. */
#define TC_TRIGGER_MAX_STUCK_SAMPLES 65535u

enum tc_trigger_state {
    TC_TRIGGER_IDLE = 0,
    TC_TRIGGER_ARMED = 1,
    TC_TRIGGER_TRIGGERED = 2,
    TC_TRIGGER_ERROR = 3
};

/* What one sample did. */
enum tc_trigger_event {
    TC_EVENT_NONE = 0,
    TC_EVENT_TRIGGER = 1,
    TC_EVENT_RELEASE = 2,
    TC_EVENT_ERROR = 3
};

struct tc_trigger_config {
    int32_t reference_tare_counts;
    int32_t force_limit_counts;   /* raw window half width (reference and tare); 0 disables;
                                     reference_tare_counts +- it must fit int32 */
    int32_t drift_limit_counts;   /* in-move window half width; 0 disables it and the quarantine */
    int32_t scale;                /* Q16.15 grams per count times 2^scale_frac_bits; < 0 = inverted */
    uint32_t scale_frac_bits;     /* 1..31 */
    int32_t trigger_q;            /* Q16.15 grams, > 0 */
    int32_t release_q;            /* Q16.15 grams; 0 = latched trigger, else 0 < release_q < trigger_q */
    uint32_t sample_period_ticks; /* 1 .. TC_TRIGGER_MAX_PERIOD_TICKS - 1 */
    uint32_t watchdog_periods;    /* 1 .. TC_TRIGGER_MAX_WATCHDOG_PERIODS */
    uint32_t stuck_samples;       /* identical raw samples in a row that mean STUCK_SENSOR; 0 disables */
};

/* Member order matters on Cortex-M0+: Thumb loads and stores reach byte
 * fields only at offsets below 32 and words below 128 without an extra address
 * computation, so the bytes come first and the large filter last. */
struct tc_trigger {
    uint8_t state;                /* enum tc_trigger_state */
    uint8_t error;                /* enum tc_error or a sensor code; sticky */
    uint8_t glitch_held;          /* 1 while a sample outside the drift window waits for its neighbour */
    /* set at arm: */
    uint32_t last_sample_ticks;   /* last accepted sample (or arm time): time base and watchdog base */
    uint32_t force_low;           /* force window = force_low .. force_low + force_span (modulo 2^32) */
    uint32_t force_span;
    int32_t last_counts;          /* raw value of the last accepted sample (INT32_MIN at arm) */
    uint32_t repeats;             /* accepted samples in a row equal to the one before */
    uint32_t drift_low;           /* drift window, the same way */
    uint32_t drift_span;
    int32_t tare_counts;          /* tare at arm time: centre of the drift window */
    int32_t filtered_q;           /* last filter output (held over ignored samples) */
    uint32_t glitches;            /* quarantined samples dropped since arm */
    uint32_t arm_ticks;
    uint32_t trigger_ticks;       /* timestamp of the last triggering sample */
    uint32_t release_ticks;       /* timestamp of the last releasing sample */
    uint32_t error_ticks;         /* timestamp of the erroring sample / watchdog check */
    /* derived at configure: */
    uint32_t watchdog_ticks;      /* watchdog_periods * sample_period_ticks */
    uint32_t stuck_repeats;       /* stuck_samples - 1, or UINT32_MAX when off */
    uint32_t scale_round;         /* 2^(scale_frac_bits - 1): round half up */
    uint32_t trigger_bias;        /* trigger_q - 1: |f| >= trigger_q <=> f + bias > 2 bias, unsigned */
    struct tc_trigger_config cfg;
    struct tc_sos_filter filter;  /* configure with tc_sos_filter_configure() */
};

/* Check and store the configuration; the trigger is idle afterwards.
 * Returns TC_OK or TC_ERR_BAD_CONFIG (nothing stored). The filter member is
 * configured separately and left untouched. */
int tc_trigger_configure(struct tc_trigger *t, const struct tc_trigger_config *cfg);

/* Start a probing move with the host's tare taken just before it. Resets the
 * filter, the glitch count, the stuck-sensor run and any sticky error, and
 * sets the force and drift windows. Returns TC_OK (armed),
 * TC_ERR_FORCE_SAFETY (state ERROR) when the tare is outside
 * reference_tare_counts +- force_limit_counts, or TC_ERR_BAD_CONFIG (state
 * unchanged, so samples stay ignored) when the trigger was never configured.
 * A trigger starts zeroed (static storage, or memset) before its first
 * configure: that is how a never-configured one is recognised. */
int tc_trigger_arm(struct tc_trigger *t, int32_t tare_counts, uint32_t arm_ticks);

/* One sensor sample; returns enum tc_trigger_event. */
int tc_trigger_sample(struct tc_trigger *t, int32_t counts, uint32_t sample_ticks);

/* Timer callback: WATCHDOG_TIMEOUT when more than watchdog_periods sample
 * periods have passed since the last sample (or the arm time). Returns the
 * sticky error code (TC_OK when healthy). */
int tc_trigger_check_watchdog(struct tc_trigger *t, uint32_t now_ticks);

/* Abort an active move with an error code, e.g. a sensor driver's own code
 * (a desynced HX711 frame) so the move stops at once instead of by watchdog. */
void tc_trigger_abort(struct tc_trigger *t, int error_code, uint32_t now_ticks);

/* Back to idle; clears the sticky error. */
void tc_trigger_disarm(struct tc_trigger *t);

/* Host only (firmware/host/batch.c): feeds samples until the first event. Returns the index
 * of the sample that caused it (its event in *event) or n (*event NONE).
 * filtered_q, when not NULL, receives t->filtered_q after each fed sample. */
size_t tc_trigger_feed(struct tc_trigger *t, const int32_t *counts, const uint32_t *ticks,
                       size_t n, int32_t *filtered_q, int *event);

/* Host only: sizeof(struct tc_trigger), so the host binding can check its declaration. */
size_t tc_trigger_struct_size(void);

#endif
