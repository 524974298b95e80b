/* A tap's Z uncertainty from its parts (tapcell.tap.uncertainty.tap_sigma_parts) in one call.
 *
 * The twin is a dozen small Python functions (misfit_um, squeeze_um, film_um, floor_um, staircase_um,
 * thread_um, ringing_um, samples_in_reach, z_sigma_um), each a few floating-point operations: their
 * calls and the ZSigmaParts they fill cost more than the arithmetic. Here the same operations in
 * the same order, so kernel and twin agree bit for bit:
 * - Python's max(a, b) keeps a unless b > a, min(a, b) keeps a unless b < a (a NaN stays where
 *   fmax / fmin would drop it): py_max / py_min below;
 * - x ** 2 is pow(x, 2), correctly rounded: x * x;
 * - the sum of the squares runs from the first part to the last, as sum() does on Python 3.11
 *   (3.12's sum compensates: there the two agree to rounding);
 * - a missing value (Python's None) is told apart from a NaN: `optional` below.
 * samples_in_reach: the pullback samples whose window's middle 0.5 (x_lo + x_hi) lies within
 * reach_um of the contact, as numpy computes each element. */
#include "buffers.h"
#include <math.h>

static double py_max(double a, double b) { return b > a ? b : a; }
static double py_min(double a, double b) { return b < a ? b : a; }

/* A float or None: *present 0 for None; else the value as a double (an int too, as Python's
 * arithmetic takes it). 0 with a TypeError set for anything else. */
static int optional(PyObject *object, double *value, int *present, const char *name)
{
    if (object == Py_None) {
        *present = 0;
        *value = 0.0;
        return 1;
    }
    *value = PyFloat_AsDouble(object);
    if (*value == -1.0 && PyErr_Occurred()) {
        PyErr_Format(PyExc_TypeError, "%s: expected a number or None", name);
        return 0;
    }
    *present = 1;
    return 1;
}

