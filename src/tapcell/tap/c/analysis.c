/* The robust statistics, checks and window heights of the tap analysis (numpy twins:
 * tapcell/tap/robust.py `median`; tapcell/tap/analysis.py `noise_sigma_g`, `repair_spikes`,
 * `model_window`, `_check_samples`, the robust pass and `near_contact_sigma_g` of `fit_pullback`,
 * `compression_sample_count`).
 *
 * Each is a handful of numpy calls on a few hundred samples, run several times a tap: numpy's
 * per-call cost, not the arithmetic, is what they spend. The arithmetic here is the twins', in
 * the same order, so the answers are the same to the last bit (a median selects, it does not sum).
 */
#include "buffers.h" /* first: Python.h sets the feature macros the C library headers read */

#include <float.h>
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "clones.h"
#include "median.h"

/* The median absolute deviation of normal noise times this is its sigma (robust.MAD_TO_SIGMA). */
#define MAD_TO_SIGMA 1.4826


/* |f[i+1] - (f[i] + f[i+2]) / 2| for i in [0, n - 2): how far each inner sample stands off the
 * midpoint of its neighbours (the twin's expression, term for term). */
static void off_midpoints(const double *force_g, Py_ssize_t n, double *off_mid)
{
    for (Py_ssize_t i = 0; i + 2 < n; i++)
        off_mid[i] = fabs(force_g[i + 1] - 0.5 * (force_g[i] + force_g[i + 2]));
}

/* White-noise sigma from off-midpoints: their robust sigma over sqrt(1.5), the median read as
 * grouped data where coarse readings put them on a lattice (`grouped_median`). Reorders them. */
static double noise_of_off_midpoints(double *off_mid, Py_ssize_t count)
{
    const double median = median_in_place(off_mid, count);
    return MAD_TO_SIGMA * grouped_median(off_mid, count, median) / sqrt(1.5);
}

static PyObject *median(PyObject *self, PyObject *args)
{
    (void)self;
    Py_buffer buffer;
    if (!PyArg_ParseTuple(args, "O&", float64_buffer, &buffer)) return NULL;
    Py_ssize_t n;
    const double *values = doubles_of(&buffer, &n, "values");
    PyObject *answer = NULL;
    if (values != NULL && n == 0) {
        PyErr_SetString(PyExc_ValueError, "values: the median of no values");
    } else if (values != NULL) {
        double *scratch = malloc((size_t)n * sizeof(double));
        if (scratch == NULL) {
            PyErr_NoMemory();
        } else {
            memcpy(scratch, values, (size_t)n * sizeof(double));
            answer = PyFloat_FromDouble(median_in_place(scratch, n));
            free(scratch);
        }
    }
    PyBuffer_Release(&buffer);
    return answer;
}

static PyObject *noise_sigma(PyObject *self, PyObject *args)
{
    (void)self;
    Py_buffer buffer;
    if (!PyArg_ParseTuple(args, "O&", float64_buffer, &buffer)) return NULL;
    Py_ssize_t n;
    const double *force_g = doubles_of(&buffer, &n, "force_g");
    PyObject *answer = NULL;
    if (force_g != NULL && n < 3) {
        answer = PyFloat_FromDouble(0.0);
    } else if (force_g != NULL) {
        double *off_mid = malloc((size_t)(n - 2) * sizeof(double));
        if (off_mid == NULL) {
            PyErr_NoMemory();
        } else {
            off_midpoints(force_g, n, off_mid);
            answer = PyFloat_FromDouble(noise_of_off_midpoints(off_mid, n - 2));
            free(off_mid);
        }
    }
    PyBuffer_Release(&buffer);
    return answer;
}

/* How far value lies outside the span of reach[0..count) (negative inside it): the twin's `_outside_g`. */
static double outside_g(double value, const double *reach, int count)
{
    double lowest = reach[0], highest = reach[0];
    for (int i = 1; i < count; i++) {
        if (reach[i] > highest) highest = reach[i];
        if (reach[i] < lowest) lowest = reach[i];
    }
    double above = value - highest, below = lowest - value;
    return above > below ? above : below;
}

/* How far sample k stands out when it is a lone spike, else 0 (`_lone_spike_g`). */
static double lone_spike_g(const double *f, Py_ssize_t n, Py_ssize_t k, double threshold)
{
    double before = f[k - 1], after = f[k + 1];
    double off_mid = fabs(f[k] - 0.5 * (before + after)); /* again: a neighbour may have been repaired */
    if (!(off_mid > threshold)) return 0.0;
    if (off_mid > 2.0 * fabs(after - before)) return off_mid;
    if (k < 2 || k > n - 3) return 0.0;
    double reach[4] = {before, after, 2.0 * before - f[k - 2], 2.0 * after - f[k + 2]};
    double out_g = outside_g(f[k], reach, 4);
    return out_g > threshold ? out_g : 0.0;
}

/* How far the farther of samples k and k + 1 stands out when both lie outside what the samples on
 * either side reach and every value the four samples on either side take, else 0 (`_spike_pair_g`). */
#define PAIR_SPAN_SAMPLES 4 /* analysis.PAIR_SPAN_SAMPLES */

static double spike_pair_g(const double *f, Py_ssize_t n, Py_ssize_t k, double threshold)
{
    double before = f[k - 1], after = f[k + 2];
    double reach[6 + 2 * PAIR_SPAN_SAMPLES] = {before, after, 2.0 * before - f[k - 2], 3.0 * before - 2.0 * f[k - 2],
                                              2.0 * after - f[k + 3], 3.0 * after - 2.0 * f[k + 3]};
    int count = 6;
    for (Py_ssize_t j = k - PAIR_SPAN_SAMPLES; j < k; j++)
        if (j >= 0) reach[count++] = f[j];
    for (Py_ssize_t j = k + 2; j < k + 2 + PAIR_SPAN_SAMPLES && j < n; j++) reach[count++] = f[j];
    double first_g = outside_g(f[k], reach, count), second_g = outside_g(f[k + 1], reach, count);
    if (first_g > threshold && second_g > threshold) return first_g > second_g ? first_g : second_g;
    return 0.0;
}

