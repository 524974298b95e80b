/* The JSON output of `tapcell analyze`: the rounding of its numbers (twin: tapcell/tap/model.py
 * `_round_num`, Python's round) and each tap's line (twin: json.dumps, below).
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
#include <string.h>

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


/* ---- json.dumps(value) for the analysis's JSON-ready results (twin: json.dumps, its defaults) ----
 *
 * Writing a tap's result is mostly float repr: the shortest decimal that reads back as the double
 * (dtoa's exact mode, ~0.5 us a number). A result's numbers are short decimals (rounded to a few
 * places), so here a double is first tried as one: x scaled to 15 significant digits, its nearest
 * integer r, and r / 10^k read back as x (one correctly rounded division). Then r's digits are the
 * repr's: decimals of at most 15 significant digits map to distinct doubles, so no other decimal as
 * short or shorter reads back as x. Anything else (17 digits, outside 1e-4..1e15, where repr writes
 * an exponent) is repr's own text. Strings are escaped as json's ensure_ascii does; a type json
 * would not take (or a key that is not a str) is a TypeError, and the caller runs json.dumps. */

typedef struct {
    char *text;
    Py_ssize_t size, capacity;
} Text;

static int grow(Text *out, Py_ssize_t more)
{
    if (out->size + more <= out->capacity) return 0;
    Py_ssize_t capacity = out->capacity ? out->capacity : 1024;
    while (capacity < out->size + more) capacity *= 2;
    char *text = PyMem_Realloc(out->text, (size_t)capacity);
    if (text == NULL) {
        PyErr_NoMemory();
        return -1;
    }
    out->text = text;
    out->capacity = capacity;
    return 0;
}

static int put(Text *out, const char *text, Py_ssize_t length)
{
    if (grow(out, length) < 0) return -1;
    memcpy(out->text + out->size, text, (size_t)length);
    out->size += length;
    return 0;
}

/* 1e-4 .. 1e15: where repr writes a plain decimal (no exponent); below each bound a count of
 * digits before the point. The negative powers are the doubles nearest them: a magnitude next to
 * one may be counted a digit off, which only makes the scale below one off, and the read-back test
 * then decides (a wrong count gives no wrong text, only repr's own). */
static const double DIGIT_BOUNDS[] = {1e-4, 1e-3, 1e-2, 1e-1, 1e0,  1e1,  1e2,  1e3,  1e4,  1e5,
                                      1e6,  1e7,  1e8,  1e9,  1e10, 1e11, 1e12, 1e13, 1e14, 1e15};
#define DIGIT_BOUNDS_COUNT ((int)(sizeof DIGIT_BOUNDS / sizeof DIGIT_BOUNDS[0]))

/* r without its trailing zeros, `count` (10^count: power) at a time; zeros counts them. r > 0. */
static inline void drop_zeros(unsigned long long *r, int *zeros, unsigned long long power, int count)
{
    while (*r % power == 0) {
        *r /= power;
        *zeros += count;
    }
}

/* The digits of a short decimal equal to x, as repr writes it, into buffer; its length, or 0 when
 * x is not one (repr must write it). */
