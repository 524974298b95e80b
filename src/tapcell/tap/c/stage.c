/* The departure's stage checks (tapcell.tap.stage): the soft-stage ramp above the contact found
 * (soft_stage) and the two-stage fit's grid (two_stage_grid), each in one pass.
 *
 * soft_stage: the samples from STAGE_FROM_UM to STAGE_REACH_UM above the contact, drift removed, by
 * height, and the ramp clip(top - x, 0) of every top from prefix sums, as the twin does with one
 * numpy call per step; the force's mean as numpy sums it (pairwise), so they agree bit for bit.
 *
 * two_stage_grid:
 * Over every (hinge, span) on the grid: a level, a drift, a stiff stage (h - x)+ and a soft stage
 * (t - x)+ solved in closed form from prefix sums over the samples by height, kept where both
 * stiffnesses are positive within the shares allowed and the span is long enough; the least
 * residual, the top marginalised over the fits (their likelihoods) and the best hinge alone. The
 * numpy twin builds the same (hinges x spans) arrays with one numpy call per operation; this
 * repeats its arithmetic element for element (only the weights' sums run in another order). */
#include "buffers.h"
#include "clones.h"
#include "median.h"
#include "sum.h"
#include <math.h>
#include <stdlib.h>

/* fmax(v, least) for a positive least, inline (libm's fmax is a call, in loops over every top, hinge
 * and grid cell): the same value for every v, a NaN included (the least). */
static inline double at_least(double v, double least) { return v > least ? v : least; }

/* Samples below `value` in the rising array x (numpy's searchsorted, side left). */
static Py_ssize_t count_below(const double *x, Py_ssize_t n, double value)
{
    Py_ssize_t lo = 0, hi = n;
    while (lo < hi) {
        Py_ssize_t mid = lo + (hi - lo) / 2;
        if (x[mid] < value) lo = mid + 1;
        else hi = mid;
    }
    return lo;
}

/* count_below(x, n, value), given the count `known` of a nearby value (the last top, hinge or
 * contact of a grid that rises): where every sample below `known` is below `value` too, counted on
 * from there a sample's step at a time (the grid's 1 µm against samples 0.3-25 µm apart: a step or
 * two, where the binary search takes seven); else the binary search below `known`. The same count,
 * so the same sums, in whatever order the grid comes. */
static Py_ssize_t count_below_near(const double *x, Py_ssize_t n, Py_ssize_t known, double value)
{
    if (known > n) known = n;
    if (known > 0 && !(x[known - 1] < value)) return count_below(x, known, value);
    while (known < n && x[known] < value) known++;
    return known;
}

/* The five prefix sums (count, x, x^2, f, x f) below a value. */
typedef struct { double s0, s1, s2, sf, sxf; } Sums;


static PyObject *soft_stage(PyObject *self, PyObject *args)
{
    (void)self;
    Py_buffer lob = {0}, hib = {0}, fb = {0}, tb = {0};
    double drift_g_um, contact_um, white_var, walk_var, from_um, reach_um;
    Py_ssize_t min_samples;
    if (!PyArg_ParseTuple(args, "O&O&O&ddddO&ddn", float64_buffer, &lob, float64_buffer, &hib, float64_buffer, &fb,
                          &drift_g_um, &contact_um, &white_var, &walk_var, float64_buffer, &tb, &from_um, &reach_um,
                          &min_samples))
        return NULL;
    PyObject *answer = NULL;
    double *x = NULL, *f = NULL, *prefix = NULL;
    Py_ssize_t n_all, n_tops;
    const double *x_lo = doubles_of(&lob, &n_all, "x_lo_um");
    const double *x_hi = x_lo ? doubles_sized(&hib, n_all, "x_hi_um") : NULL;
    const double *force = x_hi ? doubles_sized(&fb, n_all, "force_g") : NULL;
    const double *tops = force ? doubles_of(&tb, &n_tops, "tops_um") : NULL;
    if (tops == NULL) goto done;
    x = malloc(sizeof(double) * (size_t)(n_all > 0 ? n_all : 1));
    f = malloc(sizeof(double) * (size_t)(n_all > 0 ? n_all : 1));
    prefix = malloc(sizeof(double) * 4 * (size_t)(n_all + 1));
    if (x == NULL || f == NULL || prefix == NULL) {
        PyErr_NoMemory();
        goto done;
    }
    /* The samples near the contact, drift removed, in a stable insertion sort by height (they rise
     * already but for the pullback's end). */
    Py_ssize_t n = 0;
    for (Py_ssize_t i = 0; i < n_all; i++) {
        const double mid = 0.5 * (x_lo[i] + x_hi[i]);
        const double above = mid - contact_um;
        if (!(above > from_um && above < reach_um)) continue;
        const double level = force[i] - drift_g_um * mid;
        Py_ssize_t j = n++;
        for (; j > 0 && x[j - 1] > mid; j--) {
            x[j] = x[j - 1];
            f[j] = f[j - 1];
        }
        x[j] = mid;
        f[j] = level;
    }
    const double noise_var = white_var + walk_var * (double)n / 6.0;
    if (n < min_samples || !(noise_var > 0.0)) {
        answer = Py_None;
        Py_INCREF(answer);
        goto done;
    }
    const double mean = numpy_sum(f, n, 1) / (double)n;
    for (int q = 0; q < 4; q++) prefix[q] = 0.0;
    for (Py_ssize_t i = 0; i < n; i++) {
        const double h = x[i] - contact_um, level = f[i] - mean;
        const double *below = prefix + 4 * i;
        double *row = prefix + 4 * (i + 1);
        x[i] = h;
        f[i] = level * level; /* the squares, summed below as numpy sums them */
        row[0] = below[0] + h;
        row[1] = below[1] + h * h;
        row[2] = below[2] + level;
        row[3] = below[3] + h * level;
    }
    const double ff = numpy_sum(f, n, 1);
    double best_gain = 0.0, best_srf = 0.0, best_srr = 0.0;
    Py_ssize_t best = -1, count = 0;
    for (Py_ssize_t k = 0; k < n_tops; k++) {
        const double top = tops[k];
        count = count_below_near(x, n, count, top); /* the tops rise (np.arange): on from the last one's */
        const double *row = prefix + 4 * count;
        const double below = (double)count;
        const double sum_r = top * below - row[0];
        const double srr = (top * top) * below - (2.0 * top) * row[0] + row[1] - sum_r * sum_r / (double)n;
        const double srf = top * row[2] - row[3];
        const double gain = srf <= 0.0 ? 0.0 : srf * srf / at_least(srr, 1e-300);
        if (best < 0 || gain > best_gain) {
            best = k;
            best_gain = gain;
            best_srf = srf;
            best_srr = srr;
        }
    }
    if (best < 0) {
        PyErr_SetString(PyExc_ValueError, "soft_stage needs tops");
        goto done;
    }
    const double slope = best_srr > 0.0 ? best_srf / best_srr : 0.0;
    /* Weighed against the noise, or what the ramp leaves when that is more (the twin's comment). */
    const double left_var = (ff - best_gain) / (double)(n > 3 ? n - 3 : 1);
    answer = Py_BuildValue("ddd", best_gain / (left_var > noise_var ? left_var : noise_var), contact_um + tops[best],
                           slope);
done:
    free(x);
    free(f);
    free(prefix);
    PyBuffer_Release(&lob);
    PyBuffer_Release(&hib);
    PyBuffer_Release(&fb);
    PyBuffer_Release(&tb);
    return answer;
}


