/* The contact kernels of the tap analysis (numpy twins: tapcell/tap/contact.py).
 *
 * fit_fixed_onset: the whole fit of the contact model with a fixed onset, as the twin
 * `fit_fixed_onset` (search_contact's grid + parabola, at most three rounds, then fit_contact_at),
 * in one call. Each formula is the twin's, in the twin's order; only sums over samples run in
 * another order (numpy sums pairwise, BLAS dots its own way), so results agree to rounding.
 *
 * fit_pullback, fit_compression: analysis.py's pullback and compression fits around it, whole
 * (twins: analysis.pullback_fit_twin, compression_fit_twin): the robust pass and its refit, the
 * near-contact sigma; the samples before the halt, the drift taken out. The same to the last bit
 * as those twins run with the fit_fixed_onset kernel (and _c_analysis's robust pass). */
#include "buffers.h"

#include <limits.h>
#include <math.h>

#include "median.h"

/* As contact.py: candidates per sample spacing, the hinge's smallest onset, the fit's fewest samples. */
#define CANDIDATES_PER_SAMPLE 32
#define TINY_UM 1e-9
#define MIN_FIT_SAMPLES 5

/* The samples of one fit, in height space. */
typedef struct {
    const double *force_g;
    const double *x_min_um;
    const double *span_um;
    Py_ssize_t count;
} Samples;

static inline double clamp(double v, double low, double high)
{
    v = v > low ? v : low;
    return v < high ? v : high;
}

/* The antiderivative G of the hinge h with an onset w > 0 (window_mean_and_slope's). */
static inline double hinge_antiderivative(double v, double w)
{
    double inside = clamp(v, 0.0, w); /* the part of v on the onset parabola */
    double beyond = v - w > 0.0 ? v - w : 0.0; /* the part on the linear branch */
    return inside * inside * inside / (6 * w) + beyond * (0.5 * beyond + 0.5 * w);
}

/* The hinge h(u) with the onset `onset_um` (contact.py's hinge). */
static inline double hinge(double u, double onset_um)
{
    double w = onset_um > TINY_UM ? onset_um : TINY_UM;
    if (u >= w)
        return u - 0.5 * onset_um;
    return u > 0.0 ? u * u / (2 * w) : 0.0;
}

/* Mean of h(c - x) over the window [x_min, x_min + span], and its derivative by c in *slope
 * (when slope is not NULL): window_mean_and_slope for one sample, its sharp and onset forms. */
static inline double window_mean(double contact_um, double onset_um, double x_min_um, double span_um, double *slope)
{
    double u = contact_um - x_min_um;
    if (onset_um <= 0) {
        /* Most windows lie wholly below or above the contact: the twin's fraction is then exactly 1
         * (span / span) or 0, its mean u - span / 2 or 0, without the division. */
        if (u >= span_um) {
            if (slope != NULL)
                *slope = 1.0;
            return u - 0.5 * span_um;
        }
        if (u <= 0.0) {
            if (slope != NULL)
                *slope = 0.0;
            return 0.0;
        }
        double below = clamp(u, 0.0, span_um);
        double fraction = below / span_um;
        if (slope != NULL)
            *slope = fraction;
        return fraction * (u - 0.5 * below);
    }
    double u_top = u - span_um;
    if (slope != NULL)
        *slope = (hinge(u, onset_um) - hinge(u_top, onset_um)) / span_um;
    return (hinge_antiderivative(u, onset_um) - hinge_antiderivative(u_top, onset_um)) / span_um;
}

/* The index of the least of `count` values in numpy's argmin order: the first minimum, a NaN first. */
static Py_ssize_t first_argmin(const double *values, Py_ssize_t count)
{
    Py_ssize_t at = 0;
    for (Py_ssize_t k = 1; k < count && !isnan(values[at]); k++)
        if (values[k] < values[at] || isnan(values[k]))
            at = k;
    return at;
}

