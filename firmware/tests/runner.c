/* Runs every TEST registered by the test files; the last line is "N passed, N failed". */
#include "unit.h"

#define UNIT_MAX_TESTS 512

static const char *unit_names[UNIT_MAX_TESTS];
static unit_fn unit_fns[UNIT_MAX_TESTS];
static int unit_count;

void unit_register(const char *name, unit_fn fn)
{
    if (unit_count < UNIT_MAX_TESTS) {
        unit_names[unit_count] = name;
        unit_fns[unit_count] = fn;
        unit_count++;
    }
}

int main(void)
{
    int passed = 0, failed = 0;
    for (int i = 0; i < unit_count; i++) {
        int bad = 0;
        unit_fns[i](&bad);
        if (bad) {
            printf("FAIL %s\n", unit_names[i]);
            failed++;
        } else {
            passed++;
        }
    }
    printf("%d passed, %d failed\n", passed, failed);
    return failed ? 1 : 0;
}
