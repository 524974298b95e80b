/* FFTs and the unit circle, shared by the kernels that take DFTs.
 *
 * - Power-of-two FFTs for Bluestein's chirp, which takes a DFT of any length (ringing.c: the dwell's
 *   ringing at 4n bins): fft_to_bit_reversed and inverse_fft_from_bit_reversed make a circular
 *   convolution without any reordering (forward into bit-reversed bins, pointwise product, inverse back
 *   to natural order, scaled by 1 / size by the caller). Their twiddles come from one table per
 *   extension module, grown to the largest size used so far.
 * - A mixed-radix FFT for lengths 2^a 3^b 5^c (hum.c: the lengths numpy's rfft is padded to), direct:
 *   a third of Bluestein's work at these lengths, where the chirp's three power-of-two FFTs of at least
 *   the length plus the samples would be.
 * - fill_circle: e^(i pi s / half_turn), a chirp's or a twiddle table's exact indices.
 * Functions are static inline: a kernel that uses one part does not warn about the others. */
#ifndef TAPCELL_FFT_H
#define TAPCELL_FFT_H

#include "buffers.h"
#include <math.h>
#include <stdlib.h>

#ifndef M_PI /* POSIX's, not ISO C's: a strict C99 math.h may leave it out */
#define M_PI 3.14159265358979323846
#endif

typedef struct {
    double re, im;
} Complex;

/* e^(-2 pi i j / twiddle_size), j < twiddle_size / 2: the power-of-two FFTs' twiddles, of the
 * largest size used so far (a smaller FFT takes every (twiddle_size / size)-th). Grown, never shrunk:
 * one table for the process (the interpreter's lock is held throughout a call). */
static Complex *twiddles;
static Py_ssize_t twiddle_size;

static inline int ensure_twiddles(Py_ssize_t size)
{
    if (size <= twiddle_size) return 0;
    Complex *table = malloc(sizeof(Complex) * (size_t)(size / 2));
    if (table == NULL) {
        PyErr_NoMemory();
        return -1;
    }
    for (Py_ssize_t j = 0; j < size / 2; j++) {
        const double angle = -2.0 * M_PI * (double)j / (double)size;
        table[j].re = cos(angle);
        table[j].im = sin(angle);
    }
    free(twiddles);
    twiddles = table;
    twiddle_size = size;
    return 0;
}

static inline Complex times(Complex a, double wr, double wi)
{
    const Complex product = {a.re * wr - a.im * wi, a.re * wi + a.im * wr};
    return product;
}

/* The power-of-two FFTs' butterflies with a complex number as one SSE2 vector (re, im) where the
 * compiler has it (x86-64 always): each lane's operations are the plain code's, so the bits are the
 * same (a product's re is a.re wr + -(a.im wi), which IEEE rounds as a.re wr - a.im wi; its im
 * a.im wr + a.re wi, the sum in the other order, which IEEE addition does not mind). -DTAPCELL_SCALAR
 * builds the plain loops (tests/tap/test_native_ringing.py compares the two builds' bits). */
#if defined(__SSE2__) && !defined(TAPCELL_SCALAR)
#include <emmintrin.h>

typedef __m128d ComplexVector;

static inline ComplexVector cv_load(const Complex *c) { return _mm_loadu_pd(&c->re); }
static inline void cv_store(Complex *c, ComplexVector v) { _mm_storeu_pd(&c->re, v); }
static inline ComplexVector cv_add(ComplexVector a, ComplexVector b) { return _mm_add_pd(a, b); }
static inline ComplexVector cv_sub(ComplexVector a, ComplexVector b) { return _mm_sub_pd(a, b); }

/* a (wr + i wi), as `times`. */
static inline ComplexVector cv_times(ComplexVector a, double wr, double wi)
{
    const ComplexVector negate_re = _mm_set_pd(0.0, -0.0); /* flips the sign of the re lane only */
    const ComplexVector straight = _mm_mul_pd(a, _mm_set1_pd(wr)); /* (a.re wr, a.im wr) */
    const ComplexVector crossed = _mm_mul_pd(_mm_shuffle_pd(a, a, 1), _mm_set1_pd(wi)); /* (a.im wi, a.re wi) */
    return _mm_add_pd(straight, _mm_xor_pd(crossed, negate_re));
}
#else
typedef Complex ComplexVector;

