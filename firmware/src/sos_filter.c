/* sos_filter.c - fixed-point biquad cascade; formats and arithmetic in sos_filter.h. */
#include "sos_filter.h"
#include "tc_errors.h"

void tc_sos_filter_reset(struct tc_sos_filter *f)
{
    /* Zero state plus the rounding constant: z1 carries R into the next y,
     * z2 carries it into the next z1 (see the section equations). */
    for (unsigned i = 0; i < TC_SOS_MAX_SECTIONS; i++) {
        f->state[i][0] = f->round_half;
        f->state[i][1] = f->round_half;
    }
    f->overflowed = 0;
}

int tc_sos_filter_configure(struct tc_sos_filter *f, const int32_t coeff[][TC_SOS_NCOEFF],
                            unsigned n_sections, unsigned frac_bits)
{
    f->n_sections = 0;
    if (n_sections > TC_SOS_MAX_SECTIONS || frac_bits < TC_SOS_MIN_FRAC_BITS
        || frac_bits > TC_SOS_MAX_FRAC_BITS)
        return TC_ERR_BAD_CONFIG;
    /* INT32_MIN is refused: with every |coefficient| <= 2^31 - 1 the products
     * below stay within 2^62 - 2^31, which keeps each section's sums inside
     * int64 for ANY 32-bit error term, including the wrapped one after a
     * saturation (no undefined behaviour, no extra work per sample). Designed
     * filters never reach it (quantize_sos keeps |c| < 2^31 - 1). */
    for (unsigned i = 0; i < n_sections; i++)
        for (unsigned k = 0; k < TC_SOS_NCOEFF; k++) {
            if (coeff[i][k] == INT32_MIN)
                return TC_ERR_BAD_CONFIG;   /* n_sections is still 0: a pass-through */
            f->coeff[i][k] = coeff[i][k];
        }
    f->frac_bits = (uint8_t)frac_bits;
    f->round_half = (uint32_t)1 << (frac_bits - 1); /* 32-bit shift: no libcall on M0+ */
    f->n_sections = (uint8_t)n_sections;
    tc_sos_filter_reset(f);
    return TC_OK;
}

/* Size-optimised builds (-Os, the M0+ flash budget) keep one copy of the
 * saturating add instead of inlining it at each use. */
#ifdef __OPTIMIZE_SIZE__
#define TC_SIZE_NOINLINE __attribute__((noinline))
#else
#define TC_SIZE_NOINLINE
#endif

/* a + b, saturated to the int64 limits; sets *bad on overflow. An overflow can
 * only happen with both operands of one sign, so that sign picks the limit. */
static TC_SIZE_NOINLINE int64_t add_sat64(int64_t a, int64_t b, uint8_t *bad)
{
    int64_t sum;
    if (__builtin_add_overflow(a, b, &sum)) {
        *bad = 1;
        sum = a < 0 ? INT64_MIN : INT64_MAX;
    }
    return sum;
}

static inline int32_t mul_add_shift(int32_t a, int32_t b, int64_t *acc, unsigned shift, uint8_t *bad)
{
    *acc = add_sat64(tc_mul_s32(a, b), *acc, bad);
    return tc_shift_to_int32(*acc, shift, bad);
}

int32_t tc_mul_add_shift(int32_t a, int32_t b, int64_t *acc, unsigned shift, uint8_t *bad)
{
    return mul_add_shift(a, b, acc, shift, bad);
}

/* The filter inlines the step for speed, except in size-optimised builds,
 * which share the one out-of-line copy with the trigger. */
#ifdef __OPTIMIZE_SIZE__
#define section_mul_add_shift tc_mul_add_shift
#else
#define section_mul_add_shift mul_add_shift
#endif

int32_t tc_sos_filter_apply(struct tc_sos_filter *f, int32_t x)
{
    const unsigned shift = f->frac_bits;
    uint8_t bad = 0;
    for (unsigned i = 0; i < f->n_sections; i++) {
        const int32_t *c = f->coeff[i];
        int64_t *z = f->state[i];
        int64_t acc = z[0];
        int32_t y = section_mul_add_shift(c[TC_SOS_B0], x, &acc, shift, &bad);
        /* Rounding error of y in product units, in [-R, R): fits 32 bits, so
         * 32-bit arithmetic gives it exactly. After a saturation it is the wrapped
         * 32-bit difference (deterministic, flagged, and harmless: see configure). */
        int32_t err = (int32_t)((uint32_t)acc - ((uint32_t)y << shift) - (uint32_t)f->round_half);
        /* Error feedback (1 - z^-1)^2: without it the rounding error reaches the
         * output through 1/A(z), whose DC gain is ~1e4 for a drift high-pass
         * (poles near z = 1) - a 0.25 g offset. Products: |b*x - a*y| <= 2^63 - 2^32
         * (|c| <= 2^31 - 1), so adding 2*err (|.| <= 2^32) or R - err cannot overflow
         * even for a wrapped err; only the sum with the stored state is checked. */
        z[0] = add_sat64(tc_mul_s32(c[TC_SOS_B1], x) - tc_mul_s32(c[TC_SOS_A1], y) + 2 * (int64_t)err,
                         z[1], &bad);
        z[1] = tc_mul_s32(c[TC_SOS_B2], x) - tc_mul_s32(c[TC_SOS_A2], y) + f->round_half - err;
        x = y;
    }
    f->overflowed |= bad;
    return x;
}