/* contact.py's parabola_vertex_offset: grid steps from `at` to the vertex, 0 without one. */
static double parabola_vertex_offset(double before, double at, double after)
{
    double curvature = before - 2.0 * at + after;
    if (!(isfinite(before) && isfinite(after)) || curvature <= 0.0)
        return 0.0;
    return 0.5 * (before - after) / curvature;
}

/* Scratch of the searches, allocated once per fit: the samples near the candidates (x, span, force),
 * and per candidate the residual and the three sums over the near samples (room for `capacity`
 * candidates in each, `candidates` in use). */
typedef struct {
    double *near_x_um, *near_span_um, *near_force_g, *rss_g2, *sum_m, *sum_my, *sum_mm;
    Py_ssize_t candidates, capacity;
} Scratch;

/* Point the per-candidate sums into the block that starts at rss_g2 (four rows of `capacity`). */
static void point_sums(Scratch *scratch)
{
    scratch->sum_m = scratch->rss_g2 + scratch->capacity;
    scratch->sum_my = scratch->rss_g2 + 2 * scratch->capacity;
    scratch->sum_mm = scratch->rss_g2 + 3 * scratch->capacity;
}

/* The first candidate j (of `count`, heights low + step × j) above x_um: a window starting at x_um
 * has no part below the contact, so mean h = 0, for every candidate before it. */
static Py_ssize_t first_above(double low_um, double step_um, Py_ssize_t count, double x_um)
{
    double guess = ceil((x_um - low_um) / step_um);
    Py_ssize_t j = !(guess > 0) ? 0 : guess >= (double)count ? count : (Py_ssize_t)guess;
    /* the heights rise with j (each rounding is monotonic): step to the exact edge from the guess */
    while (j > 0 && (low_um + step_um * (double)(j - 1)) - x_um > 0.0)
        j--;
    while (j < count && !((low_um + step_um * (double)j) - x_um > 0.0))
        j++;
    return j;
}

/* The candidates j in [first, candidates) that press a window [x, x + span] whole add its mean
 * u - span / 2 (u = c - x, c = low + step × j) to their sums: window_mean's operations in its order,
 * without its branches, so the compiler runs two candidates at a time (the rows never overlap). */
static void pressed_whole(double low_um, double step_um, int first, int candidates, double x_um, double half_span_um,
                          double force_g, double *restrict sum_m, double *restrict sum_my, double *restrict sum_mm)
{
    for (int j = first; j < candidates; j++) {
        double mean = ((low_um + step_um * (double)j) - x_um) - half_span_um;
        sum_m[j] += mean;
        sum_my[j] += force_g * mean;
        sum_mm[j] += mean * mean;
    }
}

/* profile_rss: the residual sum of squares per candidate contact height (stiffness and baseline in
 * closed form, -inf explained where the stiffness would not be positive), into scratch->rss_g2.
 * The twin's split: samples pressed for every candidate enter through four totals, the ones near
 * the candidates are evaluated per candidate. Each candidate's sums run over the near samples in
 * their order, as the twin's; the candidates below a sample's window (mean h = 0, which adds
 * nothing to a sum) are skipped, so the sums are the same to the last bit. */
