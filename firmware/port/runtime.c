/* runtime.c - the two C library calls the compiler may emit for struct copies
 * and clears in a -nostdlib image. */
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
