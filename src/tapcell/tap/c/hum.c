/* The mains hum's screen (tapcell.tap.hum._screen) in one call, and the exact parts of its fit.
 *
 * The screen's twin: the force's first differences (steps), the tap's own ramps cut out (steps beyond
 * step_sigmas robust sigmas, with `neighbours` either side, set to 0), zero-padded to the smallest
 * 2^a 3^b 5^c length >= twice their count and transformed by np.fft.rfft; per candidate line, the
 * power at its alias against the median power of the bins around it (the noise floor), and the
 * line's amplitude in noise sigmas from the same power.
 *
 * Here: the same steps, cuts, lengths, bins, guards and floors, bit for bit; only the powers come from
 * another FFT, so they agree with the twin's to rounding: fft.h's mixed-radix FFT of half the padded
 * length over the steps packed in pairs (numpy runs pocketfft's real FFT of the whole length), its twiddles
 * from a unit circle kept between calls for the last length (a printer's taps share a few lengths; the
 * harmonics' screen reads the same length right after), and only the bins the screen reads are
 * unpacked. A decision (a line worth fitting or not) could differ from the twin's only when its ratio
 * lies within rounding of the bar: tests/tap/test_native_hum.py gives the margins measured on taplab
 * and the reference taps. Samples with a gap (not evenly spaced) read the line by one DFT at its
 * frequency, as the twin does (cos and sin from libm where numpy has its own: rounding again).
 *
 * The fit's exact parts (hat_spline, normal_equations, spline_knots, corner_windows) repeat their twins'
 * arithmetic in the same order: bit for bit. The rest of the fit (the sinusoids, the solves and the
 * matrix products) stays in numpy: LAPACK's and BLAS's order of operations cannot be repeated here,
 * and a last-bit change in the hum moves a printed digit of some tap's output. */
#include "buffers.h"
#include "fft.h"
#include "median.h"
#include "sum.h"
#include <math.h>
#include <stdint.h>
#include <stdlib.h>

/* The unit circle for the last padded length's twiddles: e^(i pi s / circle_half_turn), s < 2 circle_half_turn. */
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

/* power[q] = |X_(k0+q)|^2, q < count, k0 + count <= length / 2 + 1: bins of the length-`length` DFT of
 * x[0..m) zero-padded (m <= length, length 2^a 3^b 5^c). Even length: the samples packed in pairs,
 * z_j = x_2j + i x_2j+1, one complex FFT of half the length, and X_k = E_k + W^k O_k with E, O the even
 * and odd samples' DFTs (from Z_k and conj Z_(N-k)); odd length: one complex FFT of the samples. -1 with
 * an exception set on failure. */
