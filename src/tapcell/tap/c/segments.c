/* The segments kernels of the tap analysis (numpy twins: tapcell/tap/segments.py).
 *
 * best_five_segments: the exhaustive joint search of the four boundaries of the five-line split.
 * The numpy twin costs every candidate segment in one big work array; here the segments are costed
 * one row at a time (O(c·p + p·r + r·b) for c contact, p peak, r release and b break candidates),
 * with the twin's arithmetic in the twin's order (`_sse_of_sums`), so both see the same residuals
 * bit for bit and pick the same boundaries, exact ties included.
 * prefix_sums and segment_lines: the twin's running sums and line formulas, bit for bit too.
 * five_lines: a tap window's whole split in one call, with what the analysis reads off it next (the
 * lines' scatter, `segment_stats`, and their six points, `context.recompute_points`), bit for bit. */
#include "buffers.h"
#include "clones.h"
#include "sum.h"

#include <math.h>

#define MIN_SEGMENT_SAMPLES 2.0
#define SUM_ROWS 6

/* The prefix sums: SUM_ROWS rows (count, Σt, Σf, Σt², Σtf, Σf²) of `columns` values each. */
typedef struct {
    const double *rows;
    Py_ssize_t columns;
} PrefixSums;

/* Residual sum of squares of the best line through the sums of a segment of at least
 * MIN_SEGMENT_SAMPLES samples, its 1 / n given: the twin's `_sse_of_sums` step by step (same
 * operations, same order; a reciprocal looked up is the one computed, bit for bit), with one
 * division left where the costing of thousands of segments a tap waits on two. */
static inline double sse_of_long_sums(double inv_n, double st, double sf, double stt, double stf, double sff)
{
    double t_mean = st * inv_n;
    double sxx = stt - st * t_mean;
    double sxy = stf - t_mean * sf;
    double explained = (sxy * sxy) / sxx;
    double sse = (sff - (sf * sf) * inv_n) - explained;
    return sse < 0.0 ? 0.0 : sse; /* np.maximum(sse, 0): a NaN stays NaN */
}

/* The search's tables: the prefix sums, and 1.0 / n for every count n of the window (`inverse[n]`,
 * n >= MIN_SEGMENT_SAMPLES; the counts are the sums' first row, whole numbers). */
typedef struct {
    const PrefixSums *ps;
    const double *inverse;
} Costing;

/* The rows' loops built twice (clones.h: with AVX2, four segments at once, and without; about a
 * seventh off the search), the same sums bit for bit. */

/* out[k] = add[k] + sse of the segment [i, j0 + k) for k < count (add NULL: + 0 left out): a row of
 * segments sharing their first sample. Too short ones (j0 + k - i < 2) are +inf, as the twin's;
 * the rest run in a loop without branches, which the compiler vectorises (two divisions at once). */
ROW_LOOP static void sse_from(const Costing *cost, Py_ssize_t i, Py_ssize_t j0, Py_ssize_t count,
                     const double *restrict add, double *restrict out)
{
    const double *restrict row = cost->ps->rows, *restrict inverse = cost->inverse;
    const Py_ssize_t w = cost->ps->columns;
    Py_ssize_t k = 0;
    for (; k < count && j0 + k - i < (Py_ssize_t)MIN_SEGMENT_SAMPLES; k++)
        out[k] = add ? INFINITY + add[k] : INFINITY; /* as the twin: sse, then + add */
    if (k == count)
        return;
    const double st0 = row[w + i], sf0 = row[2 * w + i], stt0 = row[3 * w + i], stf0 = row[4 * w + i];
    const double sff0 = row[5 * w + i];
    const double *restrict st = row + w + j0, *restrict sf = row + 2 * w + j0, *restrict stt = row + 3 * w + j0;
    const double *restrict stf = row + 4 * w + j0, *restrict sff = row + 5 * w + j0;
    const Py_ssize_t apart = j0 - i; /* inverse[apart + k]: 1 / (j0 + k - i), an index >= 2 from here on */
    if (add) {
        for (; k < count; k++)
            out[k] = sse_of_long_sums(inverse[apart + k], st[k] - st0, sf[k] - sf0, stt[k] - stt0, stf[k] - stf0,
                                      sff[k] - sff0) + add[k];
    } else {
        for (; k < count; k++)
            out[k] = sse_of_long_sums(inverse[apart + k], st[k] - st0, sf[k] - sf0, stt[k] - stt0, stf[k] - stf0,
                                      sff[k] - sff0);
    }
}

