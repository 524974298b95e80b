/* Tiny unit-test harness for the firmware core (host only).
 *
 * TEST(name) { ... CHECK(cond); CHECK_EQ_INT(a, b); }
 * Each TEST registers itself at start-up (GCC/Clang constructor), so a test
 * file needs no list to maintain; runner.c runs them all and ends with the
 * line "N passed, N failed".
 */
#ifndef TAPCELL_UNIT_H
#define TAPCELL_UNIT_H

#include <stdio.h>
#include <stdint.h>

typedef void (*unit_fn)(int *failed);
void unit_register(const char *name, unit_fn fn);

#define TEST(name)                                                        \
    static void test_##name(int *unit_failed_);                           \
    __attribute__((constructor)) static void register_##name(void)        \
    { unit_register(#name, test_##name); }                                \
    static void test_##name(int *unit_failed_)

#define CHECK(cond) do {                                                  \
    if (!(cond)) {                                                        \
        printf("  %s:%d: CHECK(%s) failed\n", __FILE__, __LINE__, #cond); \
        *unit_failed_ = 1;                                                \
    } } while (0)

#define CHECK_EQ_INT(a, b) do {                                           \
    long long unit_a_ = (long long)(a), unit_b_ = (long long)(b);         \
    if (unit_a_ != unit_b_) {                                             \
        printf("  %s:%d: %s == %s failed: %lld != %lld\n",                \
               __FILE__, __LINE__, #a, #b, unit_a_, unit_b_);             \
        *unit_failed_ = 1;                                                \
    } } while (0)

#endif