static int real_dft_power(const double *x, Py_ssize_t m, Py_ssize_t length, Py_ssize_t k0, Py_ssize_t count,
                          double *power)
{
    Py_ssize_t radices[64];
    const int even = length % 2 == 0;
    const Py_ssize_t n = even ? length / 2 : length;
    if (mixed_radices(n, radices) == 0) {
        PyErr_Format(PyExc_ValueError, "screen: %zd is no product of 2, 3 and 5", n);
        return -1;
    }
    /* W_length^t = conj(circle[step t]) on the smallest circle fill_circle makes (an even half turn) that
     * holds every length-th of a turn: half turn length / 2, else length, else (odd) 2 length */
    const Py_ssize_t half_turn = length % 4 == 0 ? length / 2 : even ? length : 2 * length;
    const Py_ssize_t step = 2 * half_turn / length;
    if (ensure_circle(half_turn) < 0) return -1;
    Complex *z = malloc(sizeof(Complex) * (size_t)(2 * n));
    if (z == NULL) {
        PyErr_NoMemory();
        return -1;
    }
    Complex *spectrum = z + n;
    for (Py_ssize_t j = 0; j < n; j++) {
        const Py_ssize_t first = even ? 2 * j : j;
        z[j].re = first < m ? x[first] : 0.0;
        z[j].im = even && first + 1 < m ? x[first + 1] : 0.0;
    }
    mixed_fft(z, 1, spectrum, n, radices, circle, even ? 2 * step : step);
    for (Py_ssize_t q = 0; q < count; q++) {
        const Py_ssize_t k = k0 + q;
        Complex bin = spectrum[k % n];
        if (even) { /* E = (Z_k + conj Z_(N-k)) / 2, O = -i (Z_k - conj Z_(N-k)) / 2, X = E + W^k O */
            const Complex zk = spectrum[k % n], zc = spectrum[(n - k % n) % n];
            const double er = 0.5 * (zk.re + zc.re), ei = 0.5 * (zk.im - zc.im);
            const double o_re = 0.5 * (zk.im + zc.im), o_im = -0.5 * (zk.re - zc.re);
            const Complex w = circle[k * step];
            const double wr = w.re, wi = -w.im;
            bin.re = er + (o_re * wr - o_im * wi);
            bin.im = ei + (o_re * wi + o_im * wr);
        }
        power[q] = bin.re * bin.re + bin.im * bin.im;
    }
    free(z);
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
    Py_ssize_t padded;
    if (!PyArg_ParseTuple(args, "O&O&O&ndndnnnd", float64_buffer, &tb, float64_buffer, &fb, float64_buffer, &cb,
                          &padded, &s.step_sigmas, &s.neighbours, &s.band, &s.min_half_band_bins, &s.guard_bins,
                          &s.min_floor_bins, &s.mad_to_sigma))
        return NULL;
    PyObject *answer = NULL, *clear = NULL, *hum_to_noise = NULL;
    double *steps = NULL;
    Py_ssize_t n, lines;
    const double *force_g = doubles_of(&fb, &n, "force_g");
    const double *time_s = force_g ? doubles_sized(&tb, n, "time_s") : NULL;
    const double *candidates_hz = time_s ? doubles_of(&cb, &lines, "candidates_hz") : NULL;
    if (candidates_hz == NULL) goto done;
    if (n < 2) {
        PyErr_SetString(PyExc_ValueError, "screen: at least 2 samples");
        goto done;
    }
    if (!(time_s[n - 1] - time_s[0] > 0.0)) {
        PyErr_SetString(PyExc_ValueError, "screen: the samples span no time");
        goto done;
    }
    if (n == 2) { /* one step: a floor of 2 bins, too few for any line (as the twin finds) */
        clear = PyTuple_New(lines);
        hum_to_noise = PyTuple_New(lines);
        if (clear == NULL || hum_to_noise == NULL) goto done;
        for (Py_ssize_t c = 0; c < lines; c++) {
            PyObject *a = PyFloat_FromDouble(INFINITY), *b = PyFloat_FromDouble(INFINITY);
            PyTuple_SET_ITEM(clear, c, a); /* a NULL item is allowed in a tuple being discarded */
            PyTuple_SET_ITEM(hum_to_noise, c, b);
            if (a == NULL || b == NULL) goto done;
        }
        answer = PyTuple_Pack(2, clear, hum_to_noise);
        goto done;
    }
    const Py_ssize_t m = n - 1, last = m - 1;
    if (m > PY_SSIZE_T_MAX / (Py_ssize_t)(8 * sizeof(Complex))) {
        PyErr_NoMemory();
        goto done;
    }
    /* steps, |steps| (the median's scratch), the cut marks, the bins read, the floor's scratch */
    /* At most 4m: the twin's length (the next 2^a 3^b 5^c from 2m: a power of two lies below 4m) and
     * the bound that keeps the scratch's size from overflowing. */
    if (padded < 2 * m || padded > 4 * m) {
        PyErr_Format(PyExc_ValueError, "screen: padded length %zd, from %zd to %zd allowed", padded, 2 * m, 4 * m);
        goto done;
    }
    const Py_ssize_t bins = padded / 2 + 1;
    steps = malloc(sizeof(double) * (size_t)(3 * m + 2 * bins) + sizeof(Py_ssize_t) * (size_t)(lines + 1));
    if (steps == NULL) {
        PyErr_NoMemory();
        goto done;
    }
    double *scratch = steps + m, *cut = scratch + m, *power = cut + m, *band = power + bins;
    Py_ssize_t *line_bins = (Py_ssize_t *)(band + bins); /* each candidate's bin, int(at_bin) */
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
        const double at_bin = alias_hz(candidates_hz[c], mean_rate_sps) * bins_per_hz;
        line_bins[c] = (Py_ssize_t)at_bin;
        floor_band(at_bin, bins, &s, &low, &high);
        if (low < first) first = low;
        if (high > end) end = high;
    }
    if (end > first && real_dft_power(steps, m, padded, first, end - first, power + first) < 0) goto done;
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
                const Py_ssize_t start = line_bins[g] - 2 * s.guard_bins > 0 ? line_bins[g] - 2 * s.guard_bins : 0;
                guarded = start <= k && k < line_bins[g] + 2 * s.guard_bins + 2;
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