/* out[k] = add[k] + sse of the segment [i0 + k, j) for k < count (add NULL: + 0 left out): a row of
 * segments sharing their end. Too short ones (j - i0 - k < 2) are +inf, as the twin's. */
ROW_LOOP static void sse_to(const Costing *cost, Py_ssize_t i0, Py_ssize_t j, Py_ssize_t count,
                   const double *restrict add, double *restrict out)
{
    const double *restrict row = cost->ps->rows, *restrict inverse = cost->inverse;
    const Py_ssize_t w = cost->ps->columns;
    /* the long ones first: k < j - i0 - 1 */
    Py_ssize_t long_count = j - i0 - (Py_ssize_t)MIN_SEGMENT_SAMPLES + 1;
    long_count = long_count < 0 ? 0 : long_count > count ? count : long_count;
    Py_ssize_t k = 0;
    if (long_count > 0) {
        const double stj = row[w + j], sfj = row[2 * w + j], sttj = row[3 * w + j], stfj = row[4 * w + j];
        const double sffj = row[5 * w + j];
        const double *restrict st = row + w + i0, *restrict sf = row + 2 * w + i0, *restrict stt = row + 3 * w + i0;
        const double *restrict stf = row + 4 * w + i0, *restrict sff = row + 5 * w + i0;
        const double *restrict inv = inverse + (j - i0); /* inv[-k]: 1 / (j - i0 - k) */
        if (add) {
            for (; k < long_count; k++)
                out[k] = sse_of_long_sums(inv[-k], stj - st[k], sfj - sf[k], sttj - stt[k], stfj - stf[k],
                                          sffj - sff[k]) + add[k];
        } else {
            for (; k < long_count; k++)
                out[k] = sse_of_long_sums(inv[-k], stj - st[k], sfj - sf[k], sttj - stt[k], stfj - stf[k],
                                          sffj - sff[k]);
        }
    }
    for (; k < count; k++)
        out[k] = add ? INFINITY + add[k] : INFINITY; /* as the twin: sse, then + add */
}

/* The least of `count` values and its index (*at), in numpy's min/argmin order: the first
 * minimum, and a NaN wins (and stays) as numpy propagates it. */
static double first_min(const double *values, Py_ssize_t count, Py_ssize_t *at)
{
    double best = values[0];
    Py_ssize_t best_at = 0;
    if (best != best) { /* a NaN first: it stays */
        *at = 0;
        return best;
    }
    /* One comparison a value: !(value >= best) holds for a smaller value and for a NaN, which ends
     * the search. */
    for (Py_ssize_t k = 1; k < count; k++) {
        if (!(values[k] >= best)) {
            best = values[k];
            best_at = k;
            if (best != best)
                break;
        }
    }
    *at = best_at;
    return best;
}

/* 1.0 / n for every count n below `counts` (inverse[0] and inverse[1] are 0, never read: shorter
 * segments are +inf), kept between calls and grown as a longer window asks: every tap's search
 * reads the same reciprocals, and computing them each call cost a division per sample of the
 * window (the search's own divisions are a few per candidate segment). NULL when out of memory.
 * The module runs under the GIL (its functions never release it), so one table serves all calls. */
static double *inverse_table = NULL;
static Py_ssize_t inverse_counts = 0;