static int short_repr(double x, char *buffer)
{
    double magnitude = fabs(x);
    if (!(magnitude >= DIGIT_BOUNDS[0] && magnitude < DIGIT_BOUNDS[DIGIT_BOUNDS_COUNT - 1])) return 0;
    int bound = 1; /* magnitude < DIGIT_BOUNDS[bound]: bound - 4 digits before the point (at most 0: none) */
    while (magnitude >= DIGIT_BOUNDS[bound]) bound++;
    int integer_digits = bound - 4;
    int scale_digits = 15 - integer_digits; /* 0..18: the scale is exact */
    double scale = POWERS_OF_TEN[scale_digits];
    double nearest = nearbyint(magnitude * scale);
    if (!(nearest < 1e15) || nearest / scale != magnitude) return 0;
    /* an integer below 2^53: exact in an unsigned long long. A short decimal scaled to 15 digits
     * ends in zeros (0.7593: 759300000000000): they are dropped first, eight, four, two, one at a
     * time, so only the digits written are made */
    unsigned long long r = (unsigned long long)nearest; /* > 0: magnitude * scale >= 1e14 */
    int zeros = 0;
    drop_zeros(&r, &zeros, 100000000ULL, 8);
    drop_zeros(&r, &zeros, 10000ULL, 4);
    drop_zeros(&r, &zeros, 100ULL, 2);
    drop_zeros(&r, &zeros, 10ULL, 1);
    char buffer_of_digits[24]; /* r's digits, written from the end back */
    char *digits = buffer_of_digits + sizeof buffer_of_digits;
    do {
        *--digits = (char)('0' + r % 10);
        r /= 10;
    } while (r > 0);
    int count = (int)(buffer_of_digits + sizeof buffer_of_digits - digits);
    int decimal_point = count + zeros - scale_digits; /* digits before the point */
    int length = 0;
    if (x < 0) buffer[length++] = '-';
    if (decimal_point <= 0) {
        buffer[length++] = '0';
        buffer[length++] = '.';
        for (int k = 0; k < -decimal_point; k++) buffer[length++] = '0';
        memcpy(buffer + length, digits, (size_t)count);
        length += count;
    } else if (decimal_point >= count) {
        memcpy(buffer + length, digits, (size_t)count);
        length += count;
        for (int k = count; k < decimal_point; k++) buffer[length++] = '0';
        buffer[length++] = '.';
        buffer[length++] = '0';
    } else {
        memcpy(buffer + length, digits, (size_t)decimal_point);
        length += decimal_point;
        buffer[length++] = '.';
        memcpy(buffer + length, digits + decimal_point, (size_t)(count - decimal_point));
        length += count - decimal_point;
    }
    return length;
}

static int put_float(Text *out, double x)
{
    char buffer[48];
    int length = short_repr(x, buffer);
    if (length > 0) return put(out, buffer, length);
    if (isnan(x)) return put(out, "NaN", 3);
    if (isinf(x)) return x > 0 ? put(out, "Infinity", 8) : put(out, "-Infinity", 9);
    char *text = PyOS_double_to_string(x, 'r', 0, Py_DTSF_ADD_DOT_0, NULL);
    if (text == NULL) return -1;
    int failed = put(out, text, (Py_ssize_t)strlen(text));
    PyMem_Free(text);
    return failed;
}

static int put_string(Text *out, PyObject *string)
{
    Py_ssize_t length = PyUnicode_GET_LENGTH(string);
    int kind = PyUnicode_KIND(string);
    const void *data = PyUnicode_DATA(string);
    if (grow(out, 2 + 12 * length) < 0) return -1; /* at most a surrogate pair of escapes a character */
    char *p = out->text + out->size;
    static const char hex[] = "0123456789abcdef";
    *p++ = '"';
    for (Py_ssize_t k = 0; k < length; k++) {
        Py_UCS4 c = PyUnicode_READ(kind, data, k);
        if (c >= ' ' && c <= '~' && c != '\\' && c != '"') {
            *p++ = (char)c;
            continue;
        }
        *p++ = '\\';
        switch (c) {
        case '\\': *p++ = '\\'; break;
        case '"': *p++ = '"'; break;
        case '\b': *p++ = 'b'; break;
        case '\f': *p++ = 'f'; break;
        case '\n': *p++ = 'n'; break;
        case '\r': *p++ = 'r'; break;
        case '\t': *p++ = 't'; break;
        default:
            if (c >= 0x10000) { /* a surrogate pair, as json writes it */
                Py_UCS4 v = c - 0x10000;
                Py_UCS4 high = 0xd800 | ((v >> 10) & 0x3ff);
                *p++ = 'u';
                *p++ = hex[(high >> 12) & 0xf]; *p++ = hex[(high >> 8) & 0xf];
                *p++ = hex[(high >> 4) & 0xf]; *p++ = hex[high & 0xf];
                *p++ = '\\';
                c = 0xdc00 | (v & 0x3ff);
            }
            *p++ = 'u';
            *p++ = hex[(c >> 12) & 0xf]; *p++ = hex[(c >> 8) & 0xf];
            *p++ = hex[(c >> 4) & 0xf]; *p++ = hex[c & 0xf];
        }
    }
    *p++ = '"';
    out->size = p - out->text;
    return 0;
}

