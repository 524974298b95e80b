/* semihost.c - see semihost.h. */
#include "semihost.h"

enum { SYS_WRITE0 = 0x04, SYS_EXIT = 0x18, SYS_EXIT_EXTENDED = 0x20 };
#define ADP_STOPPED_APPLICATION_EXIT 0x20026u

static uint32_t semihost_call(uint32_t op, const void *arg)
{
    register uint32_t r0 __asm__("r0") = op;
    register const void *r1 __asm__("r1") = arg;
    __asm__ volatile("bkpt 0xab" : "+r"(r0) : "r"(r1) : "memory");
    return r0;
}

void semihost_puts(const char *text)
{
    semihost_call(SYS_WRITE0, text);
}

void semihost_put_hex(const char *key, uint32_t value)
{
    char line[16];
    int at = 0;
    line[at++] = ' ';
    line[at++] = '0';
    line[at++] = 'x';
    for (int shift = 28; shift >= 0; shift -= 4)
        line[at++] = "0123456789abcdef"[(value >> shift) & 0xFu];
    line[at++] = '\n';
    line[at] = 0;
    semihost_puts(key);
    semihost_puts(line);
}

void semihost_exit(uint32_t status)
{
    const uint32_t block[2] = {ADP_STOPPED_APPLICATION_EXIT, status};
    semihost_call(SYS_EXIT_EXTENDED, block);
    for (;;)
        semihost_call(SYS_EXIT, (const void *)(uintptr_t)ADP_STOPPED_APPLICATION_EXIT);
}