static const double *inverses(Py_ssize_t counts)
{
    if (counts > inverse_counts) {
        Py_ssize_t grown = counts > 2 * inverse_counts ? counts : 2 * inverse_counts;
        double *table = PyMem_Realloc(inverse_table, sizeof(double) * (size_t)grown);
        if (table == NULL)
            return NULL;
        table[0] = 0.0;
        if (grown > 1)
            table[1] = 0.0;
        for (Py_ssize_t n = inverse_counts > 2 ? inverse_counts : 2; n < grown; n++)
            table[n] = 1.0 / (double)n;
        inverse_table = table, inverse_counts = grown;
    }
    return inverse_table;
}

PyDoc_STRVAR(best_five_segments_doc,
             "best_five_segments(sums, start, stop, contact_first, contact_end, peak_first, peak_end,\n"
             "                   release_first, release_end, break_first, break_end)\n"
             "    -> (contact, peak, release, break) | None\n"
             "\n"
             "The boundaries of five lines over [start, stop) with the least total residual, each boundary\n"
             "from its half-open candidate range, as tapcell.tap.segments.best_five_segments (same ties).\n"
             "`sums`: the (6, n + 1) float64 prefix sums, C order. None when no split gives every line two samples.");

/* The search of `best_five_segments` over checked ranges (each non-empty, inside the sums): 1 with
 * the boundaries in found[4], 0 when no split gives every line two samples, -1 (MemoryError set). */
static int search_five(const PrefixSums *ps, Py_ssize_t start, Py_ssize_t stop, Py_ssize_t c0, Py_ssize_t c1,
                       Py_ssize_t p0, Py_ssize_t p1, Py_ssize_t r0, Py_ssize_t r1, Py_ssize_t b0, Py_ssize_t b1,
                       Py_ssize_t found[4])
{
    const Py_ssize_t c = c1 - c0, p = p1 - p0, r = r1 - r0, b = b1 - b0;
    /* One scratch block per call: 1 / n per count, the approach per contact, the departure per break,
     * one row of the compression, decompression or dwell, the best half per peak and per release,
     * and their argmins. */
    Py_ssize_t longest_row = c > b ? c : b;
    longest_row = longest_row > r ? longest_row : r;
    /* a segment of the sums holds at most columns - 1 samples */
    const double *inverse = inverses(ps->columns);
    double *scratch = inverse ? PyMem_Malloc(sizeof(double) * (size_t)(c + b + longest_row + 2 * (p + r))) : NULL;
    if (scratch == NULL) {
        PyErr_NoMemory();
        return -1;
    }
    double *approach = scratch, *departure = approach + c, *row = departure + b;
    double *left = row + longest_row, *right = left + p;
    Py_ssize_t *left_at = (Py_ssize_t *)(right + r), *right_at = left_at + p; /* doubles and indices are 8 bytes */
    const Costing cost = {ps, inverse};
    sse_from(&cost, start, c0, c, NULL, approach); /* [start, contact) */
    sse_to(&cost, b0, stop, b, NULL, departure); /* [break, stop) */
    /* Per peak, the best contact: compression + approach (the twin's order of the sum). */
    for (Py_ssize_t ip = 0; ip < p; ip++) {
        sse_to(&cost, c0, p0 + ip, c, approach, row); /* [contact, peak) */
        left[ip] = first_min(row, c, &left_at[ip]);
    }
    /* Per release, the best break: decompression + departure. */
    for (Py_ssize_t ir = 0; ir < r; ir++) {
        sse_from(&cost, r0 + ir, b0, b, departure, row); /* [release, break) */
        right[ir] = first_min(row, b, &right_at[ir]);
    }
    /* The best total per (peak, release) in row-major order, as total.argmin(): each half at its
     * best, the dwell between. */
    double best = INFINITY;
    Py_ssize_t best_ip = 0, best_ir = 0;
    for (Py_ssize_t ip = 0; ip < p; ip++) {
        sse_from(&cost, p0 + ip, r0, r, NULL, row); /* [peak, release) */
        for (Py_ssize_t k = 0; k < r; k++)
            row[k] = (left[ip] + row[k]) + right[k];
        Py_ssize_t ir;
        double value = first_min(row, r, &ir);
        if (ip == 0 || (!isnan(best) && (value < best || isnan(value)))) {
            best = value;
            best_ip = ip;
            best_ir = ir;
        }
    }
    int split = isfinite(best);
    if (split) {
        found[0] = c0 + left_at[best_ip], found[1] = p0 + best_ip;
        found[2] = r0 + best_ir, found[3] = b0 + right_at[best_ir];
    }
    PyMem_Free(scratch);
    return split;
}

