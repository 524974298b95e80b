/* The median of doubles by selection (the analysis kernels share it; numpy twin: robust.median). */
#ifndef TAPCELL_MEDIAN_H
#define TAPCELL_MEDIAN_H

#include <math.h>

#include "buffers.h"

static inline void swap(double *a, double *b)
{
    double kept = *a;
    *a = *b;
    *b = kept;
}

/* Put the k-th smallest of values[0..n) at values[k], smaller ones before it and larger after
 * (Hoare's selection; the pivot is the median of three, so sorted or reversed runs stay linear). */
static inline void select_kth(double *values, Py_ssize_t n, Py_ssize_t k)
{
    Py_ssize_t low = 0, high = n - 1;
    while (high > low) {
        Py_ssize_t middle = low + (high - low) / 2;
        if (values[middle] < values[low]) swap(&values[middle], &values[low]);
        if (values[high] < values[low]) swap(&values[high], &values[low]);
        if (values[high] < values[middle]) swap(&values[high], &values[middle]);
        double pivot = values[middle];
        Py_ssize_t i = low, j = high;
        while (i <= j) {
            while (values[i] < pivot) i++;
            while (values[j] > pivot) j--;
            if (i <= j) {
                swap(&values[i], &values[j]);
                i++;
                j--;
            }
        }
        if (k <= j) high = j;
        else if (k >= i) low = i;
        else return; /* between j and i every value equals the pivot */
    }
}

/* The median of values[0..n), reordering them: the middle one, or the mean of the middle two for
 * an even count (as robust.median computes it: 0.5 * (a + b)); NaN if any is, or when n < 1. */
static inline double median_in_place(double *values, Py_ssize_t n)
{
    if (n < 1) return NAN;
    for (Py_ssize_t i = 0; i < n; i++)
        if (isnan(values[i])) return NAN; /* as numpy's: a NaN makes the median NaN */
    Py_ssize_t half = n / 2;
    select_kth(values, n, half);
    if (n % 2) return values[half];
    double upper = values[half];
    double lower = values[0]; /* the largest of the lower half */
    for (Py_ssize_t i = 1; i < half; i++)
        if (values[i] > lower) lower = values[i];
    return 0.5 * (lower + upper);
}

#endif