/* One hinge's row of the two-stage grid: the stiff stage's sums (su, ux, uu, uf, and its prefix sums
 * s0h, s1h, s2h below the hinge) against each top's (prefix sums t0..txf below it), the level and
 * the drift projected out; the two stiffnesses solved for every cell, without a branch (the
 * compiler vectorises it: the solves' six divisions are the grid's cost). k[b], k1[b], the residual
 * rss[b] = ff - gain, and ok[b]: 1 where the solve is well conditioned and the soft share within
 * [min_share, max_share], 0 where not (there the caller reads none of them). */
static ROW_LOOP void row_solves(Py_ssize_t cells, const double *top, const double *t0, const double *t1,
                                const double *t2, const double *tf, const double *txf, double hinge, double s0h,
                                double s1h, double s2h, double su, double ux, double uu, double uf, double count,
                                double sxx, double x_mean, double ff, double min_share, double max_share,
                                double *restrict k_out, double *restrict k1_out, double *restrict rss,
                                double *restrict ok)
{
    for (Py_ssize_t b = 0; b < cells; b++) {
        const double sv = top[b] * t0[b] - t1[b];
        const double vx = top[b] * t1[b] - t2[b] - x_mean * sv;
        const double vv = top[b] * top[b] * t0[b] - 2.0 * top[b] * t1[b] + t2[b] - sv * sv / count - vx * vx / sxx;
        const double uv = hinge * top[b] * s0h - (hinge + top[b]) * s1h + s2h - su * sv / count - ux * vx / sxx;
        const double vf = top[b] * tf[b] - txf[b];
        const double det = uu * vv - uv * uv;
        const double k = (vv * uf - uv * vf) / det;
        const double k1 = (uu * vf - uv * uf) / det;
        /* det > 1e-9 at_least(uu vv, 1e-300), by comparisons alone (a select of the floor before the
         * product keeps the compiler from vectorising the loop); a NaN uu vv takes the floor, as there */
        const double scale = uu * vv;
        const int above_floor = scale > 1e-300;
        const int solved = (above_floor & (det > 1e-9 * scale)) | (!above_floor & (det > 1e-9 * 1e-300));
        const int shared = (k1 >= min_share * k) & (k1 <= max_share * k);
        k_out[b] = k;
        k1_out[b] = k1;
        rss[b] = ff - (k * uf + k1 * vf);
        ok[b] = (solved & shared) ? 1.0 : 0.0;
    }
}

/* Each cell's residual into the exponent of its likelihood, -(rss - least) / (2 noise_var), in a
 * loop the compiler vectorises (a division a cell). */
static ROW_LOOP void likelihood_exponents(Py_ssize_t cells, double *rss, double least, double noise_var)
{
    for (Py_ssize_t cell = 0; cell < cells; cell++) rss[cell] = -0.5 * (rss[cell] - least) / noise_var;
}

/* The grid's best fit (two_stage_grid's answer). */
typedef struct {
    double least, noise_var, top_mean, top_sd;
    Py_ssize_t best_span;
    double soft_share, hinge_gain;
} GridFit;