#define CREDIBLE_NOISE_SHARE 0.1 /* the twin's analysis.CREDIBLE_NOISE_SHARE */

/* What replaces a lone spike at k (width 1: its neighbours' mean, or at a corner the value both
 * sides' lines carry on to) or a pair at k, k + 1 (width 2: the line between the samples bracketing
 * it), into values (`_repaired_values`). */
static void repaired_values(const double *f, Py_ssize_t n, Py_ssize_t k, Py_ssize_t width, double threshold,
                            double values[2])
{
    if (width == 1) {
        const double middle = 0.5 * (f[k - 1] + f[k + 1]);
        values[0] = middle;
        if (k >= 2 && k <= n - 3) {
            const double from_before = 2.0 * f[k - 1] - f[k - 2], from_after = 2.0 * f[k + 1] - f[k + 2];
            const double corner = 0.5 * (from_before + from_after), off_g = fabs(middle - corner);
            if (off_g > threshold && fabs(from_before - from_after) < off_g) values[0] = corner;
        }
    } else {
        const double gap = f[k + 2] - f[k - 1];
        values[0] = f[k - 1] + gap / 3.0;
        values[1] = f[k - 1] + 2.0 * gap / 3.0;
    }
}

/* The sum of |second differences| at samples lo..hi with the spike at k (width samples) repaired
 * (`_roughness_repaired`). */
static double roughness_repaired(const double *f, Py_ssize_t n, Py_ssize_t k, Py_ssize_t width, Py_ssize_t lo,
                                 Py_ssize_t hi, double threshold)
{
    double values[2];
    repaired_values(f, n, k, width, threshold, values);
    double window[7]; /* samples lo - 1 .. hi + 1: at most the five about k and one either side */
    const Py_ssize_t count = hi - lo + 3;
    for (Py_ssize_t i = 0; i < count; i++) {
        const Py_ssize_t at = lo - 1 + i;
        window[i] = at >= k && at < k + width ? values[at - k] : f[at];
    }
    double sum = 0.0;
    for (Py_ssize_t i = 1; i + 1 < count; i++) sum += fabs(window[i - 1] - 2.0 * window[i] + window[i + 1]);
    return sum;
}

/* Of the lone spike k, a neighbour that stands out as a lone spike too and the pair of the two when
 * it stands out as a pair, the repair that leaves the five samples about k smoother
 * (`_frame_among_neighbours`): its first sample into *first, its width returned. */
static Py_ssize_t frame_among_neighbours(const double *f, Py_ssize_t n, Py_ssize_t k, const char *spike,
                                         double threshold, Py_ssize_t *first)
{
    const Py_ssize_t lo = k - 2 > 1 ? k - 2 : 1, hi = k + 2 < n - 2 ? k + 2 : n - 2;
    Py_ssize_t best = k, best_width = 1;
    double best_roughness = roughness_repaired(f, n, k, 1, lo, hi, threshold);
    for (Py_ssize_t j = k - 1; j <= k + 1; j += 2) {
        if (j < 1 || j > n - 2 || spike[j]) continue;
        Py_ssize_t starts[2], widths[2];
        int options = 0;
        if (lone_spike_g(f, n, j, threshold) > 0.0) {
            starts[options] = j;
            widths[options++] = 1;
        }
        const Py_ssize_t pair = j < k ? j : k;
        if (pair >= 2 && pair <= n - 4 && spike_pair_g(f, n, pair, threshold) > 0.0) {
            starts[options] = pair;
            widths[options++] = 2;
        }
        for (int o = 0; o < options; o++) {
            const double roughness = roughness_repaired(f, n, starts[o], widths[o], lo, hi, threshold);
            if (roughness < best_roughness) {
                best = starts[o];
                best_width = widths[o];
                best_roughness = roughness;
            }
        }
    }
    *first = best;
    return best_width;
}

static int is_step(const double *force_g, Py_ssize_t i, double threshold)
{
    return fabs(force_g[i + 1] - force_g[i]) > threshold;
}

/* The twin's loop: candidates are the samples off their neighbours' midpoint and the pairs between
 * two steps (both found once, in the force as given, as the twin's lists); the one that stands out
 * the most is repaired first in f (a copy of force_g; or, with weigh_neighbours, the neighbour whose
 * repair leaves the samples smoother), the rest judged again, until none stands out. spike marks the repaired samples; returns their count, or -1 (MemoryError set). */
static Py_ssize_t repair_in_copy(const double *force_g, double *f, char *spike, Py_ssize_t n, const double *off_mid,
                                 double threshold, int weigh_neighbours)
{
    Py_ssize_t *suspects = malloc(2 * (size_t)n * sizeof(Py_ssize_t));
    if (suspects == NULL) {
        PyErr_NoMemory();
        return -1;
    }
    Py_ssize_t *pairs = suspects + n, suspect_count = 0, pair_count = 0;
    for (Py_ssize_t k = 1; k + 1 < n; k++) {
        suspects[suspect_count] = k;
        suspect_count += off_mid[k - 1] > threshold;
    }
    for (Py_ssize_t k = 2; k <= n - 4; k++) {
        pairs[pair_count] = k;
        pair_count += is_step(force_g, k - 1, threshold) && is_step(force_g, k + 1, threshold);
    }
    /* and too many standing out make the noise estimate no measure to weigh against (the twin's
     * CREDIBLE_NOISE_SHARE) */
    weigh_neighbours = weigh_neighbours && (double)suspect_count <= CREDIBLE_NOISE_SHARE * (double)n;
    memcpy(f, force_g, (size_t)n * sizeof(double));
    memset(spike, 0, (size_t)n);
    Py_ssize_t count = 0;
    for (;;) {
        double best_g = 0.0;
        Py_ssize_t best_k = 0, best_width = 0;
        for (Py_ssize_t j = 0; j < suspect_count; j++) { /* the twin's order: every lone suspect, then every pair */
            Py_ssize_t k = suspects[j];
            if (spike[k]) continue;
            double out_g = lone_spike_g(f, n, k, threshold);
            if (out_g > best_g) { best_g = out_g; best_k = k; best_width = 1; }
        }
        for (Py_ssize_t j = 0; j < pair_count; j++) {
            Py_ssize_t k = pairs[j];
            if (spike[k] || spike[k + 1]) continue;
            double out_g = spike_pair_g(f, n, k, threshold);
            if (out_g > best_g) { best_g = out_g; best_k = k; best_width = 2; }
        }
        if (best_width == 0) break;
        Py_ssize_t k = best_k;
        if (best_width == 1 && weigh_neighbours) best_width = frame_among_neighbours(f, n, best_k, spike, threshold, &k);
        double values[2];
        /* A corner is told only against a credible noise estimate, as a neighbour is (weigh_neighbours). */
        repaired_values(f, n, k, best_width, weigh_neighbours ? threshold : INFINITY, values);
        for (Py_ssize_t j = 0; j < best_width; j++) f[k + j] = values[j];
        for (Py_ssize_t j = k; j < k + best_width; j++) spike[j] = 1;
        count += best_width;
    }
    free(suspects);
    return count;
}

