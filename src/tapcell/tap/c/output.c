/* The rounding of the analysis's JSON numbers (twin: tapcell/tap/model.py `_num`, Python's round).
 *
 * `tapcell analyze --json` rounds some 45 numbers a tap to a few decimals. Python's round(x, n)
 * finds the decimal by the correctly rounded dtoa (about half a microsecond each, a tenth of what
 * writing a tap's result costs). Here the common case takes a few instructions, with the same
 * answer. y = x * 10^n is x scaled to the last decimal kept, the exact product rounded. Below 2^52
 * every half-way point r + 1/2 is a double, and rounding is monotonic: when y lies strictly between
 * r - 1/2 and r + 1/2, so does the exact product, and r is the correctly rounded decimal, whichever
 * way a tie would break. r / 10^n (both exact, one correctly rounded division) is then the double
 * nearest that decimal: what round()'s string-to-double gives. A y on a half-way point (the product
 * may lie either side of it), a y too large, or more than 22 digits go to Python's round itself.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <math.h>

/* The powers of ten a double holds exactly. */
static const double POWERS_OF_TEN[] = {1e0,  1e1,  1e2,  1e3,  1e4,  1e5,  1e6,  1e7,  1e8,  1e9,  1e10, 1e11,
                                       1e12, 1e13, 1e14, 1e15, 1e16, 1e17, 1e18, 1e19, 1e20, 1e21, 1e22};
#define MAX_FAST_DIGITS 22
#define DEFAULT_DIGITS 9 /* model._num's */
/* Below this every integer and half-integer is a double. */
#define MAX_FAST_SCALED 0x1p52

/* Python's round(x, digits) for a finite x, via round() itself where the fast path cannot vouch. */
static PyObject *round_finite(double x, long digits)
{
    if (digits >= 0 && digits <= MAX_FAST_DIGITS) {
        double scale = POWERS_OF_TEN[digits];
        double scaled = x * scale;
        if (fabs(scaled) < MAX_FAST_SCALED) {
            double nearest = nearbyint(scaled);
            if (fabs(scaled - nearest) < 0.5) return PyFloat_FromDouble(nearest / scale);
        }
    }
    PyObject *value = PyFloat_FromDouble(x);
    if (value == NULL) return NULL;
    PyObject *rounded = PyObject_CallMethod(value, "__round__", "l", digits);
    Py_DECREF(value);
    return rounded;
}

static PyObject *json_number(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    (void)self;
    if (nargs != 1 && nargs != 2) {
        PyErr_SetString(PyExc_TypeError, "json_number(value, digits=9) takes 1 or 2 arguments");
        return NULL;
    }
    PyObject *value = args[0];
    if (value == Py_None) Py_RETURN_NONE;
    double x = PyFloat_AsDouble(value);
    if (x == -1.0 && PyErr_Occurred()) return NULL;
    long digits = nargs == 2 ? PyLong_AsLong(args[1]) : DEFAULT_DIGITS;
    if (digits == -1 && PyErr_Occurred()) return NULL;
    if (!isfinite(x)) Py_RETURN_NONE;
    return round_finite(x, digits);
}

static PyMethodDef methods[] = {
    {"json_number", (PyCFunction)(void (*)(void))json_number, METH_FASTCALL,
     "json_number(value, digits=9) -> float or None: None for None, NaN or infinity, else\n"
     "round(float(value), digits) (model._num, bit for bit)."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_c_output", "The rounding of the analysis's JSON numbers.",
                                    -1, methods, NULL, NULL, NULL, NULL};

PyMODINIT_FUNC PyInit__c_output(void) { return PyModule_Create(&module); }