static void profile_rss(const Samples *s, double low_um, double high_um, double onset_um, double step_um,
                        double sum_y, double sum_yy, Scratch *scratch)
{
    Py_ssize_t near = 0, pressed = 0, candidates = scratch->candidates;
    double pressed_x = 0.0, pressed_xx = 0.0, pressed_y = 0.0, pressed_xy = 0.0;
    for (Py_ssize_t i = 0; i < s->count; i++) {
        double top_um = s->x_min_um[i] + s->span_um[i];
        if (onset_um != 0)
            top_um += onset_um;
        if (top_um <= low_um) {
            /* mean h = c - x' with x' the window's middle + onset / 2 */
            double x = s->x_min_um[i] + 0.5 * (s->span_um[i] + onset_um);
            pressed++;
            pressed_x += x;
            pressed_xx += x * x;
            pressed_y += s->force_g[i];
            pressed_xy += x * s->force_g[i];
        } else if (s->x_min_um[i] < high_um) {
            scratch->near_x_um[near] = s->x_min_um[i];
            scratch->near_span_um[near] = s->span_um[i];
            scratch->near_force_g[near] = s->force_g[i];
            near++;
        }
    }
    double *sum_m = scratch->sum_m, *sum_my = scratch->sum_my, *sum_mm = scratch->sum_mm;
    for (Py_ssize_t j = 0; j < candidates; j++)
        sum_m[j] = sum_my[j] = sum_mm[j] = 0.0;
    for (Py_ssize_t i = 0; i < near; i++) {
        double x_um = scratch->near_x_um[i], span_um = scratch->near_span_um[i], force_g = scratch->near_force_g[i];
        Py_ssize_t j = first_above(low_um, step_um, candidates, x_um);
        if (onset_um <= 0 && candidates <= INT_MAX) {
            /* The sharp model (the analysis's every fit): the candidates rise with j, so past the few
             * whose contact cuts the window (u < span) every one presses it whole, where window_mean
             * is u - span / 2 (`pressed_whole`). */
            for (; j < candidates; j++) {
                double contact_um = low_um + step_um * (double)j;
                if (contact_um - x_um >= span_um)
                    break;
                double mean = window_mean(contact_um, onset_um, x_um, span_um, NULL);
                sum_m[j] += mean;
                sum_my[j] += force_g * mean;
                sum_mm[j] += mean * mean;
            }
            pressed_whole(low_um, step_um, (int)j, (int)candidates, x_um, 0.5 * span_um, force_g, sum_m, sum_my,
                          sum_mm);
            continue;
        }
        for (; j < candidates; j++) {
            double mean = window_mean(low_um + step_um * (double)j, onset_um, x_um, span_um, NULL);
            sum_m[j] += mean;
            sum_my[j] += force_g * mean;
            sum_mm[j] += mean * mean;
        }
    }
    double count = (double)s->count;
    double mean_y = sum_y / count;
    double total_ss = sum_yy - sum_y * sum_y / count;
    for (Py_ssize_t j = 0; j < candidates; j++) {
        double c = low_um + step_um * (double)j;
        double m = sum_m[j], my = sum_my[j], mm = sum_mm[j];
        if (pressed) {
            double pressed_m = (double)pressed * c - pressed_x; /* the pressed samples' sum of mean h */
            m += pressed_m;
            mm += (pressed_m - pressed_x) * c;
            mm += pressed_xx;
            my += c * pressed_y;
            my -= pressed_xy;
        }
        double s_mm = mm - m * m / count;
        double s_my = my - m * mean_y;
        /* A stiffness <= 0 explains nothing; s_mm is then never divided (it may be 0). */
        double explained = s_my > 0 ? s_my * s_my / s_mm : -INFINITY;
        scratch->rss_g2[j] = total_ss - explained;
    }
}

/* search_contact: the contact height in [low, high] with the least residual, into *contact_um;
 * 0 when no candidate has a positive stiffness, -1 out of memory (MemoryError set). */