/* A writable buffer of exactly `count` items of `itemsize` bytes (the caller's np.empty), else NULL with
 * a ValueError naming it. */
static void *items_sized(Py_buffer *buffer, Py_ssize_t count, Py_ssize_t itemsize, const char *name)
{
    if (buffer->len != count * itemsize) {
        PyErr_Format(PyExc_ValueError, "%s: %zd bytes, %zd expected", name, buffer->len, count * itemsize);
        return NULL;
    }
    return buffer->buf;
}

/* hum.hat_spline: per sample, the knot left of it and its share of the next, bit for bit (the knots
 * sorted, at least two). */
static PyObject *hat_spline(PyObject *self, PyObject *args)
{
    (void)self;
    Py_buffer tb = {0}, kb = {0}, left_buffer = {0}, share_buffer = {0};
    if (!PyArg_ParseTuple(args, "O&O&w*w*", float64_buffer, &tb, float64_buffer, &kb, &left_buffer, &share_buffer))
        return NULL;
    PyObject *answer = NULL;
    Py_ssize_t n, count;
    const double *time_s = doubles_of(&tb, &n, "time_s");
    const double *knots_s = time_s ? doubles_of(&kb, &count, "knots_s") : NULL;
    int64_t *left = knots_s ? items_sized(&left_buffer, n, sizeof(int64_t), "left") : NULL;
    double *share = left ? items_sized(&share_buffer, n, sizeof(double), "share") : NULL;
    if (share == NULL) goto done;
    if (count < 2) {
        PyErr_SetString(PyExc_ValueError, "hat_spline: at least two knots");
        goto done;
    }
    for (Py_ssize_t i = 0; i < n; i++) {
        /* np.searchsorted(knots, t, side="right"): the knots at or before t, clipped to 1..count-1 */
        Py_ssize_t low = 0, high = count;
        while (low < high) {
            const Py_ssize_t middle = low + (high - low) / 2;
            if (knots_s[middle] <= time_s[i]) low = middle + 1;
            else high = middle;
        }
        const Py_ssize_t right = low < 1 ? 1 : low > count - 1 ? count - 1 : low;
        const double part = (time_s[i] - knots_s[right - 1]) / (knots_s[right] - knots_s[right - 1]);
        left[i] = right - 1;
        share[i] = part < 0.0 ? 0.0 : part > 1.0 ? 1.0 : part;
    }
    answer = Py_NewRef(Py_None);
done:
    PyBuffer_Release(&tb);
    PyBuffer_Release(&kb);
    PyBuffer_Release(&left_buffer);
    PyBuffer_Release(&share_buffer);
    return answer;
}


/* hum.HatSpline.normal_equations, bit for bit: the spline's gram under the weights (dense, its ridge on
 * the diagonal) and its sums per knot of the weighted force and of each weighted wave column, each
 * sum per knot taken as np.bincount takes it (sample by sample) and the halves added as the twin adds
 * them. */
