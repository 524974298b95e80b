/* Per-sample cost harness for Klipper's sos_filter.c + trigger_analog.c, which
 * bench/firmware_cost.py builds from a Klipper checkout given at run time (never
 * copied here). Same inputs as harness.c (the globals below, written by the
 * bench), configured through Klipper's own command handlers the way klippy
 * would; bench_run() feeds every sample through trigger_analog_update(), the
 * call Klipper's sensor drivers make. klipper_runtime.c supplies the MCU
 * runtime those files call (oid allocation, timer, trsync, shutdown). */
#include <stdint.h>

struct trigger_analog;
void command_config_sos_filter(uint32_t *args);
void command_sos_filter_set_section(uint32_t *args);
void command_sos_filter_activate(uint32_t *args);
void command_trigger_analog_set_offset_scale(uint32_t *args);
void command_config_trigger_analog(uint32_t *args);
void command_trigger_analog_set_raw_range(uint32_t *args);
void command_trigger_analog_set_trigger(uint32_t *args);
void command_trigger_analog_home(uint32_t *args);
struct trigger_analog *trigger_analog_oid_lookup(uint8_t oid);
void trigger_analog_update(struct trigger_analog *ta, int32_t sample);

#define BENCH_MAX_SAMPLES 4096
enum { FILTER_OID = 0, TRIGGER_OID = 1, TRIGGER_ABS_GE = 0 };
/* bench_config, in the order of struct tc_trigger_config */
enum { CFG_REFERENCE, CFG_FORCE_LIMIT, CFG_DRIFT_LIMIT, CFG_SCALE, CFG_SCALE_FRAC_BITS, CFG_TRIGGER_Q };

int32_t bench_coeff[4][5];
uint32_t bench_n_sections, bench_frac_bits, bench_n_samples;
int32_t bench_config[10];
int32_t bench_tare_counts;
int32_t bench_counts[BENCH_MAX_SAMPLES];
uint32_t bench_ticks[BENCH_MAX_SAMPLES];
struct trigger_analog *bench_ta;
extern uint32_t klipper_triggers;   /* trsync_do_trigger calls: a trigger or a cancelled move */

static void home(uint32_t monitor_ticks)
{
    uint32_t args[] = {TRIGGER_OID, 0, 1, 2, 0, monitor_ticks, 255};
    command_trigger_analog_home(args);
}

int bench_setup(void)
{
    uint32_t config_filter[] = {FILTER_OID, 4};
    command_config_sos_filter(config_filter);
    for (uint32_t i = 0; i < bench_n_sections; i++) {
        uint32_t section[7] = {FILTER_OID, i};
        for (int c = 0; c < 5; c++)
            section[2 + c] = (uint32_t)bench_coeff[i][c];
        command_sos_filter_set_section(section);
    }
    uint32_t activate[] = {FILTER_OID, bench_n_sections, bench_frac_bits};
    command_sos_filter_activate(activate);
    uint32_t offset_scale[] = {FILTER_OID, (uint32_t)-bench_tare_counts, (uint32_t)bench_config[CFG_SCALE],
                               (uint32_t)bench_config[CFG_SCALE_FRAC_BITS], 0};
    command_trigger_analog_set_offset_scale(offset_scale);
    uint32_t config_trigger[] = {TRIGGER_OID, FILTER_OID};
    command_config_trigger_analog(config_trigger);
    /* The raw range as our force window around the reference (Klipper has one window). */
    uint32_t range[] = {TRIGGER_OID, (uint32_t)(bench_config[CFG_REFERENCE] - bench_config[CFG_FORCE_LIMIT]),
                        (uint32_t)(bench_config[CFG_REFERENCE] + bench_config[CFG_FORCE_LIMIT])};
    command_trigger_analog_set_raw_range(range);
    uint32_t trigger[] = {TRIGGER_OID, TRIGGER_ABS_GE, (uint32_t)bench_config[CFG_TRIGGER_Q]};
    command_trigger_analog_set_trigger(trigger);
    bench_ta = trigger_analog_oid_lookup(TRIGGER_OID);
    home(1000);
    return 0;
}

void bench_run(void)
{
    for (uint32_t i = 0; i < bench_n_samples; i++)
        trigger_analog_update(bench_ta, bench_counts[i]);
}

/* The same calls with homing off: the not-armed path. */
void bench_idle_setup(void)
{
    home(0);
}

void bench_run_idle(void)
{
    for (uint32_t i = 0; i < bench_n_samples; i++)
        trigger_analog_update(bench_ta, bench_counts[i]);
}
