/* Fixed-point biquad cascade: hand-computed responses, rounding, overflow, config. */
#include "unit.h"
#include "sos_filter.h"
#include "tc_errors.h"

#define Q30(x) ((int32_t)((x) * 1073741824.0))   /* exact for the binary fractions used here */
#define GRAM 32768                                /* 1 g in Q16.15 */

static struct tc_sos_filter one_section(double b0, double b1, double b2, double a1, double a2)
{
    struct tc_sos_filter f;
    const int32_t c[1][TC_SOS_NCOEFF] = {{Q30(b0), Q30(b1), Q30(b2), Q30(a1), Q30(a2)}};
    tc_sos_filter_configure(&f, c, 1, 30);
    return f;
}

TEST(sos_zero_sections_is_pass_through)
{
    struct tc_sos_filter f;
    CHECK_EQ_INT(tc_sos_filter_configure(&f, NULL, 0, 30), TC_OK);
    CHECK_EQ_INT(tc_sos_filter_apply(&f, 123456), 123456);
    CHECK_EQ_INT(tc_sos_filter_apply(&f, INT32_MIN), INT32_MIN);
    CHECK_EQ_INT(f.overflowed, 0);
}

TEST(sos_impulse_response_first_order_by_hand)
{
    /* H(z) = (0.5 + 0.25 z^-1) / (1 - 0.5 z^-1): 0.5, 0.5, 0.25, 0.125, ... */
    struct tc_sos_filter f = one_section(0.5, 0.25, 0, -0.5, 0);
    CHECK_EQ_INT(tc_sos_filter_apply(&f, GRAM), GRAM / 2);
    CHECK_EQ_INT(tc_sos_filter_apply(&f, 0), GRAM / 2);
    CHECK_EQ_INT(tc_sos_filter_apply(&f, 0), GRAM / 4);
    CHECK_EQ_INT(tc_sos_filter_apply(&f, 0), GRAM / 8);
    CHECK_EQ_INT(f.overflowed, 0);
}

TEST(sos_step_response_second_order_by_hand)
{
    /* y[n] = 0.25 x[n] + 0.5 x[n-1] + 0.25 x[n-2] + 0.5 y[n-1] - 0.25 y[n-2], step of 4 g:
     * 1, 3.5, 5.5, 5.875, 5.5625 g */
    struct tc_sos_filter f = one_section(0.25, 0.5, 0.25, -0.5, 0.25);
    const int32_t want_g_x16[] = {16, 56, 88, 94, 89};
    for (int i = 0; i < 5; i++)
        CHECK_EQ_INT(tc_sos_filter_apply(&f, 4 * GRAM), want_g_x16[i] * (GRAM / 16));
}

TEST(sos_rounds_half_up_from_zero_state)
{
    struct tc_sos_filter f = one_section(0.5, 0, 0, 0, 0);
    CHECK_EQ_INT(tc_sos_filter_apply(&f, 1), 1);    /* +0.5 LSB -> 1 */
    tc_sos_filter_reset(&f);
    CHECK_EQ_INT(tc_sos_filter_apply(&f, -1), 0);   /* -0.5 LSB -> 0 */
    tc_sos_filter_reset(&f);
    CHECK_EQ_INT(tc_sos_filter_apply(&f, -3), -1);  /* -1.5 LSB -> -1 */
    tc_sos_filter_reset(&f);
    CHECK_EQ_INT(tc_sos_filter_apply(&f, 3), 2);    /* +1.5 LSB -> 2 */
}

