/* harness.c's x86 report: every filtered value, one per line (checked bit-exact by the
 * bench); the exit status says whether any sample made an event (none may). */
#include <stdio.h>
#include <stdint.h>

extern int32_t bench_filtered[], bench_events;
extern uint32_t bench_n_samples;

int bench_report_x86(void)
{
    for (uint32_t i = 0; i < bench_n_samples; i++)
        printf("%d\n", bench_filtered[i]);
    return bench_events != 0;
}