static inline ComplexVector cv_load(const Complex *c) { return *c; }
static inline void cv_store(Complex *c, ComplexVector v) { *c = v; }
static inline ComplexVector cv_add(ComplexVector a, ComplexVector b) { return (Complex){a.re + b.re, a.im + b.im}; }
static inline ComplexVector cv_sub(ComplexVector a, ComplexVector b) { return (Complex){a.re - b.re, a.im - b.im}; }
static inline ComplexVector cv_times(ComplexVector a, double wr, double wi) { return times(a, wr, wi); }
#endif

/* The forward DFT of x (size a power of two) in place, its bins in bit-reversed order: radix 2,
 * decimation in frequency, two stages per pass over the data (the same butterflies, half the passes),
 * the last alone when their count is odd. */
static inline void fft_to_bit_reversed(Complex *x, Py_ssize_t size)
{
    Py_ssize_t len = size;
    for (; len >= 4; len /= 4) {
        /* the stages of len and len / 2: x0..x3 a quarter of a len block apart; the first stage's
         * twiddles W_len^k and W_len^(k + len/4) = -i W_len^k, the second's W_(len/2)^k */
        const Py_ssize_t h = len / 4;
        for (Py_ssize_t k = 0; k < h; k++) {
            const Complex w1 = twiddles[k * (twiddle_size / len)], w2 = twiddles[k * (twiddle_size / (len / 2))];
            const double w3r = w1.im, w3i = -w1.re; /* -i w1 */
            for (Py_ssize_t start = k; start < size; start += len) {
                Complex *p = x + start;
                const ComplexVector x0 = cv_load(p), x1 = cv_load(p + h), x2 = cv_load(p + 2 * h),
                                    x3 = cv_load(p + 3 * h);
                const ComplexVector a0 = cv_add(x0, x2), a1 = cv_add(x1, x3);
                const ComplexVector a2 = cv_times(cv_sub(x0, x2), w1.re, w1.im);
                const ComplexVector a3 = cv_times(cv_sub(x1, x3), w3r, w3i);
                cv_store(p, cv_add(a0, a1));
                cv_store(p + h, cv_times(cv_sub(a0, a1), w2.re, w2.im));
                cv_store(p + 2 * h, cv_add(a2, a3));
                cv_store(p + 3 * h, cv_times(cv_sub(a2, a3), w2.re, w2.im));
            }
        }
    }
    if (len == 2) /* the last stage alone: W_2^0 = 1 */
        for (Py_ssize_t start = 0; start < size; start += 2) {
            const ComplexVector a = cv_load(x + start), b = cv_load(x + start + 1);
            cv_store(x + start, cv_add(a, b));
            cv_store(x + start + 1, cv_sub(a, b));
        }
}

/* The inverse DFT (e^+i, unscaled) of bins in bit-reversed order, x in natural order after: radix 2,
 * decimation in time, two stages per pass, the last alone when their count is odd. With
 * fft_to_bit_reversed, a convolution needs no reordering. */
static inline void inverse_fft_from_bit_reversed(Complex *x, Py_ssize_t size)
{
    Py_ssize_t len = 2;
    for (; 2 * len <= size; len *= 4) {
        /* the stages of len and 2 len: the first's twiddle conj W_len^k, the second's conj W_2len^k
         * and conj W_2len^(k + len/2) = i conj W_2len^k */
        const Py_ssize_t h = len / 2;
        for (Py_ssize_t k = 0; k < h; k++) {
            const Complex t1 = twiddles[k * (twiddle_size / len)], t2 = twiddles[k * (twiddle_size / (2 * len))];
            const double w1r = t1.re, w1i = -t1.im, w2r = t2.re, w2i = -t2.im;
            const double w3r = -w2i, w3i = w2r; /* i w2 */
            for (Py_ssize_t start = k; start < size; start += 2 * len) {
                Complex *p = x + start;
                const ComplexVector b1 = cv_times(cv_load(p + h), w1r, w1i);
                const ComplexVector b3 = cv_times(cv_load(p + 3 * h), w1r, w1i);
                const ComplexVector p0 = cv_load(p), p2 = cv_load(p + 2 * h);
                const ComplexVector a0 = cv_add(p0, b1), a1 = cv_sub(p0, b1), a2 = cv_add(p2, b3),
                                    a3 = cv_sub(p2, b3);
                const ComplexVector c2 = cv_times(a2, w2r, w2i), c3 = cv_times(a3, w3r, w3i);
                cv_store(p, cv_add(a0, c2));
                cv_store(p + 2 * h, cv_sub(a0, c2));
                cv_store(p + h, cv_add(a1, c3));
                cv_store(p + 3 * h, cv_sub(a1, c3));
            }
        }
    }
    if (len == size) { /* the last stage alone */
        const Py_ssize_t half = len / 2, stride = twiddle_size / len;
        for (Py_ssize_t k = 0; k < half; k++) {
            const ComplexVector product = cv_times(cv_load(x + k + half), twiddles[k * stride].re,
                                                   -twiddles[k * stride].im);
            const ComplexVector low = cv_load(x + k);
            cv_store(x + k + half, cv_sub(low, product));
            cv_store(x + k, cv_add(low, product));
        }
    }
}

