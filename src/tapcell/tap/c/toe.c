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

#define SHAPES 2
/* How far short of its width each shape lifts the linear part: p / (p + 1). */
static const double LIFT_DEFICIT[SHAPES] = {0.5 / 1.5, 1.0 / 2.0};

/* The toe shape of toe.py's `toe_shapes` at one depth for both shapes, added into sums[]. The
 * operations in numpy's order (scale by w / (p + 1), then add the linear part), so the two agree
 * to the last bit on each value. */
static void add_toe_shapes(double depth_um, double width_um, double sums[SHAPES])
{
    double pressed_um = depth_um > 0.0 ? depth_um : 0.0;
    double width = width_um > 1e-9 ? width_um : 1e-9;
    double u = pressed_um / width;
    if (u > 1.0)
        u = 1.0;
    double beyond_um = pressed_um - width;
    if (beyond_um < 0.0)
        beyond_um = 0.0;
    sums[0] += sqrt(u) * u * (width * (1.0 / 1.5)) + beyond_um;
    sums[1] += u * u * (width * (1.0 / 2.0)) + beyond_um;
}

/* Both shapes' toe columns at one sample: the shape summed over the heights its conversion window
 * averages (row: `subsamples` heights); the caller scales the sums. */
static void toe_sums(double contact_um, double width_um, const double *row_um, Py_ssize_t subsamples,
                     double sums[SHAPES])
{
    sums[0] = sums[1] = 0.0;
    for (Py_ssize_t s = 0; s < subsamples; s++)
        add_toe_shapes(contact_um - row_um[s], width_um, sums);
}

static int shape_of_power(double power)
{
    if (power == 0.5)
        return 0;
    if (power == 1.0)
        return 1;
    PyErr_Format(PyExc_ValueError, "power: %g, the kernel knows 0.5 and 1.0", power);
    return -1;
}

/* Number of values <= v (sorted ascending): numpy's searchsorted(side="right"). */
static Py_ssize_t count_at_most(const double *sorted, Py_ssize_t n, double v)
{
    Py_ssize_t lo = 0, hi = n;
    while (lo < hi) {
        Py_ssize_t mid = lo + (hi - lo) / 2;
        if (sorted[mid] <= v)
            lo = mid + 1;
        else
            hi = mid;
    }
    return lo;
}

/* Number of values < v (sorted ascending): numpy's searchsorted(side="left"). */
static Py_ssize_t count_below(const double *sorted, Py_ssize_t n, double v)
{
    Py_ssize_t lo = 0, hi = n;
    while (lo < hi) {
        Py_ssize_t mid = lo + (hi - lo) / 2;
        if (sorted[mid] < v)
            lo = mid + 1;
        else
            hi = mid;
    }
    return lo;
}

/* The pullback samples of one fit: window_um (n × subsamples heights), x_mid_um and force_g (n). */
typedef struct {
    Py_buffer buffers[3];
    int held;
    const double *window_um, *x_mid_um, *force_g;
    Py_ssize_t n, subsamples;
} Samples;

static void release_samples(Samples *samples)
{
    for (int i = 0; i < samples->held; i++)
        PyBuffer_Release(&samples->buffers[i]);
    samples->held = 0;
}

/* Checks the three buffers parsed into samples->buffers; 0, or -1 with ValueError set (released). */
static int check_samples(Samples *samples)
{
    samples->held = 3;
    Py_ssize_t window_count;
    samples->x_mid_um = doubles_of(&samples->buffers[1], &samples->n, "x_mid_um");
    if (samples->x_mid_um == NULL)
        goto fail;
    samples->force_g = doubles_sized(&samples->buffers[2], samples->n, "force_g");
    samples->window_um = doubles_of(&samples->buffers[0], &window_count, "window_um");
    if (samples->force_g == NULL || samples->window_um == NULL)
        goto fail;
    if (samples->n < 2 || window_count == 0 || window_count % samples->n != 0) {
        PyErr_Format(PyExc_ValueError, "window_um: %zd heights for %zd samples", window_count, samples->n);
        goto fail;
    }
    samples->subsamples = window_count / samples->n;
    return 0;
fail:
    release_samples(samples);
    return -1;
}

/* ---- Ordinary least squares (toe.py: _Projected, _rss_over_contacts, _solve, _stiffness_at) ---- */

/* The basis beside the toe, orthonormal: the baseline 1/√n, and with the drift fitted the centred
 * heights over their norm (the span np.linalg.qr gives; only the projection matters). The force
 * with the basis projected out goes to y_free; returns the number of basis columns. */
