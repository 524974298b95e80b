/* The toe kernels of the tap analysis (numpy twins: tapcell/tap/toe.py).
 *
 * The toe fit scores a grid of candidate toes (contact height c, toe width w, shape p) over the
 * pullback; per candidate the linear solve needs three sums of its toe column h (h·h, the basis
 * part Bᵀh, h·y). numpy gets them from hundreds of small array calls a tap; here each grid is one
 * pass over the samples and, per candidate, over the few samples in its toe.
 *
 * The shapes are the two of TOE_POWERS, (0.5, 1.0): a Hertz toe (u^1.5) and a parabolic one (u^2),
 * written out rather than through pow(); the Python side runs the numpy twin for any other powers.
 * Rows of every output are (shape, candidate) in that order, as in toe.py.
 */
#include "buffers.h" /* Python.h first: it sets the feature macros the system headers read */

#include <math.h>
#include <stdlib.h>

#include "median.h"

/* Two heights a window go through SSE2 side by side where the compiler has it (x86-64 always);
 * -DTAPCELL_SCALAR builds the plain loops, which give the same bits (a check of the vector code). */
#if defined(__SSE2__) && !defined(TAPCELL_SCALAR)
#define TOE_SSE2 1
#include <emmintrin.h>
#endif

#define SHAPES 2
/* How far short of its width each shape lifts the linear part: p / (p + 1). */
static const double LIFT_DEFICIT[SHAPES] = {0.5 / 1.5, 1.0 / 2.0};

#ifdef TOE_SSE2
/* `toe_sums` of a window of two heights as one vector (Hertz, parabolic), the two heights side by
 * side: no branch, and IEEE division and square root round alike in either form. A free height
 * adds (0 · 0) · lift + 0 = +0 and a height past the toe (1 · 1) · lift + beyond, the values
 * `toe_sums` takes by its branches; each shape's two heights summed h0 + h1, as 0 + h0 + h1. */
static inline __m128d toe_pair(double contact_um, double width_um, const double *row_um)
{
    double width = width_um > 1e-9 ? width_um : 1e-9;
    __m128d zero = _mm_setzero_pd(), w = _mm_set1_pd(width);
    __m128d pressed = _mm_max_pd(_mm_sub_pd(_mm_set1_pd(contact_um), _mm_loadu_pd(row_um)), zero);
    __m128d u = _mm_min_pd(_mm_div_pd(pressed, w), _mm_set1_pd(1.0));
    __m128d beyond = _mm_max_pd(_mm_sub_pd(pressed, w), zero);
    __m128d hertz = _mm_add_pd(_mm_mul_pd(_mm_mul_pd(_mm_sqrt_pd(u), u), _mm_set1_pd(width * (1.0 / 1.5))), beyond);
    __m128d parabolic = _mm_add_pd(_mm_mul_pd(_mm_mul_pd(u, u), _mm_set1_pd(width * (1.0 / 2.0))), beyond);
    return _mm_add_pd(_mm_unpacklo_pd(hertz, parabolic), _mm_unpackhi_pd(hertz, parabolic));
}
#endif

/* Both shapes' toe columns at one sample (toe.py's `toe_shapes`): the shape summed over the
 * heights its conversion window averages (row: `subsamples` heights; the caller scales the sums).
 * The operations in numpy's order (u = min(max(depth, 0) / w, 1), beyond = max(depth - w, 0),
 * u^1.5 or u^2 scaled by w / (p + 1), then the linear part added), so each value agrees to the
 * last bit. Two heights a window (toe.py's SUBSAMPLES) with SSE2: `toe_pair`. Otherwise per
 * height, free air and past the toe without the sqrt and the division (the values come out the
 * same). Inline, with the sums in locals: it runs for every candidate's every in-toe sample. */
static inline void toe_sums(double contact_um, double width_um, const double *row_um, Py_ssize_t subsamples,
                            double sums[SHAPES])
{
    double width = width_um > 1e-9 ? width_um : 1e-9;
    double lift_hertz = width * (1.0 / 1.5), lift_parabolic = width * (1.0 / 2.0);
#ifdef TOE_SSE2
    if (subsamples == 2) {
        double pair[SHAPES];
        _mm_storeu_pd(pair, toe_pair(contact_um, width_um, row_um));
        sums[0] = pair[0];
        sums[1] = pair[1];
        return;
    }
#endif
    double hertz = 0.0, parabolic = 0.0;
    for (Py_ssize_t s = 0; s < subsamples; s++) {
        double depth_um = contact_um - row_um[s];
        if (!(depth_um > 0.0))
            continue; /* free air: both shapes 0 */
        if (depth_um >= width) { /* u = 1 */
            double beyond_um = depth_um - width;
            hertz += lift_hertz + beyond_um;
            parabolic += lift_parabolic + beyond_um;
        } else {
            double u = depth_um / width;
            hertz += sqrt(u) * u * lift_hertz;
            parabolic += u * u * lift_parabolic;
        }
    }
    sums[0] = hertz;
    sums[1] = parabolic;
}

/* Number of values <= v (at_most) or < v (!at_most) in sorted (ascending): numpy's searchsorted
 * with side="right" or "left". hint: the answer for the previous candidate. When v has not gone
 * below it (the grid's contacts ascend) the answer is a step or two on: walking there beats a
 * binary search, whose branches the processor cannot predict. */
static Py_ssize_t count_before(const double *sorted, Py_ssize_t n, double v, int at_most, Py_ssize_t hint)
{
    Py_ssize_t lo = 0, hi = n;
    if (hint > 0 && hint <= n && (at_most ? sorted[hint - 1] <= v : sorted[hint - 1] < v)) {
        lo = hint;
        while (lo < n && (at_most ? sorted[lo] <= v : sorted[lo] < v))
            lo++;
        return lo;
    }
    while (lo < hi) {
        Py_ssize_t mid = lo + (hi - lo) / 2;
        if (at_most ? sorted[mid] <= v : sorted[mid] < v)
            lo = mid + 1;
        else
            hi = mid;
    }
    return lo;
}

/* The pullback samples of one fit, laid out as toe.py's `_toe_grid` does from the conversion
 * windows [x_lo, x_hi] and the force (n each): window_um (n × subsamples heights, at (k + ½) /
 * subsamples of each window), x_mid_um, and force_g with a known drift taken out (drift_g_um NaN:
 * the drift is fitted). Built here, in the same operations: numpy's broadcasting costs more than
 * the whole grid on arrays this small. */
typedef struct {
    Py_buffer buffers[3]; /* x_lo_um, x_hi_um, force_g as parsed */
    int held;
    double *built; /* window_um, x_mid_um, force_g: one malloc */
    const double *window_um, *x_mid_um, *force_g;
    Py_ssize_t n, subsamples;
    int drift_fitted;
} Samples;

static void release_samples(Samples *samples)
{
    for (int i = 0; i < samples->held; i++)
        PyBuffer_Release(&samples->buffers[i]);
    samples->held = 0;
    free(samples->built);
    samples->built = NULL;
}

/* Builds the layout from n samples (n >= 2): window_um, x_mid_um, and the force with a known drift
 * taken out; 0, or -1 with MemoryError set. */
static int lay_out_samples(Samples *samples, const double *x_lo_um, const double *x_hi_um, const double *force_g,
                           Py_ssize_t n, double drift_g_um, Py_ssize_t subsamples)
{
    samples->built = malloc(sizeof(double) * (size_t)((subsamples + 2) * n));
    if (samples->built == NULL) {
        PyErr_NoMemory();
        return -1;
    }
    double *window_um = samples->built, *x_mid_um = window_um + subsamples * n, *y_g = x_mid_um + n;
    samples->drift_fitted = isnan(drift_g_um);
    for (Py_ssize_t i = 0; i < n; i++) {
        double span_um = x_hi_um[i] - x_lo_um[i];
        for (Py_ssize_t k = 0; k < subsamples; k++)
            window_um[i * subsamples + k] = x_lo_um[i] + span_um * (((double)k + 0.5) / (double)subsamples);
        x_mid_um[i] = 0.5 * (x_lo_um[i] + x_hi_um[i]);
        y_g[i] = samples->drift_fitted ? force_g[i] : force_g[i] - drift_g_um * x_mid_um[i];
    }
    samples->window_um = window_um, samples->x_mid_um = x_mid_um, samples->force_g = y_g;
    samples->n = n, samples->subsamples = subsamples;
    return 0;
}

/* A "O&" converter like `float64_buffer` for a 1-D float64 array of any stride (a slice with a
 * step): the fit copies the samples it keeps anyway, so it reads them where they are. */
static int float64_strided(PyObject *object, void *view)
{
    Py_buffer *buffer = view;
    if (object == NULL) { /* a later argument failed: release this one (Py_CLEANUP_SUPPORTED) */
        PyBuffer_Release(buffer);
        return 1;
    }
    if (PyObject_GetBuffer(object, buffer, PyBUF_FORMAT | PyBUF_STRIDES) < 0)
        return 0;
    const char *format = buffer->format ? buffer->format : "B";
    if (format[0] == '<' || format[0] == '=' || format[0] == '@')
        format++;
    if (buffer->itemsize != (Py_ssize_t)sizeof(double) || strcmp(format, "d") != 0 || buffer->ndim != 1) {
        PyErr_Format(PyExc_TypeError, "expected a 1-D float64 array, got format '%s' in %d dimensions",
                     buffer->format, buffer->ndim);
        PyBuffer_Release(buffer);
        return 0;
    }
    return Py_CLEANUP_SUPPORTED;
}

/* Value i of a buffer from `float64_strided`. */
static inline double strided_at(const Py_buffer *buffer, Py_ssize_t i)
{
    return *(const double *)((const char *)buffer->buf + i * buffer->strides[0]);
}

/* Sample i and all before it are pressed past a toe ending at or above pressed_to[i] (running max
 * of the windows' tops); from i on all are free of a contact at or below free_from[i] (running min
 * from the end of the windows' bottoms). Both sorted, so a search bounds each candidate's run in
 * its toe, whatever the order of the samples. */
