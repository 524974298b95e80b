/* The dwell's ringing (tapcell.tap.stage.dwell_ringing) in one call.
 *
 * The twin: a quadratic in time taken out by its 3 x 3 normal equations (np.linalg.solve), then the
 * periodogram 2 |X_k|^2 / n of the residual zero-padded to 4n samples (np.fft.rfft), its largest
 * bin from the first that spans RINGING_MIN_PERIODS periods of the dwell up to the Nyquist rate.
 * pocketfft is slow when 4n has a large prime factor, and the numpy calls around it cost more than
 * the arithmetic at these lengths (a dwell is 10-800 samples).
 *
 * Here: the same normal equations (sums in one pass, Gaussian elimination with partial pivoting,
 * as LAPACK's gesv pivots), the same residual, and the same 2n + 1 bins of the length-4n DFT,
 * computed another way:
 * - the real residual r of length 4n (zeros past n) packed as z_j = r_2j + i r_2j+1: a complex
 *   sequence of length L = 2n with only ceil(n / 2) samples that are not zero; its length-L DFT Z
 *   gives the real one's bins k = 0..L as E_k + e^(-i pi k / L) O_k (E, O: the DFTs of the even
 *   and odd samples, from Z_k and conj Z_(L-k));
 * - Z by Bluestein's chirp: jk = (j^2 + k^2 - (k-j)^2) / 2 turns the DFT of any length into a
 *   convolution with the chirp e^(i pi m^2 / L), done by power-of-two FFTs of M >= L + n / 2
 *   (no prime factors to be slow on);
 * - the chirp's e^(i pi s / L) from an eighth of the circle by exact symmetries (a sin/cos call per
 *   n / 2 samples; the indices m^2 mod 2L kept exact in integers);
 * - what depends on n alone (the circle, the chirp, the filter's FFT: about half the work) made once
 *   per dwell length and kept (`chirp_filter`): the same values made or kept.
 * Every bin is the twin's to rounding (the largest within 1e-13 of the twin's on taplab's and the
 * reference taps' dwells, 5e-13 on the sweep's): the same bin is the largest unless two bins tie to
 * rounding, which no measured dwell came near (docs/tap-analysis.md, "Compiled kernels"). The period
 * is computed as the twin does, bit for bit, given the bin. */
#include "buffers.h"
#include "fft.h"
#include <math.h>
#include <stdlib.h>

/* Solve the 3 x 3 system a x = b (a: the matrix with b as its fourth column, destroyed) by Gaussian
 * elimination with partial pivoting; 0 when the matrix is singular. */
static int solve3(double a[3][4], double x[3])
{
    for (int col = 0; col < 3; col++) {
        int pivot = col;
        for (int row = col + 1; row < 3; row++)
            if (fabs(a[row][col]) > fabs(a[pivot][col])) pivot = row;
        if (a[pivot][col] == 0.0) return 0;
        if (pivot != col)
            for (int j = 0; j < 4; j++) {
                const double swap = a[col][j];
                a[col][j] = a[pivot][j];
                a[pivot][j] = swap;
            }
        for (int row = col + 1; row < 3; row++) {
            const double factor = a[row][col] / a[col][col];
            for (int j = col; j < 4; j++) a[row][j] -= factor * a[col][j];
        }
    }
    for (int row = 2; row >= 0; row--) {
        double value = a[row][3];
        for (int j = row + 1; j < 3; j++) value -= a[row][j] * x[j];
        x[row] = value / a[row][row];
    }
    return 1;
}

/* The residual of the least-squares quadratic in time into packed[j] = r_2j + i r_2j+1 (a zero past
 * n), with the dwell's span; 0 when the span is not positive or the quadratic is undetermined. */