/* The two-stage grid over x (rising) and f (n >= 1 samples; a level and a drift removed): 1 with
 * *out filled, 0 when no grid point is allowed, -1 with MemoryError set. */
static int grid_fit(const double *x, const double *f, Py_ssize_t n, const double *hinge_offsets, Py_ssize_t hinges,
                    const double *span_offsets, Py_ssize_t spans, double contact_um, double sxx, double ff,
                    double x_mean, double noise_var, double shortest_um, double min_share, double max_share,
                    GridFit *out)
{
    int status = -1;
    double *prefix = NULL, *rss = NULL, *tops = NULL, *row = NULL;
    prefix = malloc(sizeof(double) * 5 * (size_t)(n + 1));
    rss = malloc(sizeof(double) * (size_t)(hinges * spans));
    tops = malloc(sizeof(double) * (size_t)(hinges * spans));
    row = calloc(8 * (size_t)spans, sizeof(double)); /* a row's top sums (five), k, k1 and ok */
    if (prefix == NULL || rss == NULL || tops == NULL || row == NULL) {
        PyErr_NoMemory();
        status = -1;
        goto done;
    }
    double *t0 = row, *t1 = row + spans, *t2 = row + 2 * spans, *tf = row + 3 * spans, *txf = row + 4 * spans;
    double *k_row = row + 5 * spans, *k1_row = row + 6 * spans, *ok = row + 7 * spans;
    for (int q = 0; q < 5; q++) prefix[q] = 0.0;
    for (Py_ssize_t i = 0; i < n; i++) {
        const double *below = prefix + 5 * i;
        double *next = prefix + 5 * (i + 1);
        next[0] = below[0] + 1.0;
        next[1] = below[1] + x[i];
        next[2] = below[2] + x[i] * x[i];
        next[3] = below[3] + f[i];
        next[4] = below[4] + x[i] * f[i];
    }
    /* The spans the grid allows: from the first at least shortest_um on (they rise: np.arange). */
    Py_ssize_t first_span = 0;
    while (first_span < spans && !(span_offsets[first_span] >= shortest_um)) first_span++;
    const Py_ssize_t cells = spans - first_span;
    const double count = (double)n;
    double least = INFINITY, best_share = 0.0, best_hinge_gain = 0.0;
    Py_ssize_t best = -1;
    /* The hinges rise (np.arange), and with them each row's first top: both counts go on from the
     * last row's, as the tops along a row do */
    Py_ssize_t below_hinge = 0, below_first_top = 0;
    for (Py_ssize_t a = 0; a < hinges; a++) {
        const double hinge = contact_um + hinge_offsets[a];
        below_hinge = count_below_near(x, n, below_hinge, hinge);
        const double *h_row = prefix + 5 * below_hinge;
        const Sums h = {h_row[0], h_row[1], h_row[2], h_row[3], h_row[4]};
        const double su = hinge * h.s0 - h.s1;
        const double ux = hinge * h.s1 - h.s2 - x_mean * su;
        const double uu = hinge * hinge * h.s0 - 2.0 * hinge * h.s1 + h.s2 - su * su / count - ux * ux / sxx;
        const double uf = hinge * h.sf - h.sxf;
        const double hinge_gain = (uf > 0.0 && uu > 0.0) ? uf * uf / at_least(uu, 1e-300) : 0.0;
        if (a == 0 || hinge_gain > best_hinge_gain) best_hinge_gain = hinge_gain;
        double *row_tops = tops + a * spans, *row_rss = rss + a * spans;
        for (Py_ssize_t b = 0; b < spans; b++) {
            row_tops[b] = hinge + span_offsets[b];
            row_rss[b] = INFINITY;
        }
        /* Each allowed top's prefix sums; the tops along a row rise with the spans: counted on from
         * the last one (the first from the last row's first) */
        Py_ssize_t below_top = 0;
        for (Py_ssize_t c = 0; c < cells; c++) {
            const double top = row_tops[first_span + c];
            below_top = count_below_near(x, n, c > 0 ? below_top : below_first_top, top);
            if (c == 0) below_first_top = below_top;
            const double *t = prefix + 5 * below_top;
            t0[c] = t[0];
            t1[c] = t[1];
            t2[c] = t[2];
            tf[c] = t[3];
            txf[c] = t[4];
        }
        row_solves(cells, row_tops + first_span, t0, t1, t2, tf, txf, hinge, h.s0, h.s1, h.s2, su, ux, uu, uf, count,
                   sxx, x_mean, ff, min_share, max_share, k_row, k1_row, row_rss + first_span, ok);
        /* The least residual of the cells allowed, the first of equals; a cell not allowed is infinite
         * (never below the least; the first allowed one is taken whatever its value). Without a
         * branch on ok: a row's allowed cells come and go where no branch predictor follows them. */
        for (Py_ssize_t c = 0; c < cells; c++) {
            const double cell_rss = ok[c] != 0.0 ? row_rss[first_span + c] : INFINITY;
            row_rss[first_span + c] = cell_rss;
            if (cell_rss < least || (best < 0 && ok[c] != 0.0)) {
                least = cell_rss;
                best = a * spans + first_span + c;
                best_share = k1_row[c] / k_row[c];
            }
        }
    }
    if (best < 0) {
        status = 0;
        goto done;
    }
    /* What the two stages leave is the noise when they are the tap; more than the noise estimate
     * on a tap with a hum or a walk nobody modelled (the twin's comment says why). */
    const double dof = n - 6 > 1 ? (double)(n - 6) : 1.0;
    if (least / dof > noise_var) noise_var = least / dof;
    /* The likelihoods' exponents first; then the weights summed in the cells' order. exp underflows to 0 below -745.2: a cell not allowed (rss
     * infinite) or that far off weighs nothing and is left out of the sums (it would add +0 to each:
     * the same sums), and the cells weighed are kept in order at the arrays' start for the spread. */
    likelihood_exponents(hinges * spans, rss, least, noise_var);
    double total = 0.0, top_sum = 0.0;
    Py_ssize_t weighed = 0;
    for (Py_ssize_t cell = 0; cell < hinges * spans; cell++) {
        if (rss[cell] < -750.0) continue;
        const double weight = exp(rss[cell]);
        total += weight;
        top_sum += weight * tops[cell];
        rss[weighed] = weight;
        tops[weighed++] = tops[cell];
    }
    const double top_mean = top_sum / total;
    double spread = 0.0;
    for (Py_ssize_t cell = 0; cell < weighed; cell++) {
        const double off = tops[cell] - top_mean;
        spread += rss[cell] * (off * off);
    }
    const double top_sd = sqrt(fmax(spread / total, 0.0));
    *out = (GridFit){least, noise_var, top_mean, top_sd, best % spans, best_share, best_hinge_gain};
    status = 1;
done:
    free(prefix);
    free(rss);
    free(tops);
    free(row);
    return status;
}