static int search_contact(const Samples *s, double low_um, double high_um, double onset_um, double spacing_um,
                          double sum_y, double sum_yy, Scratch *scratch, double *contact_um)
{
    /* Python's round() rounds halves to even, as nearbyint does in the default rounding mode. */
    Py_ssize_t count = (Py_ssize_t)nearbyint((high_um - low_um) / spacing_um * CANDIDATES_PER_SAMPLE) + 1;
    if (count > scratch->capacity) { /* never for a range of 2 * search_samples spacings (the first size) */
        double *larger = PyMem_Realloc(scratch->rss_g2, 4 * sizeof(double) * (size_t)count);
        if (larger == NULL)
            return -1;
        scratch->rss_g2 = larger;
        scratch->capacity = count;
        point_sums(scratch);
    }
    scratch->candidates = count;
    double step_um = (high_um - low_um) / (double)(count - 1);
    profile_rss(s, low_um, high_um, onset_um, step_um, sum_y, sum_yy, scratch);
    const double *rss = scratch->rss_g2;
    Py_ssize_t best = first_argmin(rss, count);
    if (!isfinite(rss[best]))
        return 0;
    double contact = low_um + step_um * (double)best;
    if (0 < best && best < count - 1)
        contact += parabola_vertex_offset(rss[best - 1], rss[best], rss[best + 1]) * step_um;
    *contact_um = contact;
    return 1;
}

/* The result of fit_contact_at. */
typedef struct {
    double contact_um, stiffness_g_um, baseline_g, contact_sigma_um, residual_sigma_g, rss_g2;
} Fit;

/* fit_contact_at: stiffness and baseline by least squares at a given contact height, the contact's
 * 1 sigma from the 3-parameter information, the residuals into residual_g. 0 when there is no fit. */
static int fit_contact_at(const Samples *s, double contact_um, double onset_um, double *residual_g, Fit *fit)
{
    double sum_m = 0.0, sum_y = 0.0, sum_d = 0.0, m_m = 0.0, m_d = 0.0, d_d = 0.0, m_y = 0.0;
    Py_ssize_t in_contact = 0;
    /* residual_g holds each sample's mean h until the residuals replace it */
    for (Py_ssize_t i = 0; i < s->count; i++) {
        double d_contact;
        double mean = window_mean(contact_um, onset_um, s->x_min_um[i], s->span_um[i], &d_contact);
        residual_g[i] = mean;
        sum_m += mean;
        sum_y += s->force_g[i];
        sum_d += d_contact;
        m_m += mean * mean;
        m_d += mean * d_contact;
        d_d += d_contact * d_contact;
        m_y += mean * s->force_g[i];
        in_contact += s->x_min_um[i] < contact_um;
    }
    double count = (double)s->count;
    double s_mm = m_m - sum_m * sum_m / count;
    if (!(s_mm > 0))
        return 0;
    double stiffness = (m_y - sum_m * sum_y / count) / s_mm;
    double baseline = (sum_y - stiffness * sum_m) / count;
    double rss = 0.0;
    for (Py_ssize_t i = 0; i < s->count; i++) {
        double residual = s->force_g[i] - baseline - stiffness * residual_g[i];
        residual_g[i] = residual;
        rss += residual * residual;
    }
    double residual_var = rss / (count - 3);
    /* Variance of c: residual variance / the Schur complement of the (stiffness, baseline) block of
     * JᵀJ, J = [stiffness * d_contact, mean, 1]; the centred sums eliminate the baseline. */
    double s_dd = stiffness * stiffness * (d_d - sum_d * sum_d / count);
    double s_dm = stiffness * (m_d - sum_d * sum_m / count);
    double information = s_dd - s_dm * s_dm / s_mm;
    if (!(stiffness > 0 && isfinite(stiffness) && information > 0 && in_contact >= 2))
        return 0;
    *fit = (Fit){contact_um, stiffness, baseline, sqrt(residual_var / information), sqrt(residual_var), rss};
    return 1;
}

/* The whole fixed-onset fit of the twin's `fit_fixed_onset`: the search of the contact height within
 * search_samples spacings of contact0_um (the range moved at most twice, so the answer is an interior
 * minimum of the residual), then fit_contact_at there, residuals into residual_g. 1: a fit in *fit;
 * 0: none; -1: out of memory (MemoryError set). */