static PyObject *normal_equations(PyObject *self, PyObject *args)
{
    (void)self;
    Py_buffer lb = {0}, sb = {0}, wb = {0}, fb = {0}, vb = {0}, gb = {0}, pb = {0};
    Py_ssize_t count, columns;
    if (!PyArg_ParseTuple(args, "y*O&O&O&O&nnw*w*", &lb, float64_buffer, &sb, float64_buffer, &wb, float64_buffer,
                          &fb, float64_buffer, &vb, &count, &columns, &gb, &pb))
        return NULL;
    PyObject *answer = NULL;
    double *sums = NULL;
    Py_ssize_t n;
    const double *share = doubles_of(&sb, &n, "share");
    const int64_t *left = share ? items_sized(&lb, n, sizeof(int64_t), "left") : NULL;
    const double *weight = left ? doubles_sized(&wb, n, "weight") : NULL;
    const double *force_g = weight ? doubles_sized(&fb, n, "force_g") : NULL;
    const double *waves = force_g && columns >= 0 && count >= 2 ? doubles_sized(&vb, n * columns, "waves") : NULL;
    double *gram = waves ? items_sized(&gb, count * count, sizeof(double), "gram") : NULL;
    double *per_knot = gram ? items_sized(&pb, count * (columns + 1), sizeof(double), "per_knot") : NULL;
    if (per_knot == NULL) {
        if (!PyErr_Occurred()) PyErr_SetString(PyExc_ValueError, "normal_equations: at least two knots");
        goto done;
    }
    for (Py_ssize_t i = 0; i < n; i++)
        if (left[i] < 0 || left[i] >= count - 1) {
            PyErr_Format(PyExc_ValueError, "normal_equations: left[%zd] = %lld outside 0..%zd", i, (long long)left[i],
                         count - 2);
            goto done;
        }
    /* per knot: the gram's two diagonal halves and its neighbour term, then each column's two halves */
    const Py_ssize_t width = 2 * (columns + 1);
    sums = calloc((size_t)(count * (3 + width)), sizeof(double));
    if (sums == NULL) {
        PyErr_NoMemory();
        goto done;
    }
    double *diagonal_low = sums, *diagonal_high = sums + count, *beside = sums + 2 * count, *halves = sums + 3 * count;
    for (Py_ssize_t i = 0; i < n; i++) {
        const Py_ssize_t k = (Py_ssize_t)left[i];
        const double low = 1.0 - share[i], high = share[i], w = weight[i];
        diagonal_low[k] += w * low * low;
        diagonal_high[k + 1] += w * high * high;
        beside[k] += w * low * high;
        const double weighted = w * force_g[i];
        halves[k * width] += low * weighted;
        halves[(k + 1) * width + 1] += high * weighted;
        for (Py_ssize_t c = 0; c < columns; c++) {
            const double used = waves[i * columns + c] * w;
            halves[k * width + 2 * (c + 1)] += low * used;
            halves[(k + 1) * width + 2 * (c + 1) + 1] += high * used;
        }
    }
    for (Py_ssize_t k = 0; k < count * count; k++) gram[k] = 0.0;
    for (Py_ssize_t k = 0; k < count; k++) {
        gram[k * count + k] = diagonal_low[k] + diagonal_high[k];
        if (k + 1 < count) gram[k * count + k + 1] = gram[(k + 1) * count + k] = beside[k];
        for (Py_ssize_t c = 0; c <= columns; c++)
            per_knot[k * (columns + 1) + c] = halves[k * width + 2 * c] + halves[k * width + 2 * c + 1];
    }
    /* the ridge: 1e-10 of the mean diagonal (np.trace's sum), that mean at least 1e-300 */
    const double mean_diagonal = numpy_sum(gram, count, count + 1) / (double)count;
    const double ridge = 1e-10 * (mean_diagonal > 1e-300 ? mean_diagonal : 1e-300);
    for (Py_ssize_t k = 0; k < count; k++) gram[k * count + k] += ridge;
    answer = Py_NewRef(Py_None);
done:
    free(sums);
    PyBuffer_Release(&lb);
    PyBuffer_Release(&sb);
    PyBuffer_Release(&wb);
    PyBuffer_Release(&fb);
    PyBuffer_Release(&vb);
    PyBuffer_Release(&gb);
    PyBuffer_Release(&pb);
    return answer;
}

/* hum.spline_knots, bit for bit: the uniform grid, a grid knot closer than a tenth of the spacing to a
 * corner dropped (the ends stay), the corners inside, sorted and without repeats; their count. */