static void running_bounds(const Samples *s, double *pressed_to, double *free_from)
{
    Py_ssize_t n = s->n, sub = s->subsamples;
    for (Py_ssize_t i = 0; i < n; i++) {
        double top_um = s->window_um[i * sub + sub - 1];
        pressed_to[i] = (i == 0 || top_um > pressed_to[i - 1]) ? top_um : pressed_to[i - 1];
    }
    for (Py_ssize_t i = n - 1; i >= 0; i--) {
        double bottom_um = s->window_um[i * sub];
        free_from[i] = (i == n - 1 || bottom_um < free_from[i + 1]) ? bottom_um : free_from[i + 1];
    }
}

/* ---- Ordinary least squares (toe.py: _Projected, _rss_over_contacts, _solve, _stiffness_at) ---- */

/* The basis beside the toe, orthonormal: the baseline 1/√n, and with the drift fitted the centred
 * heights over their norm (the span np.linalg.qr gives; only the projection matters), else zeros
 * (they add nothing: the loops need not branch on it). The force with the basis projected out goes
 * to y_free; returns the number of basis columns. */
static int project_out_basis(const Samples *s, double *basis_rows, double *y_free)
{
    int drift_fitted = s->drift_fitted;
    Py_ssize_t n = s->n;
    double base = 1.0 / sqrt((double)n), mean_um = 0.0, norm2 = 0.0, y_base = 0.0, y_drift = 0.0;
    int m = drift_fitted ? 2 : 1;
    for (Py_ssize_t i = 0; i < n; i++)
        mean_um += s->x_mid_um[i];
    mean_um /= (double)n;
    for (Py_ssize_t i = 0; i < n; i++) {
        basis_rows[i] = base;
        basis_rows[n + i] = 0.0;
        y_base += base * s->force_g[i];
        if (drift_fitted) {
            double centred_um = s->x_mid_um[i] - mean_um;
            basis_rows[n + i] = centred_um;
            norm2 += centred_um * centred_um;
        }
    }
    if (drift_fitted) {
        double scale = 1.0 / sqrt(norm2);
        for (Py_ssize_t i = 0; i < n; i++) {
            basis_rows[n + i] *= scale;
            y_drift += basis_rows[n + i] * s->force_g[i];
        }
    }
    for (Py_ssize_t i = 0; i < n; i++)
        y_free[i] = s->force_g[i] - (base * y_base + (drift_fitted ? basis_rows[n + i] * y_drift : 0.0));
    return m;
}

/* toe.py's `_solve` for one candidate: the residual, or +inf where the toe would pull or cannot be
 * told from the basis; the stiffness (0 when unsolvable) in *stiffness. */
static double solve_rss(double hh_all, const double *h_basis, int m, double hy, double yy, double *stiffness)
{
    double basis_part = 0.0;
    for (int r = 0; r < m; r++)
        basis_part += h_basis[r] * h_basis[r];
    double hh = hh_all - basis_part;
    if (!(hh > 1e-9 * (hh_all + 1e-300))) {
        *stiffness = 0.0;
        return INFINITY;
    }
    *stiffness = hy / hh;
    return *stiffness > 0.0 ? yy - *stiffness * hy : INFINITY;
}

/* What every candidate of the plain fit shares (toe.py's `_Projected`): the basis and the force with
 * it projected out, the runs' bounds, and prefix sums over samples < i of 1, x, x², y, x y, B (m),
 * x B (m) (the pressed run of a candidate has h = a - x, so its sums are these combined; column k
 * at sums[k * (n + 1) + i]). One malloc at `work`. */
typedef struct {
    double *work;
    double *basis_rows, *y_free, *pressed_to, *free_from, *sums;
    int m;
    double yy;
} Projected;

/* 0, or -1 with MemoryError set (nothing to release). */
static int prepare_projected(const Samples *s, Projected *p)
{
    Py_ssize_t n = s->n, sums_n = n + 1;
    /* basis (2n), y_free (n), pressed_to, free_from (n each), prefix sums (9 columns × (n + 1)) */
    p->work = malloc(sizeof(double) * (size_t)(5 * n + 9 * sums_n));
    if (p->work == NULL) {
        PyErr_NoMemory();
        return -1;
    }
    p->basis_rows = p->work, p->y_free = p->work + 2 * n, p->pressed_to = p->work + 3 * n;
    p->free_from = p->work + 4 * n, p->sums = p->work + 5 * n;
    int m = p->m = project_out_basis(s, p->basis_rows, p->y_free);
    double yy = 0.0;
    for (Py_ssize_t i = 0; i < n; i++)
        yy += p->y_free[i] * p->y_free[i];
    p->yy = yy;
    running_bounds(s, p->pressed_to, p->free_from);
    int columns = 5 + 2 * m;
    double *sums = p->sums;
    const double *basis_rows = p->basis_rows;
    for (int k = 0; k < columns; k++)
        sums[k * sums_n] = 0.0;
    for (Py_ssize_t i = 0; i < n; i++) {
        double x = s->x_mid_um[i], y = p->y_free[i];
        double values[9] = {1.0, x, x * x, y, x * y, basis_rows[i], 0.0, 0.0, 0.0};
        if (m == 2) {
            values[6] = basis_rows[n + i];
            values[7] = x * basis_rows[i];
            values[8] = x * basis_rows[n + i];
        } else {
            values[6] = x * basis_rows[i];
        }
        for (int k = 0; k < columns; k++)
            sums[k * sums_n + i + 1] = sums[k * sums_n + i] + values[k];
    }
    return 0;
}

/* toe.py's `_rss_over_contacts`: the residual of every candidate (contacts_um[j], widths_um[j]),
 * both shapes, into rss_out[shape * candidates + j]. */
static void projected_grid(const Samples *s, const Projected *p, const double *contacts_um, const double *widths_um,
                           Py_ssize_t candidates, double *rss_out)
{
    Py_ssize_t n = s->n, sub = s->subsamples, sums_n = n + 1;
    int m = p->m;
    Py_ssize_t first = 0, last = 0;
    const double *basis0 = p->basis_rows, *basis1 = p->basis_rows + n, *y_free = p->y_free;
    for (Py_ssize_t j = 0; j < candidates; j++) {
        double c = contacts_um[j], w = widths_um[j];
        first = count_before(p->pressed_to, n, c - w, 1, first);
        last = count_before(p->free_from, n, c, 0, last);
        /* In-toe sums per shape (0, 1): h·B (both basis rows), h·h, h·y; scalars, so they stay in
         * registers. */
        double hb00 = 0.0, hb01 = 0.0, hb10 = 0.0, hb11 = 0.0, hh0 = 0.0, hh1 = 0.0, hy0 = 0.0, hy1 = 0.0;
#ifdef TOE_SSE2
        if (sub == 2) { /* both shapes side by side, each lane the scalar loop's sums below */
            __m128d scale = _mm_set1_pd(1.0 / (double)sub), b0 = _mm_setzero_pd(), b1 = b0, hh_pair = b0, hy_pair = b0;
            for (Py_ssize_t i = first; i < last; i++) {
                __m128d h = _mm_mul_pd(toe_pair(c, w, s->window_um + 2 * i), scale);
                b0 = _mm_add_pd(b0, _mm_mul_pd(h, _mm_set1_pd(basis0[i])));
                b1 = _mm_add_pd(b1, _mm_mul_pd(h, _mm_set1_pd(basis1[i])));
                hh_pair = _mm_add_pd(hh_pair, _mm_mul_pd(h, h));
                hy_pair = _mm_add_pd(hy_pair, _mm_mul_pd(h, _mm_set1_pd(y_free[i])));
            }
            double lanes[4][2];
            _mm_storeu_pd(lanes[0], b0);
            _mm_storeu_pd(lanes[1], b1);
            _mm_storeu_pd(lanes[2], hh_pair);
            _mm_storeu_pd(lanes[3], hy_pair);
            hb00 = lanes[0][0], hb10 = lanes[0][1], hb01 = lanes[1][0], hb11 = lanes[1][1];
            hh0 = lanes[2][0], hh1 = lanes[2][1], hy0 = lanes[3][0], hy1 = lanes[3][1];
        } else
#endif
        for (Py_ssize_t i = first; i < last; i++) {
            double h[SHAPES];
            toe_sums(c, w, s->window_um + i * sub, sub, h);
            double h0 = h[0] * (1.0 / (double)sub), h1 = h[1] * (1.0 / (double)sub);
            hb00 += h0 * basis0[i], hb01 += h0 * basis1[i];
            hb10 += h1 * basis0[i], hb11 += h1 * basis1[i];
            hh0 += h0 * h0, hh1 += h1 * h1;
            hy0 += h0 * y_free[i], hy1 += h1 * y_free[i];
        }
        double h_basis[SHAPES][2] = {{hb00, hb01}, {hb10, hb11}}, hh[SHAPES] = {hh0, hh1}, hy[SHAPES] = {hy0, hy1};
        const double *at = p->sums + first;
        for (int q = 0; q < SHAPES; q++) {
            double a = c - w * LIFT_DEFICIT[q]; /* the pressed samples: h = a - x */
            for (int r = 0; r < m; r++)
                h_basis[q][r] += a * at[(5 + r) * sums_n] - at[(5 + m + r) * sums_n];
            double hh_all = hh[q] + (a * at[0] - 2.0 * at[sums_n]) * a + at[2 * sums_n];
            double hy_all = hy[q] + a * at[3 * sums_n] - at[4 * sums_n];
            double stiffness;
            rss_out[q * candidates + j] = solve_rss(hh_all, h_basis[q], m, hy_all, p->yy, &stiffness);
        }
    }
}

/* toe.py's `_stiffness_at`: the toe's stiffness at one contact height and toe (shape 0 or 1), its
 * column evaluated over every sample up to the first from which all are free of the contact (there
 * the column is +0, which adds nothing to a sum begun at +0: the same bits as summing them). */
