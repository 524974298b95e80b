/* Shared by the analysis kernels: float64 arrays in and out through the buffer protocol.
 *
 * Arrays come as numpy float64/int64 arrays (C-contiguous); "y*" / "w*" in PyArg_ParseTuple give
 * a Py_buffer. These checks turn a wrong dtype or length into a ValueError naming the argument
 * (a programming error in the caller, never data: the Python side has validated the tap). */
#ifndef TAPCELL_BUFFERS_H
#define TAPCELL_BUFFERS_H

#define PY_SSIZE_T_CLEAN
#include <Python.h>

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

#endif