static PyObject *grid_answer(int status, const GridFit *fit)
{
    if (status < 0) return NULL;
    if (status == 0) Py_RETURN_NONE;
    return Py_BuildValue("ddddndd", fit->least, fit->noise_var, fit->top_mean, fit->top_sd, fit->best_span,
                         fit->soft_share, fit->hinge_gain);
}

/* The samples' and the grid's arrays of two_stage_grid and two_stage_fit: 0 with an exception set
 * when one is not float64 of the size expected, or the grid has no hinge or span, or its spans do
 * not rise. */
static int grid_arrays(const Py_buffer *xb, const Py_buffer *fb, const Py_buffer *hb, const Py_buffer *sb,
                       const double **x, const double **f, Py_ssize_t *n, const double **hinge_offsets,
                       Py_ssize_t *hinges, const double **span_offsets, Py_ssize_t *spans)
{
    *x = doubles_of(xb, n, "x_um");
    *f = *x ? doubles_sized(fb, *n, "force_g") : NULL;
    *hinge_offsets = *f ? doubles_of(hb, hinges, "hinges_um") : NULL;
    *span_offsets = *hinge_offsets ? doubles_of(sb, spans, "spans_um") : NULL;
    if (*span_offsets == NULL) return 0;
    if (*hinges < 1 || *spans < 1) {
        PyErr_SetString(PyExc_ValueError, "the two-stage grid needs hinges and spans");
        return 0;
    }
    /* grid_fit takes the spans from the first at least shortest_um on: they must rise (np.arange) */
    for (Py_ssize_t b = 1; b < *spans; b++)
        if (!((*span_offsets)[b] > (*span_offsets)[b - 1])) {
            PyErr_SetString(PyExc_ValueError, "spans_um: the spans must rise");
            return 0;
        }
    return 1;
}

static PyObject *two_stage_grid(PyObject *self, PyObject *args)
{
    (void)self;
    Py_buffer xb = {0}, fb = {0}, hb = {0}, sb = {0};
    double contact_um, sxx, ff, x_mean, noise_var, shortest_um, min_share, max_share;
    if (!PyArg_ParseTuple(args, "O&O&O&O&dddddddd", float64_buffer, &xb, float64_buffer, &fb, float64_buffer, &hb,
                          float64_buffer, &sb, &contact_um, &sxx, &ff, &x_mean, &noise_var, &shortest_um,
                          &min_share, &max_share))
        return NULL;
    PyObject *answer = NULL;
    Py_ssize_t n, hinges, spans;
    const double *x, *f, *hinge_offsets, *span_offsets;
    if (!grid_arrays(&xb, &fb, &hb, &sb, &x, &f, &n, &hinge_offsets, &hinges, &span_offsets, &spans)) goto done;
    if (n < 1) {
        PyErr_SetString(PyExc_ValueError, "two_stage_grid needs samples");
        goto done;
    }
    GridFit fit;
    answer = grid_answer(grid_fit(x, f, n, hinge_offsets, hinges, span_offsets, spans, contact_um, sxx, ff, x_mean,
                                  noise_var, shortest_um, min_share, max_share, &fit), &fit);
done:
    PyBuffer_Release(&xb);
    PyBuffer_Release(&fb);
    PyBuffer_Release(&hb);
    PyBuffer_Release(&sb);
    return answer;
}

/* Python's max(a, b): a unless b is larger (a NaN first stays). */
static double py_max(double a, double b) { return b > a ? b : a; }

/* The order that sorts x rising, ties in their order (numpy's argsort kind="stable" for values
 * without NaN): nothing to do when x already rises (a pullback's heights do), else a bottom-up
 * merge sort through `scratch` (n indices). */