/* The least and the largest of values[0..n) (n >= 1, no NaN), in four independent runs (one
 * running minimum waits on the last: four keep the pipeline full); the order does not matter. */
static void span_of(const double *values, Py_ssize_t n, double *lowest, double *highest)
{
    double low[4], high[4];
    for (int j = 0; j < 4; j++)
        low[j] = high[j] = values[0];
    Py_ssize_t i = 0;
    for (; i + 4 <= n; i += 4) {
        for (int j = 0; j < 4; j++) {
            low[j] = values[i + j] < low[j] ? values[i + j] : low[j];
            high[j] = values[i + j] > high[j] ? values[i + j] : high[j];
        }
    }
    for (; i < n; i++) {
        low[0] = values[i] < low[0] ? values[i] : low[0];
        high[0] = values[i] > high[0] ? values[i] : high[0];
    }
    for (int j = 1; j < 4; j++) {
        low[0] = low[j] < low[0] ? low[j] : low[0];
        high[0] = high[j] > high[0] ? high[j] : high[0];
    }
    *lowest = low[0];
    *highest = high[0];
}

/* `repair_spikes` of force_g[0..n) (n >= 5) into repaired[0..n): the spike test's threshold from the
 * noise sigma (`noise_sigma_g` of force_g, into *noise_g) and the force's span, then the loop. spike
 * (n bytes) marks the repaired samples; returns their count, or -1 (MemoryError set). */
static Py_ssize_t repair_spikes_into(const double *force_g, Py_ssize_t n, double threshold_sigma, double *repaired,
                                     char *spike, double *noise_g)
{
    double *off_mid = malloc(2 * (size_t)(n - 2) * sizeof(double));
    if (off_mid == NULL) {
        PyErr_NoMemory();
        return -1;
    }
    double *scratch = off_mid + (n - 2);
    off_midpoints(force_g, n, off_mid);
    memcpy(scratch, off_mid, (size_t)(n - 2) * sizeof(double));
    double noise_sigma_g = *noise_g = noise_of_off_midpoints(scratch, n - 2);
    double lowest, highest;
    span_of(force_g, n, &lowest, &highest);
    double threshold = fmax(fmax(threshold_sigma * noise_sigma_g, 1e-6 * (highest - lowest)), 1e-9);
    /* smoothness weighed against the noise only where the tap shows some (the twin's weigh_neighbours) */
    const int weigh_neighbours = threshold_sigma * noise_sigma_g > 1e-6 * (highest - lowest);
    Py_ssize_t count = repair_in_copy(force_g, repaired, spike, n, off_mid, threshold, weigh_neighbours);
    free(off_mid);
    return count;
}

/* The spikes' indices and their repaired values as two lists (empty when there is none). */
static PyObject *spike_lists(const double *f, const char *spike, Py_ssize_t n, Py_ssize_t count)
{
    PyObject *indices = PyList_New(count), *values = PyList_New(count);
    if (indices == NULL || values == NULL) goto failed;
    for (Py_ssize_t k = 0, i = 0; k < n; k++) {
        if (!spike[k]) continue;
        PyObject *index = PyLong_FromSsize_t(k), *value = PyFloat_FromDouble(f[k]);
        if (index == NULL || value == NULL) {
            Py_XDECREF(index);
            Py_XDECREF(value);
            goto failed;
        }
        PyList_SET_ITEM(indices, i, index);
        PyList_SET_ITEM(values, i, value);
        i++;
    }
    return Py_BuildValue("(NN)", indices, values);
failed:
    Py_XDECREF(indices);
    Py_XDECREF(values);
    return NULL;
}

static PyObject *spikes(PyObject *self, PyObject *args)
{
    (void)self;
    Py_buffer buffer;
    double threshold_sigma;
    if (!PyArg_ParseTuple(args, "O&d", float64_buffer, &buffer, &threshold_sigma)) return NULL;
    Py_ssize_t n;
    const double *force_g = doubles_of(&buffer, &n, "force_g");
    PyObject *answer = NULL;
    if (force_g != NULL && n < 5) {
        answer = Py_BuildValue("([][])");
    } else if (force_g != NULL) {
        double *repaired = malloc((size_t)n * sizeof(double) + (size_t)n);
        if (repaired == NULL) {
            PyErr_NoMemory();
        } else {
            char *spike = (char *)(repaired + n);
            double noise_g;
            Py_ssize_t count = repair_spikes_into(force_g, n, threshold_sigma, repaired, spike, &noise_g);
            if (count >= 0) answer = spike_lists(repaired, spike, n, count);
            free(repaired);
        }
    }
    PyBuffer_Release(&buffer);
    return answer;
}


/* The median of values[first, end) (end > first) through scratch (end - first values). */
static double median_of_range(const double *values, Py_ssize_t first, Py_ssize_t end, double *scratch)
{
    memcpy(scratch, values + first, (size_t)(end - first) * sizeof(double));
    return median_in_place(scratch, end - first);
}

/* analysis.py `_polarity`'s arithmetic: +1 or -1, 0 where the force does not change (or the change
 * is not finite) between the baseline before the halt and the dwell. scratch: n values. */
