/* x86 driver for a cost harness (harness.c, or klipper_harness.c): reads the inputs
 * bench/firmware_cost.py wrote (raw little-endian words in the order of the globals
 * below), runs bench_setup() and bench_run(), then the harness's bench_report_x86()
 * prints what the bench checks. */
#include <stdio.h>
#include <stdint.h>

extern int32_t bench_coeff[4][5], bench_config[10], bench_tare_counts, bench_counts[];
extern uint32_t bench_n_sections, bench_frac_bits, bench_n_samples, bench_ticks[];
int bench_setup(void);
void bench_run(void);
int bench_report_x86(void);

int main(int argc, char **argv)
{
    FILE *in = argc > 1 ? fopen(argv[1], "rb") : NULL;
    if (!in)
        return 2;
    int ok = fread(&bench_n_sections, 4, 1, in) + fread(&bench_frac_bits, 4, 1, in)
        + fread(&bench_n_samples, 4, 1, in) + fread(&bench_tare_counts, 4, 1, in)
        + fread(bench_config, 4 * 10, 1, in) + fread(bench_coeff, 4 * 20, 1, in);
    ok += fread(bench_counts, 4, bench_n_samples, in) == bench_n_samples;
    ok += fread(bench_ticks, 4, bench_n_samples, in) == bench_n_samples;
    fclose(in);
    if (ok != 8 || bench_setup() != 0)
        return 3;
    bench_run();
    return bench_report_x86();
}