/* circle[s] = e^(i pi s / half_turn) for s in [0, 2 half_turn): a full turn, from its first eighth by
 * exact symmetries (a quarter turn multiplies by i; within a quarter, s and quarter - s swap cosine
 * and sine). half_turn even. */
static inline void fill_circle(Complex *circle, Py_ssize_t half_turn)
{
    const Py_ssize_t quarter = half_turn / 2;
    for (Py_ssize_t s = 0; 2 * s <= quarter; s++) {
        const double angle = M_PI * (double)s / (double)half_turn;
        const double c = cos(angle), sn = sin(angle);
        circle[s].re = c;
        circle[s].im = sn;
        circle[quarter - s].re = sn;
        circle[quarter - s].im = c;
    }
    for (Py_ssize_t s = quarter; s < 2 * half_turn; s++) { /* i times the value a quarter turn back */
        circle[s].re = -circle[s - quarter].im;
        circle[s].im = circle[s - quarter].re;
    }
}

static inline Py_ssize_t pow2_at_least(Py_ssize_t count)
{
    Py_ssize_t size = 1;
    while (size < count) size <<= 1;
    return size;
}

/* The radices of n (largest first: fours, then 2, 3, 5) into radices[], their count; 0 when n has
 * another prime factor (or n < 1). At most 64 radices (n < 2^64). */
static inline int mixed_radices(Py_ssize_t n, Py_ssize_t radices[64])
{
    int count = 0;
    if (n < 1) return 0;
    while (n % 4 == 0) { radices[count++] = 4; n /= 4; }
    while (n % 2 == 0) { radices[count++] = 2; n /= 2; }
    while (n % 3 == 0) { radices[count++] = 3; n /= 3; }
    while (n % 5 == 0) { radices[count++] = 5; n /= 5; }
    return n == 1 ? count : 0;
}

/* The small DFTs of the mixed-radix FFT: y[s m] = sum_q t[q] W_r^(qs), W_r = e^(-2 pi i / r), written
 * out with W_4 = -i, W_3 = -1/2 - i sqrt(3)/2 and W_5^j = cos(2 pi j / 5) - i sin(2 pi j / 5). */
static inline void dft2(Complex *y, Py_ssize_t m, const Complex *t)
{
    y[0].re = t[0].re + t[1].re;
    y[0].im = t[0].im + t[1].im;
    y[m].re = t[0].re - t[1].re;
    y[m].im = t[0].im - t[1].im;
}

static inline void dft4(Complex *y, Py_ssize_t m, const Complex *t)
{
    const Complex a = {t[0].re + t[2].re, t[0].im + t[2].im}, b = {t[0].re - t[2].re, t[0].im - t[2].im};
    const Complex c = {t[1].re + t[3].re, t[1].im + t[3].im}, d = {t[1].re - t[3].re, t[1].im - t[3].im};
    y[0].re = a.re + c.re;
    y[0].im = a.im + c.im;
    y[m].re = b.re + d.im; /* b - i d */
    y[m].im = b.im - d.re;
    y[2 * m].re = a.re - c.re;
    y[2 * m].im = a.im - c.im;
    y[3 * m].re = b.re - d.im; /* b + i d */
    y[3 * m].im = b.im + d.re;
}

static inline void dft3(Complex *y, Py_ssize_t m, const Complex *t)
{
    /* t0 + (t1 + t2) cos(2 pi / 3) -+ i (t1 - t2) sin(2 pi / 3) */
    const double half_root3 = 0.86602540378443864676;
    const Complex sum = {t[1].re + t[2].re, t[1].im + t[2].im}, diff = {t[1].re - t[2].re, t[1].im - t[2].im};
    const double mid_re = t[0].re - 0.5 * sum.re, mid_im = t[0].im - 0.5 * sum.im;
    y[0].re = t[0].re + sum.re;
    y[0].im = t[0].im + sum.im;
    y[m].re = mid_re + half_root3 * diff.im;
    y[m].im = mid_im - half_root3 * diff.re;
    y[2 * m].re = mid_re - half_root3 * diff.im;
    y[2 * m].im = mid_im + half_root3 * diff.re;
}