static void stable_order(const double *x, Py_ssize_t n, Py_ssize_t *order, Py_ssize_t *scratch)
{
    int rising = 1;
    for (Py_ssize_t i = 0; i < n; i++) {
        order[i] = i;
        if (i > 0 && x[i] < x[i - 1]) rising = 0;
    }
    if (rising) return;
    Py_ssize_t *from = order, *to = scratch;
    for (Py_ssize_t width = 1; width < n; width *= 2) {
        for (Py_ssize_t lo = 0; lo < n; lo += 2 * width) {
            const Py_ssize_t mid = lo + width < n ? lo + width : n, hi = lo + 2 * width < n ? lo + 2 * width : n;
            Py_ssize_t i = lo, j = mid, k = lo;
            while (i < mid && j < hi) to[k++] = x[from[j]] < x[from[i]] ? from[j++] : from[i++];
            while (i < mid) to[k++] = from[i++];
            while (j < hi) to[k++] = from[j++];
        }
        Py_ssize_t *kept = from;
        from = to;
        to = kept;
    }
    if (from != order) memcpy(order, from, sizeof(Py_ssize_t) * (size_t)n);
}

/* sum(a * b) as numpy takes it (the products, then their pairwise sum), through n doubles of room. */
static double products_sum(const double *a, const double *b, Py_ssize_t n, double *room)
{
    for (Py_ssize_t i = 0; i < n; i++) room[i] = a[i] * b[i];
    return numpy_sum(room, n, 1);
}

/* stage.py's two_stage_fit up to its grid, then the grid: the samples within [contact - below,
 * contact + above] by height, the heights centred and the force with its level and (unless
 * drift_held) its drift in height removed, the sample step (median of the heights' steps), the
 * shortest span it allows, the grid. The means and the sums of products as numpy takes them
 * (pairwise sums), the median as robust.median: bit for bit with the twin. On a fit, the samples
 * as the grid took them (by height; the force less its level and drift) into x_out and force_out,
 * for the one-stage toe the evidence may need next. */
static PyObject *two_stage_fit(PyObject *self, PyObject *args)
{
    (void)self;
    Py_buffer xb = {0}, fb = {0}, hb = {0}, sb = {0}, xo_b = {0}, fo_b = {0};
    double contact_um, below_um, above_um, noise_var, window_um, min_span_um, min_span_windows, min_share, max_share;
    Py_ssize_t min_samples;
    int drift_held;
    if (!PyArg_ParseTuple(args, "O&O&dddnddddO&O&ddpO&O&", float64_buffer, &xb, float64_buffer, &fb, &contact_um,
                          &below_um, &above_um, &min_samples, &noise_var, &window_um, &min_span_um,
                          &min_span_windows, float64_buffer, &hb, float64_buffer, &sb, &min_share, &max_share,
                          &drift_held, float64_out, &xo_b, float64_out, &fo_b))
        return NULL;
    PyObject *answer = NULL;
    double *xs = NULL, *fs = NULL, *xc = NULL, *steps = NULL;
    Py_ssize_t *order = NULL, *picked = NULL, *scratch = NULL;
    Py_ssize_t n_all, hinges, spans;
    const double *x_all, *f_all, *hinge_offsets, *span_offsets;
    if (!grid_arrays(&xb, &fb, &hb, &sb, &x_all, &f_all, &n_all, &hinge_offsets, &hinges, &span_offsets, &spans))
        goto done;
    double *x_out = doubles_sized(&xo_b, n_all, "x_out");
    double *f_out = x_out ? doubles_sized(&fo_b, n_all, "force_out") : NULL;
    if (f_out == NULL) goto done;
    const double low = contact_um - below_um, high = contact_um + above_um;
    Py_ssize_t n = 0;
    for (Py_ssize_t i = 0; i < n_all; i++) n += x_all[i] > low && x_all[i] < high;
    if (n < 2 * min_samples || n < 2 || noise_var <= 0.0) {
        answer = Py_None;
        Py_INCREF(answer);
        goto done;
    }
    const size_t count = (size_t)n;
    xs = malloc(sizeof(double) * count);
    fs = malloc(sizeof(double) * count);
    xc = malloc(sizeof(double) * count);
    steps = malloc(sizeof(double) * count);
    order = malloc(sizeof(Py_ssize_t) * count);
    picked = malloc(sizeof(Py_ssize_t) * count);
    scratch = malloc(sizeof(Py_ssize_t) * count);
    if (!xs || !fs || !xc || !steps || !order || !picked || !scratch) {
        PyErr_NoMemory();
        goto done;
    }
    for (Py_ssize_t i = 0, k = 0; i < n_all; i++)
        if (x_all[i] > low && x_all[i] < high) {
            steps[k] = x_all[i]; /* the near samples in their order, sorted below */
            picked[k++] = i;
        }
    stable_order(steps, n, order, scratch);
    for (Py_ssize_t k = 0; k < n; k++) {
        xs[k] = x_all[picked[order[k]]];
        fs[k] = f_all[picked[order[k]]];
    }
    const double x_mean = numpy_sum(xs, n, 1) / (double)n;
    const double f_mean = numpy_sum(fs, n, 1) / (double)n;
    for (Py_ssize_t k = 0; k < n; k++) {
        xc[k] = xs[k] - x_mean;
        fs[k] = fs[k] - f_mean;
    }
    double sxx = INFINITY;
    if (!drift_held) {
        sxx = products_sum(xc, xc, n, steps);
        if (!(sxx > 0.0)) { /* every sample at one height: no drift to tell, no stages */
            answer = Py_None;
            Py_INCREF(answer);
            goto done;
        }
        const double drift = products_sum(xc, fs, n, steps) / sxx;
        for (Py_ssize_t k = 0; k < n; k++) fs[k] = fs[k] - xc[k] * drift;
    }
    const double ff = products_sum(fs, fs, n, steps);
    for (Py_ssize_t k = 0; k + 1 < n; k++) steps[k] = xs[k + 1] - xs[k];
    const double spacing_um = median_in_place(steps, n - 1);
    const double shortest_um = py_max(min_span_um, min_span_windows * py_max(window_um, spacing_um));
    GridFit fit;
    const int status = grid_fit(xs, fs, n, hinge_offsets, hinges, span_offsets, spans, contact_um, sxx, ff, x_mean,
                                noise_var, shortest_um, min_share, max_share, &fit);
    if (status < 0) goto done;
    if (status == 0) {
        answer = Py_None;
        Py_INCREF(answer);
        goto done;
    }
    memcpy(x_out, xs, sizeof(double) * count);
    memcpy(f_out, fs, sizeof(double) * count);
    answer = Py_BuildValue("ddddndddndd", fit.least, fit.noise_var, fit.top_mean, fit.top_sd, fit.best_span,
                           fit.soft_share, fit.hinge_gain, ff, n, sxx, x_mean);
done:
    free(xs);
    free(fs);
    free(xc);
    free(steps);
    free(order);
    free(picked);
    free(scratch);
    PyBuffer_Release(&xb);
    PyBuffer_Release(&fb);
    PyBuffer_Release(&hb);
    PyBuffer_Release(&sb);
    PyBuffer_Release(&xo_b);
    PyBuffer_Release(&fo_b);
    return answer;
}

