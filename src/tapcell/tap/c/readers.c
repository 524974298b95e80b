/* The tap file reader's kernel (twin: json.loads in tapcell/tap/readers.py).
 *
 * A tap file is a small JSON object around two or three long arrays of numbers ("time", "force",
 * "z"). json.loads makes a Python float of every number, which numpy then copies again. Here the
 * whole object is decoded in one pass: those top-level arrays straight into float64, everything
 * else into the values json.loads makes of it (dict, list, str, int, float, True, False, None).
 * The kernel is as strict as JSON: anything it does not take exactly (a number outside JSON's
 * grammar, NaN, an integer of more than 15 digits, a control character in a string, a top-level
 * array key seen twice or holding anything but a flat array of finite numbers, nesting deeper than
 * MAX_DEPTH, text that ends early or goes on after the object) makes it give up, and the caller
 * reads the text with json.loads, which names the problem. Numbers are converted as Python's
 * float() and json do (an exact shortcut for short ones, else PyOS_string_to_double), so every
 * value is the same to the last bit; a string with an escape is decoded by json's own scanstring.
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
    PyObject *key; /* borrowed: the caller's tuple holds it */
    int seen;
    double *values;
    Py_ssize_t count, capacity;
} NumberArray;

static int is_json_space(char c) { return c == ' ' || c == '\t' || c == '\n' || c == '\r'; }
static int is_digit(char c) { return c >= '0' && c <= '9'; }

/* The scans below stop at the NUL that ends a str's UTF-8 (text[length]): no digit, space, comma or
 * bracket is a NUL, so none of them needs the length. */
static const char *skip_space(const char *p)
{
    while (is_json_space(*p))
        p++;
    return p;
}

/* 10^0 .. 10^22: every one exact in a double. */
static const double POWERS_OF_TEN[] = {1e0,  1e1,  1e2,  1e3,  1e4,  1e5,  1e6,  1e7,  1e8,  1e9,  1e10, 1e11,
                                       1e12, 1e13, 1e14, 1e15, 1e16, 1e17, 1e18, 1e19, 1e20, 1e21, 1e22};
#define MAX_EXACT_MANTISSA 9007199254740992ULL /* 2^53: every integer up to it is exact in a double */

/* Past the digits at p, each one also into *mantissa (it wraps after 19 digits: the caller counts
 * them and takes the slow path then). */
static const char *take_digits(const char *p, unsigned long long *mantissa)
{
    unsigned long long m = *mantissa;
    unsigned digit;
    while ((digit = (unsigned)(unsigned char)*p - '0') < 10) {
        m = m * 10 + digit;
        p++;
    }
    *mantissa = m;
    return p;
}

/* The number of `chars` characters at `start` (past a float's exact digits, or with a large
 * exponent) as Python's float() converts it; 0 when it is beyond a float. Out of parse_number's
 * line: its digits buffer would cost every short number a stack frame. */
static __attribute__((noinline)) int converted(const char *start, Py_ssize_t chars, int integer, double *value)
{
    if (chars >= MAX_NUMBER_CHARS)
        return 0;
    char digits[MAX_NUMBER_CHARS]; /* the number alone, NUL-terminated */
    memcpy(digits, start, (size_t)chars);
    digits[chars] = '\0';
    char *end = NULL;
    double number = PyOS_string_to_double(digits, &end, NULL); /* overflow: +-inf, refused below */
    if (number == -1.0 && PyErr_Occurred())
        return -1;
    if (end != digits + chars || !isfinite(number))
        return 0;
    *value = (integer && number == 0.0) ? 0.0 : number; /* json: float(int("-0")) is +0.0 */
    return 1;
}

/* One JSON number at *at into *value, and whether it is written as an integer (json makes an int
 * of it); *at moves past it. 0 when it is anything else (or one we leave to the plain path), -1
 * with a Python error set. */