static int polarity_of(const double *time_s, const double *force_g, Py_ssize_t n, double halt_s,
                       double pullback_start_s, double baseline_from_s, double *scratch)
{
    Py_ssize_t home_end = first_at_or_after(time_s, n, halt_s);
    Py_ssize_t pull_start = first_at_or_after(time_s, n, pullback_start_s);
    Py_ssize_t start = first_at_or_after(time_s, n, baseline_from_s);
    /* force_g[start:max(home_end - 1, start + 1)]: start < n, so never empty */
    Py_ssize_t baseline_end = home_end - 1 > start + 1 ? home_end - 1 : start + 1;
    double baseline = median_of_range(force_g, start, baseline_end, scratch);
    Py_ssize_t dwell_end = pull_start + 1; /* force_g[home_end:pull_start + 1]: pull_start < n */
    double change = dwell_end > home_end ? median_of_range(force_g, home_end, dwell_end, scratch) - baseline
                                         : force_g[home_end] - baseline;
    if (change == 0 || !isfinite(change)) return 0;
    return change > 0 ? 1 : -1;
}

PyDoc_STRVAR(polar_spikes_doc,
             "polar_spikes(time_s, force_g, halt_s, pullback_start_s, baseline_from_s, threshold_sigma, out)\n"
             "    -> (polarity, repaired, noise_g)\n"
             "\n"
             "The start of a tap's split in one call (analysis.py `polarity_and_repaired`): the polarity as\n"
             "`_polarity` finds it from the force read from baseline_from_s to the halt and over the dwell (0:\n"
             "the force does not change), then the force in positive polarity with its corrupted frames\n"
             "repaired (`repair_spikes`) into `out` (a float64 array as long as force_g; untouched for\n"
             "polarity 0), how many frames were repaired, and the noise sigma the repair measured on the force\n"
             "in positive polarity (`noise_sigma_g` of it; None for polarity 0 or fewer than 5 samples, which\n"
             "are not repaired). The twins' arithmetic in their order, bit for bit.");

static PyObject *polar_spikes(PyObject *self, PyObject *args)
{
    (void)self;
    Py_buffer time_buffer, force_buffer, out_buffer;
    double halt_s, pullback_start_s, baseline_from_s, threshold_sigma;
    if (!PyArg_ParseTuple(args, "O&O&ddddw*", float64_buffer, &time_buffer, float64_buffer, &force_buffer, &halt_s,
                          &pullback_start_s, &baseline_from_s, &threshold_sigma, &out_buffer))
        return NULL;
    PyObject *result = NULL;
    Py_ssize_t n = 0;
    const double *time_s = doubles_of(&time_buffer, &n, "time_s");
    const double *force_g = time_s ? doubles_sized(&force_buffer, n, "force_g") : NULL;
    double *out = force_g ? doubles_sized(&out_buffer, n, "out") : NULL;
    double *positive = NULL;
    if (out != NULL && n < 1) {
        PyErr_SetString(PyExc_ValueError, "time_s: no samples");
    } else if (out != NULL && (positive = malloc((size_t)n * sizeof(double) + (size_t)n)) == NULL) {
        PyErr_NoMemory();
    } else if (out != NULL) {
        char *spike = (char *)(positive + n);
        int polarity = polarity_of(time_s, force_g, n, halt_s, pullback_start_s, baseline_from_s, positive);
        Py_ssize_t repaired = 0;
        double noise_g = 0.0;
        int measured = polarity != 0 && n >= 5;
        if (polarity != 0) {
            for (Py_ssize_t i = 0; i < n; i++)
                positive[i] = (double)polarity * force_g[i]; /* numpy's polarity * force: the int as a double */
            if (!measured) memcpy(out, positive, (size_t)n * sizeof(double));
            else repaired = repair_spikes_into(positive, n, threshold_sigma, out, spike, &noise_g);
        }
        if (repaired >= 0 && measured)
            result = Py_BuildValue("(ind)", polarity, repaired, noise_g);
        else if (repaired >= 0)
            result = Py_BuildValue("(inO)", polarity, repaired, Py_None);
    }
    free(positive);
    PyBuffer_Release(&time_buffer);
    PyBuffer_Release(&force_buffer);
    PyBuffer_Release(&out_buffer);
    return result;
}

/* numpy's maximum and minimum of two doubles (a NaN propagates; otherwise the larger, the smaller):
 * what the twins' np.maximum / np.minimum give, inlined where C's fmax / fmin are calls into libm
 * (and drop a NaN). The samples' times and heights are finite and their zeros +0.0 (x - x), so
 * no operand order of signed zeros is met here. */
static inline double maximum(double a, double b) { return a >= b || isnan(a) ? a : b; }
static inline double minimum(double a, double b) { return a <= b || isnan(a) ? a : b; }

/* The move in force at t_s (motion.py `Motion.z_at`): the last one starting at or before t_s, the
 * first when none does. `*move` is where the previous time was: the samples' times rise, so it
 * mostly stays or steps on (a time earlier than its move's start searches afresh). */
static inline Py_ssize_t move_at(const double *start_s, Py_ssize_t moves, double t_s, Py_ssize_t *move)
{
    if (*move > 0 && start_s[*move] > t_s) {
        Py_ssize_t low = 0, high = moves; /* the count of moves starting at or before t_s (searchsorted right) */
        while (low < high) {
            Py_ssize_t middle = low + (high - low) / 2;
            if (start_s[middle] <= t_s) low = middle + 1;
            else high = middle;
        }
        *move = low > 0 ? low - 1 : 0;
    }
    while (*move + 1 < moves && start_s[*move + 1] <= t_s)
        (*move)++;
    return *move;
}

/* Commanded Z (mm) at t_s in the trapezoid move `index` (t_s clamped into it). `table`: rows start
 * time, duration, start speed, acceleration, start Z, direction; `moves` columns. */
