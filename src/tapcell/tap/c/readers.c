/* The tap file reader's kernel (twin: json.loads in tapcell/tap/readers.py).
 *
 * A tap file is a small JSON object around two or three long arrays of numbers ("time", "force",
 * "z"). json.loads makes a Python float of every number, which numpy then copies again; here those
 * arrays are parsed straight into float64 and cut out of the text, so json.loads reads only the
 * small rest. The kernel is as strict as JSON: anything it does not understand exactly (a number
 * outside JSON's grammar, NaN, a key written with escapes or seen twice, a value that is not a flat
 * array of numbers, text that ends early) makes it give up, and the caller reads the file the plain
 * way, which names the problem. Numbers are converted as Python's float() and json do (an exact
 * shortcut for short ones, else PyOS_string_to_double), so every value is the same to the last bit.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <math.h>
#include <stdlib.h>
#include <string.h>

/* Longest number written out that we convert here; longer ones (no measurement needs them) make
 * the kernel give up. */
#define MAX_NUMBER_CHARS 64
/* Integers with more digits than a float64 holds exactly: the plain path has its own rules for
 * them (readers.MAX_INTEGER_DIGITS), so leave them to it. */
#define MAX_EXACT_INTEGER_DIGITS 15
#define MAX_KEYS 8

typedef struct {
    const char *name;
    Py_ssize_t length;
    int seen;
    double *values;
    Py_ssize_t count, capacity;
} NumberArray;

static int is_json_space(char c) { return c == ' ' || c == '\t' || c == '\n' || c == '\r'; }
static int is_digit(char c) { return c >= '0' && c <= '9'; }

static Py_ssize_t skip_space(const char *text, Py_ssize_t at, Py_ssize_t length)
{
    while (at < length && is_json_space(text[at]))
        at++;
    return at;
}

/* 10^0 .. 10^22: every one exact in a double. */
static const double POWERS_OF_TEN[] = {1e0,  1e1,  1e2,  1e3,  1e4,  1e5,  1e6,  1e7,  1e8,  1e9,  1e10, 1e11,
                                       1e12, 1e13, 1e14, 1e15, 1e16, 1e17, 1e18, 1e19, 1e20, 1e21, 1e22};
#define MAX_EXACT_MANTISSA 9007199254740992ULL /* 2^53: every integer up to it is exact in a double */

/* Past the digits at p (before end), each one also into *mantissa (it wraps after 19 digits:
 * the caller counts them and takes the slow path then). */
static const char *take_digits(const char *p, const char *end, unsigned long long *mantissa)
{
    unsigned long long m = *mantissa;
    for (; p < end && is_digit(*p); p++)
        m = m * 10 + (unsigned long long)(*p - '0');
    *mantissa = m;
    return p;
}

/* One JSON number starting at text[*at] into *value; 0 when it is anything else (or one we leave
 * to the plain path), -1 with a Python error set. */