static int project_out_basis(const Samples *s, int drift_fitted, double *basis_rows, double *y_free)
{
    Py_ssize_t n = s->n;
    double base = 1.0 / sqrt((double)n), mean_um = 0.0, norm2 = 0.0, y_base = 0.0, y_drift = 0.0;
    int m = drift_fitted ? 2 : 1;
    for (Py_ssize_t i = 0; i < n; i++)
        mean_um += s->x_mid_um[i];
    mean_um /= (double)n;
    for (Py_ssize_t i = 0; i < n; i++) {
        basis_rows[i] = base;
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

static PyObject *rss_grid(PyObject *self, PyObject *args)
{
    (void)self;
    Samples s = {0};
    Py_buffer contacts_buffer, widths_buffer, out_buffer;
    int drift_fitted;
    if (!PyArg_ParseTuple(args, "y*y*y*py*y*w*", &s.buffers[0], &s.buffers[1], &s.buffers[2], &drift_fitted,
                          &contacts_buffer, &widths_buffer, &out_buffer))
        return NULL;
    PyObject *result = NULL;
    double *work = NULL;
    if (check_samples(&s) < 0)
        goto done;
    Py_ssize_t candidates = 0, n = s.n, sub = s.subsamples;
    const double *contacts_um = doubles_of(&contacts_buffer, &candidates, "contacts_um");
    const double *widths_um = doubles_sized(&widths_buffer, candidates, "widths_um");
    double *rss_out = doubles_sized(&out_buffer, SHAPES * candidates, "rss_out");
    if (contacts_um == NULL || widths_um == NULL || rss_out == NULL)
        goto done;
    /* basis (2n), y_free (n), pressed_to, free_from (n each), prefix sums (9 columns × (n + 1)) */
    Py_ssize_t sums_n = n + 1;
    work = malloc(sizeof(double) * (size_t)(5 * n + 9 * sums_n));
    if (work == NULL) {
        PyErr_NoMemory();
        goto done;
    }
    double *basis_rows = work, *y_free = work + 2 * n, *pressed_to = work + 3 * n, *free_from = work + 4 * n;
    double *sums = work + 5 * n;
    int m = project_out_basis(&s, drift_fitted, basis_rows, y_free);
    double yy = 0.0;
    for (Py_ssize_t i = 0; i < n; i++)
        yy += y_free[i] * y_free[i];
    /* Sample i and all before it are pressed past a toe ending at or above pressed_to[i] (running
     * max of the windows' tops); from i on all are free of a contact at or below free_from[i]
     * (running min from the end of the windows' bottoms): sorted, so a binary search bounds each
     * candidate's run in its toe. */
    for (Py_ssize_t i = 0; i < n; i++) {
        double top_um = s.window_um[i * sub + sub - 1];
        pressed_to[i] = (i == 0 || top_um > pressed_to[i - 1]) ? top_um : pressed_to[i - 1];
    }
    for (Py_ssize_t i = n - 1; i >= 0; i--) {
        double bottom_um = s.window_um[i * sub];
        free_from[i] = (i == n - 1 || bottom_um < free_from[i + 1]) ? bottom_um : free_from[i + 1];
    }
    /* Prefix sums over samples < i of 1, x, x², y, x y, B (m), x B (m): the pressed run of a
     * candidate has h = a - x, so its sums are these combined. Column k at sums[k * sums_n + i]. */
    int columns = 5 + 2 * m;
    for (int k = 0; k < columns; k++)
        sums[k * sums_n] = 0.0;
    for (Py_ssize_t i = 0; i < n; i++) {
        double x = s.x_mid_um[i], y = y_free[i];
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
    for (Py_ssize_t j = 0; j < candidates; j++) {
        double c = contacts_um[j], w = widths_um[j];
        Py_ssize_t first = count_at_most(pressed_to, n, c - w);
        Py_ssize_t last = count_below(free_from, n, c);
        /* In-toe sums per shape: h·B (m), h·h, h·y */
        double h_basis[SHAPES][2] = {{0.0, 0.0}, {0.0, 0.0}}, hh[SHAPES] = {0.0, 0.0}, hy[SHAPES] = {0.0, 0.0};
        for (Py_ssize_t i = first; i < last; i++) {
            double h[SHAPES];
            toe_sums(c, w, s.window_um + i * sub, sub, h);
            for (int p = 0; p < SHAPES; p++) {
                h[p] *= 1.0 / (double)sub;
                for (int r = 0; r < m; r++)
                    h_basis[p][r] += h[p] * basis_rows[r * n + i];
                hh[p] += h[p] * h[p];
                hy[p] += h[p] * y_free[i];
            }
        }
        const double *at = sums + first;
        for (int p = 0; p < SHAPES; p++) {
            double a = c - w * LIFT_DEFICIT[p]; /* the pressed samples: h = a - x */
            for (int r = 0; r < m; r++)
                h_basis[p][r] += a * at[(5 + r) * sums_n] - at[(5 + m + r) * sums_n];
            double hh_all = hh[p] + (a * at[0] - 2.0 * at[sums_n]) * a + at[2 * sums_n];
            double hy_all = hy[p] + a * at[3 * sums_n] - at[4 * sums_n];
            double stiffness;
            rss_out[p * candidates + j] = solve_rss(hh_all, h_basis[p], m, hy_all, yy, &stiffness);
        }
    }
    result = Py_NewRef(Py_None);
done:
    free(work);
    release_samples(&s);
    PyBuffer_Release(&contacts_buffer);
    PyBuffer_Release(&widths_buffer);
    PyBuffer_Release(&out_buffer);
    return result;
}

static PyObject *stiffness_at(PyObject *self, PyObject *args)
{
    (void)self;
    Samples s = {0};
    int drift_fitted;
    double contact_um, width_um, power;
    if (!PyArg_ParseTuple(args, "y*y*y*pddd", &s.buffers[0], &s.buffers[1], &s.buffers[2], &drift_fitted,
                          &contact_um, &width_um, &power))
        return NULL;
    int shape = shape_of_power(power);
    if (shape < 0 || check_samples(&s) < 0) {
        release_samples(&s);
        return NULL;
    }
    Py_ssize_t n = s.n, sub = s.subsamples;
    double *work = malloc(sizeof(double) * (size_t)(3 * n));
    if (work == NULL) {
        release_samples(&s);
        return PyErr_NoMemory();
    }
    double *basis_rows = work, *y_free = work + 2 * n;
    int m = project_out_basis(&s, drift_fitted, basis_rows, y_free);
    double h_basis[2] = {0.0, 0.0}, hh_all = 0.0, hy = 0.0;
    for (Py_ssize_t i = 0; i < n; i++) {
        double h[SHAPES];
        toe_sums(contact_um, width_um, s.window_um + i * sub, sub, h);
        double column = h[shape] * (1.0 / (double)sub);
        for (int r = 0; r < m; r++)
            h_basis[r] += basis_rows[r * n + i] * column;
        hh_all += column * column;
        hy += column * y_free[i];
    }
    free(work);
    release_samples(&s);
    double basis_part = h_basis[0] * h_basis[0] + h_basis[1] * h_basis[1];
    double hh = hh_all - basis_part;
    return PyFloat_FromDouble(hh > 1e-9 * (hh_all + 1e-300) ? hy / hh : 0.0);
}

/* ---- Under white noise + a random walk (toe.py: _Whitened, _whiten, _rss_whitened) ---- */

/* The samples' three runs and the whitening of one walk-weighted fit (`_Whitened`). */
typedef struct {
    Py_ssize_t first_near, near_count, differences;
    double *diag, *sub, *y_white; /* per difference (n - 1 each); one malloc at diag */
    double pressed_z, pressed_zz, pressed_zy, tail_zz, tail_zy, yy;
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
    wh->differences = m;
    wh->diag = malloc(sizeof(double) * (size_t)(3 * m));
    if (wh->diag == NULL) {
        PyErr_NoMemory();
        return -1;
    }
    wh->sub = wh->diag + m;
    wh->y_white = wh->diag + 2 * m;
    /* The bidiagonal Cholesky factor of the differences' covariance (2σ² + q, -σ² beside), and the
     * force's differences whitened through it. */
    double *diag = wh->diag, *subd = wh->sub, *y_white = wh->y_white;
    diag[0] = sqrt(2.0 * white_var_g2 + walk_var_g2);
    subd[0] = 0.0;
    for (Py_ssize_t j = 1; j < m; j++) {
        subd[j] = -white_var_g2 / diag[j - 1];
        diag[j] = sqrt(2.0 * white_var_g2 + walk_var_g2 - subd[j] * subd[j]);
    }
    double previous = 0.0, yy = 0.0;
    for (Py_ssize_t j = 0; j < m; j++) {
        previous = ((s->force_g[j + 1] - s->force_g[j]) - subd[j] * previous) / diag[j];
        y_white[j] = previous;
        yy += previous * previous;
    }
    wh->yy = yy;
    /* Pressed past every toe: h = a - x, whose differences do not depend on the candidate. */
    wh->pressed_z = wh->pressed_zz = wh->pressed_zy = 0.0;
    if (first >= 2) {
        double z = 0.0, zz = 0.0, zy = 0.0;
        for (Py_ssize_t j = 0; j < first - 1; j++) {
            z = (-(s->x_mid_um[j + 1] - s->x_mid_um[j]) - subd[j] * z) / diag[j];
            zz += z * z;
            zy += z * y_white[j];
        }
        wh->pressed_z = z, wh->pressed_zz = zz, wh->pressed_zy = zy;
    }
    /* Free air after the in-between run: z decays by -sub / diag a step, per unit at its start. */
    double gain = 1.0, tail_zz = 0.0, tail_zy = 0.0;
    for (Py_ssize_t j = first + count; j < m; j++) {
        gain *= -subd[j] / diag[j];
        tail_zz += gain * gain;
        tail_zy += gain * y_white[j];
    }
    wh->tail_zz = tail_zz, wh->tail_zy = tail_zy;
    return 1;
}

/* `_rss_whitened` for one candidate toe, both shapes: the toe column over the in-between run
 * (with the pressed sample before and the free one after, where there are such), differenced and
 * whitened by the recursion; residuals (white-noise units) and stiffnesses per shape. */
static void whitened_candidate(const Samples *s, const Whitened *wh, double contact_um, double width_um,
                               double rss[SHAPES], double stiffness[SHAPES])
{
    Py_ssize_t first = wh->first_near, end = first + wh->near_count, sub = s->subsamples;
    Py_ssize_t j = first > 0 ? first - 1 : 0; /* the difference the recursion starts at */
    double previous_h[SHAPES], z[SHAPES], zz[SHAPES] = {0.0, 0.0}, zy[SHAPES] = {0.0, 0.0};
    for (int p = 0; p < SHAPES; p++) {
        previous_h[p] = first > 0 ? (contact_um - width_um * LIFT_DEFICIT[p]) - s->x_mid_um[first - 1] : 0.0;
        z[p] = wh->pressed_z;
    }
    for (Py_ssize_t i = first; i <= end && i < s->n; i++) {
        double h[SHAPES] = {0.0, 0.0}; /* past the run: the free sample, h = 0 */
        if (i < end) {
            toe_sums(contact_um, width_um, s->window_um + i * sub, sub, h);
            h[0] /= (double)sub, h[1] /= (double)sub;
        }
        if (i > first || first > 0) { /* a difference: to sample i from the one before */
            for (int p = 0; p < SHAPES; p++) {
                z[p] = ((h[p] - previous_h[p]) - wh->sub[j] * z[p]) / wh->diag[j];
                zz[p] += z[p] * z[p];
                zy[p] += z[p] * wh->y_white[j];
            }
            j++;
        }
        previous_h[0] = h[0], previous_h[1] = h[1];
    }
    for (int p = 0; p < SHAPES; p++) {
        double hh = wh->pressed_zz + zz[p] + z[p] * z[p] * wh->tail_zz;
        double hy = wh->pressed_zy + zy[p] + z[p] * wh->tail_zy;
        int usable = hh > 1e-12;
        stiffness[p] = usable ? hy / hh : 0.0;
        rss[p] = usable && stiffness[p] > 0.0 ? wh->yy - stiffness[p] * hy : INFINITY;
    }
}

static PyObject *rss_grid_whitened(PyObject *self, PyObject *args)
{
    (void)self;
    Samples s = {0};
    Py_buffer contacts_buffer, widths_buffer, out_buffer;
    double white_var_g2, walk_var_g2, lowest_um, highest_um, widest_um;
    if (!PyArg_ParseTuple(args, "y*y*y*dddddy*y*w*", &s.buffers[0], &s.buffers[1], &s.buffers[2], &white_var_g2,
                          &walk_var_g2, &lowest_um, &highest_um, &widest_um, &contacts_buffer, &widths_buffer,
                          &out_buffer))
        return NULL;
    PyObject *result = NULL;
    Whitened wh = {0};
    if (check_samples(&s) < 0)
        goto done;
    Py_ssize_t candidates = 0;
    const double *contacts_um = doubles_of(&contacts_buffer, &candidates, "contacts_um");
    const double *widths_um = doubles_sized(&widths_buffer, candidates, "widths_um");
    double *rss_out = doubles_sized(&out_buffer, SHAPES * candidates, "rss_out");
    if (contacts_um == NULL || widths_um == NULL || rss_out == NULL)
        goto done;
    int prepared = prepare_whitened(&s, white_var_g2, walk_var_g2, lowest_um, highest_um, widest_um, &wh);
    if (prepared < 0)
        goto done;
    if (prepared) {
        for (Py_ssize_t j = 0; j < candidates; j++) {
            double rss[SHAPES], stiffness[SHAPES];
            whitened_candidate(&s, &wh, contacts_um[j], widths_um[j], rss, stiffness);
            rss_out[j] = rss[0];
            rss_out[candidates + j] = rss[1];
        }
    }
    result = PyBool_FromLong(prepared);
done:
    free(wh.diag);
    release_samples(&s);
    PyBuffer_Release(&contacts_buffer);
    PyBuffer_Release(&widths_buffer);
    PyBuffer_Release(&out_buffer);
    return result;
}

static PyObject *stiffness_whitened(PyObject *self, PyObject *args)
{
    (void)self;
    Samples s = {0};
    double white_var_g2, walk_var_g2, lowest_um, highest_um, widest_um, contact_um, width_um, power;
    if (!PyArg_ParseTuple(args, "y*y*y*dddddddd", &s.buffers[0], &s.buffers[1], &s.buffers[2], &white_var_g2,
                          &walk_var_g2, &lowest_um, &highest_um, &widest_um, &contact_um, &width_um, &power))
        return NULL;
    int shape = shape_of_power(power);
    if (shape < 0 || check_samples(&s) < 0) {
        release_samples(&s);
        return NULL;
    }
    Whitened wh = {0};
    int prepared = prepare_whitened(&s, white_var_g2, walk_var_g2, lowest_um, highest_um, widest_um, &wh);
    PyObject *result = NULL;
    if (prepared > 0) {
        double rss[SHAPES], stiffness[SHAPES];
        whitened_candidate(&s, &wh, contact_um, width_um, rss, stiffness);
        result = PyFloat_FromDouble(stiffness[shape]);
    } else if (prepared == 0) {
        PyErr_SetString(PyExc_ValueError, "the samples are not a plain rise: no walk-weighted fit");
    }
    free(wh.diag);
    release_samples(&s);
    return result;
}

static PyMethodDef methods[] = {
    {"rss_grid", rss_grid, METH_VARARGS,
     "rss_grid(window_um, x_mid_um, force_g, drift_fitted, contacts_um, widths_um, rss_out)\n\n"
     "Least-squares residual of the toe fit at every candidate (contacts_um[j], widths_um[j]) for both\n"
     "shapes (0.5, 1.0), written to rss_out (2 × candidates, shape-major); inf where the toe would pull\n"
     "or cannot be told from the baseline (and drift when drift_fitted). window_um: n × subsamples\n"
     "heights each sample averages over; force_g with any known drift taken out (toe.py:\n"
     "_rss_over_contacts)."},
    {"stiffness_at", stiffness_at, METH_VARARGS,
     "stiffness_at(window_um, x_mid_um, force_g, drift_fitted, contact_um, width_um, power) -> float\n\n"
     "The toe's linear stiffness (g/um) solved at one toe, 0 when unsolvable (toe.py: _stiffness_at)."},
    {"rss_grid_whitened", rss_grid_whitened, METH_VARARGS,
     "rss_grid_whitened(window_um, x_mid_um, force_g, white_var_g2, walk_var_g2, lowest_contact_um,\n"
     "                  highest_contact_um, widest_um, contacts_um, widths_um, rss_out) -> bool\n\n"
     "rss_grid under white noise + a random walk of the baseline (residuals in white-noise units).\n"
     "False (rss_out untouched) when the samples are not pressed, then in between, then free\n"
     "(toe.py: _Whitened.prepare, _rss_whitened)."},
    {"stiffness_whitened", stiffness_whitened, METH_VARARGS,
     "stiffness_whitened(window_um, x_mid_um, force_g, white_var_g2, walk_var_g2, lowest_contact_um,\n"
     "                   highest_contact_um, widest_um, contact_um, width_um, power) -> float\n\n"
     "The walk-weighted toe stiffness at one toe; ValueError when rss_grid_whitened would say False."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_c_toe", "The toe kernels of the tap analysis.", -1,
                                    methods, NULL, NULL, NULL, NULL};

PyMODINIT_FUNC PyInit__c_toe(void) { return PyModule_Create(&module); }