static PyObject *tap_sigma_parts(PyObject *self, PyObject *args)
{
    (void)self;
    Py_buffer lob = {0}, hib = {0};
    double contact_um, reach_um, stiffness, noise_um, shape_um, walk_var_g2, scatter_g, allowance_um, toe_lift_um;
    double window_staircase_um, z_step_um, delay_um, stage_um, weights[8];
    PyObject *near_o, *far_o, *residual_o, *step_o, *down_o, *up_o, *ring_var_o, *ring_period_o;
    if (!PyArg_ParseTuple(args, "O&O&ddddddOOdOOOOdddddOOd(dddddddd)", float64_buffer, &lob, float64_buffer, &hib,
                          &contact_um, &reach_um, &stiffness, &noise_um, &shape_um, &walk_var_g2, &near_o, &far_o,
                          &scatter_g, &residual_o, &step_o, &down_o, &up_o, &allowance_um, &toe_lift_um,
                          &window_staircase_um, &z_step_um, &delay_um, &ring_var_o, &ring_period_o, &stage_um,
                          &weights[0], &weights[1], &weights[2], &weights[3], &weights[4], &weights[5],
                          &weights[6], &weights[7]))
        return NULL;
    PyObject *answer = NULL;
    Py_ssize_t n;
    const double *x_lo = doubles_of(&lob, &n, "x_lo_um");
    const double *x_hi = x_lo ? doubles_sized(&hib, n, "x_hi_um") : NULL;
    double near_pull, far_pull, residual, step, down, up, ring_var, ring_period;
    int has_near, has_far, has_residual, has_step, has_down, has_up, has_ring, has_period;
    if (x_hi == NULL || !optional(near_o, &near_pull, &has_near, "near_pull_g")
        || !optional(far_o, &far_pull, &has_far, "far_pull_g")
        || !optional(residual_o, &residual, &has_residual, "residual_g")
        || !optional(step_o, &step, &has_step, "step_g") || !optional(down_o, &down, &has_down, "down_um")
        || !optional(up_o, &up, &has_up, "up_um") || !optional(ring_var_o, &ring_var, &has_ring, "ringing_var_g2")
        || !optional(ring_period_o, &ring_period, &has_period, "ringing_period_samples"))
        goto done;
    if (has_ring != has_period) {
        PyErr_SetString(PyExc_ValueError, "ringing_var_g2 and ringing_period_samples: both or neither");
        goto done;
    }
    const int stiff = stiffness > 0.0;
    /* thread_um */
    double thread = 0.0;
    if (has_near && stiff) {
        const double letting_go = has_far ? near_pull - far_pull : near_pull;
        thread = sqrt(py_max(letting_go * letting_go - walk_var_g2, 0.0)) / stiffness;
    }
    /* misfit_um: `step_g or 0.0` (None and 0 alike) */
    double misfit = 0.0;
    if (has_residual && stiff) {
        const double step_g = has_step ? step : 0.0;
        const double excess = residual * residual - scatter_g * scatter_g - step_g * step_g;
        misfit = sqrt(py_max(excess, 0.0)) / stiffness;
    }
    /* squeeze_um and film_um */
    const double squeeze = (has_down && has_up) ? py_max(down - up - allowance_um, 0.0) : 0.0;
    const double film = py_min(py_max(squeeze, 0.0), fabs(toe_lift_um));
    /* floor_um */
    const double floor_part = stiff ? 1.0 / stiffness : 0.0;
    /* staircase_um */
    const double staircase = z_step_um > 0.0 ? window_staircase_um / sqrt(py_max(reach_um / z_step_um, 1.0))
                                             : window_staircase_um;
    /* ringing_um over samples_in_reach */
    double ringing = 0.0;
    if (has_ring) {
        Py_ssize_t samples = 0;
        for (Py_ssize_t i = 0; i < n; i++)
            if (fabs(0.5 * (x_lo[i] + x_hi[i]) - contact_um) < reach_um) samples++;
        if (samples > 0 && stiff) {
            const double count = (double)samples;
            const double energy = ring_var * py_min(count, ring_period * ring_period / count);
            ringing = 2.0 * sqrt(energy / count) / stiffness;
        }
    }
    const double parts[11] = {noise_um, shape_um, thread, misfit, squeeze, film, floor_part, staircase, delay_um,
                              ringing, stage_um};
    /* the weights of noise, shape, misfit, thread, squeeze, film, floor, ringing (SigmaWeights' order);
     * staircase, delay and stage count fully */
    const double weighed[11] = {weights[0] * parts[0], weights[1] * parts[1], weights[3] * parts[2],
                                weights[2] * parts[3], weights[4] * parts[4], weights[5] * parts[5],
                                weights[6] * parts[6], parts[7], parts[8], weights[7] * parts[9], parts[10]};
    double sum = 0.0;
    for (int i = 0; i < 11; i++) sum += weighed[i] * weighed[i];
    answer = Py_BuildValue("(ddddddddddd)d", parts[0], parts[1], parts[2], parts[3], parts[4], parts[5], parts[6],
                           parts[7], parts[8], parts[9], parts[10], sqrt(sum));
done:
    PyBuffer_Release(&lob);
    PyBuffer_Release(&hib);
    return answer;
}

static PyMethodDef methods[] = {
    {"tap_sigma_parts", tap_sigma_parts, METH_VARARGS,
     "tap_sigma_parts(x_lo_um, x_hi_um, contact_um, reach_um, stiffness_g_um, noise_um, shape_um, walk_var_g2,\n"
     "                near_pull_g, far_pull_g, scatter_g, residual_g, step_g, down_um, up_um, allowance_um,\n"
     "                toe_lift_um, window_staircase_um, z_step_um, delay_um, ringing_var_g2,\n"
     "                ringing_period_samples, stage_um, weights)\n"
     "-> ((noise, shape, thread, misfit, squeeze, film, floor, staircase, delay, ringing, stage) um, z_sigma_um)\n\n"
     "A tap's Z sigma parts and their weighed sum in quadrature (uncertainty.py: tap_sigma_parts).\n"
     "None for a value the tap does not have; weights: SigmaWeights' eight, in its order."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_c_uncertainty",
                                    "A tap's Z uncertainty from its parts (tapcell.tap.uncertainty).", -1, methods,
                                    NULL, NULL, NULL, NULL};

PyMODINIT_FUNC PyInit__c_uncertainty(void) { return PyModule_Create(&module); }
