/* klipper_harness.c's x86 report: trsync triggers (0 on the full path) and the bytes
 * Klipper allocated per object (filter, trigger). */
#include <stdio.h>
#include <stdint.h>

extern uint32_t klipper_triggers, klipper_object_bytes[2];

int bench_report_x86(void)
{
    printf("triggers %u bytes %u %u\n", klipper_triggers, klipper_object_bytes[0], klipper_object_bytes[1]);
    return 0;
}