static PyObject *best_five_segments(PyObject *self, PyObject *args)
{
    (void)self;
    PyObject *sums;
    Py_buffer buffer;
    Py_ssize_t start, stop, c0, c1, p0, p1, r0, r1, b0, b1;
    /* The array is taken after the other arguments: a failure among them then leaves nothing to release. */
    if (!PyArg_ParseTuple(args, "Onnnnnnnnnn", &sums, &start, &stop, &c0, &c1, &p0, &p1, &r0, &r1, &b0, &b1) ||
        !float64_buffer(sums, &buffer))
        return NULL;
    PyObject *result = NULL;
    Py_ssize_t count;
    const double *rows = doubles_of(&buffer, &count, "sums");
    if (rows == NULL)
        goto done;
    if (count % SUM_ROWS != 0) {
        PyErr_Format(PyExc_ValueError, "sums: %zd values is not 6 rows", count);
        goto done;
    }
    const PrefixSums ps = {rows, count / SUM_ROWS};
    const Py_ssize_t edges[] = {start, stop, c0, c1, p0, p1, r0, r1, b0, b1};
    for (size_t k = 0; k < sizeof edges / sizeof edges[0]; k++) {
        /* start and stop are columns; a candidate range's end may be one past the last column */
        if (edges[k] < 0 || edges[k] > ps.columns - 1 + (k >= 2 && k % 2)) {
            PyErr_Format(PyExc_ValueError, "boundary %zd outside the %zd prefix-sum columns", edges[k], ps.columns);
            goto done;
        }
    }
    if (c1 <= c0 || p1 <= p0 || r1 <= r0 || b1 <= b0) {
        PyErr_SetString(PyExc_ValueError, "an empty candidate range");
        goto done;
    }
    Py_ssize_t found[4];
    int split = search_five(&ps, start, stop, c0, c1, p0, p1, r0, r1, b0, b1, found);
    if (split > 0)
        result = Py_BuildValue("nnnn", found[0], found[1], found[2], found[3]);
    else if (split == 0)
        result = Py_NewRef(Py_None);
done:
    PyBuffer_Release(&buffer);
    return result;
}

PyDoc_STRVAR(prefix_sums_doc,
             "prefix_sums(time_s, force_g, t_ref_s, f_ref_g, sums) -> None\n"
             "\n"
             "Fill `sums` (a (6, n + 1) float64 array, C order) with the running sums of 1, t, f, t², t·f, f²\n"
             "over t = time_s - t_ref_s, f = force_g - f_ref_g, a leading 0 column: as the numpy twin\n"
             "tapcell.tap.segments.prefix_sums (the same sums in the same order).");

/* The (6, n + 1) running sums of the twin's `prefix_sums` into sums (C order). */
static void fill_prefix_sums(const double *time_s, const double *force_g, Py_ssize_t n, double t_ref_s,
                             double f_ref_g, double *sums)
{
    const Py_ssize_t width = n + 1;
    double running[SUM_ROWS] = {0.0};
    for (int row = 0; row < SUM_ROWS; row++)
        sums[row * width] = 0.0;
    for (Py_ssize_t k = 0; k < n; k++) {
        double t = time_s[k] - t_ref_s, f = force_g[k] - f_ref_g;
        running[1] += t;
        running[2] += f;
        running[3] += t * t;
        running[4] += t * f;
        running[5] += f * f;
        sums[k + 1] = (double)(k + 1); /* the running count needs no summing */
        for (int row = 1; row < SUM_ROWS; row++)
            sums[row * width + k + 1] = running[row];
    }
}