static int quadratic_residual(const double *time_s, const double *force_g, Py_ssize_t n, Complex *packed,
                              double *span_s)
{
    double time_sum = 0.0;
    for (Py_ssize_t i = 0; i < n; i++) time_sum += time_s[i];
    const double time_mean = time_sum / (double)n;
    *span_s = time_s[n - 1] - time_s[0];
    if (!(*span_s > 0.0)) return 0;
    double s1 = 0.0, s2 = 0.0, s3 = 0.0, s4 = 0.0, b0 = 0.0, b1 = 0.0, b2 = 0.0;
    for (Py_ssize_t i = 0; i < n; i++) {
        const double u = (time_s[i] - time_mean) / *span_s, uu = u * u, f = force_g[i];
        s1 += u;
        s2 += uu;
        s3 += u * uu;
        s4 += uu * uu;
        b0 += f;
        b1 += u * f;
        b2 += uu * f;
    }
    double normal[3][4] = {{(double)n, s1, s2, b0}, {s1, s2, s3, b1}, {s2, s3, s4, b2}}, coef[3];
    if (!solve3(normal, coef)) return 0;
    for (Py_ssize_t i = 0; i < n; i++) {
        const double u = (time_s[i] - time_mean) / *span_s;
        const double r = force_g[i] - (coef[0] + coef[1] * u + coef[2] * (u * u));
        if (i % 2 == 0) {
            packed[i / 2].re = r;
            packed[i / 2].im = 0.0;
        } else {
            packed[i / 2].im = r;
        }
    }
    return 1;
}

/* What a dwell of n samples needs whatever its force, kept per n (below): the circle e^(i pi s / L),
 * s < 2L, the chirp e^(i pi m^2 / L), m < L (the most any k - j or k reaches), and the filter, the chirp at k - j
 * zero-padded to the power-of-two size and transformed (bit-reversed bins). One malloc: the struct,
 * then its arrays. */
typedef struct {
    Py_ssize_t size;
    Complex *circle, *chirp, *filter;
} ChirpFilter;

/* The chirp filter of a dwell of n samples (its bytes in *bytes); NULL with MemoryError set. */
static ChirpFilter *make_chirp_filter(Py_ssize_t n, size_t *bytes)
{
    const Py_ssize_t length = 2 * n, inputs = (n + 1) / 2, chirps = length + inputs - 1;
    const Py_ssize_t size = pow2_at_least(chirps);
    if (ensure_twiddles(size) < 0) return NULL;
    *bytes = sizeof(ChirpFilter) + sizeof(Complex) * (size_t)(3 * length + size);
    ChirpFilter *made = malloc(*bytes);
    if (made == NULL) {
        PyErr_NoMemory();
        return NULL;
    }
    Complex *circle = (Complex *)(made + 1), *chirp = circle + 2 * length, *filter = chirp + length;
    made->size = size, made->circle = circle, made->chirp = chirp, made->filter = filter;
    fill_circle(circle, length);
    /* chirp[m] = e^(i pi m^2 / length), m^2 mod 2 length exactly (2m + 1 < 3 (2 length): two subtractions at most) */
    for (Py_ssize_t m = 0, square = 0; m < length; m++) {
        chirp[m] = circle[square];
        square += 2 * m + 1;
        while (square >= 2 * length) square -= 2 * length;
    }
    /* the filter: the chirp at k - j = d - (inputs - 1), zero-padded to size */
    for (Py_ssize_t d = 0; d < size; d++) {
        if (d < chirps) {
            const Py_ssize_t m = d >= inputs - 1 ? d - (inputs - 1) : (inputs - 1) - d;
            filter[d] = chirp[m];
        } else {
            filter[d].re = filter[d].im = 0.0;
        }
    }
    fft_to_bit_reversed(filter, size);
    return made;
}

/* The chirp filters made so far, by n, up to CHIRP_KEPT_BYTES in all: a printer's taps repeat their
 * dwell's length (the benchmark sets' dwells: 58-73 % a length seen before in the run), and a
 * filter costs about half the kernel (n / 2 sines and cosines, a power-of-two FFT). The same values
 * made now or kept: a larger twiddle table holds a smaller one's values bit for bit (fft.h). Never
 * freed: one table for the process, as the twiddles. */