static double projected_stiffness(const Samples *s, const Projected *p, double contact_um, double width_um, int shape)
{
    Py_ssize_t n = s->n, sub = s->subsamples, touching = count_before(p->free_from, n, contact_um, 0, 0);
    double h_basis[2] = {0.0, 0.0}, hh_all = 0.0, hy = 0.0;
    for (Py_ssize_t i = 0; i < touching; i++) {
        double h[SHAPES];
        toe_sums(contact_um, width_um, s->window_um + i * sub, sub, h);
        double column = h[shape] * (1.0 / (double)sub);
        h_basis[0] += p->basis_rows[i] * column;
        h_basis[1] += p->basis_rows[n + i] * column;
        hh_all += column * column;
        hy += column * p->y_free[i];
    }
    double hh = hh_all - (h_basis[0] * h_basis[0] + h_basis[1] * h_basis[1]);
    return hh > 1e-9 * (hh_all + 1e-300) ? hy / hh : 0.0;
}

/* ---- Under white noise + a random walk (toe.py: _Whitened, _whiten, _rss_whitened) ---- */

/* The samples' three runs and the whitening of one walk-weighted fit (`_Whitened`), with what lets
 * a candidate skip the samples its toe does not reach: before its toe the column is a - x (its
 * differences do not depend on the candidate: `pressed_*`, the recursion run on them from the
 * start), after it 0 (the recursion decays geometrically: `tail_*`, its sums from each difference
 * on per unit of z before it). So a candidate costs a recursion over its toe's samples only. */
typedef struct {
    Py_ssize_t first_near, near_count;
    double yy;
    /* per difference j (between samples j and j + 1), n - 1 of each; one malloc at diag */
    double *diag, *inv_diag, *sub, *y_white;
    double *pressed_z, *pressed_zz, *pressed_zy; /* through difference j, h = a - x up to sample j + 1 */
    double *tail_zz, *tail_zy;                   /* from difference j on (n of these: none from n - 1) */
    double *pressed_to, *free_from;              /* per sample, as in rss_grid */
} Whitened;

/* `_Whitened.prepare`: 1 when prepared, 0 when the samples are not pressed, then in between, then
 * free (the caller fits without the walk), -1 on MemoryError. */
static int prepare_whitened(const Samples *s, double white_var_g2, double walk_var_g2, double lowest_contact_um,
                            double highest_contact_um, double widest_um, Whitened *wh)
{
    Py_ssize_t n = s->n, sub = s->subsamples, first = 0, count = 0;
    int order = 0; /* 0: pressed so far, 1: in between, 2: free air (the order the runs must come in) */
    for (Py_ssize_t i = 0; i < n; i++) {
        const double *row = s->window_um + i * sub;
        double lowest = row[0], highest = row[0];
        for (Py_ssize_t k = 1; k < sub; k++) {
            lowest = row[k] < lowest ? row[k] : lowest;
            highest = row[k] > highest ? row[k] : highest;
        }
        int pressed = highest <= lowest_contact_um - widest_um;
        int near = !pressed && lowest < highest_contact_um;
        first += pressed;
        count += near;
        if (pressed) {
            if (order != 0)
                return 0;
        } else if (near) {
            if (order == 2)
                return 0;
            order = 1;
        } else {
            order = 2;
        }
    }
    if (count < 2)
        return 0;
    Py_ssize_t m = n - 1;
    wh->first_near = first;
    wh->near_count = count;
    wh->diag = malloc(sizeof(double) * (size_t)(9 * m + 3 * n + 1));
    if (wh->diag == NULL) {
        PyErr_NoMemory();
        return -1;
    }
    double *diag = wh->diag, *inv_diag = diag + m, *subd = diag + 2 * m, *y_white = diag + 3 * m;
    double *pressed_z = diag + 4 * m, *pressed_zz = diag + 5 * m, *pressed_zy = diag + 6 * m;
    double *tail_zz = diag + 7 * m, *tail_zy = tail_zz + n, *pressed_to = tail_zy + n, *free_from = pressed_to + n;
    wh->inv_diag = inv_diag, wh->sub = subd, wh->y_white = y_white;
    wh->pressed_z = pressed_z, wh->pressed_zz = pressed_zz, wh->pressed_zy = pressed_zy;
    wh->tail_zz = tail_zz, wh->tail_zy = tail_zy, wh->pressed_to = pressed_to, wh->free_from = free_from;
    /* The bidiagonal Cholesky factor of the differences' covariance (2σ² + q, -σ² beside), and the
     * force's differences whitened through it. */
    diag[0] = sqrt(2.0 * white_var_g2 + walk_var_g2);
    subd[0] = 0.0;
    for (Py_ssize_t j = 1; j < m; j++) {
        subd[j] = -white_var_g2 / diag[j - 1];
        diag[j] = sqrt(2.0 * white_var_g2 + walk_var_g2 - subd[j] * subd[j]);
    }
    double previous = 0.0, yy = 0.0;
    for (Py_ssize_t j = 0; j < m; j++) {
        inv_diag[j] = 1.0 / diag[j];
        previous = ((s->force_g[j + 1] - s->force_g[j]) - subd[j] * previous) / diag[j];
        y_white[j] = previous;
        yy += previous * previous;
    }
    wh->yy = yy;
    double z = 0.0, zz = 0.0, zy = 0.0;
    for (Py_ssize_t j = 0; j < m; j++) {
        z = (-(s->x_mid_um[j + 1] - s->x_mid_um[j]) - subd[j] * z) * inv_diag[j];
        zz += z * z;
        zy += z * y_white[j];
        pressed_z[j] = z, pressed_zz[j] = zz, pressed_zy[j] = zy;
    }
    tail_zz[m] = tail_zy[m] = 0.0;
    for (Py_ssize_t j = m - 1; j >= 0; j--) {
        double gain = -subd[j] * inv_diag[j];
        tail_zz[j] = gain * gain * (1.0 + tail_zz[j + 1]);
        tail_zy[j] = gain * (y_white[j] + tail_zy[j + 1]);
    }
    running_bounds(s, pressed_to, free_from);
    return 1;
}

/* `_rss_whitened` for one candidate toe, both shapes: its toe column over the samples from the
 * last one pressed past its toe to the first one from which all are free, differenced and whitened
 * by the recursion, the parts before and after from the prepared sums; residuals (white-noise
 * units) and stiffnesses per shape. hints: where the searches of the previous candidate ended. */
static void whitened_candidate(const Samples *s, const Whitened *wh, double contact_um, double width_um,
                               Py_ssize_t hints[2], double rss[SHAPES], double stiffness[SHAPES])
{
    Py_ssize_t n = s->n, sub = s->subsamples, end = wh->first_near + wh->near_count;
    hints[0] = count_before(wh->pressed_to, n, contact_um - width_um, 1, hints[0]);
    hints[1] = count_before(wh->free_from, n, contact_um, 0, hints[1]);
    /* Samples before `start` are pressed past the toe (h = a - x); from `stop` on all are free (h = 0). */
    Py_ssize_t start = hints[0] > wh->first_near ? hints[0] : wh->first_near;
    Py_ssize_t stop = hints[1] > start ? hints[1] : start;
    stop = stop < end ? stop : end;
    double previous_h[SHAPES] = {0.0, 0.0}, z[SHAPES] = {0.0, 0.0}, zz[SHAPES] = {0.0, 0.0}, zy[SHAPES] = {0.0, 0.0};
    Py_ssize_t j = start > 0 ? start - 1 : 0; /* the next difference */
    if (start > 0) {
        for (int p = 0; p < SHAPES; p++) {
            previous_h[p] = (contact_um - width_um * LIFT_DEFICIT[p]) - s->x_mid_um[start - 1];
            if (start >= 2)
                z[p] = wh->pressed_z[start - 2], zz[p] = wh->pressed_zz[start - 2], zy[p] = wh->pressed_zy[start - 2];
        }
    }
#ifdef TOE_SSE2
    if (sub == 2) { /* both shapes side by side, each lane the scalar loop's recursion below */
        __m128d divisor = _mm_set1_pd((double)sub), previous = _mm_loadu_pd(previous_h), z_pair = _mm_loadu_pd(z);
        __m128d zz_pair = _mm_loadu_pd(zz), zy_pair = _mm_loadu_pd(zy);
        for (Py_ssize_t i = start; i <= stop && i < n; i++) {
            __m128d h = _mm_div_pd(toe_pair(contact_um, width_um, s->window_um + 2 * i), divisor);
            if (i > 0) {
                z_pair = _mm_mul_pd(_mm_sub_pd(_mm_sub_pd(h, previous), _mm_mul_pd(_mm_set1_pd(wh->sub[j]), z_pair)),
                                    _mm_set1_pd(wh->inv_diag[j]));
                zz_pair = _mm_add_pd(zz_pair, _mm_mul_pd(z_pair, z_pair));
                zy_pair = _mm_add_pd(zy_pair, _mm_mul_pd(z_pair, _mm_set1_pd(wh->y_white[j])));
                j++;
            }
            previous = h;
        }
        _mm_storeu_pd(z, z_pair);
        _mm_storeu_pd(zz, zz_pair);
        _mm_storeu_pd(zy, zy_pair);
    } else
#endif
    for (Py_ssize_t i = start; i <= stop && i < n; i++) {
        double h[SHAPES];
        toe_sums(contact_um, width_um, s->window_um + i * sub, sub, h);
        h[0] /= (double)sub, h[1] /= (double)sub;
        if (i > 0) { /* a difference: to sample i from the one before */
            for (int p = 0; p < SHAPES; p++) {
                z[p] = ((h[p] - previous_h[p]) - wh->sub[j] * z[p]) * wh->inv_diag[j];
                zz[p] += z[p] * z[p];
                zy[p] += z[p] * wh->y_white[j];
            }
            j++;
        }
        previous_h[0] = h[0], previous_h[1] = h[1];
    }
    for (int p = 0; p < SHAPES; p++) {
        double hh = zz[p] + z[p] * z[p] * wh->tail_zz[j];
        double hy = zy[p] + z[p] * wh->tail_zy[j];
        int usable = hh > 1e-12;
        stiffness[p] = usable ? hy / hh : 0.0;
        rss[p] = usable && stiffness[p] > 0.0 ? wh->yy - stiffness[p] * hy : INFINITY;
    }
}

/* ---- The contact with the toe marginalised out (toe.py: marginal_contact_um) ---- */