static PyObject *prefix_sums(PyObject *self, PyObject *args)
{
    (void)self;
    PyObject *time_array, *force_array;
    Py_buffer time_buffer, force_buffer, sums_buffer;
    double t_ref_s, f_ref_g;
    if (!PyArg_ParseTuple(args, "OOddw*", &time_array, &force_array, &t_ref_s, &f_ref_g, &sums_buffer))
        return NULL;
    if (!float64_buffer(time_array, &time_buffer)) {
        PyBuffer_Release(&sums_buffer);
        return NULL;
    }
    if (!float64_buffer(force_array, &force_buffer)) {
        PyBuffer_Release(&time_buffer);
        PyBuffer_Release(&sums_buffer);
        return NULL;
    }
    PyObject *result = NULL;
    Py_ssize_t n;
    const double *time_s = doubles_of(&time_buffer, &n, "time_s");
    const double *force_g = time_s ? doubles_sized(&force_buffer, n, "force_g") : NULL;
    double *sums = force_g ? doubles_sized(&sums_buffer, SUM_ROWS * (n + 1), "sums") : NULL;
    if (sums != NULL) {
        fill_prefix_sums(time_s, force_g, n, t_ref_s, f_ref_g, sums);
        result = Py_NewRef(Py_None);
    }
    PyBuffer_Release(&time_buffer);
    PyBuffer_Release(&force_buffer);
    PyBuffer_Release(&sums_buffer);
    return result;
}

/* The line over [first, end) from prefix sums `width` columns wide, as the twin's `_line_of_sums`
 * (the same arithmetic in the same order): 0 for an empty segment (the twin divides by zero). */
static int line_of(const double *rows, Py_ssize_t width, Py_ssize_t first, Py_ssize_t end, double t_ref_s,
                   double f_ref_g, double *slope_out, double *intercept_out)
{
    double sum[SUM_ROWS];
    for (int row = 0; row < SUM_ROWS; row++)
        sum[row] = rows[row * width + end] - rows[row * width + first];
    double n = sum[0], st = sum[1], sf = sum[2], stt = sum[3], stf = sum[4];
    if (n == 0.0)
        return 0;
    double sxx = stt - st * st / n;
    double sxy = stf - st * sf / n;
    double slope = sxx > 0 ? sxy / sxx : 0.0;
    /* Line through the segment's centroid, then moved back to the original origins. */
    double intercept_centred = sf / n - slope * st / n;
    *slope_out = slope;
    *intercept_out = intercept_centred + f_ref_g - slope * t_ref_s;
    return 1;
}

PyDoc_STRVAR(segment_lines_doc,
             "segment_lines(sums, edges, t_ref_s, f_ref_g) -> [(slope, intercept), ...]\n"
             "\n"
             "The least-squares lines over consecutive segments [edges[k], edges[k + 1]) from the (6, n + 1)\n"
             "prefix sums, moved back to the original origins: as tapcell.tap.segments.segment_lines (the same\n"
             "arithmetic in the same order).");