static int put_value(Text *out, PyObject *value, int depth);

static int put_items(Text *out, PyObject *sequence, int depth)
{
    if (put(out, "[", 1) < 0) return -1;
    Py_ssize_t count = PySequence_Fast_GET_SIZE(sequence);
    PyObject **items = PySequence_Fast_ITEMS(sequence);
    for (Py_ssize_t k = 0; k < count; k++) {
        if (k > 0 && put(out, ", ", 2) < 0) return -1;
        if (put_value(out, items[k], depth + 1) < 0) return -1;
    }
    return put(out, "]", 1);
}

static int put_value(Text *out, PyObject *value, int depth)
{
    if (depth > 64) {
        PyErr_SetString(PyExc_TypeError, "nested too deeply for the kernel");
        return -1;
    }
    if (value == Py_None) return put(out, "null", 4);
    if (value == Py_True) return put(out, "true", 4);
    if (value == Py_False) return put(out, "false", 5);
    /* json writes a str, float or int subclass (numpy's float64) as the str, float or int it is */
    if (PyUnicode_Check(value)) return put_string(out, value);
    if (PyFloat_Check(value)) return put_float(out, PyFloat_AS_DOUBLE(value));
    if (PyLong_Check(value)) {
        PyObject *text = PyLong_Type.tp_repr(value);
        if (text == NULL) return -1;
        Py_ssize_t length;
        const char *utf8 = PyUnicode_AsUTF8AndSize(text, &length);
        int failed = utf8 == NULL ? -1 : put(out, utf8, length);
        Py_DECREF(text);
        return failed;
    }
    if (PyList_CheckExact(value) || PyTuple_CheckExact(value)) return put_items(out, value, depth);
    if (PyDict_CheckExact(value)) {
        if (put(out, "{", 1) < 0) return -1;
        Py_ssize_t position = 0, k = 0;
        PyObject *key, *item;
        while (PyDict_Next(value, &position, &key, &item)) {
            if (!PyUnicode_Check(key)) {
                PyErr_SetString(PyExc_TypeError, "a key that is not a str: left to json");
                return -1;
            }
            if (k++ > 0 && put(out, ", ", 2) < 0) return -1;
            if (put_string(out, key) < 0 || put(out, ": ", 2) < 0 || put_value(out, item, depth + 1) < 0) return -1;
        }
        return put(out, "}", 1);
    }
    PyErr_Format(PyExc_TypeError, "%.100s: left to json", Py_TYPE(value)->tp_name);
    return -1;
}

static PyObject *json_text(PyObject *self, PyObject *value)
{
    (void)self;
    Text out = {NULL, 0, 0};
    PyObject *answer = NULL;
    if (put_value(&out, value, 0) == 0) answer = PyUnicode_DecodeASCII(out.text, out.size, "strict");
    PyMem_Free(out.text);
    return answer;
}

static PyMethodDef methods[] = {
    {"json_number", (PyCFunction)(void (*)(void))json_number, METH_FASTCALL,
     "json_number(value, digits=9) -> float or None: None for None, NaN or infinity, else\n"
     "round(float(value), digits) (model._num, bit for bit)."},
    {"json_text", json_text, METH_O,
     "json_text(value) -> str: json.dumps(value) with its defaults, byte for byte, for values made of\n"
     "dict (str keys), list, tuple, str, int, float, bool and None; TypeError for anything else."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_c_output", "The JSON output of the analysis: its numbers' rounding and each tap's line.",
                                    -1, methods, NULL, NULL, NULL, NULL};

PyMODINIT_FUNC PyInit__c_output(void) { return PyModule_Create(&module); }
