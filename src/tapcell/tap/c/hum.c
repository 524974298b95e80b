/* The mains hum's screen (tapcell.tap.hum._screen) in one call.
 *
 * The twin: the force's first differences (steps), the tap's own ramps cut out (steps beyond
 * step_sigmas robust sigmas, with `neighbours` either side, set to 0), zero-padded to the smallest
 * 2^a 3^b 5^c length >= twice their count and transformed by np.fft.rfft; per candidate line, the
 * power at its alias against the median power of the bins around it (the noise floor), and the
 * line's amplitude in noise sigmas from the same power.
 *
 * Here: the same steps, cuts, lengths, bins, guards and floors, bit for bit; only the powers are
 * computed another way, so they agree with the twin's to rounding:
 * - only the bins the screen reads (from the lowest floor band's first to the highest's last) of the
 *   length-L DFT of the steps, by Bluestein's chirp-z: jk = (j^2 + k^2 - (k-j)^2) / 2 turns the bins
 *   k0..k0+M-1 of the m steps into a linear convolution of m + M - 1 terms with the chirp
 *   e^(i pi s^2 / L), done by the power-of-two FFTs of fft.h (size >= m + M - 1, no prime factor of L
 *   to be slow on, and typically a third of the length rfft transforms);
 * - the chirp from the unit circle of fft.h, its indices s^2 mod 2L exact in integers; the circle is
 *   kept between calls for the last L (a printer's taps share a few lengths; the harmonics' screen
 *   reads the same L right after).
 * A decision (a line worth fitting or not) could differ from the twin's only when its ratio lies
 * within rounding of the bar: tests/tap/test_native_hum.py measures the margin on taplab and the
 * reference taps. Samples with a gap (not evenly spaced) read the line by one DFT at its frequency,
 * as the twin does (cos and sin from libm where numpy has its own: rounding again). */
#include "buffers.h"
#include "fft.h"
#include "median.h"
#include <math.h>
#include <stdlib.h>

/* The unit circle for the last chirp length: e^(i pi s / circle_half_turn), s < 2 circle_half_turn. */
static Complex *circle;
static Py_ssize_t circle_half_turn;

static int ensure_circle(Py_ssize_t half_turn)
{
    if (half_turn == circle_half_turn) return 0;
    Complex *table = malloc(sizeof(Complex) * (size_t)(2 * half_turn));
    if (table == NULL) {
        PyErr_NoMemory();
        return -1;
    }
    fill_circle(table, half_turn);
    free(circle);
    circle = table;
    circle_half_turn = half_turn;
    return 0;
}

/* The smallest 2^a 3^b 5^c >= at_least, as hum._fast_length finds it in its table (up to 2^24; past
 * that, at_least itself). */
static Py_ssize_t fast_length(Py_ssize_t at_least)
{
    const Py_ssize_t limit = (Py_ssize_t)1 << 24;
    Py_ssize_t best = -1;
    for (Py_ssize_t twos = 1; twos <= limit; twos *= 2)
        for (Py_ssize_t threes = twos; threes <= limit; threes *= 3)
            for (Py_ssize_t fives = threes; fives <= limit; fives *= 5)
                if (fives >= at_least && (best < 0 || fives < best)) best = fives;
    return best < 0 ? at_least : best;
}

/* power[q] = |X_(k0+q)|^2, q < count: the bins of the length-`length` DFT of x[0..m) zero-padded, by
 * the chirp-z convolution; -1 (MemoryError set) when out of memory. */
static int dft_power(const double *x, Py_ssize_t m, Py_ssize_t length, Py_ssize_t k0, Py_ssize_t count,
                     double *power)
{
    /* e^(i pi s^2 / length) = circle[stride (s^2 mod 2 length)]: fill_circle needs an even half turn */
    const Py_ssize_t stride = length % 2 ? 2 : 1, turn = 2 * length;
    if (ensure_circle(stride * length) < 0) return -1;
    const Py_ssize_t terms = m + count - 1, size = pow2_at_least(terms);
    if (ensure_twiddles(size) < 0) return -1;
    Complex *signal = malloc(sizeof(Complex) * (size_t)(2 * size));
    if (signal == NULL) {
        PyErr_NoMemory();
        return -1;
    }
    Complex *filter = signal + size;
    /* the steps times the conjugate chirp */
    for (Py_ssize_t j = 0; j < m; j++) {
        const Complex c = circle[stride * (Py_ssize_t)(((long long)j * j) % turn)];
        signal[j].re = x[j] * c.re;
        signal[j].im = -x[j] * c.im;
    }
    for (Py_ssize_t j = m; j < size; j++) signal[j].re = signal[j].im = 0.0;
    /* the chirp at k - j = d + k0 - (m - 1): y_q = (signal * filter)[q + m - 1] */
    for (Py_ssize_t d = 0; d < size; d++) {
        if (d < terms) {
            const Py_ssize_t s = d + k0 - (m - 1), a = s < 0 ? -s : s;
            filter[d] = circle[stride * (Py_ssize_t)(((long long)a * a) % turn)];
        } else {
            filter[d].re = filter[d].im = 0.0;
        }
    }
    fft_to_bit_reversed(signal, size);
    fft_to_bit_reversed(filter, size);
    for (Py_ssize_t i = 0; i < size; i++) {
        const Complex a = signal[i], b = filter[i];
        signal[i].re = a.re * b.re - a.im * b.im;
        signal[i].im = a.re * b.im + a.im * b.re;
    }
    inverse_fft_from_bit_reversed(signal, size);
    for (Py_ssize_t q = 0; q < count; q++) {
        const Py_ssize_t k = k0 + q;
        const Complex y = signal[q + m - 1], c = circle[stride * (Py_ssize_t)(((long long)k * k) % turn)];
        /* X_k = conj(chirp_k) y_q / size; its power */
        const double re = (y.re * c.re + y.im * c.im) / (double)size, im = (y.im * c.re - y.re * c.im) / (double)size;
        power[q] = re * re + im * im;
    }
    free(signal);
    return 0;
}

