/* x86 driver for harness.c: reads the inputs bench/firmware_cost.py wrote (raw
 * little-endian words in the order of the globals below), runs, prints the outputs. */
#include <stdio.h>
#include "load_cell_trigger.h"

extern struct tc_trigger bench_trigger;
extern int32_t bench_coeff[TC_SOS_MAX_SECTIONS][TC_SOS_NCOEFF];
extern uint32_t bench_n_sections, bench_frac_bits, bench_n_samples;
extern struct tc_trigger_config bench_config;
extern int32_t bench_tare_counts, bench_counts[], bench_filtered[], bench_events;
extern uint32_t bench_ticks[];
int bench_setup(void);
void bench_run(void);

int main(int argc, char **argv)
{
    FILE *in = argc > 1 ? fopen(argv[1], "rb") : NULL;
    if (!in)
        return 2;
    int ok = fread(&bench_n_sections, 4, 1, in) + fread(&bench_frac_bits, 4, 1, in)
        + fread(&bench_n_samples, 4, 1, in) + fread(&bench_tare_counts, 4, 1, in)
        + fread(&bench_config, sizeof bench_config, 1, in) + fread(bench_coeff, sizeof bench_coeff, 1, in);
    ok += fread(bench_counts, 4, bench_n_samples, in) == bench_n_samples;
    ok += fread(bench_ticks, 4, bench_n_samples, in) == bench_n_samples;
    fclose(in);
    if (ok != 8 || bench_setup() != 0)
        return 3;
    bench_run();
    for (uint32_t i = 0; i < bench_n_samples; i++)
        printf("%d\n", bench_filtered[i]);
    return bench_events != 0;
}
