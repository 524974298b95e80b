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

/* Below this many values the selection's scratch (2 n values) is on the stack (4 kB), not malloc'ed:
 * the analysis's medians are mostly of a few dozen values (the polarity's, the window's noise). */
#define SELECT_SCRATCH_ON_STACK_BELOW 256

/* The k-th smallest of values[0..n) at values[k], smaller or equal ones before it, larger or
 * equal after (no NaN among them). */
static inline void select_kth(double *values, Py_ssize_t n, Py_ssize_t k)
{
    double on_stack[2 * SELECT_SCRATCH_ON_STACK_BELOW];
    double *scratch = n < SELECT_SCRATCH_ON_STACK_BELOW ? on_stack : malloc(2 * (size_t)n * sizeof(double));
    if (scratch == NULL) {
        select_kth_in_place(values, n, k);
        return;
    }
    select_kth_into(values, n, k, scratch);
    if (scratch != on_stack)
        free(scratch);
}

/* From this many values on, the median is looked for among the values between two pivots that a
 * sample brackets it with (`median_between_pivots`) before a selection over them all. */
#define MEDIAN_SAMPLED_FROM 256
#define MEDIAN_SAMPLE 64
/* The pivots lie this many sample ranks either side of the median's: the median falls outside
 * them about once in 80 calls (the sample's count below the median is binomial, sigma 4), and
 * they hold about 20 / 64 of the values. */
#define MEDIAN_SAMPLE_MARGIN 10

/* What `median_between_pivots` found. */
enum { PIVOTS_MISSED = 0, PIVOTS_FOUND = 1, PIVOTS_SAW_NAN = 2 };

/* Floyd and Rivest's selection, one step: the k-th smallest values lo_rank and hi_rank (hi_rank =
 * lo_rank or lo_rank + 1) of values[0..n), from the values between two pivots taken from an evenly
 * spaced sample (one pass picks them out into scratch; the selection then runs on a third of the
 * values). PIVOTS_FOUND with them in *lower and *upper; PIVOTS_SAW_NAN when a value is NaN (it
 * lies neither below, between nor above the pivots); PIVOTS_MISSED when the pivots missed them
 * (the caller selects over every value then) or there was no memory. values are only read. */
static inline int median_between_pivots(const double *values, Py_ssize_t n, Py_ssize_t lo_rank, Py_ssize_t hi_rank,
                                        double *lower, double *upper)
{
    double sample[MEDIAN_SAMPLE], sample_scratch[2 * MEDIAN_SAMPLE];
    for (Py_ssize_t j = 0; j < MEDIAN_SAMPLE; j++)
        sample[j] = values[j * n / MEDIAN_SAMPLE];
    Py_ssize_t a = lo_rank * MEDIAN_SAMPLE / n - MEDIAN_SAMPLE_MARGIN;
    Py_ssize_t b = hi_rank * MEDIAN_SAMPLE / n + MEDIAN_SAMPLE_MARGIN;
    a = a < 0 ? 0 : a;
    b = b > MEDIAN_SAMPLE - 1 ? MEDIAN_SAMPLE - 1 : b;
    select_kth_into(sample, MEDIAN_SAMPLE, b, sample_scratch);
    const double high_pivot = sample[b];
    select_kth_into(sample, b, a, sample_scratch); /* sample[0..b) holds the values up to sample[b] */
    const double low_pivot = sample[a];
    double *between = malloc((size_t)n * sizeof(double));
    if (between == NULL) return PIVOTS_MISSED;
    Py_ssize_t below = 0, count = 0, above = 0;
    for (Py_ssize_t i = 0; i < n; i++) { /* without branches on the values, as select_kth_into */
        const double value = values[i];
        between[count] = value;
        below += value < low_pivot;
        count += (value >= low_pivot) & (value <= high_pivot);
        above += value > high_pivot;
    }
    int found = below + count + above < n ? PIVOTS_SAW_NAN : below <= lo_rank && hi_rank < below + count;
    if (found == PIVOTS_FOUND) {
        Py_ssize_t k = hi_rank - below;
        select_kth(between, count, k);
        *upper = between[k];
        double largest_before = between[0]; /* the lo_rank-th when it is not the hi_rank-th */
        for (Py_ssize_t i = 1; i < k; i++)
            if (between[i] > largest_before) largest_before = between[i];
        *lower = lo_rank == hi_rank ? *upper : largest_before;
    }
    free(between);
    return found;
}

/* The median of values[0..n), perhaps reordering them: the middle one, or the mean of the middle two
 * for an even count (as robust.median computes it: 0.5 * (a + b)); NaN if any is, or when n < 1. */