static int parse_number(const char *text, Py_ssize_t *at, Py_ssize_t length, double *value)
{
    Py_ssize_t start = *at, k = *at;
    int negative = k < length && text[k] == '-';
    k += negative;
    if (!(k < length && is_digit(text[k])) || (text[k] == '0' && k + 1 < length && is_digit(text[k + 1])))
        return 0; /* no digit, or a leading zero */
    const char *text_end = text + length;
    unsigned long long mantissa = 0;
    const char *first = text + k;
    const char *after = take_digits(first, text_end, &mantissa);
    Py_ssize_t integer_digits = after - first, fraction_digits = 0;
    k += integer_digits;
    int is_integer = 1;
    if (k < length && text[k] == '.') {
        k++;
        first = text + k;
        after = take_digits(first, text_end, &mantissa);
        fraction_digits = after - first;
        k += fraction_digits;
        if (fraction_digits == 0)
            return 0;
        is_integer = 0;
    }
    /* Up to 19 digits cannot wrap the mantissa; exact in a double up to 2^53. */
    int inexact = integer_digits + fraction_digits > 19 || mantissa > MAX_EXACT_MANTISSA;
    long exponent = 0;
    if (k < length && (text[k] == 'e' || text[k] == 'E')) {
        k++;
        int exponent_negative = 0;
        if (k < length && (text[k] == '+' || text[k] == '-'))
            exponent_negative = text[k++] == '-';
        Py_ssize_t exponent_start = k;
        for (; k < length && is_digit(text[k]); k++)
            if (exponent < 100000) /* far beyond any double: the slow path below sees the digits */
                exponent = exponent * 10 + (text[k] - '0');
        if (k == exponent_start)
            return 0;
        exponent = exponent_negative ? -exponent : exponent;
        is_integer = 0;
    }
    if (is_integer && integer_digits > MAX_EXACT_INTEGER_DIGITS)
        return 0;
    *at = k;
    /* json reads an integer as a Python int, and float(int("-0")) is +0.0 */
    int sign_of_zero = is_integer ? 0 : negative;
    /* Exact mantissa and power of ten: one IEEE multiply or divide rounds it correctly, as
     * Python's float() does (which takes this same shortcut). */
    long power = exponent - (long)fraction_digits;
    if (!inexact && power >= -22 && power <= 22) {
        double number = (double)mantissa;
        number = power < 0 ? number / POWERS_OF_TEN[-power] : number * POWERS_OF_TEN[power];
        /* number is 0 exactly when the mantissa is: the sign is settled without waiting for the division */
        *value = (negative && (mantissa != 0 || sign_of_zero)) ? -number : number;
        return 1;
    }
    Py_ssize_t chars = k - start;
    if (chars >= MAX_NUMBER_CHARS)
        return 0;
    char digits[MAX_NUMBER_CHARS]; /* the text need not be NUL-terminated after the number */
    memcpy(digits, text + start, (size_t)chars);
    digits[chars] = '\0';
    char *end = NULL;
    double number = PyOS_string_to_double(digits, &end, NULL); /* overflow: +-inf, refused below */
    if (number == -1.0 && PyErr_Occurred())
        return -1;
    if (end != digits + chars || !isfinite(number))
        return 0;
    *value = (is_integer && number == 0.0) ? 0.0 : number;
    return 1;
}

static int append(NumberArray *array, double value)
{
    if (array->count == array->capacity) {
        Py_ssize_t capacity = array->capacity ? 2 * array->capacity : 1024;
        double *values = realloc(array->values, (size_t)capacity * sizeof(double));
        if (values == NULL) {
            PyErr_NoMemory();
            return -1;
        }
        array->values = values;
        array->capacity = capacity;
    }
    array->values[array->count++] = value;
    return 0;
}

/* The array of numbers at text[*at] ('['); *at moves past its ']'. 1, 0 (not a flat array of
 * JSON numbers), -1 (Python error). */
static int parse_array(const char *text, Py_ssize_t *at, Py_ssize_t length, NumberArray *array)
{
    Py_ssize_t k = *at;
    if (!(k < length && text[k] == '['))
        return 0;
    k = skip_space(text, k + 1, length);
    if (k < length && text[k] == ']') {
        *at = k + 1;
        return 1;
    }
    for (;;) {
        double value;
        int parsed = parse_number(text, &k, length, &value);
        if (parsed != 1)
            return parsed;
        if (append(array, value) < 0)
            return -1;
        k = skip_space(text, k, length);
        if (k < length && text[k] == ',') {
            k = skip_space(text, k + 1, length);
            continue;
        }
        if (k < length && text[k] == ']') {
            *at = k + 1;
            return 1;
        }
        return 0;
    }
}

/* Past the string whose opening quote is text[at]: the index after its closing quote, or -1 when
 * the text ends first. *escaped says whether it holds a backslash. */
static Py_ssize_t skip_string(const char *text, Py_ssize_t at, Py_ssize_t length, int *escaped)
{
    *escaped = 0;
    for (Py_ssize_t k = at + 1; k < length; k++) {
        if (text[k] == '\\') {
            *escaped = 1;
            k++; /* the escaped character, whatever it is, does not end the string */
        } else if (text[k] == '"')
            return k + 1;
    }
    return -1;
}

