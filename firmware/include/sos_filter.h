/* sos_filter.h - fixed-point cascade of up to 4 biquads (direct form II transposed).
 *
 * Formats
 *   values (input and output of every section): int32 Q16.15 grams, 1 LSB = 1/32768 g,
 *     range +-65536 g.
 *   coefficients: int32 with `frac_bits` fractional bits shared by the whole cascade
 *     (Q1.30 when every |c| < 2, fewer bits when a coefficient reaches 2). Stored per
 *     section as b0, b1, b2, a1, a2; a0 is 1 and not stored.
 *   state: int64 in the product format (Q16.15 scaled by 2^frac_bits), so the state
 *     keeps every bit of the products and only the section output is rounded.
 *
 * One section, with R = 2^(frac_bits-1) (round half up) and every product 32x32->64:
 *   acc = b0*x + z1                          z1 already holds R
 *   y   = acc >> frac_bits                   the section output, int32 Q16.15
 *   err = acc - R - (y << frac_bits)         rounding error, in [-R, R)
 *   z1  = b1*x - a1*y + 2*err + z2
 *   z2  = b2*x - a2*y + R - err
 * The err terms are second-order error feedback: the rounding error reaches the
 * output shaped by (1 - z^-1)^2 / A(z) instead of 1 / A(z), which matters for the
 * drift high-pass (poles near z = 1, DC gain of 1/A about 1e4).
 * Overflow: the two 64-bit additions with a stored state are checked, and y must
 * fit int32. On overflow the value saturates (int64 or int32 limit, sign of the
 * true result) and `overflowed` is set until tc_sos_filter_reset(). Never undefined
 * behaviour, never silent. tapcell.filters.reference_sosfilt_q() is the bit-exact
 * Python model of exactly this arithmetic.
 *
 * The caller owns the struct; there is no allocation and no floating point.
 */
#ifndef TAPCELL_SOS_FILTER_H
#define TAPCELL_SOS_FILTER_H

#include <stddef.h>
#include <stdint.h>

#define TC_SOS_MAX_SECTIONS 4
#define TC_SOS_MIN_FRAC_BITS 1
#define TC_SOS_MAX_FRAC_BITS 30   /* keeps R - err and 2*err below 2^30 */

/* Section coefficient order. */
enum { TC_SOS_B0, TC_SOS_B1, TC_SOS_B2, TC_SOS_A1, TC_SOS_A2, TC_SOS_NCOEFF };

struct tc_sos_filter {
    int64_t state[TC_SOS_MAX_SECTIONS][2];            /* z1, z2 per section */
    int64_t round_half;                               /* R = 2^(frac_bits-1) */
    int32_t coeff[TC_SOS_MAX_SECTIONS][TC_SOS_NCOEFF];
    uint8_t n_sections;                               /* 0 = pass-through */
    uint8_t frac_bits;
    uint8_t overflowed;                               /* sticky until reset */
};

/* Signed 32x32 -> 64 product from four 16x16 -> 32 multiplies. ARMv6-M
 * (Cortex-M0/M0+) has no 64-bit multiply instruction; the compiler would call
 * the general 64x64 helper __aeabi_lmul (about 57 cycles) for every product,
 * while this needs four single-cycle MULS and some 32-bit adds. It forms the
 * unsigned product of the two bit patterns, then corrects the high word for
 * negative operands (a < 0 adds 2^32 to a, so subtract b * 2^32; same for b).
 * Exact, so bit-identical to the native multiply. */
static inline int64_t tc_mul_s32_halves(int32_t a, int32_t b)
{
    uint32_t ua = (uint32_t)a, ub = (uint32_t)b;
    uint32_t a_lo = ua & 0xFFFFu, a_hi = ua >> 16, b_lo = ub & 0xFFFFu, b_hi = ub >> 16;
    uint32_t lo = a_lo * b_lo, hi = a_hi * b_hi;
    uint32_t cross = a_hi * b_lo, cross2 = a_lo * b_hi;
    cross += cross2;
    hi += (uint32_t)(cross < cross2) << 16;          /* carry out of the cross sum */
    uint32_t lo_sum = lo + (cross << 16);
    hi += (cross >> 16) + (lo_sum < lo);
    hi -= (ub & (uint32_t)(a >> 31)) + (ua & (uint32_t)(b >> 31));
    return (int64_t)(((uint64_t)hi << 32) | lo_sum); /* modular conversion (gcc, clang) */
}