static int fit_fixed(const Samples *s, double contact0_um, double spacing_um, double onset_um, Py_ssize_t search_samples,
                     double *residual_g, Fit *fit)
{
    /* fit_contact_at's least count: fewer samples never give a fit. A line estimate that is not
     * finite gives no search range (the callers never pass one). */
    if (s->count < MIN_FIT_SAMPLES || !isfinite(contact0_um))
        return 0;
    Scratch scratch = {NULL, NULL, NULL, NULL, NULL, NULL, NULL, 0, 2 * search_samples * CANDIDATES_PER_SAMPLE + 1};
    double *memory = PyMem_Malloc(sizeof(double) * (size_t)(3 * s->count));
    scratch.rss_g2 = PyMem_Malloc(4 * sizeof(double) * (size_t)scratch.capacity);
    if (memory == NULL || scratch.rss_g2 == NULL) {
        PyMem_Free(memory);
        PyMem_Free(scratch.rss_g2);
        PyErr_NoMemory();
        return -1;
    }
    point_sums(&scratch);
    scratch.near_x_um = memory;
    scratch.near_span_um = memory + s->count;
    scratch.near_force_g = memory + 2 * s->count;
    double sum_y = 0.0, sum_yy = 0.0;
    for (Py_ssize_t i = 0; i < s->count; i++) {
        sum_y += s->force_g[i];
        sum_yy += s->force_g[i] * s->force_g[i];
    }
    double reach_um = (double)search_samples * spacing_um, centre_um = contact0_um, contact_um = 0.0;
    int searched = 0;
    for (int round = 0; round < 3; round++) {
        double low_um = centre_um - reach_um, high_um = centre_um + reach_um;
        searched = search_contact(s, low_um, high_um, onset_um, spacing_um, sum_y, sum_yy, &scratch, &contact_um);
        if (searched != 1)
            break;
        if (low_um + 1e-3 * spacing_um < contact_um && contact_um < high_um - 1e-3 * spacing_um)
            break;
        centre_um = contact_um;
    }
    PyMem_Free(scratch.rss_g2);
    PyMem_Free(memory);
    if (searched < 0) {
        PyErr_NoMemory();
        return -1;
    }
    return searched && fit_contact_at(s, contact_um, onset_um, residual_g, fit);
}

/* The six numbers of a fit as a tuple (fit_fixed_onset's answer). */
static PyObject *fit_tuple(const Fit *fit)
{
    return Py_BuildValue("dddddd", fit->contact_um, fit->stiffness_g_um, fit->baseline_g, fit->contact_sigma_um,
                         fit->residual_sigma_g, fit->rss_g2);
}

/* The three sample arrays (force, x_min, span) of one length: *taken counts the buffers held. */
static int sample_buffers(PyObject **arrays, Py_buffer *buffers, int *taken, Samples *s)
{
    while (*taken < 3 && float64_buffer(arrays[*taken], &buffers[*taken]))
        (*taken)++;
    if (*taken < 3)
        return 0;
    s->force_g = doubles_of(&buffers[0], &s->count, "force_g");
    s->x_min_um = s->force_g ? doubles_sized(&buffers[1], s->count, "x_min_um") : NULL;
    s->span_um = s->x_min_um ? doubles_sized(&buffers[2], s->count, "span_um") : NULL;
    return s->span_um != NULL;
}

/* The search's arguments make sense, else a ValueError. */
static int check_search(Py_ssize_t search_samples, double spacing_um)
{
    if (search_samples < 1 || !(spacing_um > 0 && isfinite(spacing_um))) {
        PyErr_SetString(PyExc_ValueError, "search_samples and spacing_um must be positive");
        return 0;
    }
    return 1;
}