static PyObject *segment_lines(PyObject *self, PyObject *args)
{
    (void)self;
    PyObject *sums, *edge_list;
    Py_buffer buffer;
    double t_ref_s, f_ref_g;
    if (!PyArg_ParseTuple(args, "OOdd", &sums, &edge_list, &t_ref_s, &f_ref_g) || !float64_buffer(sums, &buffer))
        return NULL;
    PyObject *lines = NULL, *edges = PySequence_Fast(edge_list, "edges must be a sequence of indices");
    Py_ssize_t count;
    const double *rows = edges ? doubles_of(&buffer, &count, "sums") : NULL;
    if (rows == NULL)
        goto done;
    const Py_ssize_t width = count / SUM_ROWS, segments = PySequence_Fast_GET_SIZE(edges) - 1;
    lines = PyList_New(segments > 0 ? segments : 0);
    Py_ssize_t first = segments >= 0 ? PyLong_AsSsize_t(PySequence_Fast_GET_ITEM(edges, 0)) : 0;
    if (PyErr_Occurred())
        Py_CLEAR(lines);
    for (Py_ssize_t k = 0; lines != NULL && k < segments; k++) {
        Py_ssize_t end = PyLong_AsSsize_t(PySequence_Fast_GET_ITEM(edges, k + 1));
        if (PyErr_Occurred() || first < 0 || end < 0 || first >= width || end >= width) {
            if (!PyErr_Occurred())
                PyErr_Format(PyExc_ValueError, "edge %zd or %zd outside the %zd prefix-sum columns", first, end, width);
            Py_CLEAR(lines);
            break;
        }
        double slope, intercept;
        if (!line_of(rows, width, first, end, t_ref_s, f_ref_g, &slope, &intercept)) { /* as the twin's Python */
            PyErr_SetString(PyExc_ZeroDivisionError, "float division by zero");
            Py_CLEAR(lines);
            break;
        }
        PyObject *line = Py_BuildValue("(dd)", slope, intercept);
        if (line == NULL) {
            Py_CLEAR(lines);
            break;
        }
        PyList_SET_ITEM(lines, k, line);
        first = end;
    }
done:
    Py_XDECREF(edges);
    PyBuffer_Release(&buffer);
    return lines;
}


/* The twin's `segment_stats` of [first, end) (the same arithmetic in the same order; Python's
 * max(a, b) is b only when b > a): (residual variance, mean re-centred time, Sxx), as a new tuple. */
static PyObject *segment_stats_of(const double *rows, Py_ssize_t width, Py_ssize_t first, Py_ssize_t end)
{
    double sum[SUM_ROWS];
    for (int row = 0; row < SUM_ROWS; row++)
        sum[row] = rows[row * width + end] - rows[row * width + first];
    double n = sum[0], st = sum[1], sf = sum[2], stt = sum[3], stf = sum[4], sff = sum[5];
    double sxx = stt - st * st / n;
    double sxy = stf - st * sf / n;
    double syy = sff - sf * sf / n;
    double residual = syy - (sxx > 0 ? sxy * sxy / sxx : 0.0);
    double sse = 0.0 > residual ? 0.0 : residual;
    double dof = 1.0 > n - 2.0 ? 1.0 : n - 2.0;
    return Py_BuildValue("(ddd)", sse / dof, st / n, sxx);
}

/* `context.line_intersection` of lines (a_slope, a_intercept) and (b_slope, b_intercept) around t_ref
 * (the same arithmetic): NaN, NaN for parallel lines. */
static void intersect(double a_slope, double a_intercept, double b_slope, double b_intercept, double t_ref,
                      double *t_out, double *f_out)
{
    double slope_diff = a_slope - b_slope;
    if (slope_diff == 0) {
        *t_out = *f_out = NAN;
        return;
    }
    double fa = a_slope * t_ref + a_intercept, fb = b_slope * t_ref + b_intercept;
    double dt = (fb - fa) / slope_diff;
    *t_out = t_ref + dt;
    *f_out = fa + a_slope * dt;
}