#define CHIRP_KEPT_MAX_N 4096
#define CHIRP_KEPT_BYTES ((size_t)16 << 20)
static ChirpFilter *chirp_kept[CHIRP_KEPT_MAX_N + 1];
static size_t chirp_kept_bytes;

/* The chirp filter of n, kept or made; one that is not kept goes to *made for the caller to free.
 * NULL with MemoryError set. */
static const ChirpFilter *chirp_filter(Py_ssize_t n, ChirpFilter **made)
{
    if (n <= CHIRP_KEPT_MAX_N && chirp_kept[n] != NULL) return chirp_kept[n];
    size_t bytes;
    ChirpFilter *filter = make_chirp_filter(n, &bytes);
    if (filter == NULL) return NULL;
    if (n <= CHIRP_KEPT_MAX_N && bytes <= CHIRP_KEPT_BYTES - chirp_kept_bytes) {
        chirp_kept[n] = filter;
        chirp_kept_bytes += bytes;
    } else {
        *made = filter;
    }
    return filter;
}

/* The largest bin of the periodogram 2 |X_k|^2 / n, k in [lowest, 2n], of the residual packed[0..
 * ceil(n/2)) zero-padded to 4n real samples; its power in *best_power. -1 (MemoryError set) when out
 * of memory. */
static Py_ssize_t largest_bin(Complex *packed, Py_ssize_t n, Py_ssize_t lowest, double *best_power)
{
    const Py_ssize_t length = 2 * n, inputs = (n + 1) / 2;
    ChirpFilter *made = NULL;
    const ChirpFilter *kept = chirp_filter(n, &made);
    if (kept == NULL) return -1;
    const Py_ssize_t size = kept->size;
    const Complex *circle = kept->circle, *chirp = kept->chirp, *filter = kept->filter;
    /* one block: the signal (size), the spectrum (length) */
    Complex *signal = malloc(sizeof(Complex) * (size_t)(size + length));
    if (signal == NULL) {
        free(made);
        PyErr_NoMemory();
        return -1;
    }
    /* Z_k = conj(chirp_k) sum_j (z_j conj(chirp_j)) chirp_(k-j): the signal times the conjugate
     * chirp, zero-padded to size, convolved with the filter */
    for (Py_ssize_t j = 0; j < inputs; j++) {
        const Complex z = packed[j], c = chirp[j];
        signal[j].re = z.re * c.re + z.im * c.im;
        signal[j].im = z.im * c.re - z.re * c.im;
    }
    for (Py_ssize_t j = inputs; j < size; j++) signal[j].re = signal[j].im = 0.0;
    fft_to_bit_reversed(signal, size);
    for (Py_ssize_t i = 0; i < size; i++) /* signal × filter (re: a.re b.re - a.im b.im, im: a.re b.im + a.im b.re) */
        cv_store(signal + i, cv_times(cv_load(signal + i), filter[i].re, filter[i].im));
    inverse_fft_from_bit_reversed(signal, size);
    /* Z_k, k < length (the convolution's index k + inputs - 1, scaled by 1 / size) */
    Complex *spectrum = signal + size;
    for (Py_ssize_t k = 0; k < length; k++) {
        const Complex y = signal[k + inputs - 1], c = chirp[k];
        spectrum[k].re = (y.re * c.re + y.im * c.im) / (double)size;
        spectrum[k].im = (y.im * c.re - y.re * c.im) / (double)size;
    }
    Py_ssize_t best = -1;
    for (Py_ssize_t k = lowest; k <= length; k++) {
        /* Z_(k mod L) and Z_((L - k) mod L), k in [0, L], without a division per bin */
        const Complex zk = spectrum[k < length ? k : 0], zc = spectrum[k > 0 ? length - k : 0];
        /* E = (Z_k + conj Z_(L-k)) / 2, O = -i (Z_k - conj Z_(L-k)) / 2, X = E + e^(-i pi k / L) O */
        const double er = 0.5 * (zk.re + zc.re), ei = 0.5 * (zk.im - zc.im);
        const double o_re = 0.5 * (zk.im + zc.im), o_im = -0.5 * (zk.re - zc.re);
        const double wr = circle[k].re, wi = -circle[k].im;
        const double xr = er + (o_re * wr - o_im * wi), xi = ei + (o_re * wi + o_im * wr);
        const double power = 2.0 * (xr * xr + xi * xi) / (double)n;
        if (best < 0 || power > *best_power) {
            best = k;
            *best_power = power;
        }
    }
    free(signal);
    free(made);
    return best;
}