/* One toe's row of residuals over the contact grid: its parabola through the least residual and
 * its neighbours (best height, residual there, the Gaussian's variance in c). 0 when the least is
 * at an end, a neighbour is infinite or the row is not curved upwards there. */
static int toe_minimum(const double *rss, Py_ssize_t count, const double *heights_um, double step_um,
                       double noise_var, double *centre_um, double *lowest, double *var_um2)
{
    Py_ssize_t k = 0;
    for (Py_ssize_t i = 1; i < count; i++)
        if (rss[i] < rss[k]) /* the first of equal least values, as argmin */
            k = i;
    if (!(k > 0 && k < count - 1))
        return 0;
    double before = rss[k - 1], at = rss[k], after = rss[k + 1];
    if (!(isfinite(before) && isfinite(after)))
        return 0;
    double bend = before - 2.0 * at + after;
    if (!(bend > 0.0))
        return 0;
    double offset = 0.5 * (before - after) / bend;
    *centre_um = heights_um[k] + offset * step_um;
    *lowest = at - 0.25 * offset * (before - after);
    *var_um2 = 2.0 * noise_var * step_um * step_um / bend;
    return 1;
}

/* One toe's `toe_minimum`, kept for the passes of `marginal_of` (and the shapes' own marginals), with
 * its weight in the marginal `marginal_of` last computed (its third pass reads what its second found). */
typedef struct {
    double centre_um, lowest, var_um2, weight;
    int found;
} ToeMinimum;

/* `toe_minimum` of each of `toes` rows, once (PyMem; NULL with MemoryError set). */
static ToeMinimum *toe_minima(const double *heights_um, Py_ssize_t count, const double *rss, Py_ssize_t toes,
                              double noise_var)
{
    ToeMinimum *minima = PyMem_Malloc(sizeof(ToeMinimum) * (size_t)(toes > 0 ? toes : 1));
    if (minima == NULL) {
        PyErr_NoMemory();
        return NULL;
    }
    double step_um = heights_um[1] - heights_um[0];
    for (Py_ssize_t t = 0; t < toes; t++) {
        ToeMinimum *toe = &minima[t];
        toe->found = toe_minimum(rss + t * count, count, heights_um, step_um, noise_var, &toe->centre_um, &toe->lowest,
                                 &toe->var_um2);
    }
    return minima;
}

/* The mean and sd of the contact over `toes` toes' minima (toe.py `marginal_contact_um`'s arithmetic);
 * 0 when no toe has a curved interior minimum. */
static int marginal_of(ToeMinimum *minima, Py_ssize_t toes, const double *prior, double noise_var,
                       double *mean_out_um, double *sd_out_um)
{
    /* Three passes over the toes (a score of them): the least residual; the weights (kept) and their
     * total and mean; the spread about the mean. */
    double least = INFINITY, total = 0.0, weighted = 0.0, spread = 0.0;
    int any = 0;
    for (Py_ssize_t t = 0; t < toes; t++)
        if (minima[t].found) {
            least = any && least <= minima[t].lowest ? least : minima[t].lowest;
            any = 1;
        }
    if (!any)
        return 0;
    for (Py_ssize_t t = 0; t < toes; t++)
        if (minima[t].found) {
            double weight = exp(-(minima[t].lowest - least) / (2.0 * noise_var)) * sqrt(minima[t].var_um2) * prior[t];
            minima[t].weight = weight;
            total += weight;
            weighted += weight * minima[t].centre_um;
        }
    double mean_um = weighted / total;
    for (Py_ssize_t t = 0; t < toes; t++)
        if (minima[t].found) {
            const ToeMinimum *toe = &minima[t];
            spread += toe->weight * (toe->var_um2 + (toe->centre_um - mean_um) * (toe->centre_um - mean_um));
        }
    spread /= total;
    *mean_out_um = mean_um;
    *sd_out_um = sqrt(spread > 0.0 ? spread : 0.0);
    return 1;
}

/* Half the range of the shapes' own marginals (toe.py's `shape_spread_um`): `minima` and `prior` in
 * `shapes` equal blocks, one a shape (its widths); the highest and lowest of the marginals that exist
 * (the twin's max - min), 0 unless two shapes have one. */
static double shapes_spread_um(ToeMinimum *minima, Py_ssize_t toes, Py_ssize_t shapes, const double *prior,
                               double noise_var)
{
    Py_ssize_t widths = toes / shapes;
    double highest_um = -INFINITY, lowest_um = INFINITY, shape_mean_um, shape_sd_um;
    int known = 0;
    for (Py_ssize_t k = 0; k < shapes; k++)
        if (marginal_of(minima + k * widths, widths, prior + k * widths, noise_var, &shape_mean_um, &shape_sd_um)) {
            highest_um = known && highest_um >= shape_mean_um ? highest_um : shape_mean_um;
            lowest_um = known && lowest_um <= shape_mean_um ? lowest_um : shape_mean_um;
            known++;
        }
    return known > 1 ? 0.5 * (highest_um - lowest_um) : 0.0;
}

/* The arrays of the marginal kernels, checked: heights (count >= 2), prior (toes), rss (toes × count). */
static int load_marginal(Py_buffer *heights_buffer, Py_buffer *rss_buffer, Py_buffer *prior_buffer,
                         const double **heights_um, Py_ssize_t *count, const double **rss, const double **prior,
                         Py_ssize_t *toes)
{
    *heights_um = doubles_of(heights_buffer, count, "contacts_um");
    *prior = doubles_of(prior_buffer, toes, "prior");
    *rss = doubles_sized(rss_buffer, *count * *toes, "rss");
    if (*heights_um == NULL || *prior == NULL || *rss == NULL)
        return 0;
    if (*count < 2) {
        PyErr_Format(PyExc_ValueError, "contacts_um: %zd heights, at least 2 expected", *count);
        return 0;
    }
    return 1;
}

/* marginal_contact (with_spread 0: (mean, sd)) and marginal_contact_and_spread (1: also half the
 * range of each shape's own marginal, `shape_spread_um`: rss and prior in `shapes` equal blocks of
 * rows, each shape's widths), each toe's minimum found once for all of them. */
static PyObject *marginal(PyObject *args, int with_spread)
{
    Py_buffer heights_buffer, rss_buffer, prior_buffer;
    double noise_var;
    Py_ssize_t shapes = 1;
    if (!PyArg_ParseTuple(args, with_spread ? "O&O&dO&n" : "O&O&dO&", float64_buffer, &heights_buffer, float64_buffer,
                          &rss_buffer, &noise_var, float64_buffer, &prior_buffer, &shapes))
        return NULL;
    PyObject *result = NULL;
    Py_ssize_t count = 0, toes = 0;
    const double *heights_um, *rss, *prior;
    double mean_um, sd_um;
    ToeMinimum *minima = NULL;
    if (!load_marginal(&heights_buffer, &rss_buffer, &prior_buffer, &heights_um, &count, &rss, &prior, &toes))
        goto done;
    if (shapes < 1 || toes % shapes != 0) {
        PyErr_Format(PyExc_ValueError, "shapes: %zd does not divide the %zd toes", shapes, toes);
        goto done;
    }
    minima = toe_minima(heights_um, count, rss, toes, noise_var);
    if (minima == NULL)
        goto done;
    if (!marginal_of(minima, toes, prior, noise_var, &mean_um, &sd_um)) {
        result = Py_NewRef(Py_None);
        goto done;
    }
    if (!with_spread) {
        result = Py_BuildValue("dd", mean_um, sd_um);
        goto done;
    }
    result = Py_BuildValue("ddd", mean_um, sd_um, shapes_spread_um(minima, toes, shapes, prior, noise_var));
done:
    PyMem_Free(minima);
    PyBuffer_Release(&heights_buffer);
    PyBuffer_Release(&rss_buffer);
    PyBuffer_Release(&prior_buffer);
    return result;
}

static PyObject *marginal_contact(PyObject *self, PyObject *args)
{
    (void)self;
    return marginal(args, 0);
}

/* toe.py's `shape_spread_um` (with the marginal over every toe, which comes with it). */
static PyObject *marginal_contact_and_spread(PyObject *self, PyObject *args)
{
    (void)self;
    return marginal(args, 1);
}

/* ---- One tap's whole toe fit (toe.py: fit_toe) ---- */

/* toe.py's `fit_toe` with the grids of `_toe_grid_native` (both shapes): the samples kept near the
 * start, the walk-weighted grid when the walk matters and the samples allow it, else the plain
 * one, the least residual's toe, the marginal contact and the stiffness there, in one call. The
 * contact heights and the residual grid go into contacts_out and rss_out (the pooling keeps them);
 * returns (contact_um, sigma_um, shape, width index, stiffness_g_um, residual variance, residual
 * sigma g, the shapes' spread `shape_spread_um`), or None where fit_toe returns None. */