/* One toe shape's least-squares sums over the samples (one_stage_rss): its column's sum, its products
 * with the centred heights and with the force, its square; scale: the shape's width x 1/(power + 1). */
typedef struct { double sum, x, ss, f, scale; } ShapeSums;

/* The sums over the samples pressed past the toe (prefix sums p below it), where the shape is the line
 * s = B - z (B = the contact's offset - width (1 - 1/(power + 1))). */
static inline ShapeSums pressed_sums(const double *p, double offset, double width, double power, double z_mean)
{
    const double share = 1.0 / (power + 1.0), b = offset - width * (1.0 - share);
    ShapeSums s;
    s.scale = width * share;
    s.sum = b * p[0] - p[1];
    s.x = b * p[1] - b * p[0] * z_mean - p[2] + z_mean * p[1];
    s.ss = b * b * p[0] - 2.0 * b * p[1] + p[2];
    s.f = b * p[3] - p[4];
    return s;
}

/* One sample inside the toe: its shape value (scaled), its centred height and its force. */
static inline void add_in_toe(ShapeSums *s, double shape, double centred, double force_g)
{
    s->sum += shape;
    s->x += shape * centred;
    s->ss += shape * shape;
    s->f += shape * force_g;
}

/* What the shape's column lowers the residual by (0 where it pulls the wrong way or explains nothing). */
static inline double shape_gain(const ShapeSums *s, double count, double sxx)
{
    const double s_var = s->ss - s->sum * s->sum / count - s->x * s->x / sxx;
    return (s->f > 0.0 && s_var > 0.0) ? s->f * s->f / at_least(s_var, 1e-300) : 0.0;
}

/* The larger gain, the earlier one kept on a tie (the twin's order). */
static inline double fmax_gain(double best, double gain) { return gain > best ? gain : best; }

/* The one-stage toe's least residual (stage.py: _one_stage_rss, its numpy twin) over every shape,
 * width and contact on the grid. The samples pressed at least a width deep lie on the toe's linear
 * part, s = B - z (z: height above the contact found, B = contact - width (1 - 1/(power + 1))),
 * whose sums come from prefix sums over the samples by height; only those inside the toe are
 * evaluated one by one, their depth over the width once for both shapes. Along a width's rising
 * contacts the counts of samples below the contact and below its toe go on from the last
 * contact's (binary searches there cost more than the sums: their branches mispredict). The same
 * least squares as the twin's, summed in another order. */