PyDoc_STRVAR(five_lines_doc,
             "five_lines(time_s, force_g, halt_s, pullback_start_s, pullback_cruise_s,\n"
             "           lag_samples, release_lag_samples, approach_share, angle_scale_s_per_g, sums, derived)\n"
             "    -> (t_ref_s, f_ref_g, problem, bounds, lines, points, angles_deg)\n"
             "\n"
             "The five-line split of a window of samples in one call (segments.py `five_lines`, whose numpy\n"
             "twin runs prefix_sums, the candidate ranges, best_five_segments, segment_stats, segment_lines\n"
             "and context.recompute_points): the sums' reference time and force (the middle sample's time,\n"
             "the force's mean by numpy's pairwise sum: `prefix_sums`' own, bit for bit), then\n"
             "`sums`, a (6, n + 1) float64 array, gets the prefix sums; problem 0\n"
             "with the four boundaries, the five lines, their six points and the four angles between them\n"
             "(angles.line_angles_deg, its ANGLE_SCALE_S_PER_G given), and each line's segment_stats in the dict `derived` under (first, end);\n"
             "else one of segments.py's NO_DWELL_SAMPLES, TOO_FEW_AROUND, TOO_FEW_FOR_FIVE and four None.\n"
             "All bit for bit the twin's arithmetic.");