PyDoc_STRVAR(fit_fixed_onset_doc,
             "fit_fixed_onset(force_g, x_min_um, span_um, contact0_um, spacing_um, onset_um, search_samples,\n"
             "                residual_g)\n"
             "    -> (contact_um, stiffness_g_um, baseline_g, contact_sigma_um, residual_sigma_g, rss_g2) | None\n"
             "\n"
             "The contact model with a fixed onset, as tapcell.tap.contact.fit_fixed_onset: the global search of the\n"
             "contact height within search_samples sample spacings of contact0_um (moved at most twice), then\n"
             "stiffness, baseline and the contact's 1 sigma there. Writes the residuals into residual_g (float64,\n"
             "one per sample). None when there is no fit. Arrays: float64, C order, one length.");

static PyObject *fit_fixed_onset(PyObject *self, PyObject *args)
{
    (void)self;
    PyObject *arrays[3];
    Py_buffer inputs[3], residual_buffer; /* force, x_min, span */
    double contact0_um, spacing_um, onset_um;
    Py_ssize_t search_samples;
    if (!PyArg_ParseTuple(args, "OOOdddnw*", &arrays[0], &arrays[1], &arrays[2], &contact0_um, &spacing_um,
                          &onset_um, &search_samples, &residual_buffer))
        return NULL;
    PyObject *result = NULL;
    int taken = 0; /* the input buffers held */
    Samples s;
    double *residual_g = NULL;
    if (sample_buffers(arrays, inputs, &taken, &s))
        residual_g = doubles_sized(&residual_buffer, s.count, "residual_g");
    if (residual_g != NULL && check_search(search_samples, spacing_um)) {
        Fit fit;
        int found = fit_fixed(&s, contact0_um, spacing_um, onset_um, search_samples, residual_g, &fit);
        if (found > 0)
            result = fit_tuple(&fit);
        else if (found == 0)
            result = Py_NewRef(Py_None);
    }
    while (taken > 0)
        PyBuffer_Release(&inputs[--taken]);
    PyBuffer_Release(&residual_buffer);
    return result;
}

/* The median absolute deviation of normal noise times this is its sigma (robust.MAD_TO_SIGMA). */
#define MAD_TO_SIGMA 1.4826

/* The pullback's fit after the first (analysis.py `fit_pullback`, fixed onset): the robust pass keeps the
 * residuals within outlier_sigma × max(their robust sigma, the fit's residual sigma) (`_outliers_kept`,
 * as _c_analysis.outlier_mask), fits those again from the first fit's contact and, when that fits,
 * takes it with the residuals over every sample (`_residual`); then the rms (3 dof taken) of the
 * residuals whose window starts below contact + near_reach_um (`near_contact_sigma_g`, as
 * _c_analysis.near_sigma; the fit's residual sigma when 3 or fewer are there). 0, or -1 out of memory. */