static inline double z_in_move_mm(const double *table, Py_ssize_t moves, Py_ssize_t index, double t_s)
{
    const double start_s = table[index], duration_s = table[moves + index], start_v = table[2 * moves + index];
    const double accel = table[3 * moves + index], start_z = table[4 * moves + index], z_r = table[5 * moves + index];
    double tau_s = minimum(maximum(t_s - start_s, 0.0), duration_s);
    return start_z + z_r * (start_v + 0.5 * accel * tau_s) * tau_s;
}

static inline double z_at_mm(const double *table, Py_ssize_t moves, double t_s, Py_ssize_t *move)
{
    return z_in_move_mm(table, moves, move_at(table, moves, t_s, move), t_s);
}

/* The move table's values, row by row, from a sequence of numbers (`Motion.move_rows`, a list the
 * analysis builds without an array), into `table` (PyMem_Malloc'ed: the caller frees it); their count
 * in *cells. NULL with an exception set when they are not numbers (or out of memory). */
static double *move_table_of(PyObject *rows, Py_ssize_t *cells)
{
    PyObject *sequence = PySequence_Fast(rows, "move_rows: not a sequence of numbers");
    if (sequence == NULL)
        return NULL;
    Py_ssize_t count = PySequence_Fast_GET_SIZE(sequence);
    double *table = PyMem_Malloc(sizeof(double) * (size_t)(count > 0 ? count : 1));
    if (table == NULL)
        PyErr_NoMemory();
    for (Py_ssize_t k = 0; table != NULL && k < count; k++) {
        table[k] = PyFloat_AsDouble(PySequence_Fast_GET_ITEM(sequence, k));
        if (table[k] == -1.0 && PyErr_Occurred()) {
            PyMem_Free(table);
            table = NULL;
        }
    }
    Py_DECREF(sequence);
    *cells = count;
    return table;
}

static PyObject *window_heights(PyObject *self, PyObject *args)
{
    (void)self;
    Py_buffer time_buffer, x_min_buffer, span_buffer;
    PyObject *rows;
    double delay_s, integration_s, z_halt_mm, min_span_um, contact_line_s, break_line_s, rising_s;
    if (!PyArg_ParseTuple(args, "OO&dddddddw*w*", &rows, float64_buffer, &time_buffer, &delay_s, &integration_s,
                          &z_halt_mm, &min_span_um, &contact_line_s, &break_line_s, &rising_s, &x_min_buffer,
                          &span_buffer))
        return NULL;
    PyObject *result = NULL;
    Py_ssize_t cells = 0, n = 0;
    double *table = move_table_of(rows, &cells);
    const double *time_s = table ? doubles_of(&time_buffer, &n, "time_s") : NULL;
    double *x_min_um = time_s ? doubles_sized(&x_min_buffer, n, "x_min_um") : NULL;
    double *span_um = x_min_um ? doubles_sized(&span_buffer, n, "span_um") : NULL;
    if (span_um != NULL && (cells == 0 || cells % 6 != 0)) {
        PyErr_Format(PyExc_ValueError, "move_table: %zd values, not 6 rows of moves", cells);
    } else if (span_um != NULL) {
        Py_ssize_t moves = cells / 6, low_move = 0, high_move = 0, line_move = 0, read_by_rising = 0;
        for (Py_ssize_t i = 0; i < n; i++) {
            /* searchsorted(rising_s, side="right") over the rising times (a NaN key: every sample) */
            read_by_rising += !(time_s[i] > rising_s);
            /* the twin's steps: read time, window start, heights above the halt, then the edges */
            double read_s = time_s[i] - delay_s;
            double low_um = (z_at_mm(table, moves, read_s - integration_s, &low_move) - z_halt_mm) * 1000.0;
            double high_um = (z_at_mm(table, moves, read_s, &high_move) - z_halt_mm) * 1000.0;
            x_min_um[i] = minimum(low_um, high_um);
            span_um[i] = maximum(maximum(low_um, high_um) - x_min_um[i], min_span_um);
        }
        double contact_line_um = (z_at_mm(table, moves, contact_line_s, &line_move) - z_halt_mm) * 1000.0;
        double break_line_um = (z_at_mm(table, moves, break_line_s, &line_move) - z_halt_mm) * 1000.0;
        result = Py_BuildValue("(ddn)", contact_line_um, break_line_um, read_by_rising);
    }
    PyMem_Free(table);
    PyBuffer_Release(&time_buffer);
    PyBuffer_Release(&x_min_buffer);
    PyBuffer_Release(&span_buffer);
    return result;
}

/* Commanded Z (mm) at one time from the move table's rows (motion.py `Motion.z_at` of a single time,
 * its twin: the same move, the same clamp and the same arithmetic in its order). */
static PyObject *z_at(PyObject *self, PyObject *args)
{
    (void)self;
    PyObject *rows;
    double t_s;
    if (!PyArg_ParseTuple(args, "Od", &rows, &t_s))
        return NULL;
    Py_ssize_t cells = 0, move = 0;
    double *table = move_table_of(rows, &cells);
    if (table == NULL)
        return NULL;
    PyObject *result = NULL;
    if (cells == 0 || cells % 6 != 0)
        PyErr_Format(PyExc_ValueError, "move_table: %zd values, not 6 rows of moves", cells);
    else
        result = PyFloat_FromDouble(z_at_mm(table, cells / 6, t_s, &move));
    PyMem_Free(table);
    return result;
}

/* What is wrong with a tap's samples for the analysis (analysis.py `_check_samples`, whose
 * SAMPLES_* numbers these are), the first found. */
/* SAMPLES_REPEATING: fine, but some reading equals the one before it (where analysis.py's
 * `stale_readings` looks; a clean tap has none, so most taps skip it). */
enum sample_problem {
    SAMPLES_FINE = 0,
    SAMPLES_NOT_FINITE = 1,
    SAMPLES_NOT_INCREASING = 2,
    SAMPLES_SATURATED = 3,
    SAMPLES_REPEATING = 4
};

/* A saturated sensor (analysis.py `saturated_run`, the twin): at least SATURATED_RUN samples in a row
 * exactly at the tap's extreme force on the side away from its first sample (its max, or its min
 * for a negative polarity), the force leaving it before the last sample, while the rest of the tap repeats a value from one sample to the next
 * in at most one step in SATURATED_REPEATS_OTHER (a sensor whose steps are coarser than its noise
 * repeats values everywhere: a run proves nothing there). */
