/* The median of doubles by selection (the analysis kernels share it; numpy twin: robust.median). */
#ifndef TAPCELL_MEDIAN_H
#define TAPCELL_MEDIAN_H

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "buffers.h"

static inline void swap(double *a, double *b)
{
    double kept = *a;
    *a = *b;
    *b = kept;
}

/* Put the k-th smallest of values[0..n) at values[k], smaller ones before it and larger after
 * (Hoare's selection; the pivot is the median of three, so sorted or reversed runs stay linear).
 * The fallback of `select_kth` when it gets no scratch memory. */
static inline void select_kth_in_place(double *values, Py_ssize_t n, Py_ssize_t k)
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

/* Below this many values a range is finished by insertion sort. */
#define SELECT_SORT_BELOW 12

/* The middle one of three values. */
static inline double middle_of_three(double a, double b, double c)
{
    if (a > b) swap(&a, &b);
    return c < a ? a : c > b ? b : c;
}

/* `select_kth_in_place` without its branches: each pass sends every value of the range to one of
 * three runs (below the pivot: back into the range's front, which the pass has read already;
 * equal and above: into `scratch`, 2 n values), counting each run with a comparison instead of
 * branching on it (the values' order is noise: a branch on it is mispredicted every other
 * value). The runs go back in order, below, equal, above, and the pass continues in the run that
 * holds k. The same value lands at values[k] (the k-th smallest is one value, whichever way it is
 * selected), smaller or equal ones before it. No NaN among the values (`median_in_place`). */
static inline void select_kth_into(double *values, Py_ssize_t n, Py_ssize_t k, double *scratch)
{
    Py_ssize_t low = 0, high = n; /* [low, high) holds k */
    while (high - low >= SELECT_SORT_BELOW) {
        const double pivot = middle_of_three(values[low], values[low + (high - low) / 2], values[high - 1]);
        double *equal = scratch, *above = scratch + n;
        Py_ssize_t below_count = 0, equal_count = 0, above_count = 0;
        for (Py_ssize_t i = low; i < high; i++) {
            const double value = values[i];
            values[low + below_count] = value; /* at or before i: read already */
            equal[equal_count] = value;
            above[above_count] = value;
            below_count += value < pivot;
            equal_count += value == pivot;
            above_count += value > pivot;
        }
        const Py_ssize_t equal_first = low + below_count, above_first = equal_first + equal_count;
        memcpy(values + equal_first, equal, (size_t)equal_count * sizeof(double));
        memcpy(values + above_first, above, (size_t)above_count * sizeof(double));
        if (k < equal_first) high = equal_first;
        else if (k < above_first) return; /* the pivot's run (never empty: the pivot is one of the values) */
        else low = above_first;
    }
    for (Py_ssize_t i = low + 1; i < high; i++) { /* insertion sort of the rest */
        const double value = values[i];
        Py_ssize_t j = i;
        for (; j > low && values[j - 1] > value; j--)
            values[j] = values[j - 1];
        values[j] = value;
    }
}

/* The k-th smallest of values[0..n) at values[k], smaller or equal ones before it, larger or
 * equal after (no NaN among them). */
static inline void select_kth(double *values, Py_ssize_t n, Py_ssize_t k)
{
    double *scratch = n >= SELECT_SORT_BELOW ? malloc(2 * (size_t)n * sizeof(double)) : NULL;
    if (scratch == NULL && n >= SELECT_SORT_BELOW) {
        select_kth_in_place(values, n, k);
        return;
    }
    select_kth_into(values, n, k, scratch);
    free(scratch);
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