static PyObject *fit(PyObject *self, PyObject *args)
{
    (void)self;
    Samples s = {0};
    Py_buffer offsets_buffer, widths_buffer, prior_buffer, contacts_buffer, rss_buffer;
    double contact0_um, spacing_um, drift_g_um, white_var_g2, walk_var_g2, above_um, penetration_um, wander_share;
    Py_ssize_t departure_samples, subsamples, min_samples;
    if (!PyArg_ParseTuple(args, "O&O&O&ddddd(dnddnnO&O&O&)w*w*", float64_strided, &s.buffers[0], float64_strided,
                          &s.buffers[1], float64_strided, &s.buffers[2], &contact0_um, &spacing_um, &drift_g_um,
                          &white_var_g2, &walk_var_g2, &above_um, &departure_samples, &penetration_um, &wander_share,
                          &subsamples, &min_samples, float64_buffer, &offsets_buffer, float64_buffer, &widths_buffer,
                          float64_buffer, &prior_buffer, &contacts_buffer, &rss_buffer))
        return NULL;
    PyObject *result = NULL;
    double *kept = NULL, *grid_c = NULL;
    ToeMinimum *minima = NULL;
    Projected plain = {0};
    Whitened wh = {0};
    s.held = 3;
    Py_ssize_t n = s.buffers[0].shape[0], count = 0, widths_n = 0;
    for (int i = 1; i < 3; i++)
        if (s.buffers[i].shape[0] != n) {
            PyErr_Format(PyExc_ValueError, "%s: %zd values, %zd expected", i == 1 ? "x_hi_um" : "force_g",
                         s.buffers[i].shape[0], n);
            goto done;
        }
    const Py_buffer *x_lo_um = &s.buffers[0], *x_hi_um = &s.buffers[1], *force_g = &s.buffers[2];
    const double *offsets_um = doubles_of(&offsets_buffer, &count, "offsets_um");
    const double *widths_um = offsets_um == NULL ? NULL : doubles_of(&widths_buffer, &widths_n, "widths_um");
    const double *prior = widths_um == NULL ? NULL : doubles_sized(&prior_buffer, SHAPES * widths_n, "prior");
    double *contacts_um = prior == NULL ? NULL : doubles_sized(&contacts_buffer, count, "contacts_out");
    double *rss = contacts_um == NULL ? NULL : doubles_sized(&rss_buffer, SHAPES * widths_n * count, "rss_out");
    if (rss == NULL)
        goto done;
    if (count < 2 || widths_n < 1 || subsamples < 1 || subsamples > 64 || min_samples < 2) {
        PyErr_Format(PyExc_ValueError,
                     "%zd contacts, %zd widths, %zd subsamples, at least %zd samples: 2+, 1+, 1..64 and 2+ expected",
                     count, widths_n, subsamples, min_samples);
        goto done;
    }
    /* The samples near the start: below the highest candidate plus the departure's reach, above
     * the deepest penetration (toe.py's `keep`, the same sums). */
    double top_um = contact0_um + above_um + (double)departure_samples * spacing_um;
    double bottom_um = contact0_um - penetration_um;
    kept = malloc(sizeof(double) * (size_t)(3 * (n > 0 ? n : 1)));
    if (kept == NULL) {
        PyErr_NoMemory();
        goto done;
    }
    Py_ssize_t samples = 0;
    for (Py_ssize_t i = 0; i < n; i++) {
        double lo_um = strided_at(x_lo_um, i), hi_um = strided_at(x_hi_um, i);
        if (lo_um < top_um && hi_um > bottom_um) {
            kept[samples] = lo_um, kept[n + samples] = hi_um, kept[2 * n + samples] = strided_at(force_g, i);
            samples++;
        }
    }
    if (samples < min_samples) {
        result = Py_NewRef(Py_None);
        goto done;
    }
    if (lay_out_samples(&s, kept, kept + n, kept + 2 * n, samples, drift_g_um, subsamples) < 0)
        goto done;
    /* The candidates, widths × contacts, contacts fastest (toe.py's _GRID_OFFSETS_UM, _GRID_WIDTHS_UM). */
    Py_ssize_t candidates = widths_n * count, toes = SHAPES * widths_n;
    grid_c = malloc(sizeof(double) * (size_t)(2 * candidates));
    if (grid_c == NULL) {
        PyErr_NoMemory();
        goto done;
    }
    double *grid_w = grid_c + candidates;
    for (Py_ssize_t k = 0; k < count; k++)
        contacts_um[k] = contact0_um + offsets_um[k];
    for (Py_ssize_t w = 0; w < widths_n; w++)
        for (Py_ssize_t k = 0; k < count; k++) {
            grid_c[w * count + k] = contacts_um[k];
            grid_w[w * count + k] = widths_um[w];
        }
    /* The walk-weighted fit has no drift column: a drift to be fitted runs the plain fit. */
    int walk = !isnan(white_var_g2) && !s.drift_fitted && walk_var_g2 * (double)samples > wander_share * white_var_g2;
    int whitened = 0;
    if (walk) {
        whitened = prepare_whitened(&s, white_var_g2, walk_var_g2, contacts_um[0], contacts_um[count - 1],
                                    widths_um[widths_n - 1], &wh);
        if (whitened < 0)
            goto done;
    }
    if (whitened) {
        Py_ssize_t hints[2] = {0, 0};
        for (Py_ssize_t j = 0; j < candidates; j++) {
            double toe_rss[SHAPES], stiffness[SHAPES];
            whitened_candidate(&s, &wh, grid_c[j], grid_w[j], hints, toe_rss, stiffness);
            rss[j] = toe_rss[0];
            rss[candidates + j] = toe_rss[1];
        }
    } else {
        if (prepare_projected(&s, &plain) < 0)
            goto done;
        projected_grid(&s, &plain, grid_c, grid_w, candidates, rss);
    }
    /* The least residual (np.argmin: the first of equal values, the first NaN if any). */
    Py_ssize_t best = 0;
    for (Py_ssize_t i = 0; i < SHAPES * candidates; i++) {
        if (isnan(rss[i])) {
            best = i;
            break;
        }
        if (rss[i] < rss[best])
            best = i;
    }
    double least = rss[best];
    if (!isfinite(least)) {
        result = Py_NewRef(Py_None);
        goto done;
    }
    Py_ssize_t shape = best / count / widths_n, width_index = best / count % widths_n;
    Py_ssize_t dof = samples - 4 - (s.drift_fitted ? 2 : 1); /* the toe's c, w, p, k and the basis */
    double residual_var = least / (double)(dof > 1 ? dof : 1);
    residual_var = 1e-12 > residual_var ? 1e-12 : residual_var; /* max(least / dof, 1e-12) */
    minima = toe_minima(contacts_um, count, rss, toes, residual_var);
    if (minima == NULL)
        goto done;
    double contact_um, sigma_um;
    if (!marginal_of(minima, toes, prior, residual_var, &contact_um, &sigma_um)) {
        result = Py_NewRef(Py_None);
        goto done;
    }
    double width_um = widths_um[width_index], stiffness_g_um, unit_g2 = 1.0;
    if (whitened) {
        double toe_rss[SHAPES], stiffness[SHAPES];
        Py_ssize_t hints[2] = {0, 0};
        whitened_candidate(&s, &wh, contact_um, width_um, hints, toe_rss, stiffness);
        stiffness_g_um = stiffness[shape];
        unit_g2 = white_var_g2;
    } else {
        stiffness_g_um = projected_stiffness(&s, &plain, contact_um, width_um, (int)shape);
    }
    /* The shape part of z_sigma_um (`shape_spread_um`) from the same minima, as marginal_contact_and_spread
     * finds it from the grid: computed here, it costs no second pass over the grid. */
    result = Py_BuildValue("ddnndddd", contact_um, sigma_um, shape, width_index, stiffness_g_um, residual_var,
                           sqrt(residual_var * unit_g2), shapes_spread_um(minima, toes, SHAPES, prior, residual_var));
done:
    free(kept);
    free(grid_c);
    PyMem_Free(minima);
    free(plain.work);
    free(wh.diag);
    release_samples(&s);
    PyBuffer_Release(&offsets_buffer);
    PyBuffer_Release(&widths_buffer);
    PyBuffer_Release(&prior_buffer);
    PyBuffer_Release(&contacts_buffer);
    PyBuffer_Release(&rss_buffer);
    return result;
}

/* ---- The baseline's walk from free air (toe.py: free_air_variogram, free_air_walks) ---- */

/* The slope of a segment's straight line against the centred sample index t: (t·f) / (t·t). */
static double line_slope(const double *force_g, Py_ssize_t n)
{
    double tf = 0.0, tt = 0.0;
    for (Py_ssize_t k = 0; k < n; k++) {
        double t = (double)k - 0.5 * (double)(n - 1);
        tf += t * force_g[k];
        tt += t * t;
    }
    return tf / tt;
}

/* The mean of (r[k + lag] - r[k])² over the segment, r the force with its line fitted out (the
 * mean cancels, the line leaves lag × slope): r is never stored. 1 <= lag < n. */
static double lag_mean_square(const double *force_g, Py_ssize_t n, Py_ssize_t lag, double slope)
{
    double sum = 0.0;
    for (Py_ssize_t k = 0; k + lag < n; k++) {
        double d = (force_g[k + lag] - force_g[k]) - (double)lag * slope;
        sum += d * d;
    }
    return sum / (double)(n - lag);
}

/* lag_mean_square of each of `count` lags (each 1 <= lag < n) into out, four lags at a time: each
 * lag's sum still runs over k in order (the same bits as one lag at a time), and four independent sums
 * keep the adder busy where one waits on its last addition. */
static void lag_mean_squares_of(const double *force_g, Py_ssize_t n, const Py_ssize_t *lags, Py_ssize_t count,
                                double slope, double *out)
{
    Py_ssize_t l = 0;
    for (; l + 4 <= count; l += 4) {
        const Py_ssize_t *lag = lags + l;
        double offset[4], sum[4] = {0.0, 0.0, 0.0, 0.0};
        Py_ssize_t longest = 0;
        for (int j = 0; j < 4; j++) {
            offset[j] = (double)lag[j] * slope;
            longest = lag[j] > longest ? lag[j] : longest;
        }
        Py_ssize_t k = 0;
        for (; k + longest < n; k++) { /* every lag's pair is there */
            const double at = force_g[k];
            for (int j = 0; j < 4; j++) {
                const double d = (force_g[k + lag[j]] - at) - offset[j];
                sum[j] += d * d;
            }
        }
        for (int j = 0; j < 4; j++) {
            for (Py_ssize_t rest = k; rest + lag[j] < n; rest++) { /* the shorter lags' last pairs */
                const double d = (force_g[rest + lag[j]] - force_g[rest]) - offset[j];
                sum[j] += d * d;
            }
            out[l + j] = sum[j] / (double)(n - lag[j]);
        }
    }
    for (; l < count; l++)
        out[l] = lag_mean_square(force_g, n, lags[l], slope);
}