static PyObject *one_stage_rss(PyObject *self, PyObject *args)
{
    (void)self;
    Py_buffer xb = {0}, fb = {0}, cb = {0}, wb = {0}, pb = {0};
    double contact_um, sxx, ff, x_mean;
    if (!PyArg_ParseTuple(args, "O&O&O&O&O&dddd", float64_buffer, &xb, float64_buffer, &fb, float64_buffer, &cb,
                          float64_buffer, &wb, float64_buffer, &pb, &contact_um, &sxx, &ff, &x_mean))
        return NULL;
    PyObject *answer = NULL;
    double *prefix = NULL, *depth = NULL;
    Py_ssize_t n, contacts, widths, powers;
    const double *x = doubles_of(&xb, &n, "x_um");
    const double *f = x ? doubles_sized(&fb, n, "force_g") : NULL;
    const double *offsets = f ? doubles_of(&cb, &contacts, "contacts_um") : NULL;
    const double *width_list = offsets ? doubles_of(&wb, &widths, "widths_um") : NULL;
    const double *power_list = width_list ? doubles_of(&pb, &powers, "powers") : NULL;
    if (power_list == NULL) goto done;
    if (n < 1) {
        PyErr_SetString(PyExc_ValueError, "one_stage_rss needs samples");
        goto done;
    }
    prefix = malloc(sizeof(double) * 5 * (size_t)(n + 1));
    depth = malloc(sizeof(double) * (size_t)n);
    if (prefix == NULL || depth == NULL) {
        PyErr_NoMemory();
        goto done;
    }
    /* Prefix sums over the samples (rising) of 1, z, z^2, f, z f; z about the contact found. */
    for (int q = 0; q < 5; q++) prefix[q] = 0.0;
    for (Py_ssize_t i = 0; i < n; i++) {
        const double z = x[i] - contact_um;
        const double *below = prefix + 5 * i;
        double *row = prefix + 5 * (i + 1);
        row[0] = below[0] + 1.0;
        row[1] = below[1] + z;
        row[2] = below[2] + z * z;
        row[3] = below[3] + f[i];
        row[4] = below[4] + z * f[i];
    }
    const double count = (double)n, z_mean = x_mean - contact_um;
    /* The grid's two shapes (stage.py ONE_STAGE_POWERS): summed side by side in one pass. */
    const int hertz_and_parabola = powers == 2 && power_list[0] == 0.5 && power_list[1] == 1.0;
    double best_gain = 0.0;
    for (Py_ssize_t w = 0; w < widths; w++) {
        const double width = fmax(width_list[w], 1e-9);
        Py_ssize_t pressed = 0, deep = 0;
        for (Py_ssize_t c = 0; c < contacts; c++) {
            const double contact = contact_um + offsets[c];
            /* [0, linear): pressed a width deep or more; [linear, pressed): inside the toe. deep: the
             * samples below contact - width. The contacts rise (np.arange): both counts go on from
             * the last contact's. */
            pressed = count_below_near(x, n, pressed, contact);
            deep = count_below_near(x, pressed, deep, contact - width);
            Py_ssize_t linear = deep;
            while (linear < pressed && contact - x[linear] >= width) linear++;
            const double *p = prefix + 5 * linear;
            if (hertz_and_parabola) { /* both shapes over the toe's samples in one pass, each sum in the same order */
                ShapeSums hertz = pressed_sums(p, offsets[c], width, 0.5, z_mean);
                ShapeSums parabola = pressed_sums(p, offsets[c], width, 1.0, z_mean);
                for (Py_ssize_t i = linear; i < pressed; i++) {
                    const double u = (contact - x[i]) / width, centred = x[i] - x_mean;
                    add_in_toe(&hertz, (sqrt(u) * u) * hertz.scale, centred, f[i]);
                    add_in_toe(&parabola, (u * u) * parabola.scale, centred, f[i]);
                }
                best_gain = fmax_gain(best_gain, shape_gain(&hertz, count, sxx));
                best_gain = fmax_gain(best_gain, shape_gain(&parabola, count, sxx));
                continue;
            }
            /* the depth over the width of each sample inside the toe, once for every shape */
            for (Py_ssize_t i = linear; i < pressed; i++) depth[i - linear] = (contact - x[i]) / width;
            for (Py_ssize_t k = 0; k < powers; k++) {
                const double power = power_list[k];
                ShapeSums sums = pressed_sums(p, offsets[c], width, power, z_mean);
                for (Py_ssize_t i = linear; i < pressed; i++) {
                    const double u = depth[i - linear];
                    double shape;
                    if (power == 0.5) shape = sqrt(u) * u;
                    else if (power == 1.0) shape = u * u;
                    else shape = pow(u, power + 1.0);
                    add_in_toe(&sums, shape * sums.scale, x[i] - x_mean, f[i]);
                }
                best_gain = fmax_gain(best_gain, shape_gain(&sums, count, sxx));
            }
        }
    }
    answer = PyFloat_FromDouble(ff - best_gain);
done:
    free(prefix);
    free(depth);
    PyBuffer_Release(&xb);
    PyBuffer_Release(&fb);
    PyBuffer_Release(&cb);
    PyBuffer_Release(&wb);
    PyBuffer_Release(&pb);
    return answer;
}

/* stage.py's `_departure_fit` selection: the windows' mid-heights x = (x_lo + x_hi) / 2 strictly
 * between low_um and high_um, in their order, into x_out, their force less drift × x into force_out;
 * returns (count, the median of their windows' widths x_hi - x_lo, NaN when none): the twin's
 * element-wise operations and robust.median's (the same bits). */