static PyObject *five_lines(PyObject *self, PyObject *args)
{
    (void)self;
    Py_buffer time_buffer, force_buffer, sums_buffer;
    double halt_s, pull_start_s, pull_cruise_s, approach_share, angle_scale_s_per_g;
    Py_ssize_t lag, release_lag;
    PyObject *derived;
    if (!PyArg_ParseTuple(args, "O&O&dddnnddw*O!", float64_buffer, &time_buffer, float64_buffer, &force_buffer,
                          &halt_s, &pull_start_s, &pull_cruise_s, &lag, &release_lag,
                          &approach_share, &angle_scale_s_per_g, &sums_buffer, &PyDict_Type, &derived))
        return NULL;
    PyObject *result = NULL;
    Py_ssize_t m = 0;
    const double *time_s = doubles_of(&time_buffer, &m, "time_s");
    const double *force_g = time_s ? doubles_sized(&force_buffer, m, "force_g") : NULL;
    double *sums = force_g ? doubles_sized(&sums_buffer, SUM_ROWS * (m + 1), "sums") : NULL;
    if (sums == NULL)
        goto done;
    if (m < 1) {
        PyErr_SetString(PyExc_ValueError, "time_s: no samples");
        goto done;
    }
    const double t_ref_s = time_s[m / 2], f_ref_g = numpy_sum(force_g, m, 1) / (double)m;
    fill_prefix_sums(time_s, force_g, m, t_ref_s, f_ref_g, sums);
    const PrefixSums ps = {sums, m + 1};
    /* The candidate ranges, half-open [first, end), as the twin's ranges. */
    Py_ssize_t home_end = first_at_or_after(time_s, m, halt_s), pull_start = first_at_or_after(time_s, m, pull_start_s);
    Py_ssize_t pull_cruise = first_at_or_after(time_s, m, pull_cruise_s);
    Py_ssize_t p0 = home_end - 1 > 2 ? home_end - 1 : 2;
    Py_ssize_t p1 = (pull_start < home_end + lag ? pull_start : home_end + lag) + 1;
    Py_ssize_t r0 = pull_start - 1 > 0 ? pull_start - 1 : 0;
    Py_ssize_t pull_last = pull_start > pull_cruise ? pull_start : pull_cruise;
    Py_ssize_t r1 = (m - 2 < pull_last + release_lag ? m - 2 : pull_last + release_lag) + 1;
    /* The twin's int(approach_share * home_end): the product in double, truncated toward zero. */
    Py_ssize_t share_first = (Py_ssize_t)(approach_share * (double)home_end);
    Py_ssize_t c0 = share_first > 2 ? share_first : 2;
    int problem = 0;
    Py_ssize_t found[4];
    if (p1 <= p0 || r1 <= r0) {
        problem = 1; /* NO_DWELL_SAMPLES */
    } else if (p1 - 2 <= c0 || m - 1 <= r0 + 2) {
        problem = 2; /* TOO_FEW_AROUND: range(c0, peak[-1] - 1) or range(release[0] + 2, m - 1) empty */
    } else {
        int split = search_five(&ps, 0, m, c0, p1 - 2, p0, p1, r0, r1, r0 + 2, m - 1, found);
        if (split < 0)
            goto done;
        problem = split ? 0 : 3; /* TOO_FEW_FOR_FIVE */
    }
    if (problem) {
        result = Py_BuildValue("(ddiOOOO)", t_ref_s, f_ref_g, problem, Py_None, Py_None, Py_None, Py_None);
        goto done;
    }
    const Py_ssize_t edges[] = {0, found[0], found[1], found[2], found[3], m};
    double slope[5], intercept[5];
    for (int k = 0; k < 5; k++) {
        /* every line holds at least 2 samples (the search's inf otherwise): no count of zero below */
        line_of(sums, m + 1, edges[k], edges[k + 1], t_ref_s, f_ref_g, &slope[k], &intercept[k]);
        PyObject *key = Py_BuildValue("(nn)", edges[k], edges[k + 1]);
        PyObject *stats = key ? segment_stats_of(sums, m + 1, edges[k], edges[k + 1]) : NULL;
        int stored = stats ? PyDict_SetItem(derived, key, stats) : -1;
        Py_XDECREF(key);
        Py_XDECREF(stats);
        if (stored < 0)
            goto done;
    }
    /* recompute_points: P0 and P5 on the end lines at the first and last sample, P1..P4 the
     * consecutive lines' intersections around the window's middle. */
    const double t_first = time_s[0], t_last = time_s[m - 1], t_mid = 0.5 * (t_first + t_last);
    double point_t[6], point_f[6];
    point_t[0] = t_first, point_f[0] = slope[0] * t_first + intercept[0];
    for (int k = 0; k < 4; k++)
        intersect(slope[k], intercept[k], slope[k + 1], intercept[k + 1], t_mid, &point_t[k + 1], &point_f[k + 1]);
    point_t[5] = t_last, point_f[5] = slope[4] * t_last + intercept[4];
    /* angles.line_angles_deg: each line's angle on the plot scale, math.degrees(math.atan(slope × scale))
     * (math.degrees multiplies by 180 / π; both call the C library's atan), then consecutive differences. */
    double angle[5];
    for (int k = 0; k < 5; k++)
        angle[k] = atan(slope[k] * angle_scale_s_per_g) * (180.0 / Py_MATH_PI);
    result = Py_BuildValue("(ddi(nnnn)[(dd)(dd)(dd)(dd)(dd)][(dd)(dd)(dd)(dd)(dd)(dd)][dddd])", t_ref_s, f_ref_g, 0,
                           found[0], found[1], found[2], found[3], slope[0], intercept[0], slope[1], intercept[1],
                           slope[2], intercept[2], slope[3], intercept[3], slope[4], intercept[4], point_t[0],
                           point_f[0], point_t[1], point_f[1], point_t[2], point_f[2], point_t[3], point_f[3],
                           point_t[4], point_f[4], point_t[5], point_f[5], angle[0] - angle[1], angle[1] - angle[2],
                           angle[2] - angle[3], angle[3] - angle[4]);
done:
    PyBuffer_Release(&time_buffer);
    PyBuffer_Release(&force_buffer);
    PyBuffer_Release(&sums_buffer);
    return result;
}

static PyMethodDef methods[] = {
    {"best_five_segments", best_five_segments, METH_VARARGS, best_five_segments_doc},
    {"prefix_sums", prefix_sums, METH_VARARGS, prefix_sums_doc},
    {"segment_lines", segment_lines, METH_VARARGS, segment_lines_doc},
    {"five_lines", five_lines, METH_VARARGS, five_lines_doc},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_c_segments", "The segments kernels of the tap analysis.", -1,
                                    methods, NULL, NULL, NULL, NULL};

PyMODINIT_FUNC PyInit__c_segments(void) { return PyModule_Create(&module); }