static PyObject *lag_mean_squares(PyObject *self, PyObject *args)
{
    (void)self;
    Py_buffer force_buffer;
    PyObject *lags;
    if (!PyArg_ParseTuple(args, "O&O!", float64_buffer, &force_buffer, &PyTuple_Type, &lags))
        return NULL;
    PyObject *result = NULL;
    Py_ssize_t n = 0, count = PyTuple_GET_SIZE(lags), *lag_of = NULL;
    double *measured = NULL;
    const double *force_g = doubles_of(&force_buffer, &n, "force_g");
    if (force_g == NULL)
        goto done;
    if (n < 2) {
        PyErr_Format(PyExc_ValueError, "force_g: %zd samples, at least 2 expected", n);
        goto done;
    }
    lag_of = PyMem_Malloc(sizeof(Py_ssize_t) * (size_t)(count > 0 ? count : 1));
    measured = PyMem_Malloc(sizeof(double) * (size_t)(count > 0 ? count : 1));
    if (lag_of == NULL || measured == NULL) {
        PyErr_NoMemory();
        goto done;
    }
    for (Py_ssize_t l = 0; l < count; l++) {
        Py_ssize_t lag = PyLong_AsSsize_t(PyTuple_GET_ITEM(lags, l));
        if (lag == -1 && PyErr_Occurred())
            goto done;
        if (lag < 1 || lag >= n) {
            PyErr_Format(PyExc_ValueError, "lags: %zd for %zd samples, 1..%zd allowed", lag, n, n - 1);
            goto done;
        }
        lag_of[l] = lag;
    }
    lag_mean_squares_of(force_g, n, lag_of, count, line_slope(force_g, n), measured);
    result = PyList_New(count);
    for (Py_ssize_t l = 0; result != NULL && l < count; l++) {
        PyObject *value = PyFloat_FromDouble(measured[l]);
        if (value == NULL) {
            Py_CLEAR(result);
            break;
        }
        PyList_SET_ITEM(result, l, value);
    }
done:
    PyMem_Free(lag_of);
    PyMem_Free(measured);
    PyBuffer_Release(&force_buffer);
    return result;
}

/* 2^53: below it every integer, and so every multiple of 0.25 below 2^51, is a double. */
#define EXACT_UNITS 9007199254740992.0

/* toe.py's `_detrended_variogram` for n samples at `lags`: per lag, (its mean squared difference for
 * unit white noise, for a unit walk) once a line is fitted out, in the twin's closed form and
 * operations. The cumulative sums run in numpy's order (np.cumsum adds left to right); the two dot
 * products (t·t, t·f: BLAS sums them in its own order) are exact, so every order gives the same:
 * t and f are multiples of 1/2 (2t and 2f integers), their products of 1/4, and while the sum of the
 * products' sizes stays under 2^51 every partial sum is a double. Longer segments than that (t·f
 * grows as n^5: past ~2,000 samples) return None and the twin runs. Error: -1 (exception set). */
static int detrended_variogram_of(Py_ssize_t n, const Py_ssize_t *lags, Py_ssize_t count, double *white,
                                  double *walk)
{
    double *f = malloc(sizeof(double) * (size_t)(2 * n + 1));
    if (f == NULL) {
        PyErr_NoMemory();
        return -1;
    }
    double *f_sums = f + n; /* n + 1: f_sums[m] = the sum of f(k) over k < m */
    const double middle = 0.5 * (double)(n - 1);
    /* f(m) = cumsum(k t)[m] - k cumsum(t)[m], each cumulative sum starting at its first term */
    double kt_sum = 0.0, t_sum = 0.0, tt_units = 0.0;
    for (Py_ssize_t k = 0; k < n; k++) {
        const double kd = (double)k, t = kd - middle;
        kt_sum = k == 0 ? kd * t : kt_sum + kd * t;
        t_sum = k == 0 ? t : t_sum + t;
        f[k] = kt_sum - kd * t_sum;
        tt_units += 4.0 * (t * t); /* (2t)^2: an integer, exact while the total stays under 2^53 */
    }
    f_sums[0] = 0.0;
    for (Py_ssize_t k = 0; k < n; k++)
        f_sums[k + 1] = k == 0 ? f[0] : f_sums[k] + f[k];
    /* t·f in units of 1/4: (2t)(2f), integers; their sizes' sum bounds every partial sum */
    double tf_units = 0.0, size_units = 0.0;
    for (Py_ssize_t k = 0; k < n && size_units < EXACT_UNITS; k++) {
        const double product = (2.0 * ((double)k - middle)) * (2.0 * f[k]);
        tf_units += product;
        size_units += fabs(product);
    }
    if (!(tt_units < EXACT_UNITS && size_units < EXACT_UNITS)) {
        free(f);
        return 0; /* too long to be exact: the twin's own sums */
    }
    const double s = tt_units / 4.0, tf = tf_units / 4.0;
    for (Py_ssize_t l = 0; l < count; l++) {
        const Py_ssize_t at = lags[l];
        const double lag = (double)at;
        const double mean_df = (f_sums[n] - f_sums[at] - f_sums[n - at]) / ((double)n - lag);
        white[l] = 2.0 - lag * lag / s;
        const double share = lag / s;
        walk[l] = lag - 2.0 * share * mean_df + (share * share) * tf;
    }
    free(f);
    return 1;
}

/* Longer segments are not even tried (t·f stops being exact near 2,930 samples). */
#define DETRENDED_MOST_SAMPLES 8192

/* The lags of a tuple of ints for n samples (at least 2), each 1..n-1, in a PyMem_Malloc'd array
 * (its length in *count); NULL with the exception set otherwise. */
static Py_ssize_t *lags_of(PyObject *lag_tuple, Py_ssize_t n, Py_ssize_t *count)
{
    *count = PyTuple_GET_SIZE(lag_tuple);
    if (n < 2) {
        PyErr_Format(PyExc_ValueError, "n: %zd samples, at least 2 expected", n);
        return NULL;
    }
    Py_ssize_t *lags = PyMem_Malloc(sizeof(Py_ssize_t) * (size_t)(*count > 0 ? *count : 1));
    if (lags == NULL) {
        PyErr_NoMemory();
        return NULL;
    }
    for (Py_ssize_t l = 0; l < *count; l++) {
        lags[l] = PyLong_AsSsize_t(PyTuple_GET_ITEM(lag_tuple, l));
        if (lags[l] == -1 && PyErr_Occurred())
            goto fail;
        if (lags[l] < 1 || lags[l] >= n) {
            PyErr_Format(PyExc_ValueError, "lags: %zd for %zd samples, 1..%zd allowed", lags[l], n, n - 1);
            goto fail;
        }
    }
    return lags;
fail:
    PyMem_Free(lags);
    return NULL;
}

/* `detrended_variogram_of` into a PyMem_Malloc'd array at *values (white per lag, then walk per
 * lag): 1; 0 where it cannot be exact (past DETRENDED_MOST_SAMPLES or its sums' bound: the twin's);
 * -1 with the exception set. Free *values (NULL or the array) whatever it answers. */
static int expected_variogram(Py_ssize_t n, const Py_ssize_t *lags, Py_ssize_t count, double **values)
{
    *values = NULL;
    if (n > DETRENDED_MOST_SAMPLES)
        return 0; /* far past where t·f can be exact */
    *values = PyMem_Malloc(sizeof(double) * (size_t)(2 * (count > 0 ? count : 1)));
    if (*values == NULL) {
        PyErr_NoMemory();
        return -1;
    }
    return detrended_variogram_of(n, lags, count, *values, *values + count);
}

static PyObject *detrended_variogram(PyObject *self, PyObject *args)
{
    (void)self;
    Py_ssize_t n, count;
    PyObject *lag_tuple;
    if (!PyArg_ParseTuple(args, "nO!", &n, &PyTuple_Type, &lag_tuple))
        return NULL;
    Py_ssize_t *lags = lags_of(lag_tuple, n, &count);
    if (lags == NULL)
        return NULL;
    PyObject *result = NULL;
    double *values;
    int found = expected_variogram(n, lags, count, &values);
    if (found < 0)
        goto done;
    if (!found) {
        result = Py_NewRef(Py_None);
        goto done;
    }
    result = PyTuple_New(count);
    for (Py_ssize_t l = 0; result != NULL && l < count; l++) {
        PyObject *pair = Py_BuildValue("(dd)", values[l], values[count + l]);
        if (pair == NULL) {
            Py_CLEAR(result);
            break;
        }
        PyTuple_SET_ITEM(result, l, pair);
    }
done:
    PyMem_Free(lags);
    PyMem_Free(values);
    return result;
}

/* toe.py's `_free_air_model` for n samples at `lags` (`_variogram_lags`'), into `model` (a row per
 * lag: the lag, `detrended_variogram_of`'s white and walk, `_height_pull_per_step4`'s
 * lag^2 ((n - lag)^2 - 1) / 12). The pull's integer is exact in 64 bits and as a double (under 2^53
 * while n <= DETRENDED_MOST_SAMPLES and the lags are under n), then divided by 12 as Python divides
 * an int by a float: the same bits. False (nothing written) where detrended_variogram answers None:
 * the twin fills the rows then. */
static PyObject *free_air_model(PyObject *self, PyObject *args)
{
    (void)self;
    Py_ssize_t n, count;
    PyObject *lag_tuple;
    Py_buffer mb = {0};
    if (!PyArg_ParseTuple(args, "nO!O&", &n, &PyTuple_Type, &lag_tuple, float64_out, &mb))
        return NULL;
    PyObject *result = NULL;
    double *values = NULL;
    Py_ssize_t *lags = lags_of(lag_tuple, n, &count);
    if (lags == NULL)
        goto done;
    double *model = doubles_sized(&mb, 4 * count, "model");
    if (model == NULL)
        goto done;
    int found = expected_variogram(n, lags, count, &values);
    if (found < 0)
        goto done;
    for (Py_ssize_t l = 0; found && l < count; l++) {
        const long long lag = (long long)lags[l], rest = (long long)n - lag;
        double *row = model + 4 * l;
        row[0] = (double)lag;
        row[1] = values[l];
        row[2] = values[count + l];
        row[3] = (double)(lag * lag * (rest * rest - 1)) / 12.0;
    }
    result = Py_NewRef(found ? Py_True : Py_False);
done:
    PyMem_Free(lags);
    PyMem_Free(values);
    PyBuffer_Release(&mb);
    return result;
}

/* The sums of products of the least squares in white, walk and height pull (toe.py's
 * `walk_beside_height_pull`), added up row by row in its order. */