/* Splits the text: 1 with the arrays parsed and their spans in cut_from/cut_to (cuts in text
 * order), 0 to give up, -1 on a Python error. */
static int scan(const char *text, Py_ssize_t length, NumberArray *arrays, int keys, Py_ssize_t *cut_from,
                Py_ssize_t *cut_to, int *cuts)
{
    Py_ssize_t k = skip_space(text, 0, length);
    if (!(k < length && text[k] == '{'))
        return 0; /* not an object (a list, or no JSON at all) */
    int depth = 0, expect_key = 0;
    *cuts = 0;
    while (k < length) {
        char c = text[k];
        if (c == '"') {
            int escaped;
            Py_ssize_t end = skip_string(text, k, length, &escaped);
            if (end < 0)
                return 0;
            if (depth == 1 && expect_key) {
                expect_key = 0;
                if (escaped)
                    return 0; /* json would decode it: it could spell one of our keys */
                Py_ssize_t name_length = end - k - 2;
                int key = -1;
                for (int j = 0; j < keys; j++)
                    if (arrays[j].length == name_length && memcmp(arrays[j].name, text + k + 1, (size_t)name_length) == 0)
                        key = j;
                k = end;
                if (key >= 0) {
                    if (arrays[key].seen)
                        return 0; /* json keeps the last: leave that to it */
                    arrays[key].seen = 1;
                    k = skip_space(text, k, length);
                    if (!(k < length && text[k] == ':'))
                        return 0;
                    k = skip_space(text, k + 1, length);
                    cut_from[*cuts] = k;
                    int parsed = parse_array(text, &k, length, &arrays[key]);
                    if (parsed != 1)
                        return parsed;
                    cut_to[(*cuts)++] = k;
                }
                continue;
            }
            k = end;
            continue;
        }
        if (c == '{' || c == '[') {
            depth++;
            expect_key = depth == 1; /* only the top-level object's keys matter */
        } else if (c == '}' || c == ']') {
            depth--;
            if (depth < 0)
                return 0;
            if (depth == 0) /* the object's end: only space may follow (else json names the extra data) */
                return skip_space(text, k + 1, length) == length;
        } else if (c == ',')
            expect_key = depth == 1;
        k++;
    }
    return 0; /* the text ends inside the object */
}

/* The text with the cuts replaced by "[]", as a str, and the most digits it holds in a row. */
static PyObject *rest_of(const char *text, Py_ssize_t length, const Py_ssize_t *cut_from, const Py_ssize_t *cut_to,
                         int cuts, Py_ssize_t *longest_digit_run)
{
    char *rest = malloc((size_t)length + 2 * (size_t)cuts + 1);
    if (rest == NULL)
        return PyErr_NoMemory();
    Py_ssize_t from = 0, size = 0;
    for (int j = 0; j < cuts; j++) {
        memcpy(rest + size, text + from, (size_t)(cut_from[j] - from));
        size += cut_from[j] - from;
        rest[size++] = '[';
        rest[size++] = ']';
        from = cut_to[j];
    }
    memcpy(rest + size, text + from, (size_t)(length - from));
    size += length - from;
    /* without branches: a digit or not is as good as random to a branch predictor */
    Py_ssize_t run = 0, longest = 0;
    for (Py_ssize_t k = 0; k < size; k++) {
        Py_ssize_t digit = (unsigned char)(rest[k] - '0') < 10;
        run = (run + 1) & -digit;
        longest = run > longest ? run : longest;
    }
    *longest_digit_run = longest;
    /* cut only at ASCII characters, so valid UTF-8 stays valid */
    PyObject *result = PyUnicode_DecodeUTF8(rest, size, "strict");
    free(rest);
    return result;
}