static int ascending(const void *a, const void *b)
{
    const double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

static PyObject *spline_knots(PyObject *self, PyObject *args)
{
    (void)self;
    double first, last, spacing;
    Py_buffer cb = {0}, ob = {0};
    if (!PyArg_ParseTuple(args, "dddO&w*", &first, &last, &spacing, float64_buffer, &cb, &ob)) return NULL;
    PyObject *answer = NULL;
    Py_ssize_t corner_count, room;
    const double *corners_s = doubles_of(&cb, &corner_count, "corners_s");
    double *knots = corners_s ? (double *)doubles_of(&ob, &room, "knots") : NULL;
    if (knots == NULL) goto done;
    const double cells = ceil((last - first) / spacing);
    if (!(cells < 1e9) || !(spacing > 0.0)) {
        PyErr_SetString(PyExc_ValueError, "spline_knots: the span over the spacing is no count of knots");
        goto done;
    }
    const Py_ssize_t grid = cells > 1.0 ? (Py_ssize_t)cells : 1;
    if (room < grid + 1 + corner_count) {
        PyErr_Format(PyExc_ValueError, "knots: room for %zd, %zd needed", room, grid + 1 + corner_count);
        goto done;
    }
    Py_ssize_t used = 0;
    for (Py_ssize_t k = 0; k <= grid; k++) {
        const double knot = first + (last - first) * (double)k / (double)grid;
        int near = 0;
        for (Py_ssize_t c = 0; c < corner_count && k > 0 && k < grid; c++)
            if (first < corners_s[c] && corners_s[c] < last && isfinite(corners_s[c]))
                near |= fabs(knot - corners_s[c]) < 0.1 * spacing;
        if (!near) knots[used++] = knot;
    }
    for (Py_ssize_t c = 0; c < corner_count; c++)
        if (first < corners_s[c] && corners_s[c] < last && isfinite(corners_s[c])) knots[used++] = corners_s[c];
    qsort(knots, (size_t)used, sizeof(double), ascending);
    Py_ssize_t distinct = used > 0 ? 1 : 0;
    for (Py_ssize_t k = 1; k < used; k++)
        if (knots[k] != knots[distinct - 1]) knots[distinct++] = knots[k];
    answer = PyLong_FromSsize_t(distinct);
done:
    PyBuffer_Release(&cb);
    PyBuffer_Release(&ob);
    return answer;
}

/* analysis._corner_windows, bit for bit: the samples whose conversion window (a margin either side)
 * holds one of the (finite) corners, as bytes 0/1 into a bool array. */
static PyObject *corner_windows(PyObject *self, PyObject *args)
{
    (void)self;
    Py_buffer tb = {0}, cb = {0}, ob = {0};
    double delay_s, integration_s, margin_s;
    if (!PyArg_ParseTuple(args, "O&O&dddw*", float64_buffer, &tb, float64_buffer, &cb, &delay_s, &integration_s,
                          &margin_s, &ob))
        return NULL;
    PyObject *answer = NULL;
    Py_ssize_t n, corner_count;
    const double *time_s = doubles_of(&tb, &n, "time_s");
    const double *corners_s = time_s ? doubles_of(&cb, &corner_count, "corners_s") : NULL;
    unsigned char *inside = corners_s ? items_sized(&ob, n, 1, "exclude") : NULL;
    if (inside == NULL) goto done;
    for (Py_ssize_t i = 0; i < n; i++) {
        const double start_s = time_s[i] - delay_s - integration_s - margin_s, end_s = time_s[i] - delay_s + margin_s;
        unsigned char holds = 0;
        for (Py_ssize_t c = 0; c < corner_count; c++)
            holds |= isfinite(corners_s[c]) && start_s <= corners_s[c] && corners_s[c] <= end_s;
        inside[i] = holds;
    }
    answer = Py_NewRef(Py_None);
done:
    PyBuffer_Release(&tb);
    PyBuffer_Release(&cb);
    PyBuffer_Release(&ob);
    return answer;
}

static PyMethodDef methods[] = {
    {"screen", screen, METH_VARARGS,
     "screen(time_s, force_g, candidates_hz, padded, step_sigmas, neighbours, band, min_half_band_bins,\n"
     "       guard_bins, min_floor_bins, mad_to_sigma) -> (clear, hum_to_noise)\n\n"
     "Per candidate line: the power at its alias in the tap's steps against the median of the bins around\n"
     "it (chi2 units), and its amplitude in noise sigmas; inf where the floor has too few bins\n"
     "(hum.py: _screen). padded: the DFT's length, hum._fast_length of twice the steps."},
    {"hat_spline", hat_spline, METH_VARARGS,
     "hat_spline(time_s, knots_s, left_out, share_out)\n\n"
     "Per sample the knot left of it (int64) and its share of the next, as hum.hat_spline computes them."},
    {"normal_equations", normal_equations, METH_VARARGS,
     "normal_equations(left, share, weight, force_g, waves, count, columns, gram_out, per_knot_out)\n\n"
     "The hat spline's gram under the weights (dense, with its ridge) and its sums per knot of the weighted\n"
     "force and wave columns, bit for bit as hum.HatSpline.normal_equations computes them."},
    {"spline_knots", spline_knots, METH_VARARGS,
     "spline_knots(t_first_s, t_last_s, spacing_s, corners_s, knots_out) -> count\n\n"
     "The knots of hum.spline_knots into knots_out (room for the grid and every corner), bit for bit."},
    {"corner_windows", corner_windows, METH_VARARGS,
     "corner_windows(time_s, corners_s, delay_s, integration_s, margin_s, exclude_out)\n\n"
     "analysis._corner_windows into a bool array."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_c_hum", "The mains hum's screen and the exact parts of its fit (tapcell.tap.hum).",
                                    -1, methods, NULL, NULL, NULL, NULL};

PyMODINIT_FUNC PyInit__c_hum(void) { return PyModule_Create(&module); }