#define SATURATED_RUN 8
#define SATURATED_REPEATS_OTHER 4

/* Whether the rest of the tap (the samples not at `extreme`) repeats a value in at most one step
 * in SATURATED_REPEATS_OTHER: read only for a tap whose extreme already holds a long run. */
static int repeats_rarely_off(const double *force_g, Py_ssize_t n, double extreme)
{
    Py_ssize_t repeats = 0, steps = 0;
    for (Py_ssize_t i = 1; i < n; i++) {
        int off = force_g[i] != extreme;
        steps += off;
        repeats += off & (force_g[i] == force_g[i - 1]);
    }
    return SATURATED_REPEATS_OTHER * repeats <= steps;
}

/* The sample check's loops (built twice, ROW_LOOP: clones.h): every sample is looked at without an early exit, so the
 * compiler runs four at a time (a good tap, the common case, is read to its end anyway). A NaN or
 * infinity anywhere is the problem named before times out of order, and both before a saturated
 * sensor, as in analysis.py's `_check_samples`. */
ROW_LOOP
static enum sample_problem problem_of_samples(const double *time_s, const double *force_g, Py_ssize_t n)
{
    if (n == 0)
        return SAMPLES_FINE;
    int64_t finite = 1, increasing = 1;
    double high = force_g[0], low = force_g[0];
    for (Py_ssize_t i = 0; i < n; i++) {
        finite &= (fabs(time_s[i]) <= DBL_MAX) & (fabs(force_g[i]) <= DBL_MAX);
        high = force_g[i] > high ? force_g[i] : high;
        low = force_g[i] < low ? force_g[i] : low;
    }
    int64_t at_high = force_g[0] == high, at_low = force_g[0] == low, repeating = 0;
    for (Py_ssize_t i = 1; i < n; i++) {
        increasing &= time_s[i] > time_s[i - 1];
        at_high += force_g[i] == high;
        at_low += force_g[i] == low;
        repeating |= force_g[i] == force_g[i - 1];
    }
    if (!finite)
        return SAMPLES_NOT_FINITE;
    if (!increasing)
        return SAMPLES_NOT_INCREASING;
    const enum sample_problem fine = repeating ? SAMPLES_REPEATING : SAMPLES_FINE;
    /* The extreme away from the first sample; its runs are read only where it holds enough samples
     * at all (a clean tap's extreme is one or two samples: the loop above counted them). */
    int at_high_side = high - force_g[0] >= force_g[0] - low;
    double extreme = at_high_side ? high : low;
    if ((at_high_side ? at_high : at_low) < SATURATED_RUN)
        return fine;
    /* A run counts where the force came back from it: one held to the last sample is a sensor that
     * stopped changing (or a nozzle still pressing), not a limit the force went past and returned. */
    Py_ssize_t run = 0, longest = 0;
    for (Py_ssize_t i = 0; i < n; i++) {
        int at = force_g[i] == extreme;
        longest = !at && run > longest ? run : longest;
        run = at ? run + 1 : 0;
    }
    return longest >= SATURATED_RUN && repeats_rarely_off(force_g, n, extreme) ? SAMPLES_SATURATED : fine;
}

static PyObject *sample_problem(PyObject *self, PyObject *args)
{
    (void)self;
    Py_buffer time_buffer, force_buffer;
    if (!PyArg_ParseTuple(args, "O&O&", float64_buffer, &time_buffer, float64_buffer, &force_buffer))
        return NULL;
    PyObject *result = NULL;
    Py_ssize_t n = 0;
    const double *time_s = doubles_of(&time_buffer, &n, "time_s");
    const double *force_g = time_s ? doubles_sized(&force_buffer, n, "force_g") : NULL;
    if (force_g != NULL) {
        enum sample_problem problem = problem_of_samples(time_s, force_g, n);
        result = PyLong_FromLong(problem);
    }
    PyBuffer_Release(&time_buffer);
    PyBuffer_Release(&force_buffer);
    return result;
}

/* The stale readings among the samples (analysis.py `stale_readings`, the twin): each run of readings
 * equal to the one before it, where the force then moves on by more than jump_noise × `noise_sigma_g`
 * of the samples; none where no reading repeats or more than max_share of them do. The twin's
 * comparisons on the same doubles, and its noise sigma (the same selection): the same indices. The
 * noise, the costly part, is measured only where some run is followed by a move at all. */
static PyObject *stale_readings(PyObject *self, PyObject *args)
{
    (void)self;
    Py_buffer buffer;
    double jump_noise, max_share;
    if (!PyArg_ParseTuple(args, "O&dd", float64_buffer, &buffer, &jump_noise, &max_share)) return NULL;
    Py_ssize_t n;
    const double *force_g = doubles_of(&buffer, &n, "force_g");
    PyObject *result = NULL;
    double *off_mid = NULL;
    if (force_g == NULL) goto done;
    Py_ssize_t repeats = 0, moved = 0; /* moved: runs the force moves on from (a run ends where the next reading differs) */
    for (Py_ssize_t i = 1; i < n; i++) {
        if (force_g[i] != force_g[i - 1]) continue;
        repeats++;
        if (i + 1 < n && force_g[i + 1] != force_g[i]) moved++;
    }
    if (repeats == 0 || (double)repeats > max_share * (double)n || moved == 0) {
        result = Py_NewRef(Py_None);
        goto done;
    }
    double noise_g = 0.0;
    if (n >= 3) {
        off_mid = malloc((size_t)(n - 2) * sizeof(double));
        if (off_mid == NULL) {
            PyErr_NoMemory();
            goto done;
        }
        off_midpoints(force_g, n, off_mid);
        noise_g = noise_of_off_midpoints(off_mid, n - 2);
    }
    const double jump_g = jump_noise * noise_g;
    if ((result = PyList_New(0)) == NULL) goto done;
    Py_ssize_t run_start = 0; /* the first repeat of the current run */
    for (Py_ssize_t i = 1; i < n; i++) {
        if (force_g[i] != force_g[i - 1]) continue;
        if (i == 1 || force_g[i - 1] != force_g[i - 2]) run_start = i;
        if (i + 1 < n && force_g[i + 1] == force_g[i]) continue; /* the run goes on */
        if (i + 1 < n && fabs(force_g[i + 1] - force_g[i]) > jump_g) {
            for (Py_ssize_t r = run_start; r <= i; r++) {
                PyObject *index = PyLong_FromSsize_t(r);
                if (index == NULL || PyList_Append(result, index) < 0) {
                    Py_XDECREF(index);
                    Py_CLEAR(result);
                    goto done;
                }
                Py_DECREF(index);
            }
        }
    }
    if (PyList_GET_SIZE(result) == 0) Py_SETREF(result, Py_NewRef(Py_None));
done:
    free(off_mid);
    PyBuffer_Release(&buffer);
    return result;
}

