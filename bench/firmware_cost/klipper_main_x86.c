/* x86 driver for klipper_harness.c: reads the input file bench/firmware_cost.py writes
 * for harness.c, runs the samples, prints the trigger count, the object sizes and,
 * with --filtered (a build with -Wl,--wrap=sos_filter_apply), each filter output. */
#include <stdio.h>
#include <stdint.h>
#include <string.h>

extern int32_t bench_coeff[4][5], bench_config[10], bench_tare_counts, bench_counts[];
extern uint32_t bench_n_sections, bench_frac_bits, bench_n_samples, bench_ticks[];
extern uint32_t klipper_triggers, klipper_object_bytes[2];
int bench_setup(void);
void bench_run(void);

int main(int argc, char **argv)
{
    FILE *in = argc > 1 ? fopen(argv[1], "rb") : NULL;
    if (!in)
        return 2;
    int ok = fread(&bench_n_sections, 4, 1, in) + fread(&bench_frac_bits, 4, 1, in)
        + fread(&bench_n_samples, 4, 1, in) + fread(&bench_tare_counts, 4, 1, in)
        + fread(bench_config, sizeof bench_config, 1, in) + fread(bench_coeff, sizeof bench_coeff, 1, in);
    ok += fread(bench_counts, 4, bench_n_samples, in) == bench_n_samples;
    ok += fread(bench_ticks, 4, bench_n_samples, in) == bench_n_samples;
    fclose(in);
    if (ok != 8 || bench_setup() != 0)
        return 3;
    bench_run();
    printf("triggers %u bytes %u %u\n", klipper_triggers, klipper_object_bytes[0], klipper_object_bytes[1]);
    return 0;
}
