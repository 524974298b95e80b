/* The contact kernels of the tap analysis (numpy twins: tapcell/tap/contact.py).
 *
 * fit_fixed_onset: the whole fit of the contact model with a fixed onset, as the twin
 * `fit_fixed_onset` (search_contact's grid + parabola, at most three rounds, then fit_contact_at),
 * in one call. Each formula is the twin's, in the twin's order; only sums over samples run in
 * another order (numpy sums pairwise, BLAS dots its own way), so results agree to rounding. */
#include "buffers.h"

#include <math.h>

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

/* Scratch of the searches, allocated once per fit: the samples near the candidates (x, span, force)
 * and the residual per candidate (room for `capacity`, `candidates` in use). */
typedef struct {
    double *near_x_um, *near_span_um, *near_force_g, *rss_g2;
    Py_ssize_t candidates, capacity;
} Scratch;

/* profile_rss: the residual sum of squares per candidate contact height (stiffness and baseline in
 * closed form, -inf explained where the stiffness would not be positive), into scratch->rss_g2.
 * The twin's split: samples pressed for every candidate enter through four totals, the ones near
 * the candidates are evaluated per candidate. */
static void profile_rss(const Samples *s, double low_um, double high_um, double onset_um, double step_um,
                        double sum_y, double sum_yy, Scratch *scratch)
{
    Py_ssize_t near = 0, pressed = 0;
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
    double count = (double)s->count;
    double mean_y = sum_y / count;
    double total_ss = sum_yy - sum_y * sum_y / count;
    for (Py_ssize_t j = 0; j < scratch->candidates; j++) {
        double c = low_um + step_um * (double)j;
        double sum_m = 0.0, sum_my = 0.0, sum_mm = 0.0;
        for (Py_ssize_t i = 0; i < near; i++) {
            double mean = window_mean(c, onset_um, scratch->near_x_um[i], scratch->near_span_um[i], NULL);
            sum_m += mean;
            sum_my += scratch->near_force_g[i] * mean;
            sum_mm += mean * mean;
        }
        if (pressed) {
            double pressed_m = (double)pressed * c - pressed_x; /* the pressed samples' sum of mean h */
            sum_m += pressed_m;
            sum_mm += (pressed_m - pressed_x) * c;
            sum_mm += pressed_xx;
            sum_my += c * pressed_y;
            sum_my -= pressed_xy;
        }
        double s_mm = sum_mm - sum_m * sum_m / count;
        double s_my = sum_my - sum_m * mean_y;
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
        double *larger = PyMem_Realloc(scratch->rss_g2, sizeof(double) * (size_t)count);
        if (larger == NULL)
            return -1;
        scratch->rss_g2 = larger;
        scratch->capacity = count;
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
    double *memory = NULL;
    int taken = 0; /* the input buffers held */
    while (taken < 3 && float64_buffer(arrays[taken], &inputs[taken]))
        taken++;
    if (taken < 3)
        goto done;
    Samples s;
    s.force_g = doubles_of(&inputs[0], &s.count, "force_g");
    s.x_min_um = s.force_g ? doubles_sized(&inputs[1], s.count, "x_min_um") : NULL;
    s.span_um = s.x_min_um ? doubles_sized(&inputs[2], s.count, "span_um") : NULL;
    double *residual_g = s.span_um ? doubles_sized(&residual_buffer, s.count, "residual_g") : NULL;
    if (residual_g == NULL)
        goto done;
    if (search_samples < 1 || !(spacing_um > 0 && isfinite(spacing_um))) {
        PyErr_SetString(PyExc_ValueError, "search_samples and spacing_um must be positive");
        goto done;
    }
    Fit fit;
    int found = 0;
    /* fit_contact_at's least count: fewer samples never give a fit. A line estimate that is not
     * finite gives no search range (the callers never pass one). */
    if (s.count >= MIN_FIT_SAMPLES && isfinite(contact0_um)) {
        Scratch scratch = {NULL, NULL, NULL, NULL, 0, 2 * search_samples * CANDIDATES_PER_SAMPLE + 1};
        memory = PyMem_Malloc(sizeof(double) * (size_t)(3 * s.count));
        scratch.rss_g2 = PyMem_Malloc(sizeof(double) * (size_t)scratch.capacity);
        if (memory == NULL || scratch.rss_g2 == NULL) {
            PyMem_Free(scratch.rss_g2);
            PyErr_NoMemory();
            goto done;
        }
        scratch.near_x_um = memory;
        scratch.near_span_um = memory + s.count;
        scratch.near_force_g = memory + 2 * s.count;
        double sum_y = 0.0, sum_yy = 0.0;
        for (Py_ssize_t i = 0; i < s.count; i++) {
            sum_y += s.force_g[i];
            sum_yy += s.force_g[i] * s.force_g[i];
        }
        /* A minimum on the edge of the range means the estimate was off: the range moves there
         * (at most twice) so the answer is an interior minimum of the residual. */
        double reach_um = (double)search_samples * spacing_um, centre_um = contact0_um, contact_um = 0.0;
        int searched = 0;
        for (int round = 0; round < 3; round++) {
            double low_um = centre_um - reach_um, high_um = centre_um + reach_um;
            searched = search_contact(&s, low_um, high_um, onset_um, spacing_um, sum_y, sum_yy, &scratch, &contact_um);
            if (searched != 1)
                break;
            if (low_um + 1e-3 * spacing_um < contact_um && contact_um < high_um - 1e-3 * spacing_um)
                break;
            centre_um = contact_um;
        }
        PyMem_Free(scratch.rss_g2);
        if (searched < 0) {
            PyErr_NoMemory();
            goto done;
        }
        found = searched && fit_contact_at(&s, contact_um, onset_um, residual_g, &fit);
    }
    if (found) {
        result = Py_BuildValue("dddddd", fit.contact_um, fit.stiffness_g_um, fit.baseline_g, fit.contact_sigma_um,
                               fit.residual_sigma_g, fit.rss_g2);
    } else {
        Py_INCREF(Py_None);
        result = Py_None;
    }
done:
    PyMem_Free(memory);
    while (taken > 0)
        PyBuffer_Release(&inputs[--taken]);
    PyBuffer_Release(&residual_buffer);
    return result;
}

static PyMethodDef methods[] = {
    {"fit_fixed_onset", fit_fixed_onset, METH_VARARGS, fit_fixed_onset_doc},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_c_contact", "The contact kernels of the tap analysis.", -1,
                                    methods, NULL, NULL, NULL, NULL};

PyMODINIT_FUNC PyInit__c_contact(void) { return PyModule_Create(&module); }
