/* numpy's sum of float64 values, bit for bit: what np.sum / np.add.reduce / np.trace compute, so a
 * kernel's mean or trace is its numpy twin's to the last bit.
 *
 * numpy adds pairwise (its loops_utils.h): fewer than 8 values one after another; up to 128 in eight
 * running sums, the eight then added as ((0+1)+(2+3))+((4+5)+(6+7)) and the rest one by one; more
 * split in two at a multiple of 8 below the half. Its reduction then adds that to its identity, +0.0,
 * which changes nothing but the sign of a zero: values that are all -0.0 sum to +0.0. */
#ifndef TAPCELL_SUM_H
#define TAPCELL_SUM_H

#define PY_SSIZE_T_CLEAN
#include <Python.h>

static inline double pairwise_sum_of(const double *values, Py_ssize_t n, Py_ssize_t stride)
{
    if (n < 8) {
        double sum = 0.0;
        for (Py_ssize_t i = 0; i < n; i++)
            sum += values[i * stride];
        return sum;
    }
    if (n <= 128) {
        double r[8];
        for (int k = 0; k < 8; k++)
            r[k] = values[k * stride];
        Py_ssize_t i = 8;
        for (; i < n - n % 8; i += 8)
            for (int k = 0; k < 8; k++)
                r[k] += values[(i + k) * stride];
        double sum = ((r[0] + r[1]) + (r[2] + r[3])) + ((r[4] + r[5]) + (r[6] + r[7]));
        for (; i < n; i++)
            sum += values[i * stride];
        return sum;
    }
    Py_ssize_t half = n / 2;
    half -= half % 8;
    return pairwise_sum_of(values, half, stride) + pairwise_sum_of(values + half * stride, n - half, stride);
}

/* The sum of n values `stride` apart (1: contiguous), as numpy's reduction gives it. */
static inline double numpy_sum(const double *values, Py_ssize_t n, Py_ssize_t stride)
{
    return 0.0 + pairwise_sum_of(values, n, stride);
}

#endif