static int robust_pass(const Samples *s, double spacing_um, double onset_um, Py_ssize_t search_samples,
                       double outlier_sigma, double near_reach_um, double *residual_g, Fit *fit, double *near_sigma_g)
{
    Py_ssize_t n = s->count;
    /* The limit is at least outlier_sigma × the residual sigma (each rounding is monotonic): when no
     * residual lies beyond that, every one is kept and the median is not needed. */
    double floor_limit_g = outlier_sigma * fit->residual_sigma_g;
    Py_ssize_t beyond = 0;
    for (Py_ssize_t i = 0; i < n; i++)
        beyond += !(fabs(residual_g[i]) <= floor_limit_g);
    if (beyond) {
        /* the |residuals| (their median), then the kept samples' force, x_min, span and residuals */
        double *memory = PyMem_Malloc(sizeof(double) * (size_t)(4 * n));
        if (memory == NULL) {
            PyErr_NoMemory();
            return -1;
        }
        for (Py_ssize_t i = 0; i < n; i++)
            memory[i] = fabs(residual_g[i]);
        double limit_g = outlier_sigma * fmax(MAD_TO_SIGMA * median_in_place(memory, n), fit->residual_sigma_g);
        Samples kept = {memory, memory + n, memory + 2 * n, 0};
        for (Py_ssize_t i = 0; i < n; i++) {
            if (fabs(residual_g[i]) <= limit_g) {
                memory[kept.count] = s->force_g[i];
                memory[n + kept.count] = s->x_min_um[i];
                memory[2 * n + kept.count] = s->span_um[i];
                kept.count++;
            }
        }
        Fit refit;
        int found = kept.count < n ? fit_fixed(&kept, fit->contact_um + 0.5 * onset_um, spacing_um, onset_um,
                                               search_samples, memory + 3 * n, &refit)
                                   : 0;
        if (found < 0) {
            PyMem_Free(memory);
            return -1;
        }
        if (found) {
            *fit = refit;
            for (Py_ssize_t i = 0; i < n; i++) /* over every sample, the dropped ones too */
                residual_g[i] = s->force_g[i] - (fit->baseline_g + fit->stiffness_g_um
                                                 * window_mean(fit->contact_um, onset_um, s->x_min_um[i], s->span_um[i], NULL));
        }
        PyMem_Free(memory);
    }
    double below_um = fit->contact_um + near_reach_um, sum_g2 = 0.0;
    Py_ssize_t near = 0;
    for (Py_ssize_t i = 0; i < n; i++) {
        if (s->x_min_um[i] < below_um) {
            sum_g2 += residual_g[i] * residual_g[i];
            near++;
        }
    }
    *near_sigma_g = near <= 3 ? fit->residual_sigma_g : sqrt(sum_g2 / (double)(near - 3));
    return 0;
}

PyDoc_STRVAR(fit_pullback_doc,
             "fit_pullback(force_g, x_min_um, span_um, contact0_um, spacing_um, onset_um, search_samples,\n"
             "             outlier_sigma, near_reach_um)\n"
             "    -> (contact_um, stiffness_g_um, baseline_g, contact_sigma_um, residual_sigma_g, rss_g2,\n"
             "        near_sigma_g) | None\n"
             "\n"
             "tapcell.tap.analysis.fit_pullback's fit with a fixed onset over the pullback's samples: fit_fixed_onset\n"
             "from contact0_um + onset / 2, the robust pass (samples beyond outlier_sigma x max(robust sigma, the\n"
             "residual sigma) dropped, fitted again) and the residual sigma of the samples whose window starts\n"
             "below the contact + near_reach_um. None when there is no first fit.");

static PyObject *fit_pullback(PyObject *self, PyObject *args)
{
    (void)self;
    PyObject *arrays[3];
    Py_buffer inputs[3];
    double contact0_um, spacing_um, onset_um, outlier_sigma, near_reach_um;
    Py_ssize_t search_samples;
    if (!PyArg_ParseTuple(args, "OOOdddndd", &arrays[0], &arrays[1], &arrays[2], &contact0_um, &spacing_um,
                          &onset_um, &search_samples, &outlier_sigma, &near_reach_um))
        return NULL;
    PyObject *result = NULL;
    int taken = 0;
    Samples s;
    if (sample_buffers(arrays, inputs, &taken, &s) && check_search(search_samples, spacing_um)) {
        double *residual_g = PyMem_Malloc(sizeof(double) * (size_t)(s.count > 0 ? s.count : 1));
        Fit fit;
        double near_sigma_g;
        int found = residual_g == NULL ? (PyErr_NoMemory(), -1)
                    : fit_fixed(&s, contact0_um + 0.5 * onset_um, spacing_um, onset_um, search_samples, residual_g, &fit);
        if (found > 0 && robust_pass(&s, spacing_um, onset_um, search_samples, outlier_sigma, near_reach_um, residual_g,
                                     &fit, &near_sigma_g) == 0)
            result = Py_BuildValue("ddddddd", fit.contact_um, fit.stiffness_g_um, fit.baseline_g, fit.contact_sigma_um,
                                   fit.residual_sigma_g, fit.rss_g2, near_sigma_g);
        else if (found == 0)
            result = Py_NewRef(Py_None);
        PyMem_Free(residual_g);
    }
    while (taken > 0)
        PyBuffer_Release(&inputs[--taken]);
    return result;
}