/* The robust pass of the pullback fit (analysis.py `fit_pullback`): None when every residual lies
 * within outlier_sigma × max(their robust sigma, floor_g), else the keep mask as a bytes object (one
 * 0/1 per residual; numpy reads it as a bool array without a copy). */
static PyObject *outlier_mask(PyObject *self, PyObject *args)
{
    (void)self;
    Py_buffer residual_buffer;
    double outlier_sigma, floor_g;
    if (!PyArg_ParseTuple(args, "O&dd", float64_buffer, &residual_buffer, &outlier_sigma, &floor_g))
        return NULL;
    PyObject *result = NULL;
    Py_ssize_t n = 0;
    const double *residual_g = doubles_of(&residual_buffer, &n, "residual_g");
    double *scratch = residual_g && n > 0 ? malloc((size_t)n * sizeof(double)) : NULL;
    if (residual_g != NULL && n == 0) {
        PyErr_SetString(PyExc_ValueError, "residual_g: no residuals");
    } else if (residual_g != NULL && scratch == NULL) {
        PyErr_NoMemory();
    } else if (residual_g != NULL) {
        for (Py_ssize_t i = 0; i < n; i++)
            scratch[i] = fabs(residual_g[i]);
        double limit_g = outlier_sigma * fmax(MAD_TO_SIGMA * median_in_place(scratch, n), floor_g);
        Py_ssize_t outside = 0;
        for (Py_ssize_t i = 0; i < n; i++)
            outside += !(fabs(residual_g[i]) <= limit_g);
        if (outside == 0) {
            result = Py_NewRef(Py_None);
        } else if ((result = PyBytes_FromStringAndSize(NULL, n)) != NULL) {
            char *keep = PyBytes_AS_STRING(result);
            for (Py_ssize_t i = 0; i < n; i++)
                keep[i] = fabs(residual_g[i]) <= limit_g;
        }
    }
    free(scratch);
    PyBuffer_Release(&residual_buffer);
    return result;
}

/* The root mean square, with 3 degrees of freedom taken, of the residuals whose window starts
 * below below_um (analysis.py `near_contact_sigma_g`); NaN when 3 or fewer are there. */
static PyObject *near_sigma(PyObject *self, PyObject *args)
{
    (void)self;
    Py_buffer residual_buffer, x_min_buffer;
    double below_um;
    if (!PyArg_ParseTuple(args, "O&O&d", float64_buffer, &residual_buffer, float64_buffer, &x_min_buffer, &below_um))
        return NULL;
    PyObject *result = NULL;
    Py_ssize_t n = 0;
    const double *residual_g = doubles_of(&residual_buffer, &n, "residual_g");
    const double *x_min_um = residual_g ? doubles_sized(&x_min_buffer, n, "x_min_um") : NULL;
    if (x_min_um != NULL) {
        double sum_g2 = 0.0;
        Py_ssize_t count = 0;
        for (Py_ssize_t i = 0; i < n; i++) {
            if (x_min_um[i] < below_um) {
                sum_g2 += residual_g[i] * residual_g[i];
                count++;
            }
        }
        result = PyFloat_FromDouble(count <= 3 ? NAN : sqrt(sum_g2 / (double)(count - 3)));
    }
    PyBuffer_Release(&residual_buffer);
    PyBuffer_Release(&x_min_buffer);
    return result;
}

/* Samples read before the halt whose whole window lies at least an onset into contact
 * (analysis.py `compression_sample_count`). */
static PyObject *compression_samples(PyObject *self, PyObject *args)
{
    (void)self;
    Py_buffer time_buffer, x_min_buffer, span_buffer;
    double delay_s, halt_s, deepest_top_um;
    if (!PyArg_ParseTuple(args, "O&O&O&ddd", float64_buffer, &time_buffer, float64_buffer, &x_min_buffer,
                          float64_buffer, &span_buffer, &delay_s, &halt_s, &deepest_top_um))
        return NULL;
    PyObject *result = NULL;
    Py_ssize_t n = 0;
    const double *time_s = doubles_of(&time_buffer, &n, "time_s");
    const double *x_min_um = time_s ? doubles_sized(&x_min_buffer, n, "x_min_um") : NULL;
    const double *span_um = x_min_um ? doubles_sized(&span_buffer, n, "span_um") : NULL;
    if (span_um != NULL) {
        Py_ssize_t count = 0;
        for (Py_ssize_t i = 0; i < n; i++)
            count += (time_s[i] - delay_s <= halt_s) && (x_min_um[i] + span_um[i] <= deepest_top_um);
        result = PyLong_FromSsize_t(count);
    }
    PyBuffer_Release(&time_buffer);
    PyBuffer_Release(&x_min_buffer);
    PyBuffer_Release(&span_buffer);
    return result;
}

/* Index of the first sample at or after each time, the last sample for times past the end
 * (analysis.py `_indices`). */