static inline void dft5(Complex *y, Py_ssize_t m, const Complex *t)
{
    /* the pairs (t1, t4) and (t2, t3) share cosines; their differences the sines */
    const double cos1 = 0.30901699437494742410, sin1 = 0.95105651629515357212;
    const double cos2 = -0.80901699437494742410, sin2 = 0.58778525229247312917;
    const Complex a1 = {t[1].re + t[4].re, t[1].im + t[4].im}, b1 = {t[1].re - t[4].re, t[1].im - t[4].im};
    const Complex a2 = {t[2].re + t[3].re, t[2].im + t[3].im}, b2 = {t[2].re - t[3].re, t[2].im - t[3].im};
    const double c1_re = t[0].re + cos1 * a1.re + cos2 * a2.re, c1_im = t[0].im + cos1 * a1.im + cos2 * a2.im;
    const double c2_re = t[0].re + cos2 * a1.re + cos1 * a2.re, c2_im = t[0].im + cos2 * a1.im + cos1 * a2.im;
    const double s1_re = sin1 * b1.re + sin2 * b2.re, s1_im = sin1 * b1.im + sin2 * b2.im;
    const double s2_re = sin2 * b1.re - sin1 * b2.re, s2_im = sin2 * b1.im - sin1 * b2.im;
    y[0].re = t[0].re + a1.re + a2.re;
    y[0].im = t[0].im + a1.im + a2.im;
    y[m].re = c1_re + s1_im; /* c1 - i s1 */
    y[m].im = c1_im - s1_re;
    y[4 * m].re = c1_re - s1_im; /* c1 + i s1 */
    y[4 * m].im = c1_im + s1_re;
    y[2 * m].re = c2_re + s2_im; /* c2 - i s2 */
    y[2 * m].im = c2_im - s2_re;
    y[3 * m].re = c2_re - s2_im; /* c2 + i s2 */
    y[3 * m].im = c2_im + s2_re;
}

static inline void small_dft(Complex *y, Py_ssize_t m, Py_ssize_t r, const Complex *t)
{
    switch (r) {
    case 2: dft2(y, m, t); break;
    case 3: dft3(y, m, t); break;
    case 4: dft4(y, m, t); break;
    default: dft5(y, m, t); break;
    }
}

/* out[k] = sum_j in[j stride] W^(jk), k < n, W = e^(-2 pi i / n): decimation in time, out of place
 * (in and out must not overlap), n the product of radices[0..]. W^t is conj(circle[t circle_step])
 * with circle[s] = e^(i pi s / half_turn), circle_step = 2 half_turn / n (the caller's table, full turn). */
static inline void mixed_fft(const Complex *in, Py_ssize_t stride, Complex *out, Py_ssize_t n,
                             const Py_ssize_t *radices, const Complex *circle, Py_ssize_t circle_step)
{
    const Py_ssize_t r = radices[0], m = n / r;
    Complex t[5];
    if (m == 1) { /* the last radix: one small DFT of the samples themselves */
        for (Py_ssize_t q = 0; q < r; q++) t[q] = in[q * stride];
        small_dft(out, 1, r, t);
        return;
    }
    /* the r interleaved subsequences' DFTs side by side: out[q m + k] = DFT_m(in[q + r j])_k */
    for (Py_ssize_t q = 0; q < r; q++)
        mixed_fft(in + q * stride, stride * r, out + q * m, m, radices + 1, circle, circle_step * r);
    /* X_(k + s m) = sum_q (W^(qk) out[q m + k]) W_r^(qs), W_r = W^m; k = 0 needs no twiddle */
    for (Py_ssize_t q = 0; q < r; q++) t[q] = out[q * m];
    small_dft(out, m, r, t);
    for (Py_ssize_t k = 1; k < m; k++) {
        t[0] = out[k];
        for (Py_ssize_t q = 1; q < r; q++) {
            const Complex w = circle[q * k * circle_step];
            t[q] = times(out[q * m + k], w.re, -w.im);
        }
        small_dft(out + k, m, r, t);
    }
}

#endif