PyDoc_STRVAR(fit_compression_doc,
             "fit_compression(time_s, force_g, x_min_um, span_um, read_until_s, contact0_um, spacing_um, onset_um,\n"
             "                drift_g_um, search_samples)\n"
             "    -> (contact_um, stiffness_g_um, baseline_g, contact_sigma_um, residual_sigma_g, rss_g2) | None\n"
             "\n"
             "tapcell.tap.analysis.fit_compression's fit: over the samples read up to read_until_s (time_s sorted;\n"
             "None for fewer than 6), the force less drift_g_um x each window's middle height (when the drift is\n"
             "not 0), fit_fixed_onset from contact0_um + onset / 2. Arrays: float64, C order, one length.");

static PyObject *fit_compression(PyObject *self, PyObject *args)
{
    (void)self;
    PyObject *arrays[3], *time_array;
    Py_buffer inputs[3], time_buffer;
    double read_until_s, contact0_um, spacing_um, onset_um, drift_g_um;
    Py_ssize_t search_samples;
    if (!PyArg_ParseTuple(args, "OOOOdddddn", &time_array, &arrays[0], &arrays[1], &arrays[2], &read_until_s,
                          &contact0_um, &spacing_um, &onset_um, &drift_g_um, &search_samples))
        return NULL;
    if (!float64_buffer(time_array, &time_buffer))
        return NULL;
    PyObject *result = NULL;
    int taken = 0;
    Samples s;
    const double *time_s = NULL;
    if (sample_buffers(arrays, inputs, &taken, &s))
        time_s = doubles_sized(&time_buffer, s.count, "time_s");
    if (time_s != NULL && check_search(search_samples, spacing_um)) {
        /* numpy's searchsorted(read_until_s, side="right"): the samples read at or before it */
        Py_ssize_t low = 0, high = s.count;
        while (low < high) {
            Py_ssize_t middle = low + (high - low) / 2;
            if (time_s[middle] <= read_until_s)
                low = middle + 1;
            else
                high = middle;
        }
        s.count = low;
        /* the force less the drift, then the residuals */
        double *memory = s.count >= 6 ? PyMem_Malloc(sizeof(double) * (size_t)(2 * s.count)) : NULL;
        int found = 0;
        if (s.count >= 6 && memory == NULL) {
            PyErr_NoMemory();
            found = -1;
        } else if (s.count >= 6) {
            if (drift_g_um != 0.0) {
                for (Py_ssize_t i = 0; i < s.count; i++)
                    memory[i] = s.force_g[i] - drift_g_um * (s.x_min_um[i] + 0.5 * s.span_um[i]);
                s.force_g = memory;
            }
            Fit fit;
            found = fit_fixed(&s, contact0_um + 0.5 * onset_um, spacing_um, onset_um, search_samples,
                              memory + s.count, &fit);
            if (found > 0)
                result = fit_tuple(&fit);
        }
        if (found == 0)
            result = Py_NewRef(Py_None);
        PyMem_Free(memory);
    }
    while (taken > 0)
        PyBuffer_Release(&inputs[--taken]);
    PyBuffer_Release(&time_buffer);
    return result;
}

static PyMethodDef methods[] = {
    {"fit_fixed_onset", fit_fixed_onset, METH_VARARGS, fit_fixed_onset_doc},
    {"fit_pullback", fit_pullback, METH_VARARGS, fit_pullback_doc},
    {"fit_compression", fit_compression, METH_VARARGS, fit_compression_doc},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_c_contact", "The contact kernels of the tap analysis.", -1,
                                    methods, NULL, NULL, NULL, NULL};

PyMODINIT_FUNC PyInit__c_contact(void) { return PyModule_Create(&module); }