static inline double median_in_place(double *values, Py_ssize_t n)
{
    if (n < 1) return NAN;
    Py_ssize_t half = n / 2;
    double lower, upper;
    if (n >= MEDIAN_SAMPLED_FROM) {
        int found = median_between_pivots(values, n, n % 2 ? half : half - 1, half, &lower, &upper);
        if (found == PIVOTS_FOUND) return n % 2 ? upper : 0.5 * (lower + upper);
        if (found == PIVOTS_SAW_NAN) return NAN;
    }
    for (Py_ssize_t i = 0; i < n; i++)
        if (isnan(values[i])) return NAN; /* as numpy's: a NaN makes the median NaN */
    select_kth(values, n, half);
    if (n % 2) return values[half];
    upper = values[half];
    lower = values[0]; /* the largest of the lower half */
    for (Py_ssize_t i = 1; i < half; i++)
        if (values[i] > lower) lower = values[i];
    return 0.5 * (lower + upper);
}

/* A coarse converter (a low gain, a big load cell, readings in whole grams) rounds every reading
 * to a step: |deviations| then sit on a lattice of it, and once the step nears the noise their
 * median lands on a lattice value, 0 when most readings repeat. robust.grouped_median's constants
 * and arithmetic (its twin, the same bits): the median of grouped data, interpolated in its step. */
#define LATTICE_STEP_SHARE 0.05  /* a step finer than this share of the median leaves it as it is */
#define ON_LATTICE 0.05          /* a value within this share of a step of a multiple of it */
#define LATTICE_SHARE_MIN 0.9    /* of the values above zero, at least this share on the lattice */
#define LATTICE_MIN_VALUES 8     /* and at least this many (a reading frozen but a few times is no step) */
#define LATTICE_BINS 32          /* a step over a twentieth of the median puts it in bin 20 at most */
#define LATTICE_MAX_DOUBLINGS 8  /* repairs between repairs: a step at most 256 times the smallest value */

/* How many of the values above `tiny` lie within ON_LATTICE of a multiple of `step`. */
static inline Py_ssize_t count_on_lattice(const double *values, Py_ssize_t n, double tiny, double step)
{
    Py_ssize_t on_lattice = 0;
    for (Py_ssize_t i = 0; i < n; i++) {
        if (values[i] > tiny) {
            const double ratio = values[i] / step;
            on_lattice += fabs(ratio - floor(ratio + 0.5)) <= ON_LATTICE;
        }
    }
    return on_lattice;
}

/* The median of the n non-negative `values` (`median` of them: median_in_place's answer) read as
 * grouped data where they sit on a lattice coarse against that median, else the median itself. */
static inline double grouped_median(const double *values, Py_ssize_t n, double median)
{
    /* What lies at or under `tiny` is the difference of equal readings left in the last bits: a
     * billionth of the median, or where the median is 0, of the largest value. */
    double tiny;
    if (median > 0.0) {
        tiny = 1e-9 * median;
        const double finer = LATTICE_STEP_SHARE * median;
        for (Py_ssize_t i = 0; i < n; i++) /* continuous readings: a few values in, one finer than a lattice */
            if (values[i] > tiny && values[i] <= finer) return median;
    } else {
        double largest = 0.0;
        for (Py_ssize_t i = 0; i < n; i++)
            if (values[i] > largest) largest = values[i];
        tiny = 1e-9 * largest;
    }
    double step = INFINITY;
    Py_ssize_t above = 0;
    for (Py_ssize_t i = 0; i < n; i++) {
        if (values[i] > tiny) {
            above++;
            if (values[i] < step) step = values[i];
        }
    }
    if (above < LATTICE_MIN_VALUES || !(step > LATTICE_STEP_SHARE * median)) return median;
    if (count_on_lattice(values, n, tiny, step) < LATTICE_SHARE_MIN * above) return median;
    /* The coarsest lattice most values keep: a spike repaired to its neighbours' mean puts a few
     * values halfway between, and the smallest value alone would halve the step. */
    for (int doubled = 0; doubled < LATTICE_MAX_DOUBLINGS
                          && count_on_lattice(values, n, tiny, 2.0 * step) >= LATTICE_SHARE_MIN * above; doubled++)
        step *= 2.0;
    Py_ssize_t counts[LATTICE_BINS] = {0};
    counts[0] = n - above;
    for (Py_ssize_t i = 0; i < n; i++) {
        if (values[i] > tiny) {
            const double multiple = floor(values[i] / step + 0.5);
            counts[multiple < LATTICE_BINS - 1 ? (int)multiple : LATTICE_BINS - 1]++;
        }
    }
    /* bin 0 holds [0, step / 2), bin j [(j - 1/2) step, (j + 1/2) step): where the half count falls */
    const double half = 0.5 * n;
    Py_ssize_t below = 0;
    int bin = 0;
    while (bin < LATTICE_BINS - 1 && below + counts[bin] <= half)
        below += counts[bin++];
    const double low = bin == 0 ? 0.0 : (bin - 0.5) * step, width = bin == 0 ? 0.5 * step : step;
    return low + (half - below) / counts[bin] * width;
}

#endif