static PyObject *departure_near(PyObject *self, PyObject *args)
{
    (void)self;
    Py_buffer buffers[3], xo_b = {0}, fo_b = {0};
    double drift_g_um, low_um, high_um;
    if (!PyArg_ParseTuple(args, "O&O&O&dddO&O&", float64_buffer, &buffers[0], float64_buffer, &buffers[1],
                          float64_buffer, &buffers[2], &drift_g_um, &low_um, &high_um, float64_out, &xo_b,
                          float64_out, &fo_b))
        return NULL;
    PyObject *answer = NULL;
    Py_ssize_t n = 0;
    const double *x_lo, *x_hi, *force_g;
    pullback_samples_of(buffers, &n, &x_lo, &x_hi, &force_g);
    double *x_out = force_g ? doubles_sized(&xo_b, n, "x_out") : NULL;
    double *force_out = x_out ? doubles_sized(&fo_b, n, "force_out") : NULL;
    if (force_out == NULL)
        goto done;
    double *widths = malloc(sizeof(double) * (size_t)(n > 0 ? n : 1));
    if (widths == NULL) {
        PyErr_NoMemory();
        goto done;
    }
    Py_ssize_t count = 0;
    for (Py_ssize_t i = 0; i < n; i++) {
        const double x_um = 0.5 * (x_lo[i] + x_hi[i]);
        if (x_um > low_um && x_um < high_um) {
            x_out[count] = x_um;
            force_out[count] = force_g[i] - drift_g_um * x_um;
            widths[count] = x_hi[i] - x_lo[i];
            count++;
        }
    }
    const double window_um = median_in_place(widths, count); /* NaN when none */
    free(widths);
    answer = Py_BuildValue("nd", count, window_um);
done:
    for (int i = 0; i < 3; i++)
        PyBuffer_Release(&buffers[i]);
    PyBuffer_Release(&xo_b);
    PyBuffer_Release(&fo_b);
    return answer;
}

static PyMethodDef methods[] = {
    {"departure_near", departure_near, METH_VARARGS,
     "departure_near(x_lo_um, x_hi_um, force_g, drift_g_um, low_um, high_um, x_out, force_out)\n"
     "-> (count, window_um)\n\n"
     "The samples whose windows' mid-heights lie strictly between low_um and high_um, in order: their\n"
     "mid-heights into x_out, their force less drift_g_um x height into force_out (both of the samples'\n"
     "length), and the median of their windows' widths (NaN for none) (stage.py: _departure_fit)."},
    {"one_stage_rss", one_stage_rss, METH_VARARGS,
     "one_stage_rss(x_um, force_g, contacts_um, widths_um, powers, contact_um, sxx, ff, x_mean) -> float\n\n"
     "The least residual of a level, a drift and a one-stage toe over every power, width and contact\n"
     "(contact_um + contacts_um): x_um rising, force_g with the level and drift removed, sxx the centred\n"
     "heights' sum of squares, ff the force's, x_mean the heights' mean (stage.py: _one_stage_rss)."},
    {"soft_stage", soft_stage, METH_VARARGS,
     "soft_stage(x_lo_um, x_hi_um, force_g, drift_g_um, contact_um, white_var_g2, walk_var_g2, tops_um, from_um,\n"
     "           reach_um, min_samples) -> (chi2, top_um, slope_g_um) or None\n\n"
     "The best soft-stage ramp over the pullback's samples (conversion windows [x_lo, x_hi]) from from_um\n"
     "to reach_um above contact_um, drift removed, every top contact_um + tops_um; its gain over the\n"
     "noise variance white + walk x samples / 6. None when fewer than min_samples or no noise (stage.py:\n"
     "departure_soft_stage, soft_stage)."},
    {"two_stage_fit", two_stage_fit, METH_VARARGS,
     "two_stage_fit(x_um, force_g, contact_um, below_um, above_um, min_samples, noise_var_g2, window_um,\n"
     "              min_span_um, min_span_windows, hinges_um, spans_um, min_soft_share, max_soft_share, drift_held,\n"
     "              x_out, force_out)\n"
     "-> (least_rss, noise_var_g2, top_mean_um, top_sd_um, best_span_index, soft_share, best_hinge_gain, ff,\n"
     "    count, sxx, x_mean) or None\n\n"
     "stage.py's two_stage_fit up to the one-stage toe: the samples within below_um under and above_um over\n"
     "the contact, by height, a level and (unless drift_held) a drift taken out, then two_stage_grid over\n"
     "them; ff the force's sum of squares left, sxx the centred heights' (infinite with the drift held),\n"
     "x_mean their mean; those count samples into x_out and force_out (both of x_um's length). None when\n"
     "fewer than 2 min_samples samples, no noise, all at one height, or no grid point allowed."},
    {"two_stage_grid", two_stage_grid, METH_VARARGS,
     "two_stage_grid(x_um, force_g, hinges_um, spans_um, contact_um, sxx, ff, x_mean, noise_var_g2, shortest_um,\n"
     "               min_soft_share, max_soft_share)\n"
     "-> (least_rss, noise_var_g2, top_mean_um, top_sd_um, best_span_index, soft_share, best_hinge_gain)\n"
     "   or None\n\n"
     "The two-stage fit over every hinge (contact_um + hinges_um) and span on the grid (stage.py:\n"
     "two_stage_fit): x_um rising, force_g with a level and a drift removed, sxx the centred heights'\n"
     "sum of squares, ff the force's. None when no grid point has both stiffnesses within the shares\n"
     "and a span of at least shortest_um."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_c_stage",
                                    "The departure's stage checks (tapcell.tap.stage).", -1, methods,
                                    NULL, NULL, NULL, NULL};

PyMODINIT_FUNC PyInit__c_stage(void) { return PyModule_Create(&module); }