static inline int64_t tc_mul_s32_native(int32_t a, int32_t b)
{
    return (int64_t)a * b;
}

/* v >> shift (arithmetic, 1 <= shift <= 31) as int32, using 32-bit word
 * operations only: ARMv6-M has no 64-bit shifter and the compiler would call
 * __aeabi_lasr. Sets *bad and saturates when the result does not fit int32:
 * it fits exactly when the bits of v above bit shift+30 are all copies of the
 * sign, i.e. when hi >> (shift-1) is 0 or -1. */
static inline int32_t tc_shift_to_int32_words(int64_t v, unsigned shift, uint8_t *bad)
{
    int32_t hi = (int32_t)(v >> 32);
    uint32_t lo = (uint32_t)v;
    int32_t above = hi >> (shift - 1);
    if ((uint32_t)above + 1u > 1u) {
        *bad = 1;
        return hi < 0 ? INT32_MIN : INT32_MAX;
    }
    return (int32_t)(((uint32_t)hi << (32 - shift)) | (lo >> shift));
}

static inline int32_t tc_shift_to_int32_native(int64_t v, unsigned shift, uint8_t *bad)
{
    int64_t wide = v >> shift;
    if (wide != (int32_t)wide) {
        *bad = 1;
        return wide < 0 ? INT32_MIN : INT32_MAX;
    }
    return (int32_t)wide;
}

/* Cores without a 32x32->64 multiply and 64-bit shifts (ARMv6-M) use the
 * word-level versions; everything else the native ones. Both are exact, so
 * the results are identical (tests/test_sos_filter.c checks this on the host). */
#if defined(__ARM_ARCH_6M__) || defined(TC_FORCE_WORD_MATH)
#define tc_mul_s32 tc_mul_s32_halves
#define tc_shift_to_int32 tc_shift_to_int32_words
#else
#define tc_mul_s32 tc_mul_s32_native
#define tc_shift_to_int32 tc_shift_to_int32_native
#endif

/* Load coefficients (n_sections rows of b0 b1 b2 a1 a2) and reset the state.
 * Returns TC_OK, or TC_ERR_BAD_CONFIG when n_sections > 4, frac_bits is
 * outside 1..30 or a coefficient is INT32_MIN (the filter is then left as a
 * pass-through). */
int tc_sos_filter_configure(struct tc_sos_filter *f, const int32_t coeff[][TC_SOS_NCOEFF],
                            unsigned n_sections, unsigned frac_bits);

/* Zero state (a tared input starts at 0 g) and clear the overflow flag. */
void tc_sos_filter_reset(struct tc_sos_filter *f);

/* Filter one Q16.15 sample; sets f->overflowed when a value saturates. */
int32_t tc_sos_filter_apply(struct tc_sos_filter *f, int32_t x);

/* *acc = a*b + *acc (64-bit, saturating), returned as *acc >> shift in int32
 * (saturating); *bad is set on either overflow. With *acc = 2^(shift-1) this is a
 * round-half-up fixed-point multiply (the trigger's counts -> grams scale); the
 * filter passes its state and keeps the sum for the rounding error. One shared
 * out-of-line copy keeps the M0+ code small. */
int32_t tc_mul_add_shift(int32_t a, int32_t b, int64_t *acc, unsigned shift, uint8_t *bad);

/* Host only (firmware/host/batch.c): filter n samples. Returns the index of the first sample
 * whose processing overflowed, or n when none did. */
size_t tc_sos_filter_run(struct tc_sos_filter *f, const int32_t *x, int32_t *y, size_t n);

#endif