/* Where a line of frequency_hz shows when sampled at rate_sps (0..Nyquist): hum.alias_hz. */
static double alias_hz(double frequency_hz, double rate_sps)
{
    const double folded = fmod(frequency_hz, rate_sps);
    return folded < rate_sps - folded ? folded : rate_sps - folded;
}

typedef struct {
    double step_sigmas, band, mad_to_sigma;
    Py_ssize_t neighbours, min_half_band_bins, guard_bins, min_floor_bins;
} ScreenSettings;

/* The floor band of a candidate: bins [low, high) of the rfft's `bins`. */
static void floor_band(double at_bin, Py_ssize_t bins, const ScreenSettings *s, Py_ssize_t *low, Py_ssize_t *high)
{
    const double wide = s->band * at_bin, least = (double)(2 * s->min_half_band_bins);
    const double half_band = wide > least ? wide : least;
    const Py_ssize_t lo = (Py_ssize_t)(at_bin - half_band), hi = (Py_ssize_t)(at_bin + half_band) + 1;
    *low = lo > 0 ? lo : 0;
    *high = hi < bins ? hi : bins;
}

static PyObject *screen(PyObject *self, PyObject *args)
{
    (void)self;
    Py_buffer tb = {0}, fb = {0}, cb = {0};
    ScreenSettings s;
    if (!PyArg_ParseTuple(args, "O&O&O&dndnnnd", float64_buffer, &tb, float64_buffer, &fb, float64_buffer, &cb,
                          &s.step_sigmas, &s.neighbours, &s.band, &s.min_half_band_bins, &s.guard_bins,
                          &s.min_floor_bins, &s.mad_to_sigma))
        return NULL;
    PyObject *answer = NULL, *clear = NULL, *hum_to_noise = NULL;
    double *steps = NULL;
    Py_ssize_t n, lines;
    const double *force_g = doubles_of(&fb, &n, "force_g");
    const double *time_s = force_g ? doubles_sized(&tb, n, "time_s") : NULL;
    const double *candidates_hz = time_s ? doubles_of(&cb, &lines, "candidates_hz") : NULL;
    if (candidates_hz == NULL) goto done;
    if (n < 3) {
        PyErr_SetString(PyExc_ValueError, "screen: at least 3 samples");
        goto done;
    }
    if (!(time_s[n - 1] - time_s[0] > 0.0)) {
        PyErr_SetString(PyExc_ValueError, "screen: the samples span no time");
        goto done;
    }
    const Py_ssize_t m = n - 1, last = m - 1;
    if (m > PY_SSIZE_T_MAX / (Py_ssize_t)(8 * sizeof(Complex))) {
        PyErr_NoMemory();
        goto done;
    }
    /* steps, |steps| (the median's scratch), the cut marks, the bins read, the floor's scratch */
    const Py_ssize_t padded = fast_length(2 * m), bins = padded / 2 + 1;
    steps = malloc(sizeof(double) * (size_t)(3 * m + 2 * bins));
    if (steps == NULL) {
        PyErr_NoMemory();
        goto done;
    }
    double *scratch = steps + m, *cut = scratch + m, *power = cut + m, *band = power + bins;
    for (Py_ssize_t i = 0; i < m; i++) {
        steps[i] = force_g[i + 1] - force_g[i];
        scratch[i] = fabs(steps[i]);
    }
    const double step_sigma_g = s.mad_to_sigma * median_in_place(scratch, m);
    const double limit = s.step_sigmas * (step_sigma_g > 1e-12 ? step_sigma_g : 1e-12);
    for (Py_ssize_t i = 0; i < m; i++) cut[i] = 0.0;
    for (Py_ssize_t i = 0; i < m; i++) /* the ramps of the original steps, then cut */
        if (fabs(steps[i]) > limit) {
            const Py_ssize_t from = i - s.neighbours > 0 ? i - s.neighbours : 0;
            const Py_ssize_t to = i + s.neighbours < last ? i + s.neighbours : last;
            for (Py_ssize_t j = from; j <= to; j++) cut[j] = 1.0;
        }
    Py_ssize_t kept = 0;
    for (Py_ssize_t i = 0; i < m; i++) {
        if (cut[i] != 0.0) steps[i] = 0.0;
        kept += steps[i] != 0.0;
    }
    if (kept < 1) kept = 1;
    const double mean_rate_sps = (double)m / (time_s[n - 1] - time_s[0]);
    double widest_gap_s = time_s[1] - time_s[0];
    for (Py_ssize_t i = 1; i < m; i++)
        if (time_s[i + 1] - time_s[i] > widest_gap_s) widest_gap_s = time_s[i + 1] - time_s[i];
    const int evenly = widest_gap_s * mean_rate_sps < 1.5;
    const double bins_per_hz = (double)padded / mean_rate_sps;
    /* the bins read: every candidate's floor band (its line's two bins lie inside) */
    Py_ssize_t first = bins, end = 0;
    for (Py_ssize_t c = 0; c < lines; c++) {
        Py_ssize_t low, high;
        floor_band(alias_hz(candidates_hz[c], mean_rate_sps) * bins_per_hz, bins, &s, &low, &high);
        if (low < first) first = low;
        if (high > end) end = high;
    }
    if (end > first && dft_power(steps, m, padded, first, end - first, power + first) < 0) goto done;
    clear = PyTuple_New(lines);
    hum_to_noise = PyTuple_New(lines);
    if (clear == NULL || hum_to_noise == NULL) goto done;
    for (Py_ssize_t c = 0; c < lines; c++) {
        const double frequency = candidates_hz[c], at_bin = alias_hz(frequency, mean_rate_sps) * bins_per_hz;
        Py_ssize_t low, high, count = 0;
        floor_band(at_bin, bins, &s, &low, &high);
        for (Py_ssize_t k = low; k < high; k++) {
            /* left out: the bins around every candidate (the guard in bins of the unpadded length:
             * twice as many padded ones), DC and Nyquist */
            int guarded = k == 0 || k == bins - 1;
            for (Py_ssize_t g = 0; g < lines && !guarded; g++) {
                const Py_ssize_t at = (Py_ssize_t)(alias_hz(candidates_hz[g], mean_rate_sps) * bins_per_hz);
                const Py_ssize_t start = at - 2 * s.guard_bins > 0 ? at - 2 * s.guard_bins : 0;
                guarded = start <= k && k < at + 2 * s.guard_bins + 2;
            }
            if (!guarded) band[count++] = power[k];
        }
        double clear_value = INFINITY, ratio = INFINITY;
        if (count >= 2 * s.min_floor_bins) {
            const double mean_floor = median_in_place(band, count) / log(2.0);
            const Py_ssize_t at = (Py_ssize_t)at_bin, next = at + 1 < bins - 1 ? at + 1 : bins - 1;
            double line_power;
            if (evenly) {
                line_power = power[at] > power[next] ? power[at] : power[next];
            } else { /* one DFT at the line's own frequency, over the samples' times */
                double in_phase = 0.0, quadrature = 0.0;
                for (Py_ssize_t i = 0; i < m; i++) {
                    const double angle = 2.0 * M_PI * frequency * (time_s[i + 1] - time_s[1]);
                    in_phase += steps[i] * cos(angle);
                    quadrature += steps[i] * sin(angle);
                }
                line_power = in_phase * in_phase + quadrature * quadrature;
            }
            if (mean_floor > 0.0) clear_value = 2.0 * line_power / mean_floor;
            const double step_gain = 2.0 * sin(M_PI * at_bin / (double)padded);
            const double amplitude_g = 2.0 * sqrt(line_power) / (double)kept / (step_gain > 1e-12 ? step_gain : 1e-12);
            const double noise_g = step_sigma_g / sqrt(2.0);
            if (noise_g > 0.0) ratio = amplitude_g / noise_g;
        }
        PyObject *a = PyFloat_FromDouble(clear_value), *b = PyFloat_FromDouble(ratio);
        if (a == NULL || b == NULL) {
            Py_XDECREF(a);
            Py_XDECREF(b);
            goto done;
        }
        PyTuple_SET_ITEM(clear, c, a);
        PyTuple_SET_ITEM(hum_to_noise, c, b);
    }
    answer = PyTuple_Pack(2, clear, hum_to_noise);
done:
    Py_XDECREF(clear);
    Py_XDECREF(hum_to_noise);
    free(steps);
    PyBuffer_Release(&tb);
    PyBuffer_Release(&fb);
    PyBuffer_Release(&cb);
    return answer;
}

static PyMethodDef methods[] = {
    {"screen", screen, METH_VARARGS,
     "screen(time_s, force_g, candidates_hz, step_sigmas, neighbours, band, min_half_band_bins, guard_bins,\n"
     "       min_floor_bins, mad_to_sigma) -> (clear, hum_to_noise)\n\n"
     "Per candidate line: the power at its alias in the tap's steps against the median of the bins around\n"
     "it (chi2 units), and its amplitude in noise sigmas; inf where the floor has too few bins\n"
     "(hum.py: _screen)."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_c_hum", "The mains hum's screen (tapcell.tap.hum._screen).",
                                    -1, methods, NULL, NULL, NULL, NULL};

PyMODINIT_FUNC PyInit__c_hum(void) { return PyModule_Create(&module); }
