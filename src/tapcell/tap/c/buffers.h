/* Shared by the analysis kernels: float64 arrays in and out through the buffer protocol.
 *
 * Arrays come as numpy float64 arrays (C-contiguous): "O&" with `float64_buffer` (read) or
 * `float64_out` (written: a read-only one refused) checks the type ("y*" / "w*" in
 * PyArg_ParseTuple give a Py_buffer of any bytes). These checks turn a wrong dtype or length into
 * an error naming the argument (a programming error in the caller, never data: the Python side
 * has validated the tap). */
#ifndef TAPCELL_BUFFERS_H
#define TAPCELL_BUFFERS_H

#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>
#include <string.h>

/* `object` as a C-contiguous float64 buffer (with `flags` beyond those) in the Py_buffer `view`
 * points to, else a TypeError naming what it is (an int array of the same byte size would
 * otherwise be read as garbage): the "O&" converters below. */
static inline int float64_view(PyObject *object, void *view, int flags)
{
    Py_buffer *buffer = view;
    if (object == NULL) { /* a later argument failed: release this one (Py_CLEANUP_SUPPORTED) */
        PyBuffer_Release(buffer);
        return 1;
    }
    if (PyObject_GetBuffer(object, buffer, flags | PyBUF_FORMAT | PyBUF_C_CONTIGUOUS) < 0) return 0;
    const char *format = buffer->format ? buffer->format : "B";
    if (format[0] == '<' || format[0] == '=' || format[0] == '@') format++;
    if (buffer->itemsize != (Py_ssize_t)sizeof(double) || strcmp(format, "d") != 0) {
        PyErr_Format(PyExc_TypeError, "expected a float64 array, got format '%s'", buffer->format);
        PyBuffer_Release(buffer);
        return 0;
    }
    return Py_CLEANUP_SUPPORTED;
}

/* A "O&" converter for PyArg_ParseTuple: a float64 array read (`float64_view`). Release the view with
 * PyBuffer_Release; parsing that fails on a later argument releases it. */
static inline int float64_buffer(PyObject *object, void *view)
{
    return float64_view(object, view, PyBUF_SIMPLE);
}

/* The same for a float64 array the kernel writes: a read-only one is refused (numpy's ValueError). */
static inline int float64_out(PyObject *object, void *view)
{
    return float64_view(object, view, PyBUF_WRITABLE);
}

/* The buffer as doubles: its count in *n, NULL (ValueError set) when its size is not whole doubles. */
static inline const double *doubles_of(const Py_buffer *buffer, Py_ssize_t *n, const char *name)
{
    if (buffer->len % (Py_ssize_t)sizeof(double) != 0) {
        PyErr_Format(PyExc_ValueError, "%s: %zd bytes is not a float64 array", name, buffer->len);
        return NULL;
    }
    *n = buffer->len / (Py_ssize_t)sizeof(double);
    return (const double *)buffer->buf;
}

/* The buffer as doubles of exactly `expected` elements, NULL (ValueError set) otherwise. */
static inline double *doubles_sized(const Py_buffer *buffer, Py_ssize_t expected, const char *name)
{
    Py_ssize_t n;
    const double *values = doubles_of(buffer, &n, name);
    if (values != NULL && n != expected) {
        PyErr_Format(PyExc_ValueError, "%s: %zd values, %zd expected", name, n, expected);
        return NULL;
    }
    return (double *)values;
}

/* The pullback's samples (conversion windows' low and high edges, force) from three buffers of one
 * length into *x_lo, *x_hi, *force_g; *force_g is NULL (ValueError set) when they are not. */
static inline void pullback_samples_of(const Py_buffer buffers[3], Py_ssize_t *n, const double **x_lo,
                                       const double **x_hi, const double **force_g)
{
    *x_lo = doubles_of(&buffers[0], n, "x_lo_um");
    *x_hi = *x_lo ? doubles_sized(&buffers[1], *n, "x_hi_um") : NULL;
    *force_g = *x_hi ? doubles_sized(&buffers[2], *n, "force_g") : NULL;
}

/* The first sample at or after `time` (numpy's searchsorted, side "left", NaN after every
 * number), the last for times past the end (n >= 1): analysis.py's `_indices`. */
static inline Py_ssize_t first_at_or_after(const double *time_s, Py_ssize_t n, double time)
{
    Py_ssize_t lo = 0, hi = n;
    while (lo < hi) {
        Py_ssize_t mid = lo + (hi - lo) / 2;
        if (time_s[mid] < time || (isnan(time) && !isnan(time_s[mid])))
            lo = mid + 1;
        else
            hi = mid;
    }
    return lo < n - 1 ? lo : n - 1;
}

#endif