static PyObject *dwell_ringing(PyObject *self, PyObject *args)
{
    (void)self;
    Py_buffer tb = {0}, fb = {0};
    double white_var, min_periods, min_chi2;
    Py_ssize_t min_samples;
    if (!PyArg_ParseTuple(args, "O&O&dndd", float64_buffer, &tb, float64_buffer, &fb, &white_var, &min_samples,
                          &min_periods, &min_chi2))
        return NULL;
    PyObject *answer = NULL;
    Complex *packed = NULL;
    Py_ssize_t n;
    const double *force_g = doubles_of(&fb, &n, "force_g");
    const double *time_s = force_g ? doubles_sized(&tb, n, "time_s") : NULL;
    if (time_s == NULL) goto done;
    if (n < min_samples || n < 2 || white_var <= 0.0) goto none;
    if (n > PY_SSIZE_T_MAX / (Py_ssize_t)(32 * sizeof(Complex))) {
        PyErr_NoMemory();
        goto done;
    }
    packed = malloc(sizeof(Complex) * (size_t)((n + 1) / 2));
    if (packed == NULL) {
        PyErr_NoMemory();
        goto done;
    }
    double span_s;
    if (!quadratic_residual(time_s, force_g, n, packed, &span_s)) goto none;
    const Py_ssize_t padded = 4 * n;
    const double period_s = span_s / (double)(n - 1);
    /* as the twin: ceil(RINGING_MIN_PERIODS * padded * period_s / span_s), left to right */
    const double lowest_bin = ceil(min_periods * (double)padded * period_s / span_s);
    if (!(lowest_bin < (double)(2 * n + 1))) goto none;
    const Py_ssize_t lowest = lowest_bin > 0.0 ? (Py_ssize_t)lowest_bin : 0;
    double power = 0.0;
    const Py_ssize_t best = largest_bin(packed, n, lowest, &power);
    if (best < 0) goto done;
    if (power < min_chi2 * white_var) goto none;
    const double hz = (double)best / ((double)padded * period_s);
    answer = Py_BuildValue("(dd)", power / (double)n, 1.0 / (hz * period_s));
    goto done;
none:
    answer = Py_NewRef(Py_None);
done:
    free(packed);
    PyBuffer_Release(&tb);
    PyBuffer_Release(&fb);
    return answer;
}

static PyMethodDef methods[] = {
    {"dwell_ringing", dwell_ringing, METH_VARARGS,
     "dwell_ringing(time_s, force_g, white_var_g2, min_samples, min_periods, min_chi2)\n"
     "-> (var_g2, period_samples) or None\n\n"
     "The dwell's strongest oscillation once a quadratic in time is taken out: the periodogram of the\n"
     "residual zero-padded to 4n, from min_periods periods per dwell up; None when fewer than\n"
     "min_samples samples (or 2), no white noise, no time span, or its power is under min_chi2 white\n"
     "variances (stage.py: dwell_ringing)."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_c_ringing",
                                    "The dwell's ringing (tapcell.tap.stage.dwell_ringing).", -1, methods,
                                    NULL, NULL, NULL, NULL};

PyMODINIT_FUNC PyInit__c_ringing(void) { return PyModule_Create(&module); }