static PyObject *indices(PyObject *self, PyObject *args)
{
    (void)self;
    Py_buffer time_buffer;
    PyObject *times;
    if (!PyArg_ParseTuple(args, "O&O!", float64_buffer, &time_buffer, &PyTuple_Type, &times))
        return NULL;
    PyObject *result = NULL;
    Py_ssize_t n = 0, count = PyTuple_GET_SIZE(times);
    const double *time_s = doubles_of(&time_buffer, &n, "time_s");
    if (time_s != NULL && n == 0) {
        PyErr_SetString(PyExc_ValueError, "time_s: no samples");
    } else if (time_s != NULL && (result = PyList_New(count)) != NULL) {
        for (Py_ssize_t k = 0; k < count; k++) {
            double t_s = PyFloat_AsDouble(PyTuple_GET_ITEM(times, k));
            if (t_s == -1.0 && PyErr_Occurred()) {
                Py_CLEAR(result);
                break;
            }
            PyList_SET_ITEM(result, k, PyLong_FromSsize_t(first_at_or_after(time_s, n, t_s)));
        }
    }
    PyBuffer_Release(&time_buffer);
    return result;
}

/* The median of the force over the first sample read at or after t_s (the last for a time past the
 * end) and up to `before` samples before it (analysis.py `force_at_g`: robust.median of that slice). */
static PyObject *median_up_to(PyObject *self, PyObject *args)
{
    (void)self;
    Py_buffer time_buffer, force_buffer;
    double t_s;
    Py_ssize_t before;
    if (!PyArg_ParseTuple(args, "O&O&dn", float64_buffer, &time_buffer, float64_buffer, &force_buffer, &t_s, &before))
        return NULL;
    PyObject *result = NULL;
    Py_ssize_t n = 0;
    const double *time_s = doubles_of(&time_buffer, &n, "time_s");
    const double *force_g = time_s ? doubles_sized(&force_buffer, n, "force_g") : NULL;
    if (force_g != NULL && n == 0) {
        PyErr_SetString(PyExc_ValueError, "time_s: no samples");
    } else if (force_g != NULL && before < 0) {
        PyErr_SetString(PyExc_ValueError, "before: a count of samples, not negative");
    } else if (force_g != NULL) {
        Py_ssize_t end = first_at_or_after(time_s, n, t_s) + 1, first = end - 1 - before > 0 ? end - 1 - before : 0;
        double *scratch = malloc((size_t)(end - first) * sizeof(double));
        if (scratch == NULL)
            PyErr_NoMemory();
        else
            result = PyFloat_FromDouble(median_of_range(force_g, first, end, scratch));
        free(scratch);
    }
    PyBuffer_Release(&time_buffer);
    PyBuffer_Release(&force_buffer);
    return result;
}

static PyMethodDef methods[] = {
    {"median_up_to", median_up_to, METH_VARARGS,
     "median_up_to(time_s, force_g, t_s, before) -> float: the median of force_g over the first sample at\n"
     "or after t_s (the last sample for a time past the end) and up to `before` samples before it."},
    {"median", median, METH_VARARGS,
     "median(values: float64 array) -> float: the middle value, or the mean of the middle two."},
    {"noise_sigma", noise_sigma, METH_VARARGS,
     "noise_sigma(force_g) -> float: white-noise sigma from the median absolute second difference."},
    {"spikes", spikes, METH_VARARGS,
     "spikes(force_g, threshold_sigma) -> (indices, values): corrupted frames, alone or two in a row, "
     "and the values that replace them."},
    {"polar_spikes", polar_spikes, METH_VARARGS, polar_spikes_doc},
    {"window_heights", window_heights, METH_VARARGS,
     "window_heights(move_rows, time_s, delay_s, integration_s, z_halt_mm, min_span_um, contact_line_s,\n"
     "               break_line_s, rising_s, x_min_out, span_out) -> (contact_line_um, break_line_um, first)\n\n"
     "Each sample's conversion window in heights above the halt (um): its lower edge and width (at least\n"
     "min_span_um) into the outputs, the two line points' heights (analysis.py: model_window), and how\n"
     "many samples were read at or before rising_s (time_s.searchsorted(rising_s, side='right'), the\n"
     "rising times in order: analysis.py pullback_first).\n"
     "move_rows: the move table's six rows one after the other, a sequence of numbers (Motion.move_rows)."},
    {"z_at", z_at, METH_VARARGS,
     "z_at(move_rows, t_s) -> float: the commanded Z (mm) at t_s (motion.py Motion.z_at of one time).\n"
     "move_rows: the move table's six rows one after the other, a sequence of numbers (Motion.move_rows)."},
    {"stale_readings", stale_readings, METH_VARARGS,
     "stale_readings(force_g, jump_noise, max_share) -> list of indices or None: the readings equal to the one\n"
     "before them, run by run, after which the force moves on by more than jump_noise noise sigmas; None\n"
     "where none, or where more than max_share of the samples repeat (analysis.py `stale_readings`)."},
    {"sample_problem", sample_problem, METH_VARARGS,
     "sample_problem(time_s, force_g) -> int: 0 fine, 1 NaN or infinity, 2 times not strictly increasing, "
     "3 a saturated sensor (a long run at the extreme force)."},
    {"outlier_mask", outlier_mask, METH_VARARGS,
     "outlier_mask(residual_g, outlier_sigma, floor_g) -> None or bytes: the residuals to keep (1) when\n"
     "any lies beyond outlier_sigma x max(their robust sigma, floor_g), else None."},
    {"near_sigma", near_sigma, METH_VARARGS,
     "near_sigma(residual_g, x_min_um, below_um) -> float: rms (3 dof taken) of the residuals whose\n"
     "window starts below below_um; NaN when 3 or fewer."},
    {"compression_samples", compression_samples, METH_VARARGS,
     "compression_samples(time_s, x_min_um, span_um, delay_s, halt_s, deepest_top_um) -> int: samples\n"
     "read by the halt whose window's top is at or below deepest_top_um."},
    {"indices", indices, METH_VARARGS,
     "indices(time_s, times) -> list of int: per time (a tuple of floats), the first sample at or after it,\n"
     "the last sample for times past the end."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_c_analysis", "The robust statistics and window heights of the tap analysis.",
                                    -1, methods, NULL, NULL, NULL, NULL};

PyMODINIT_FUNC PyInit__c_analysis(void) { return PyModule_Create(&module); }