TEST(sos_error_feedback_carries_rounding_error)
{
    /* gain 0.5, x = 1, -1, -3, 3 LSB (exact 0.5, -0.5, -1.5, 1.5): the error of
     * each rounding moves into the next outputs, 1, -1, -2, 2 (sum 0 = exact sum) */
    struct tc_sos_filter f = one_section(0.5, 0, 0, 0, 0);
    CHECK_EQ_INT(tc_sos_filter_apply(&f, 1), 1);
    CHECK_EQ_INT(tc_sos_filter_apply(&f, -1), -1);
    CHECK_EQ_INT(tc_sos_filter_apply(&f, -3), -2);
    CHECK_EQ_INT(tc_sos_filter_apply(&f, 3), 2);
    /* gain 1/4 of a constant 1 LSB: plain rounding would give 0 forever; with the
     * feedback the outputs average exactly 1/4 */
    f = one_section(0.25, 0, 0, 0, 0);
    long sum = 0;
    for (int i = 0; i < 400; i++)
        sum += tc_sos_filter_apply(&f, 1);
    CHECK_EQ_INT(sum, 100);
}

TEST(sos_two_sections_cascade_and_q2_29)
{
    /* frac_bits 29 allows a coefficient of 2.0: gain 2 then gain 0.75 = 1.5 */
    struct tc_sos_filter f;
    const int32_t c[2][TC_SOS_NCOEFF] = {{2 << 29, 0, 0, 0, 0}, {3 << 27, 0, 0, 0, 0}};
    CHECK_EQ_INT(tc_sos_filter_configure(&f, c, 2, 29), TC_OK);
    CHECK_EQ_INT(tc_sos_filter_apply(&f, 1000 * GRAM), 1500 * GRAM);
    CHECK_EQ_INT(tc_sos_filter_apply(&f, -7), -10);  /* -14 then -10.5 -> -10 (fresh error) */
}

TEST(sos_output_overflow_saturates_and_sticks)
{
    struct tc_sos_filter f = one_section(1.5, 0, 0, 0, 0);
    CHECK_EQ_INT(tc_sos_filter_apply(&f, 50000 * GRAM), INT32_MAX);  /* 75000 g > 65536 g */
    CHECK_EQ_INT(f.overflowed, 1);
    /* flag sticky; the saturated sample's (wrapped) error term leaves 2 LSB in the next output */
    CHECK_EQ_INT(tc_sos_filter_apply(&f, GRAM), GRAM + GRAM / 2 + 2);
    CHECK_EQ_INT(f.overflowed, 1);
    CHECK_EQ_INT(tc_sos_filter_apply(&f, -50000 * GRAM), INT32_MIN);
    tc_sos_filter_reset(&f);
    CHECK_EQ_INT(f.overflowed, 0);
}

TEST(sos_unstable_state_growth_is_flagged_never_ub)
{
    /* pole at 1.99: the state grows by ~2x per sample until it saturates */
    struct tc_sos_filter f = one_section(1.0, 0, 0, -1.9990234375, 0);
    int first = -1;
    for (int i = 0; i < 200; i++) {
        tc_sos_filter_apply(&f, GRAM);
        if (f.overflowed && first < 0)
            first = i;
    }
    /* step response y[n] = sum_{k<=n} 1.999^k g = 65078 g at n = 15, 130093 g at n = 16 */
    CHECK_EQ_INT(first, 16);
    CHECK_EQ_INT(tc_sos_filter_apply(&f, GRAM) == INT32_MAX, 1);
}

TEST(sos_run_reports_first_overflow_index)
{
    struct tc_sos_filter f = one_section(1.5, 0, 0, 0, 0);
    int32_t x[4] = {GRAM, 2 * GRAM, 60000 * GRAM, GRAM}, y[4];
    CHECK_EQ_INT(tc_sos_filter_run(&f, x, y, 4), 2);
    CHECK_EQ_INT(y[1], 3 * GRAM);
    CHECK_EQ_INT(y[2], INT32_MAX);
    tc_sos_filter_reset(&f);
    CHECK_EQ_INT(tc_sos_filter_run(&f, x, y, 2), 2);  /* n: no overflow */
}