static inline int parse_number(const char **at, double *value, int *is_integer)
{
    const char *start = *at, *p = start;
    int negative = *p == '-';
    p += negative;
    unsigned long long mantissa = 0;
    const char *first = p;
    p = take_digits(p, &mantissa);
    Py_ssize_t integer_digits = p - first, fraction_digits = 0;
    if (integer_digits == 0 || (*first == '0' && integer_digits > 1))
        return 0; /* no digit, or a leading zero */
    int integer = 1;
    if (*p == '.') {
        first = ++p;
        p = take_digits(p, &mantissa);
        fraction_digits = p - first;
        if (fraction_digits == 0)
            return 0;
        integer = 0;
    }
    long exponent = 0;
    if ((*p | 0x20) == 'e') { /* 'e' or 'E' */
        p++;
        int exponent_negative = *p == '-';
        p += *p == '+' || *p == '-';
        const char *exponent_start = p;
        for (; is_digit(*p); p++)
            if (exponent < 100000) /* far beyond any double: the slow path below sees the digits */
                exponent = exponent * 10 + (*p - '0');
        if (p == exponent_start)
            return 0;
        exponent = exponent_negative ? -exponent : exponent;
        integer = 0;
    }
    if (integer && integer_digits > MAX_EXACT_INTEGER_DIGITS)
        return 0;
    *at = p;
    *is_integer = integer;
    /* Exact mantissa (up to 19 digits cannot wrap it; exact in a double up to 2^53) and power of
     * ten: one IEEE multiply or divide rounds it correctly, as Python's float() does (which takes
     * this same shortcut). */
    long power = exponent - (long)fraction_digits;
    if (integer_digits + fraction_digits <= 19 && mantissa <= MAX_EXACT_MANTISSA && power >= -22 && power <= 22) {
        double number = (double)mantissa;
        number = power < 0 ? number / POWERS_OF_TEN[-power] : number * POWERS_OF_TEN[power];
        /* json makes +0 of the integer "-0" (float(int("-0"))); a float -0.0 keeps its sign. Zero
         * exactly when the mantissa is: the sign is settled without waiting for the division. */
        *value = (negative && (mantissa != 0 || !integer)) ? -number : number;
        return 1;
    }
    return converted(start, p - start, integer, value);
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
static int parse_array(const char *text, Py_ssize_t *at, NumberArray *array)
{
    const char *p = text + *at;
    if (*p != '[')
        return 0;
    p = skip_space(p + 1);
    if (*p == ']') {
        *at = p + 1 - text;
        return 1;
    }
    for (;;) {
        double value;
        int is_integer; /* json's int or float: the same double either way */
        int parsed = parse_number(&p, &value, &is_integer);
        if (parsed != 1)
            return parsed;
        if (append(array, value) < 0)
            return -1;
        p = skip_space(p);
        if (*p == ',') {
            p = skip_space(p + 1);
            continue;
        }
        if (*p == ']') {
            *at = p + 1 - text;
            return 1;
        }
        return 0;
    }
}

/* Objects and lists nested deeper than this make the kernel give up (json.loads has its own limit,
 * and its message, for absurd depths; a tap object is three levels deep). */
#define MAX_DEPTH 64

/* json's own decoder of a string with escapes (_json.scanstring), or NULL: then such strings give up. */
static PyObject *scanstring;

typedef struct {
    PyObject *source; /* the str being decoded */
    int ascii;        /* every character ASCII: a byte offset is a character offset (for scanstring) */
    const char *text;
    Py_ssize_t length, at;
    int depth;
    NumberArray *arrays; /* the top-level keys whose arrays go straight into float64 */
    int keys;
} Decoder;

/* Every decode_* returns 1 with a new reference in *out and d->at past the value, 0 to give up,
 * -1 with a Python error set. */
static int decode_value(Decoder *d, PyObject **out);

static void skip(Decoder *d) { d->at = skip_space(d->text + d->at) - d->text; }

static int next_is(Decoder *d, char c) { return d->at < d->length && d->text[d->at] == c; }

/* A string with an escape, as json decodes it (only in an all-ASCII text, where json's character
 * offsets are this kernel's byte offsets). */
static int decode_escaped_string(Decoder *d, PyObject **out)
{
    if (!d->ascii || scanstring == NULL)
        return 0;
    PyObject *decoded = PyObject_CallFunction(scanstring, "Oni", d->source, d->at + 1, 1);
    if (decoded == NULL) {
        if (!PyErr_ExceptionMatches(PyExc_ValueError)) /* json's JSONDecodeError: a bad escape */
            return -1;
        PyErr_Clear();
        return 0;
    }
    Py_ssize_t end;
    if (!PyTuple_Check(decoded) || PyTuple_GET_SIZE(decoded) != 2 || !PyUnicode_Check(PyTuple_GET_ITEM(decoded, 0))) {
        Py_DECREF(decoded);
        return 0;
    }
    end = PyLong_AsSsize_t(PyTuple_GET_ITEM(decoded, 1));
    if (end == -1 && PyErr_Occurred()) {
        Py_DECREF(decoded);
        return -1;
    }
    if (end <= d->at || end > d->length) {
        Py_DECREF(decoded);
        return 0;
    }
    *out = PyTuple_GET_ITEM(decoded, 0);
    Py_INCREF(*out);
    Py_DECREF(decoded);
    d->at = end;
    return 1;
}

static int decode_string(Decoder *d, PyObject **out)
{
    const char *text = d->text;
    Py_ssize_t start = d->at + 1;
    for (Py_ssize_t k = start; k < d->length; k++) {
        unsigned char c = (unsigned char)text[k];
        if (c == '"') {
            /* cut only at ASCII quotes of a str's UTF-8: the span is valid UTF-8 */
            *out = PyUnicode_DecodeUTF8(text + start, k - start, "strict");
            if (*out == NULL)
                return -1;
            d->at = k + 1;
            return 1;
        }
        if (c == '\\')
            return decode_escaped_string(d, out);
        if (c < 0x20)
            return 0; /* json (strict) refuses a control character in a string */
    }
    return 0; /* the text ends inside the string */
}

/* Object keys seen before, by their text: a tap file's keys repeat (each move's six) and so do
 * every file's, and a str made once keeps its hash, which a dict would compute again for a new one. */
#define KEY_CACHE_SIZE 64
static PyObject *key_cache[KEY_CACHE_SIZE];

/* An object's key (a string): a plain ASCII one from the cache, any other the general way. */
static int decode_key(Decoder *d, PyObject **out)
{
    const char *start = d->text + d->at + 1, *p = start;
    unsigned hash = 2166136261u; /* FNV-1a: to pick the cache's slot */
    /* stops at the closing quote, an escape, a control character (the text's NUL too) or non-ASCII */
    while (*p != '"' && *p != '\\' && (unsigned char)*p >= 0x20 && (unsigned char)*p < 0x80)
        hash = (hash ^ (unsigned char)*p++) * 16777619u;
    if (*p != '"')
        return decode_string(d, out);
    Py_ssize_t size = p - start;
    PyObject **slot = &key_cache[hash % KEY_CACHE_SIZE];
    if (*slot == NULL || PyUnicode_GET_LENGTH(*slot) != size || memcmp(PyUnicode_DATA(*slot), start, (size_t)size) != 0) {
        PyObject *key = PyUnicode_FromStringAndSize(start, size); /* ASCII: one byte a character */
        if (key == NULL)
            return -1;
        Py_XSETREF(*slot, key);
    }
    Py_INCREF(*slot);
    *out = *slot;
    d->at = p + 1 - d->text;
    return 1;
}

static int decode_literal(Decoder *d, const char *word, PyObject *value, PyObject **out)
{
    Py_ssize_t size = (Py_ssize_t)strlen(word);
    if (d->length - d->at < size || memcmp(d->text + d->at, word, (size_t)size) != 0)
        return 0;
    d->at += size;
    Py_INCREF(value);
    *out = value;
    return 1;
}

static int decode_number(Decoder *d, PyObject **out)
{
    double value;
    int is_integer;
    const char *p = d->text + d->at;
    int parsed = parse_number(&p, &value, &is_integer);
    if (parsed != 1)
        return parsed;
    d->at = p - d->text;
    /* an integer here has at most 15 digits: exact in the double */
    *out = is_integer ? PyLong_FromDouble(value) : PyFloat_FromDouble(value);
    return *out == NULL ? -1 : 1;
}

/* Past a container's opening bracket and the space after it, and past `close` too when it follows
 * at once (an empty list or object): whether it did. */
static int closes_at_once(Decoder *d, char close)
{
    d->at++;
    skip(d);
    if (!next_is(d, close))
        return 0;
    d->at++;
    return 1;
}

static int decode_list(Decoder *d, PyObject **out)
{
    PyObject *list = PyList_New(0);
    if (list == NULL)
        return -1;
    if (closes_at_once(d, ']')) {
        *out = list;
        return 1;
    }
    for (;;) {
        PyObject *item;
        int decoded = decode_value(d, &item);
        if (decoded != 1) {
            Py_DECREF(list);
            return decoded;
        }
        int appended = PyList_Append(list, item);
        Py_DECREF(item);
        if (appended < 0) {
            Py_DECREF(list);
            return -1;
        }
        skip(d);
        if (next_is(d, ',')) {
            d->at++;
            skip(d);
            continue;
        }
        if (next_is(d, ']')) {
            d->at++;
            *out = list;
            return 1;
        }
        Py_DECREF(list);
        return 0;
    }
}

/* The array of the top-level key `array` as float64 bytes (a bytearray), parsed in place. */
static int decode_number_array(Decoder *d, NumberArray *array, PyObject **out)
{
    if (array->seen)
        return 0; /* json keeps the last of a key seen twice: leave that to it */
    array->seen = 1;
    int parsed = parse_array(d->text, &d->at, array);
    if (parsed != 1)
        return parsed;
    *out = PyByteArray_FromStringAndSize(array->values ? (const char *)array->values : "",
                                         array->count * (Py_ssize_t)sizeof(double));
    return *out == NULL ? -1 : 1;
}

/* The top-level key's number array, or NULL when `key` is none of them. */
static NumberArray *number_array_of(Decoder *d, PyObject *key)
{
    for (int j = 0; j < d->keys; j++)
        if (PyUnicode_Compare(key, d->arrays[j].key) == 0)
            return &d->arrays[j];
    return NULL;
}

static int decode_object(Decoder *d, PyObject **out)
{
    int top_level = d->depth == 1;
    PyObject *object = PyDict_New();
    if (object == NULL)
        return -1;
    if (closes_at_once(d, '}')) {
        *out = object;
        return 1;
    }
    for (;;) {
        PyObject *key = NULL, *value = NULL;
        int decoded = next_is(d, '"') ? decode_key(d, &key) : 0;
        if (decoded == 1) {
            skip(d);
            decoded = next_is(d, ':');
        }
        if (decoded == 1) {
            d->at++;
            skip(d);
            NumberArray *array = top_level ? number_array_of(d, key) : NULL;
            decoded = array != NULL ? decode_number_array(d, array, &value) : decode_value(d, &value);
        }
        if (decoded == 1 && PyDict_SetItem(object, key, value) < 0)
            decoded = -1;
        Py_XDECREF(key);
        Py_XDECREF(value);
        if (decoded != 1) {
            Py_DECREF(object);
            return decoded;
        }
        skip(d);
        if (next_is(d, ',')) {
            d->at++;
            skip(d);
            continue;
        }
        if (next_is(d, '}')) {
            d->at++;
            *out = object;
            return 1;
        }
        Py_DECREF(object);
        return 0;
    }
}

static int decode_value(Decoder *d, PyObject **out)
{
    if (d->at >= d->length)
        return 0;
    switch (d->text[d->at]) {
    case '"':
        return decode_string(d, out);
    case '{':
    case '[': {
        if (d->depth >= MAX_DEPTH)
            return 0;
        d->depth++;
        int decoded = d->text[d->at] == '{' ? decode_object(d, out) : decode_list(d, out);
        d->depth--;
        return decoded;
    }
    case 't':
        return decode_literal(d, "true", Py_True, out);
    case 'f':
        return decode_literal(d, "false", Py_False, out);
    case 'n':
        return decode_literal(d, "null", Py_None, out);
    default:
        return decode_number(d, out); /* gives up on anything that is no JSON number */
    }
}

static PyObject *decode_tap_json(PyObject *self, PyObject *args)
{
    (void)self;
    PyObject *source, *names;
    if (!PyArg_ParseTuple(args, "UO!", &source, &PyTuple_Type, &names))
        return NULL;
    Py_ssize_t keys = PyTuple_GET_SIZE(names);
    if (keys > MAX_KEYS) {
        PyErr_Format(PyExc_ValueError, "at most %d keys", MAX_KEYS);
        return NULL;
    }
    NumberArray arrays[MAX_KEYS];
    memset(arrays, 0, sizeof arrays);
    for (Py_ssize_t j = 0; j < keys; j++) {
        arrays[j].key = PyTuple_GET_ITEM(names, j);
        if (!PyUnicode_Check(arrays[j].key)) {
            PyErr_SetString(PyExc_TypeError, "the keys must be str");
            return NULL;
        }
    }
    Decoder d = {source, PyUnicode_IS_ASCII(source), NULL, 0, 0, 0, arrays, (int)keys};
    d.text = PyUnicode_AsUTF8AndSize(source, &d.length);
    if (d.text == NULL) { /* lone surrogates: not from a UTF-8 file; json says what it makes of them */
        if (!PyErr_ExceptionMatches(PyExc_UnicodeEncodeError))
            return NULL;
        PyErr_Clear();
        Py_RETURN_NONE;
    }
    PyObject *document = NULL;
    skip(&d);
    /* only an object (a list, or no JSON at all, is json's to name) */
    int decoded = next_is(&d, '{') ? decode_value(&d, &document) : 0;
    if (decoded == 1) {
        skip(&d);
        if (d.at != d.length) /* only space may follow (else json names the extra data) */
            decoded = 0;
    }
    PyObject *result = NULL;
    if (decoded == 1) {
        Py_ssize_t seen = 0;
        for (Py_ssize_t j = 0; j < keys; j++)
            seen += arrays[j].seen != 0;
        PyObject *parsed = PyTuple_New(seen);
        if (parsed == NULL)
            Py_DECREF(document);
        else {
            for (Py_ssize_t j = 0, at = 0; j < keys; j++)
                if (arrays[j].seen)
                    PyTuple_SET_ITEM(parsed, at++, Py_NewRef(arrays[j].key));
            result = Py_BuildValue("(NN)", document, parsed); /* "N" takes both, even when it fails */
        }
    } else {
        Py_XDECREF(document);
        if (decoded == 0)
            result = Py_NewRef(Py_None);
    }
    for (Py_ssize_t j = 0; j < keys; j++)
        free(arrays[j].values);
    return result;
}

/* ---- The plain tap: tap_from_object's checks on a decoded tapcell.tap.v1 object, in one call. ---- */

/* The keys of a tap object this part reads, made once (their hashes kept). */
enum { KEY_TAP, KEY_FORMAT, KEY_TIME, KEY_FORCE, KEY_Z, KEY_POSITION, KEY_MOVES, KEY_EVENTS, KEY_SAMPLE_RATE,
       KEY_PROBE, KEY_TRUTH, KEY_META, KEY_COUNT };
static const char *const KEY_NAMES[KEY_COUNT] = {"tap", "format", "time", "force", "z", "position", "moves",
                                                 "events", "sample_rate", "probe", "truth", "meta"};
static PyObject *tap_keys[KEY_COUNT];

/* A number as tap_from_object takes it without a second look: a float or an int (not a bool) that
 * is finite as a float. 0 for anything else (the Python path looks again, and names it). */
static int plain_float(PyObject *value, double *number)
{
    if (PyFloat_CheckExact(value))
        *number = PyFloat_AS_DOUBLE(value);
    else if (PyLong_CheckExact(value)) {
        *number = PyLong_AsDouble(value);
        if (*number == -1.0 && PyErr_Occurred()) {
            PyErr_Clear(); /* beyond a float: not finite */
            return 0;
        }
    } else
        return 0;
    return isfinite(*number);
}

/* obj[key] as a float64 array the reader's kernel parsed (`finite`: those keys), a new reference in
 * *array, and its count of values, or 0. */
static int finite_array(PyObject *obj, int key, PyObject *finite, PyObject **array, Py_ssize_t *count)
{
    PyObject *value = PyDict_GetItemWithError(obj, tap_keys[key]);
    if (value == NULL || PySequence_Contains(finite, tap_keys[key]) != 1)
        return 0;
    Py_buffer view;
    if (PyObject_GetBuffer(value, &view, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT) < 0) {
        PyErr_Clear();
        return 0;
    }
    int plain = view.itemsize == 8 && view.format != NULL && strcmp(view.format, "d") == 0;
    *count = view.len / 8;
    PyBuffer_Release(&view);
    if (plain) {
        Py_INCREF(value);
        *array = value;
    }
    return plain;
}

/* Whether the float64 array's values rise strictly (its buffer read while the caller holds it). */
static int strictly_rising(PyObject *array)
{
    Py_buffer view;
    if (PyObject_GetBuffer(array, &view, PyBUF_C_CONTIGUOUS) < 0) {
        PyErr_Clear();
        return 0;
    }
    const double *values = view.buf;
    Py_ssize_t count = view.len / 8, k = 1;
    while (k < count && values[k] > values[k - 1])
        k++;
    PyBuffer_Release(&view);
    return k >= count;
}

/* obj[key] as tap_from_object's _dict makes it: absent or null {}, an object copied; NULL for
 * anything else (with no error set) or on an error. */
static PyObject *object_copy(PyObject *obj, int key)
{
    PyObject *value = PyDict_GetItemWithError(obj, tap_keys[key]);
    if (value == NULL || value == Py_None)
        return PyErr_Occurred() ? NULL : PyDict_New();
    return PyDict_Check(value) ? PyDict_Copy(value) : NULL;
}

/* Each of `keys` in `values` that is not null made a float (_known_numbers); 0 when one is no
 * plain finite number, -1 on an error. */
static int known_floats(PyObject *values, PyObject *keys)
{
    for (Py_ssize_t j = 0; j < PyTuple_GET_SIZE(keys); j++) {
        PyObject *key = PyTuple_GET_ITEM(keys, j);
        PyObject *value = PyDict_GetItemWithError(values, key);
        double number;
        if (value == NULL) {
            if (PyErr_Occurred())
                return -1;
            continue;
        }
        if (value == Py_None || PyFloat_CheckExact(value)) {
            if (value != Py_None && !isfinite(PyFloat_AS_DOUBLE(value)))
                return 0;
            continue;
        }
        if (!plain_float(value, &number))
            return 0;
        PyObject *as_float = PyFloat_FromDouble(number);
        int set = as_float == NULL ? -1 : PyDict_SetItem(values, key, as_float);
        Py_XDECREF(as_float);
        if (set < 0)
            return -1;
    }
    return 1;
}

/* The moves as rows of floats (_plain_moves, then _moves' checks): a list of tuples; NULL with no
 * error when anything is not plain (the Python path names it), or on an error. */
static PyObject *plain_move_rows(PyObject *moves, PyObject *move_keys)
{
    if (!PyList_Check(moves))
        return NULL;
    Py_ssize_t count = PyList_GET_SIZE(moves), width = PyTuple_GET_SIZE(move_keys);
    PyObject *rows = PyList_New(count);
    if (rows == NULL)
        return NULL;
    double last_print_time = -INFINITY;
    for (Py_ssize_t k = 0; k < count; k++) {
        PyObject *item = PyList_GET_ITEM(moves, k);
        PyObject *row = PyDict_Check(item) ? PyTuple_New(width) : NULL;
        if (row == NULL)
            goto not_plain;
        PyList_SET_ITEM(rows, k, row);
        for (Py_ssize_t j = 0; j < width; j++) {
            PyObject *value = PyDict_GetItemWithError(item, PyTuple_GET_ITEM(move_keys, j));
            double number;
            if (value == NULL || !plain_float(value, &number))
                goto not_plain;
            PyObject *as_float = PyFloat_FromDouble(number);
            if (as_float == NULL)
                goto not_plain;
            PyTuple_SET_ITEM(row, j, as_float);
        }
        /* MOVE_KEYS' order: print_time, move_t, start_v, ... */
        double print_time = PyFloat_AS_DOUBLE(PyTuple_GET_ITEM(row, 0));
        if (PyFloat_AS_DOUBLE(PyTuple_GET_ITEM(row, 1)) < 0 || PyFloat_AS_DOUBLE(PyTuple_GET_ITEM(row, 2)) < 0 ||
            print_time < last_print_time)
            goto not_plain;
        last_print_time = print_time;
    }
    return rows;
not_plain:
    Py_DECREF(rows);
    return NULL;
}

static PyObject *plain_tap_fields(PyObject *self, PyObject *args)
{
    (void)self;
    PyObject *obj, *finite, *format, *move_keys, *event_keys, *probe_keys;
    Py_ssize_t min_samples;
    if (!PyArg_ParseTuple(args, "O!O!(UO!O!O!n)", &PyDict_Type, &obj, &PyTuple_Type, &finite, &format, &PyTuple_Type,
                          &move_keys, &PyTuple_Type, &event_keys, &PyTuple_Type, &probe_keys, &min_samples))
        return NULL;
    if (PyTuple_GET_SIZE(move_keys) < 3) {
        PyErr_SetString(PyExc_ValueError, "the move keys start print_time, move_t, start_v");
        return NULL;
    }
    PyObject *events = NULL, *probe = NULL, *truth = NULL, *meta = NULL, *rows = NULL, *result = NULL;
    PyObject *time_s = NULL, *force_g = NULL, *z_mm = NULL; /* held: nothing below can drop them */
    PyObject *sample_rate = Py_None;
    Py_INCREF(sample_rate);
    /* a dump_taps event, a workbench capture, another format: the Python path */
    PyObject *value = PyDict_GetItemWithError(obj, tap_keys[KEY_TAP]);
    if (value != NULL || PyErr_Occurred())
        goto done;
    value = PyDict_GetItemWithError(obj, tap_keys[KEY_FORMAT]);
    if ((value != NULL && (!PyUnicode_CheckExact(value) || PyUnicode_Compare(value, format) != 0)) || PyErr_Occurred())
        goto done;
    Py_ssize_t samples, forces, heights;
    if (!finite_array(obj, KEY_TIME, finite, &time_s, &samples) || !finite_array(obj, KEY_FORCE, finite, &force_g, &forces))
        goto done;
    int has_z = PyDict_Contains(obj, tap_keys[KEY_Z]);
    if (has_z < 0 || (has_z && !finite_array(obj, KEY_Z, finite, &z_mm, &heights)))
        goto done;
    if (!has_z && PyDict_Contains(obj, tap_keys[KEY_POSITION]) != 0)
        goto done;
    /* moves: `obj.get("moves")` taken only when true, as tap_from_object does */
    value = PyDict_GetItemWithError(obj, tap_keys[KEY_MOVES]);
    int has_moves = value == NULL ? 0 : PyObject_IsTrue(value);
    if (PyErr_Occurred() || has_moves < 0)
        goto done;
    rows = has_moves ? plain_move_rows(value, move_keys) : PyList_New(0);
    if (rows == NULL || (!has_z && !has_moves))
        goto done;
    /* _check_samples: equal lengths, enough samples, time strictly increasing */
    if (forces != samples || (has_z && heights != samples) || samples < min_samples || !strictly_rising(time_s))
        goto done;
    events = object_copy(obj, KEY_EVENTS);
    if (events == NULL)
        goto done;
    for (Py_ssize_t j = 0; j < PyTuple_GET_SIZE(event_keys); j++) { /* dump_taps keeps them on top */
        PyObject *key = PyTuple_GET_ITEM(event_keys, j);
        PyObject *top = PyDict_GetItemWithError(obj, key);
        int there = top == NULL ? 0 : PyDict_Contains(events, key);
        if (PyErr_Occurred() || there < 0 || (top != NULL && !there && PyDict_SetItem(events, key, top) < 0))
            goto done;
    }
    if (known_floats(events, event_keys) != 1)
        goto done;
    value = PyDict_GetItemWithError(obj, tap_keys[KEY_SAMPLE_RATE]);
    if (PyErr_Occurred())
        goto done;
    if (value != NULL && value != Py_None) {
        double rate;
        if (!plain_float(value, &rate) || !(rate > 0))
            goto done;
        Py_SETREF(sample_rate, PyFloat_FromDouble(rate));
        if (sample_rate == NULL)
            goto done;
    }
    probe = object_copy(obj, KEY_PROBE);
    if (probe == NULL || known_floats(probe, probe_keys) != 1)
        goto done;
    truth = object_copy(obj, KEY_TRUTH);
    meta = truth == NULL ? NULL : object_copy(obj, KEY_META);
    if (meta == NULL)
        goto done;
    result = PyTuple_Pack(9, time_s, force_g, has_z ? z_mm : Py_None, rows, sample_rate, events, probe, truth, meta);
done:
    Py_XDECREF(time_s);
    Py_XDECREF(force_g);
    Py_XDECREF(z_mm);
    Py_XDECREF(rows);
    Py_XDECREF(sample_rate);
    Py_XDECREF(events);
    Py_XDECREF(probe);
    Py_XDECREF(truth);
    Py_XDECREF(meta);
    if (result == NULL && !PyErr_Occurred())
        Py_RETURN_NONE;
    return result;
}

static PyMethodDef methods[] = {
    {"decode_tap_json", decode_tap_json, METH_VARARGS,
     "decode_tap_json(text, keys) -> (document, parsed) or None\n\n"
     "The JSON object `text` (a str) decoded as json.loads decodes it, except that the top-level\n"
     "keys among `keys` that hold a flat array of finite numbers map to their values as native\n"
     "float64 bytes (a bytearray, for np.frombuffer); `parsed`: those keys, in `keys`' order. None\n"
     "when anything is unusual (not an object, a number outside JSON or an integer of more than\n"
     "15 digits, NaN, a control character in a string, an escape in a text that is not all ASCII,\n"
     "one of `keys` seen twice or holding anything else, nesting deeper than 64, text ending early\n"
     "or going on after the object): then json.loads must read the text, and name the problem."},
    {"plain_tap_fields", plain_tap_fields, METH_VARARGS,
     "plain_tap_fields(obj, finite_arrays, (format, move_keys, event_keys, probe_keys, min_samples))\n"
     "-> (time, force, z, move_rows, sample_rate, events, probe, truth, meta) or None\n\n"
     "What tap_from_object builds from a decoded tapcell.tap.v1 object whose time, force (and z)\n"
     "arrays the reader's kernel parsed (`finite_arrays`), with its checks: the moves as rows of\n"
     "floats (Move(*row)), events and probe with their known keys made floats, copies of truth and\n"
     "meta, the sample rate as a float (the caller checks it against the times). None when anything\n"
     "is not plain or not right (a dump_taps event, another format, a list where the kernel gave\n"
     "arrays, a move or an event that is no finite plain number, unequal lengths, too few samples,\n"
     "time not increasing, ...): tap_from_object's Python path then builds it, or names the problem."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_c_readers",
                                    "The tap file reader's kernel: a tap's JSON decoded in one pass, number arrays into float64.",
                                    -1, methods, NULL, NULL, NULL, NULL};

PyMODINIT_FUNC PyInit__c_readers(void)
{
    for (int key = 0; key < KEY_COUNT; key++) {
        tap_keys[key] = PyUnicode_InternFromString(KEY_NAMES[key]);
        if (tap_keys[key] == NULL)
            return NULL;
    }
    PyObject *json = PyImport_ImportModule("_json");
    if (json != NULL) {
        scanstring = PyObject_GetAttrString(json, "scanstring");
        Py_DECREF(json);
    }
    if (scanstring == NULL)
        PyErr_Clear(); /* no C json: strings with escapes give up */
    return PyModule_Create(&module);
}
