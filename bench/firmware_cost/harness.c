/* Per-sample cost harness for bench/firmware_cost.py (x86 under callgrind, M0+ under unicorn).
 * The host writes the inputs into the globals, calls bench_setup() once, then
 * bench_run() feeds every sample through tc_trigger_sample() - the call the
 * sensor driver makes - and keeps each filtered value for a bit-exactness check. */
#include "load_cell_trigger.h"

#define BENCH_MAX_SAMPLES 4096

struct tc_trigger bench_trigger;
int32_t bench_coeff[TC_SOS_MAX_SECTIONS][TC_SOS_NCOEFF];
uint32_t bench_n_sections, bench_frac_bits, bench_n_samples;
int32_t bench_config[10];   /* struct tc_trigger_config's members in order (the input file's words) */
int32_t bench_tare_counts;
int32_t bench_counts[BENCH_MAX_SAMPLES];
uint32_t bench_ticks[BENCH_MAX_SAMPLES];
int32_t bench_filtered[BENCH_MAX_SAMPLES];
int32_t bench_events;

int bench_setup(void)
{
    struct tc_trigger_config config;
    typedef char config_is_10_words[sizeof config == sizeof bench_config ? 1 : -1];
    (void)sizeof(config_is_10_words);
    __builtin_memcpy(&config, bench_config, sizeof config);
    int status = tc_sos_filter_configure(&bench_trigger.filter, bench_coeff, bench_n_sections, bench_frac_bits);
    status |= tc_trigger_configure(&bench_trigger, &config);
    status |= tc_trigger_arm(&bench_trigger, bench_tare_counts, 0);
    return status;
}

void bench_run(void)
{
    for (uint32_t i = 0; i < bench_n_samples; i++) {
        bench_events += tc_trigger_sample(&bench_trigger, bench_counts[i], bench_ticks[i]);
        bench_filtered[i] = bench_trigger.filtered_q;
    }
}

/* The same calls on a disarmed trigger: the not-armed path. */
void bench_idle_setup(void)
{
    tc_trigger_disarm(&bench_trigger);
}

void bench_run_idle(void)
{
    for (uint32_t i = 0; i < bench_n_samples; i++)
        bench_events += tc_trigger_sample(&bench_trigger, bench_counts[i], bench_ticks[i]);
}

/* RAM per instance as this target lays the struct out. */
const uint32_t bench_trigger_bytes = sizeof(struct tc_trigger);