typedef struct {
    double ww, wk, wp, kk, kp, pp, wy, ky, py, yy;
    Py_ssize_t rows;
} WalkSums;

/* Adds one segment's rows: model (lags × 4: lag, expectation for unit white noise, for a unit walk,
 * the height pull's per unit curvature² and step⁴), its force and the height it crosses per
 * sample; 0, or -1 with ValueError set when a lag does not fit the segment. */
/* The most lags a segment's model has (toe.py's WANDER_LAGS: 10). */
#define MODEL_MOST_LAGS 64

static int add_segment(WalkSums *sums, const double *model, Py_ssize_t lags, const double *force_g, Py_ssize_t n,
                       double step_um)
{
    if (lags == 0)
        return 0;
    if (n < 2) {
        PyErr_Format(PyExc_ValueError, "force_g: %zd samples, at least 2 expected", n);
        return -1;
    }
    double slope = line_slope(force_g, n), step4 = pow(step_um, 4.0);
    /* The model's lags checked, then every lag's measured mean square in one pass (`lag_mean_squares_of`). */
    Py_ssize_t lag_of[MODEL_MOST_LAGS];
    double measured[MODEL_MOST_LAGS];
    if (lags > MODEL_MOST_LAGS) {
        PyErr_Format(PyExc_ValueError, "model: %zd lags, at most %d", lags, MODEL_MOST_LAGS);
        return -1;
    }
    for (Py_ssize_t l = 0; l < lags; l++) {
        const double *row = model + 4 * l;
        if (!(row[0] >= 1.0 && row[0] < (double)n) || row[0] != floor(row[0])) {
            PyErr_Format(PyExc_ValueError, "model: row %zd's lag is not a whole number of 1..%zd (%zd samples)", l,
                         n - 1, n);
            return -1;
        }
        lag_of[l] = (Py_ssize_t)row[0];
    }
    lag_mean_squares_of(force_g, n, lag_of, lags, slope, measured);
    for (Py_ssize_t l = 0; l < lags; l++) {
        const double *row = model + 4 * l;
        double w = row[1], k = row[2], p = row[3] * step4, y = measured[l];
        sums->ww += w * w;
        sums->wk += w * k;
        sums->wp += w * p;
        sums->kk += k * k;
        sums->kp += k * p;
        sums->pp += p * p;
        sums->wy += w * y;
        sums->ky += k * y;
        sums->py += p * y;
        sums->yy += y * y;
    }
    sums->rows += lags;
    return 0;
}

/* toe.py's `_white_walk_pull`, operation for operation: 1 with (white, walk), 0 for None. */
static int white_walk_pull(const WalkSums *t, double *white_out, double *walk_out)
{
    if (!(t->ww > 0.0 && t->kk > 0.0 && t->pp > 0.0))
        return 0;
    double sw = sqrt(t->ww), sk = sqrt(t->kk), sp = sqrt(t->pp);
    double a = t->wk / (sw * sk), b = t->wp / (sw * sp), c = t->kp / (sk * sp);
    double u = t->wy / sw, v = t->ky / sk, w = t->py / sp;
    double determinant = 1.0 - a * a - b * b - c * c + 2.0 * a * b * c;
    if (determinant > 1e-12) {
        double white = (u * (1.0 - c * c) - a * (v - c * w) + b * (v * c - w)) / determinant;
        double walk = (v - c * w - u * (a - c * b) + b * (a * w - v * b)) / determinant;
        double pull = (w - c * v - a * (a * w - v * b) + u * (a * c - b)) / determinant;
        if (white > 0.0 && walk >= 0.0 && pull >= 0.0) {
            *white_out = white / sw, *walk_out = walk / sk;
            return 1;
        }
    }
    int found = 0;
    double best_residual = 0.0;
    const double rs[2] = {a, b}, qs[2] = {v, w}; /* the white with the walk, with the pull */
    for (int pair = 0; pair < 2; pair++) {
        double r = rs[pair], q = qs[pair];
        if (1.0 - r * r > 1e-12) {
            double white = (u - r * q) / (1.0 - r * r), other = (q - r * u) / (1.0 - r * r);
            if (white > 0.0 && other >= 0.0) {
                double residual = t->yy - white * u - other * q;
                if (!found || residual < best_residual) {
                    found = 1, best_residual = residual;
                    *white_out = white / sw, *walk_out = pair == 0 ? other / sk : 0.0;
                }
            }
        }
    }
    if (u > 0.0 && (!found || t->yy - u * u < best_residual)) { /* the white alone */
        found = 1;
        *white_out = u / sw, *walk_out = 0.0;
    }
    return found;
}

/* toe.py's `_wander_of_normal_sums` over the rows summed so far: 1 with (white, walk), 0 for None. */
static int white_walk(const WalkSums *t, double *white_out, double *walk_out)
{
    if (!t->rows)
        return 0;
    double determinant = t->ww * t->kk - t->wk * t->wk;
    if (!(determinant > 0.0))
        return 0;
    double white = (t->kk * t->wy - t->wk * t->ky) / determinant, walk = (t->ww * t->ky - t->wk * t->wy) / determinant;
    if (!(white > 0.0))
        return 0;
    *white_out = white, *walk_out = 0.0 > walk ? 0.0 : walk; /* max(walk, 0.0) */
    return 1;
}

static PyObject *pair_or_none(int found, double first, double second)
{
    return found ? Py_BuildValue("dd", first, second) : Py_NewRef(Py_None);
}

/* toe.py's `free_air_walks`: the walk beside a pull curved in height of the approach's and the
 * departure's free air, and the approach's walk alone, each (white, walk) or None. */
static PyObject *free_air_walks(PyObject *self, PyObject *args)
{
    (void)self;
    Py_buffer buffers[4]; /* approach force, departure force, their models */
    double steps_um[2];
    if (!PyArg_ParseTuple(args, "O&O&O&O&dd", float64_buffer, &buffers[0], float64_buffer, &buffers[1],
                          float64_buffer, &buffers[2], float64_buffer, &buffers[3], &steps_um[0], &steps_um[1]))
        return NULL;
    PyObject *result = NULL;
    WalkSums sums = {0};
    double approach_white = 0.0, approach_walk = 0.0, white = 0.0, walk = 0.0;
    int approach_found = 0;
    for (int segment = 0; segment < 2; segment++) {
        Py_ssize_t n = 0, values = 0;
        const double *force_g = doubles_of(&buffers[segment], &n, segment ? "departure_g" : "approach_g");
        const double *model = force_g == NULL ? NULL : doubles_of(&buffers[2 + segment], &values, "model");
        if (model == NULL)
            goto done;
        if (values % 4 != 0) {
            PyErr_Format(PyExc_ValueError, "model: %zd values, not rows of 4", values);
            goto done;
        }
        if (add_segment(&sums, model, values / 4, force_g, n, steps_um[segment]) < 0)
            goto done;
        if (segment == 0)
            approach_found = white_walk(&sums, &approach_white, &approach_walk);
    }
    int found = sums.rows >= 2 && white_walk_pull(&sums, &white, &walk);
    PyObject *beside = pair_or_none(found, white, walk);
    PyObject *approach = beside == NULL ? NULL : pair_or_none(approach_found, approach_white, approach_walk);
    if (approach != NULL)
        result = PyTuple_Pack(2, beside, approach);
    Py_XDECREF(beside);
    Py_XDECREF(approach);
done:
    for (int i = 0; i < 4; i++)
        PyBuffer_Release(&buffers[i]);
    return result;
}

/* The heights and limits of the two adhesion measures (toe.py: ADHESION_*, THREAD_*). */
struct adhesion_limits {
    double dip_from_um, dip_reach_um, level_to_um; /* near: (from, reach], level: (reach, to) above contact */
    Py_ssize_t run_samples, min_level_samples;
    double thread_from_um, thread_to_um; /* (from, to) above contact */
    Py_ssize_t min_thread_samples;
};

/* adhesion_dip of toe.py over x_um = (x_lo + x_hi) / 2: the free-air level's median less the lowest
 * mean of run_samples consecutive near samples; NaN when too few samples to know. `scratch` holds n. */
static double adhesion_dip_g(const double *x_lo, const double *x_hi, const double *force_g, Py_ssize_t n,
                             double drift_g_um, double contact_um, const struct adhesion_limits *limits,
                             double *scratch)
{
    Py_ssize_t levels = 0, nears = 0;
    double *level = scratch; /* filled from the front; the near samples from the back, in reverse */
    for (Py_ssize_t i = 0; i < n; i++) {
        double x_um = 0.5 * (x_lo[i] + x_hi[i]);
        double level_force_g = force_g[i] - drift_g_um * x_um;
        double above_um = x_um - contact_um;
        if (above_um > limits->dip_reach_um && above_um < limits->level_to_um)
            level[levels++] = level_force_g;
        else if (above_um > limits->dip_from_um && above_um <= limits->dip_reach_um)
            scratch[n - 1 - nears++] = level_force_g;
    }
    if (levels < limits->min_level_samples || nears < limits->run_samples)
        return NAN;
    const double *near = scratch + n - nears; /* reversed: near[nears - 1] is the first one */
    double lowest_run_g = INFINITY;
    for (Py_ssize_t k = 0; k + limits->run_samples <= nears; k++) {
        double run_g = 0.0;
        for (Py_ssize_t j = 0; j < limits->run_samples; j++)
            run_g += near[k + j] * (1.0 / (double)limits->run_samples);
        if (run_g < lowest_run_g)
            lowest_run_g = run_g;
    }
    return median_in_place(level, levels) - lowest_run_g;
}

/* thread_pull_g of toe.py over the same heights: the median of how far the departure lies below the
 * approach's free-air line; NaN when too few samples lie in reach. `scratch` holds n. */