static PyObject *build_result(const char *text, Py_ssize_t length, NumberArray *arrays, int keys,
                              const Py_ssize_t *cut_from, const Py_ssize_t *cut_to, int cuts)
{
    PyObject *values = PyDict_New();
    if (values == NULL)
        return NULL;
    for (int j = 0; j < keys; j++) {
        if (!arrays[j].seen)
            continue;
        PyObject *bytes = PyByteArray_FromStringAndSize(arrays[j].values ? (const char *)arrays[j].values : "",
                                                        arrays[j].count * (Py_ssize_t)sizeof(double));
        if (bytes == NULL || PyDict_SetItemString(values, arrays[j].name, bytes) < 0) {
            Py_XDECREF(bytes);
            Py_DECREF(values);
            return NULL;
        }
        Py_DECREF(bytes);
    }
    Py_ssize_t longest_digit_run = 0;
    PyObject *rest = rest_of(text, length, cut_from, cut_to, cuts, &longest_digit_run);
    if (rest == NULL) {
        Py_DECREF(values);
        return NULL;
    }
    return Py_BuildValue("(NNn)", rest, values, longest_digit_run);
}

static PyObject *split_number_arrays(PyObject *self, PyObject *args)
{
    (void)self;
    PyObject *source, *names;
    if (!PyArg_ParseTuple(args, "OO!", &source, &PyTuple_Type, &names))
        return NULL;
    Py_ssize_t keys = PyTuple_GET_SIZE(names);
    if (keys > MAX_KEYS) {
        PyErr_Format(PyExc_ValueError, "at most %d keys", MAX_KEYS);
        return NULL;
    }
    NumberArray arrays[MAX_KEYS];
    memset(arrays, 0, sizeof arrays);
    for (Py_ssize_t j = 0; j < keys; j++) {
        arrays[j].name = PyUnicode_AsUTF8AndSize(PyTuple_GET_ITEM(names, j), &arrays[j].length);
        if (arrays[j].name == NULL)
            return NULL;
    }
    Py_buffer view = {0};
    const char *text;
    Py_ssize_t length;
    if (PyUnicode_Check(source)) {
        text = PyUnicode_AsUTF8AndSize(source, &length);
        if (text == NULL) { /* lone surrogates: not from a UTF-8 file; json says what it makes of them */
            if (!PyErr_ExceptionMatches(PyExc_UnicodeEncodeError))
                return NULL;
            PyErr_Clear();
            Py_RETURN_NONE;
        }
    } else {
        if (PyObject_GetBuffer(source, &view, PyBUF_SIMPLE) < 0)
            return NULL;
        text = view.buf;
        length = view.len;
    }
    /* at most one cut per key: a key seen twice gives up */
    Py_ssize_t cut_from[MAX_KEYS], cut_to[MAX_KEYS];
    int cuts = 0;
    int found = scan(text, length, arrays, (int)keys, cut_from, cut_to, &cuts);
    PyObject *result;
    if (found == 1)
        result = build_result(text, length, arrays, (int)keys, cut_from, cut_to, cuts);
    else if (found == 0) {
        Py_INCREF(Py_None);
        result = Py_None;
    } else
        result = NULL;
    for (Py_ssize_t j = 0; j < keys; j++)
        free(arrays[j].values);
    if (view.obj != NULL)
        PyBuffer_Release(&view);
    return result;
}

static PyMethodDef methods[] = {
    {"split_number_arrays", split_number_arrays, METH_VARARGS,
     "split_number_arrays(text, keys) -> (rest, {key: bytearray}, longest_digit_run) or None\n\n"
     "Cuts the arrays of numbers that the top-level object of the JSON `text` (str or bytes) holds\n"
     "under `keys` out of it: `rest` is the text with each replaced by [], and each key found maps\n"
     "to its values as native float64 bytes (np.frombuffer); `longest_digit_run`: the most digit\n"
     "characters `rest` holds in a row (no integer in it is longer). None when anything is unusual (not an\n"
     "object, a key with escapes or seen twice, a value that is not a flat array of finite JSON\n"
     "numbers, an integer of more than 15 digits, a number over 63 characters, text ending early):\n"
     "then json.loads must read the whole text, and name the problem."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_c_readers",
                                    "The tap file reader's kernel: number arrays cut out of the JSON text.", -1,
                                    methods, NULL, NULL, NULL, NULL};

PyMODINIT_FUNC PyInit__c_readers(void) { return PyModule_Create(&module); }
