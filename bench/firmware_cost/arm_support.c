/* Freestanding M0+ build of the harness: the compiler may emit calls to these. */
#include <stddef.h>

void *memset(void *dst, int value, size_t n)
{
    unsigned char *p = dst;
    while (n--)
        *p++ = (unsigned char)value;
    return dst;
}

void *memcpy(void *dst, const void *src, size_t n)
{
    unsigned char *d = dst;
    const unsigned char *s = src;
    while (n--)
        *d++ = *s++;
    return dst;
}