static double thread_pull_of(const double *x_lo, const double *x_hi, const double *force_g, Py_ssize_t n,
                             double drift_g_um, double approach_at_halt_g, double contact_um,
                             const struct adhesion_limits *limits, double *scratch)
{
    Py_ssize_t count = 0;
    for (Py_ssize_t i = 0; i < n; i++) {
        double x_um = 0.5 * (x_lo[i] + x_hi[i]);
        double above_um = x_um - contact_um;
        if (above_um > limits->thread_from_um && above_um < limits->thread_to_um)
            scratch[count++] = approach_at_halt_g + drift_g_um * x_um - force_g[i];
    }
    return count < limits->min_thread_samples ? NAN : median_in_place(scratch, count);
}

static PyObject *float_or_none(double value)
{
    if (isnan(value))
        Py_RETURN_NONE;
    return PyFloat_FromDouble(value);
}

static PyObject *adhesion(PyObject *self, PyObject *args)
{
    (void)self;
    Py_buffer buffers[3];
    double drift_g_um, contact_um, approach_at_halt_g;
    struct adhesion_limits limits;
    if (!PyArg_ParseTuple(args, "O&O&O&ddd(dddnnddn)", float64_buffer, &buffers[0], float64_buffer, &buffers[1],
                          float64_buffer, &buffers[2], &drift_g_um, &contact_um, &approach_at_halt_g,
                          &limits.dip_from_um, &limits.dip_reach_um, &limits.level_to_um, &limits.run_samples,
                          &limits.min_level_samples, &limits.thread_from_um, &limits.thread_to_um,
                          &limits.min_thread_samples))
        return NULL;
    PyObject *result = NULL;
    Py_ssize_t n = 0;
    const double *x_lo, *x_hi, *force_g;
    pullback_samples_of(buffers, &n, &x_lo, &x_hi, &force_g);
    if (force_g != NULL && limits.run_samples < 1) {
        PyErr_SetString(PyExc_ValueError, "run_samples: at least 1");
    } else if (force_g != NULL) {
        double *scratch = malloc((size_t)(n > 0 ? n : 1) * sizeof(double));
        if (scratch == NULL) {
            PyErr_NoMemory();
        } else {
            double dip_g = adhesion_dip_g(x_lo, x_hi, force_g, n, drift_g_um, contact_um, &limits, scratch);
            double pull_g = thread_pull_of(x_lo, x_hi, force_g, n, drift_g_um, approach_at_halt_g, contact_um,
                                           &limits, scratch);
            result = Py_BuildValue("(NN)", float_or_none(dip_g), float_or_none(pull_g));
            free(scratch);
        }
    }
    for (int i = 0; i < 3; i++)
        PyBuffer_Release(&buffers[i]);
    return result;
}

/* thread_pull_g of toe.py at two reaches over the same samples, and their highest mid-height: what
 * the Z uncertainty's thread part reads (analysis.z_uncertainty, toe.thread_pulls_g). One pass over
 * the samples (each mid-height once) fills both reaches' pulls in sample order, as thread_pull_of
 * fills one: the same values, so the same medians. */
static PyObject *thread_pulls(PyObject *self, PyObject *args)
{
    (void)self;
    Py_buffer buffers[3];
    double drift_g_um, contact_um, approach_at_halt_g, near_from, near_to, far_from, far_to;
    Py_ssize_t min_samples;
    if (!PyArg_ParseTuple(args, "O&O&O&ddd(dd)(dd)n", float64_buffer, &buffers[0], float64_buffer, &buffers[1],
                          float64_buffer, &buffers[2], &drift_g_um, &approach_at_halt_g, &contact_um, &near_from,
                          &near_to, &far_from, &far_to, &min_samples))
        return NULL;
    PyObject *result = NULL;
    Py_ssize_t n = 0;
    const double *x_lo, *x_hi, *force_g;
    pullback_samples_of(buffers, &n, &x_lo, &x_hi, &force_g);
    if (force_g != NULL) {
        /* the near reach's pulls from the front, the far reach's from scratch + n (the reaches may overlap) */
        double *scratch = malloc((size_t)(n > 0 ? 2 * n : 1) * sizeof(double));
        if (scratch == NULL) {
            PyErr_NoMemory();
        } else {
            double *near = scratch, *far = scratch + n;
            Py_ssize_t near_count = 0, far_count = 0;
            double highest_um = -INFINITY;
            for (Py_ssize_t i = 0; i < n; i++) {
                const double x_um = 0.5 * (x_lo[i] + x_hi[i]);
                const double above_um = x_um - contact_um;
                if (above_um > near_from && above_um < near_to)
                    near[near_count++] = approach_at_halt_g + drift_g_um * x_um - force_g[i];
                if (above_um > far_from && above_um < far_to)
                    far[far_count++] = approach_at_halt_g + drift_g_um * x_um - force_g[i];
                if (x_um > highest_um || isnan(x_um)) highest_um = x_um;
            }
            const double near_g = near_count < min_samples ? NAN : median_in_place(near, near_count);
            const double far_g = far_count < min_samples ? NAN : median_in_place(far, far_count);
            result = Py_BuildValue("(NNd)", float_or_none(near_g), float_or_none(far_g), highest_um);
            free(scratch);
        }
    }
    for (int i = 0; i < 3; i++)
        PyBuffer_Release(&buffers[i]);
    return result;
}

static PyMethodDef methods[] = {
    {"thread_pulls", thread_pulls, METH_VARARGS,
     "thread_pulls(x_lo_um, x_hi_um, force_g, drift_g_um, approach_at_halt_g, contact_um, near_reach_um,\n"
     "             far_reach_um, min_samples) -> (near_pull_g or None, far_pull_g or None, highest_um)\n\n"
     "thread_pull_g at both reaches (each a (from, to) pair of um above contact) over the conversion\n"
     "windows' mid-heights, and the highest of those (-inf with no samples) (toe.py: thread_pulls_g)."},
    {"fit", fit, METH_VARARGS,
     "fit(x_lo_um, x_hi_um, force_g, contact0_um, spacing_um, drift_g_um, white_var_g2, walk_var_g2, grid,\n"
     "    contacts_out, rss_out) -> (contact_um, sigma_um, shape, width_index, stiffness_g_um, residual_var,\n"
     "    residual_sigma_g, shape_spread_um) or None\n\n"
     "toe.py's fit_toe for the shapes (0.5, 1.0). Samples: conversion windows [x_lo, x_hi] (um above the\n"
     "halt) and the force; drift_g_um: the known drift, NaN to fit it; white_var_g2: the baseline's\n"
     "white noise with walk_var_g2 its walk per sample, NaN for none. grid: (above_um, departure\n"
     "samples, penetration_um, wander_share, subsamples, least samples, contact offsets (um), widths\n"
     "(um), prior per (shape, width)). contacts_out gets contact0 + offsets, rss_out the residual per\n"
     "(shape, width, contact); None where fit_toe returns None (too few samples, no finite residual,\n"
     "no toe with a curved minimum)."},
    {"marginal_contact", marginal_contact, METH_VARARGS,
     "marginal_contact(contacts_um, rss, noise_var, prior) -> (mean_um, sd_um) or None\n\n"
     "The contact height's mean and sd with the toe marginalised out; rss: toes × contacts residuals\n"
     "(flat, row-major) on the even grid contacts_um, prior: a weight per toe. None when no toe has a\n"
     "curved interior minimum (toe.py: marginal_contact_um)."},
    {"marginal_contact_and_spread", marginal_contact_and_spread, METH_VARARGS,
     "marginal_contact_and_spread(contacts_um, rss, noise_var, prior, shapes) -> (mean_um, sd_um, spread_um)\n"
     "or None\n\n"
     "marginal_contact over every toe, and half the range of the marginals of each shape alone (rss and\n"
     "prior in `shapes` equal blocks of rows, each shape's widths); None as marginal_contact (toe.py:\n"
     "shape_spread_um, the spread's twin)."},
    {"detrended_variogram", detrended_variogram, METH_VARARGS,
     "detrended_variogram(n, lags) -> ((white, walk) per lag) or None\n\n"
     "Per lag (a tuple of ints, 1..n-1), the mean squared difference of n samples once a line is fitted\n"
     "out, for unit white noise and for a unit random walk (toe.py: _detrended_variogram, the same bits);\n"
     "None where its dot products could round (past ~2,000 samples), which the twin then computes."},
    {"free_air_model", free_air_model, METH_VARARGS,
     "free_air_model(n, lags, model) -> bool\n\n"
     "Fills model (len(lags) x 4 float64, C order) with a row per lag: the lag, detrended_variogram's\n"
     "white and walk, lag^2 ((n - lag)^2 - 1) / 12 (toe.py: _free_air_model, the same bits); False,\n"
     "nothing written, where detrended_variogram answers None."},
    {"lag_mean_squares", lag_mean_squares, METH_VARARGS,
     "lag_mean_squares(force_g, lags) -> list of float\n\n"
     "Per lag (a tuple of ints, 1..n-1), the mean of (r[i+lag] - r[i])^2 over i, r the force with its\n"
     "straight line fitted out (toe.py: free_air_variogram's measured part)."},
    {"free_air_walks", free_air_walks, METH_VARARGS,
     "free_air_walks(approach_g, departure_g, approach_model, departure_model, approach_step_um,\n"
     "               departure_step_um) -> ((white, walk) or None, (white, walk) or None)\n\n"
     "The baseline's white noise and walk (g^2 per sample) of the two free-air segments with a pull\n"
     "curved in height beside them, and of the approach alone (toe.py: free_air_walks; a model: rows\n"
     "of lag, unit white, unit walk, pull per curvature^2 and step^4, none when the segment is short)."},
    {"adhesion", adhesion, METH_VARARGS,
     "adhesion(x_lo_um, x_hi_um, force_g, drift_g_um, contact_um, approach_at_halt_g, limits)\n"
     "-> (dip_g or None, pull_g or None)\n\n"
     "toe.py's adhesion_dip and thread_pull_g over the windows' mid-heights, in one pass each; limits:\n"
     "(dip from, dip reach, level to (um), run samples, least level samples, thread from, thread to (um),\n"
     "least thread samples) (toe.py: ADHESION_LIMITS)."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_c_toe", "The toe kernels of the tap analysis.", -1,
                                    methods, NULL, NULL, NULL, NULL};

PyMODINIT_FUNC PyInit__c_toe(void) { return PyModule_Create(&module); }