TEST(sos_configure_rejects_bad_values)
{
    struct tc_sos_filter f;
    const int32_t c[5][TC_SOS_NCOEFF] = {{0}};
    CHECK_EQ_INT(tc_sos_filter_configure(&f, c, 5, 30), TC_ERR_BAD_CONFIG);
    CHECK_EQ_INT(f.n_sections, 0);
    CHECK_EQ_INT(tc_sos_filter_configure(&f, c, 1, 0), TC_ERR_BAD_CONFIG);
    CHECK_EQ_INT(tc_sos_filter_configure(&f, c, 1, 31), TC_ERR_BAD_CONFIG);
    CHECK_EQ_INT(tc_sos_filter_configure(&f, c, 4, 30), TC_OK);
    CHECK_EQ_INT(f.round_half, 1 << 29);
}

/* The M0+ build uses the word-level multiply and shift; they must equal the
 * native 64-bit ones for every input. Edge values plus a pseudo-random sweep. */
static uint32_t lcg(uint32_t *s) { return *s = *s * 1664525u + 1013904223u; }

TEST(sos_word_math_equals_native_math)
{
    const int32_t edge[] = {0, 1, -1, 2, -2, 65535, 65536, -65536, -65537, 32767, -32768,
                            INT32_MAX, INT32_MIN, INT32_MAX - 1, INT32_MIN + 1, 0x12345678, -0x12345678};
    const int n_edge = (int)(sizeof edge / sizeof edge[0]);
    for (int i = 0; i < n_edge; i++)
        for (int k = 0; k < n_edge; k++)
            CHECK_EQ_INT(tc_mul_s32_halves(edge[i], edge[k]), tc_mul_s32_native(edge[i], edge[k]));
    uint32_t seed = 12345;
    int mismatches = 0;
    for (int i = 0; i < 200000; i++) {
        int32_t a = (int32_t)lcg(&seed), b = (int32_t)lcg(&seed);
        unsigned shift = 1 + lcg(&seed) % 31;
        int64_t p = tc_mul_s32_native(a, b) >> (lcg(&seed) % 40);
        uint8_t bad_w = 0, bad_n = 0;
        mismatches += tc_mul_s32_halves(a, b) != tc_mul_s32_native(a, b);
        mismatches += tc_shift_to_int32_words(p, shift, &bad_w) != tc_shift_to_int32_native(p, shift, &bad_n);
        mismatches += bad_w != bad_n;
    }
    CHECK_EQ_INT(mismatches, 0);
    uint8_t bad = 0;
    CHECK_EQ_INT(tc_shift_to_int32_words((int64_t)INT32_MAX << 30, 30, &bad), INT32_MAX);
    CHECK_EQ_INT(bad, 0);
    CHECK_EQ_INT(tc_shift_to_int32_words(((int64_t)INT32_MAX + 1) << 30, 30, &bad), INT32_MAX);
    CHECK_EQ_INT(bad, 1);
    bad = 0;
    CHECK_EQ_INT(tc_shift_to_int32_words((int64_t)INT32_MIN * ((int64_t)1 << 31), 31, &bad), INT32_MIN);
    CHECK_EQ_INT(bad, 0);
    CHECK_EQ_INT(tc_shift_to_int32_words(((int64_t)INT32_MIN * ((int64_t)1 << 31)) - 1, 31, &bad), INT32_MIN);
    CHECK_EQ_INT(bad, 1);
}

TEST(sos_configure_refuses_int32_min_coefficient)
{
    /* -2^31 is the one value that would let a section's sums leave int64 */
    struct tc_sos_filter f;
    const int32_t coeff[1][TC_SOS_NCOEFF] = {{1 << 30, 0, 0, 0, INT32_MIN}};
    CHECK_EQ_INT(tc_sos_filter_configure(&f, coeff, 1, 30), TC_ERR_BAD_CONFIG);
    CHECK_EQ_INT(f.n_sections, 0);   /* left as a pass-through */
    const int32_t ok[1][TC_SOS_NCOEFF] = {{1 << 30, 0, 0, 0, INT32_MIN + 1}};
    CHECK_EQ_INT(tc_sos_filter_configure(&f, ok, 1, 30), TC_OK);
}
