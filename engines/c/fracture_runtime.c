/*
 * fracture_runtime.c - reader of the `fracture` impact-projection file (C99, libc only).
 * See fracture_runtime.h for the API and docs/FORMAT.md for the format and algorithm.
 *
 * MIT licence, Copyright (c) fracture developers.
 *
 * Layout of this file: JSON (a small validating parser for the header), header
 * (the keys of docs/FORMAT.md section 1), load (validation, one allocation, the
 * k-d tree and the spanning forest), project (section 4, no allocation).
 */
#include "fracture_runtime.h"

#include <locale.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#ifdef __FAST_MATH__
#error "fracture_runtime.c relies on IEEE semantics (NaN checks, exact ties): do not compile it with -ffast-math"
#endif
#if defined(__clang__)
#pragma STDC FP_CONTRACT OFF /* section 4's sums in double, unfused (GCC's -std=c99 is already off) */
#endif

#define JSON_MAX_DEPTH 64
#define NUMBER_MAX 511  /* longest number token accepted (the writer's are under 30 characters) */
#define URI_MAX 255
#define KD_LEAF 8
#define KD_STACK 96
#define BOUND_SLACK 1e-9 /* far above the rounding of a k-term sum in double for any k << 1e6 */

/* ------------------------------------------------------------------ messages */

static fr_status fail(char *message, size_t size, fr_status status, const char *format, ...)
{
    if (message != NULL && size > 0) {
        va_list args;
        va_start(args, format);
        vsnprintf(message, size, format, args);
        va_end(args);
    }
    return status;
}

const char *fr_status_string(fr_status status)
{
    switch (status) {
    case FR_OK: return "ok";
    case FR_ERR_ARGUMENT: return "invalid argument";
    case FR_ERR_JSON: return "invalid JSON header";
    case FR_ERR_FORMAT: return "not a supported fracture runtime file";
    case FR_ERR_HEADER: return "missing or malformed header entry";
    case FR_ERR_SIZE: return "sizes, offsets or shapes disagree";
    case FR_ERR_CRC: return "binary file does not match its header (crc32)";
    case FR_ERR_DATA: return "invalid values in the binary file";
    case FR_ERR_MEMORY: return "out of memory";
    case FR_ERR_INPUT: return "invalid impact (non-finite point or impulse, NaN or negative threshold)";
    }
    return "unknown status";
}

/* ------------------------------------------------------------------ JSON */

typedef struct jp {
    const unsigned char *p, *end;
    int depth;
} jp;

static void j_ws(jp *j)
{
    while (j->p < j->end && (*j->p == ' ' || *j->p == '\t' || *j->p == '\n' || *j->p == '\r'))
        j->p++;
}

static int j_peek(jp *j)
{
    j_ws(j);
    return j->p < j->end ? *j->p : -1;
}

static int j_eat(jp *j, int c)
{
    if (j_peek(j) != c)
        return 0;
    j->p++;
    return 1;
}

/* Length of the valid UTF-8 sequence at p (first byte >= 0x80), 0 if invalid. */
static int utf8_length(const unsigned char *p, const unsigned char *end)
{
    unsigned c = p[0], cp, min;
    int n, i;
    if (c >= 0xC2 && c <= 0xDF) { n = 2; cp = c & 0x1F; min = 0x80; }
    else if (c >= 0xE0 && c <= 0xEF) { n = 3; cp = c & 0x0F; min = 0x800; }
    else if (c >= 0xF0 && c <= 0xF4) { n = 4; cp = c & 0x07; min = 0x10000; }
    else return 0;
    if (end - p < n)
        return 0;
    for (i = 1; i < n; i++) {
        if ((p[i] & 0xC0) != 0x80)
            return 0;
        cp = (cp << 6) | (p[i] & 0x3F);
    }
    if (cp < min || cp > 0x10FFFF || (cp >= 0xD800 && cp <= 0xDFFF))
        return 0;
    return n;
}

static int utf8_encode(unsigned cp, unsigned char *out)
{
    if (cp < 0x80) { out[0] = (unsigned char)cp; return 1; }
    if (cp < 0x800) { out[0] = (unsigned char)(0xC0 | (cp >> 6)); out[1] = (unsigned char)(0x80 | (cp & 0x3F)); return 2; }
    if (cp < 0x10000) {
        out[0] = (unsigned char)(0xE0 | (cp >> 12));
        out[1] = (unsigned char)(0x80 | ((cp >> 6) & 0x3F));
        out[2] = (unsigned char)(0x80 | (cp & 0x3F));
        return 3;
    }
    out[0] = (unsigned char)(0xF0 | (cp >> 18));
    out[1] = (unsigned char)(0x80 | ((cp >> 12) & 0x3F));
    out[2] = (unsigned char)(0x80 | ((cp >> 6) & 0x3F));
    out[3] = (unsigned char)(0x80 | (cp & 0x3F));
    return 4;
}

static int hex4(const unsigned char *p, unsigned *value)
{
    unsigned v = 0;
    int i;
    for (i = 0; i < 4; i++) {
        unsigned c = p[i], h;
        if (c >= '0' && c <= '9') h = c - '0';
        else if (c >= 'a' && c <= 'f') h = c - 'a' + 10;
        else if (c >= 'A' && c <= 'F') h = c - 'A' + 10;
        else return 0;
        v = (v << 4) | h;
    }
    *value = v;
    return 1;
}

/* One escape after the backslash at j->p; decoded UTF-8 into buf, its length into *n. */
static int j_escape(jp *j, unsigned char *buf, int *n)
{
    unsigned cp, low;
    if (j->end - j->p < 2)
        return 0;
    j->p += 2;
    switch (j->p[-1]) {
    case '"': cp = '"'; break;
    case '\\': cp = '\\'; break;
    case '/': cp = '/'; break;
    case 'b': cp = '\b'; break;
    case 'f': cp = '\f'; break;
    case 'n': cp = '\n'; break;
    case 'r': cp = '\r'; break;
    case 't': cp = '\t'; break;
    case 'u':
        if (j->end - j->p < 4 || !hex4(j->p, &cp))
            return 0;
        j->p += 4;
        if (cp >= 0xDC00 && cp <= 0xDFFF)
            return 0; /* a lone low surrogate */
        if (cp >= 0xD800 && cp <= 0xDBFF) {
            if (j->end - j->p < 6 || j->p[0] != '\\' || j->p[1] != 'u' || !hex4(j->p + 2, &low)
                || low < 0xDC00 || low > 0xDFFF)
                return 0;
            j->p += 6;
            cp = 0x10000 + ((cp - 0xD800) << 10) + (low - 0xDC00);
        }
        break;
    default: return 0;
    }
    *n = utf8_encode(cp, buf);
    return 1;
}

/*
 * A string: decoded bytes go to out[0 .. cap) when out is not NULL; *length gets the
 * full decoded length; *has_nul says whether it decoded a U+0000.
 */
static int j_string(jp *j, char *out, size_t cap, size_t *length, int *has_nul)
{
    size_t n = 0;
    int nul = 0;
    if (!j_eat(j, '"'))
        return 0;
    for (;;) {
        unsigned char buf[4];
        const unsigned char *src = buf;
        int count, i;
        unsigned c;
        if (j->p >= j->end)
            return 0;
        c = *j->p;
        if (c == '"') {
            j->p++;
            break;
        }
        if (c < 0x20)
            return 0;
        if (c == '\\') {
            if (!j_escape(j, buf, &count))
                return 0;
            nul |= count == 1 && buf[0] == 0;
        } else if (c < 0x80) {
            src = j->p;
            count = 1;
            j->p++;
        } else {
            count = utf8_length(j->p, j->end);
            if (count == 0)
                return 0;
            src = j->p;
            j->p += count;
        }
        for (i = 0; i < count; i++, n++)
            if (out != NULL && n < cap)
                out[n] = (char)src[i];
    }
    *length = n;
    if (has_nul != NULL)
        *has_nul = nul;
    return 1;
}

static int is_digit(int c) { return c >= '0' && c <= '9'; }

/* Scan a number token (RFC 8259 grammar); *integer says whether it has no fraction or exponent. */
static int j_number(jp *j, const unsigned char **start, size_t *length, int *integer)
{
    const unsigned char *p, *e = j->end;
    j_ws(j);
    p = *start = j->p;
    *integer = 1;
    if (p < e && *p == '-')
        p++;
    if (p < e && *p == '0')
        p++;
    else if (p < e && *p >= '1' && *p <= '9')
        while (p < e && is_digit(*p)) p++;
    else
        return 0;
    if (p < e && *p == '.') {
        *integer = 0;
        if (++p >= e || !is_digit(*p))
            return 0;
        while (p < e && is_digit(*p)) p++;
    }
    if (p < e && (*p == 'e' || *p == 'E')) {
        *integer = 0;
        if (++p < e && (*p == '+' || *p == '-'))
            p++;
        if (p >= e || !is_digit(*p))
            return 0;
        while (p < e && is_digit(*p)) p++;
    }
    *length = (size_t)(p - *start);
    j->p = p;
    return 1;
}

/* An integer token; rejects fractions, exponents and values beyond +-(2^63 - 1). */
static int j_int(jp *j, int64_t *value)
{
    const unsigned char *s;
    size_t n, i = 0;
    int integer, negative;
    uint64_t acc = 0;
    if (!j_number(j, &s, &n, &integer) || !integer)
        return 0;
    negative = s[0] == '-';
    for (i = (size_t)negative; i < n; i++) {
        unsigned digit = (unsigned)(s[i] - '0');
        if (acc > (UINT64_C(0x7FFFFFFFFFFFFFFF) - digit) / 10)
            return 0;
        acc = acc * 10 + digit;
    }
    *value = negative ? -(int64_t)acc : (int64_t)acc;
    return 1;
}

/* Any number token as a double, independent of the C locale's decimal point. */
static int j_double(jp *j, double *value)
{
    const unsigned char *s;
    size_t n, i;
    int integer;
    char buf[NUMBER_MAX + 1], *stop;
    const struct lconv *lc = localeconv();
    char point = (lc != NULL && lc->decimal_point != NULL && lc->decimal_point[0] != 0) ? lc->decimal_point[0] : '.';
    if (!j_number(j, &s, &n, &integer) || n > NUMBER_MAX)
        return 0;
    for (i = 0; i < n; i++)
        buf[i] = s[i] == '.' ? point : (char)s[i];
    buf[n] = 0;
    *value = strtod(buf, &stop);
    return stop == buf + n;
}

static int j_literal(jp *j, const char *word)
{
    size_t n = strlen(word);
    if ((size_t)(j->end - j->p) < n || memcmp(j->p, word, n) != 0)
        return 0;
    j->p += n;
    return 1;
}

static int j_open(jp *j, int c)
{
    if (!j_eat(j, c))
        return 0;
    return ++j->depth <= JSON_MAX_DEPTH;
}

/* Next key of an object opened with j_open: 1 = key read (and ':'), 0 = end ('}'), -1 = error. */
static int j_next_key(jp *j, int *first, char *key, size_t cap, size_t *length)
{
    if (j_eat(j, '}')) {
        j->depth--;
        return 0;
    }
    if (!*first && !j_eat(j, ','))
        return -1;
    *first = 0;
    if (j_peek(j) != '"' || !j_string(j, key, cap, length, NULL) || !j_eat(j, ':'))
        return -1;
    return 1;
}

/* Next element of an array opened with j_open: 1 = an element follows, 0 = end (']'), -1 = error. */
static int j_next_item(jp *j, int *first)
{
    if (j_eat(j, ']')) {
        j->depth--;
        return 0;
    }
    if (!*first && !j_eat(j, ','))
        return -1;
    *first = 0;
    return 1;
}

/* Validate and skip any value. */
static int j_skip(jp *j)
{
    int c = j_peek(j), first = 1, more;
    size_t n;
    char key[1];
    const unsigned char *s;
    int integer;
    if (c == '"')
        return j_string(j, NULL, 0, &n, NULL);
    if (c == '{') {
        if (!j_open(j, '{'))
            return 0;
        while ((more = j_next_key(j, &first, key, 0, &n)) == 1)
            if (!j_skip(j))
                return 0;
        return more == 0;
    }
    if (c == '[') {
        if (!j_open(j, '['))
            return 0;
        while ((more = j_next_item(j, &first)) == 1)
            if (!j_skip(j))
                return 0;
        return more == 0;
    }
    if (c == '-' || is_digit(c))
        return j_number(j, &s, &n, &integer);
    return j_literal(j, "true") || j_literal(j, "false") || j_literal(j, "null");
}

static int key_is(const char *key, size_t length, const char *name)
{
    return length == strlen(name) && memcmp(key, name, length) == 0;
}

/* ------------------------------------------------------------------ header */

enum { A_SITES, A_B, A_W, A_EDGES, A_AREAS, A_COUNT };
enum { DT_NONE, DT_F32, DT_I32, DT_OTHER };
static const char *const ARRAY_NAMES[A_COUNT] = {"sites", "B", "W", "edges", "edge_areas"};
static const int ARRAY_RANK[A_COUNT] = {2, 3, 3, 2, 1};
static const int ARRAY_DTYPE[A_COUNT] = {DT_F32, DT_F32, DT_F32, DT_I32, DT_F32};
static const char *const COUNT_NAMES[4] = {"sites", "modes", "fragments", "edges"};

enum {
    K_FORMAT = 1, K_VERSION = 2, K_DIM = 4, K_COUNTS = 8, K_NAMES = 16, K_TRANSFORM = 32, K_THRESHOLD = 64,
    K_RADIUS = 128, K_BUFFER = 256, K_ARRAYS = 512, K_URI = 1024, K_LENGTH = 2048, K_CRC = 4096
};

typedef struct array_entry {
    int present, dtype, rank, has_offset, has_length;
    int64_t shape[3], offset, length;
} array_entry;

typedef struct header {
    unsigned seen, counts_seen;
    int format_ok, shape_bad;
    int64_t version, dim, counts[4], byte_length, crc32;
    double transform[16], default_threshold, impact_radius;
    char uri[URI_MAX + 1];
    size_t uri_length;
    const unsigned char *names_at, *text_end; /* where the fragment_names array starts; end of the header */
    int64_t name_count, name_bytes;
    int name_bad; /* a name is not a string or holds U+0000 */
    array_entry arrays[A_COUNT];
} header;

/* fragment_names: count the strings and their decoded bytes (out == NULL) or decode them. */
static int parse_names(jp *j, header *h, char *out, int32_t *offsets)
{
    int first = 1, more;
    int64_t count = 0, bytes = 0;
    if (j_peek(j) != '[') {
        h->name_bad = 1;
        return j_skip(j);
    }
    if (!j_open(j, '['))
        return 0;
    while ((more = j_next_item(j, &first)) == 1) {
        size_t n;
        int nul = 0;
        if (j_peek(j) != '"') {
            if (!j_skip(j))
                return 0;
            h->name_bad = 1;
            continue;
        }
        if (!j_string(j, out != NULL ? out + bytes : NULL, out != NULL ? (size_t)(h->name_bytes - bytes) : 0, &n, &nul))
            return 0;
        h->name_bad |= nul;
        if (offsets != NULL)
            offsets[count] = (int32_t)bytes;
        bytes += (int64_t)n + 1;
        if (out != NULL)
            out[bytes - 1] = 0;
        count++;
    }
    h->name_count = count;
    h->name_bytes = bytes;
    return more == 0;
}

/*
 * Number-valued helpers: a number that is not an integer (or not a number) is
 * skipped and the key marked absent, so the caller reports "missing or malformed".
 */
static int read_int(jp *j, int64_t *value, unsigned *seen, unsigned bit)
{
    const unsigned char *save = j->p;
    if ((j_peek(j) == '-' || is_digit(j_peek(j))) && j_int(j, value)) {
        *seen |= bit;
        return 1;
    }
    j->p = save;
    return j_skip(j);
}

static int read_double(jp *j, double *value, unsigned *seen, unsigned bit)
{
    const unsigned char *save = j->p;
    if ((j_peek(j) == '-' || is_digit(j_peek(j))) && j_double(j, value)) {
        *seen |= bit;
        return 1;
    }
    j->p = save;
    return j_skip(j);
}

static int parse_array_entry(jp *j, array_entry *a)
{
    int first = 1, more;
    char key[16];
    size_t n;
    a->present = 1;
    a->dtype = DT_NONE;
    a->rank = -1;
    a->has_offset = a->has_length = 0;
    if (!j_open(j, '{'))
        return j_skip(j); /* not an object: reported as missing fields */
    while ((more = j_next_key(j, &first, key, sizeof key, &n)) == 1) {
        if (key_is(key, n, "dtype") && j_peek(j) == '"') {
            char name[16];
            size_t len;
            if (!j_string(j, name, sizeof name, &len, NULL))
                return 0;
            a->dtype = key_is(name, len, "float32") ? DT_F32 : key_is(name, len, "int32") ? DT_I32 : DT_OTHER;
        } else if (key_is(key, n, "shape") && j_peek(j) == '[') {
            int f = 1, m;
            a->rank = 0;
            if (!j_open(j, '['))
                return 0;
            while ((m = j_next_item(j, &f)) == 1) {
                int64_t v = -1; /* not an integer: an invalid size */
                unsigned ok = 0;
                if (!read_int(j, &v, &ok, 1))
                    return 0;
                if (a->rank < 3)
                    a->shape[a->rank] = ok ? v : -1;
                a->rank++;
            }
            if (m < 0)
                return 0;
        } else if (key_is(key, n, "byte_offset")) {
            unsigned ok = 0;
            if (!read_int(j, &a->offset, &ok, 1))
                return 0;
            a->has_offset = ok != 0;
        } else if (key_is(key, n, "byte_length")) {
            unsigned ok = 0;
            if (!read_int(j, &a->length, &ok, 1))
                return 0;
            a->has_length = ok != 0;
        } else if (!j_skip(j)) {
            return 0;
        }
    }
    return more == 0;
}

static int parse_object_of(jp *j, header *h, int which);

static int parse_top_key(jp *j, header *h, const char *key, size_t n)
{
    if (key_is(key, n, "format")) {
        char value[32];
        size_t len;
        if (j_peek(j) != '"')
            return j_skip(j);
        if (!j_string(j, value, sizeof value, &len, NULL))
            return 0;
        h->seen |= K_FORMAT;
        h->format_ok = key_is(value, len, "fracture-modes-runtime");
        return 1;
    }
    if (key_is(key, n, "version"))
        return read_int(j, &h->version, &h->seen, K_VERSION);
    if (key_is(key, n, "dim"))
        return read_int(j, &h->dim, &h->seen, K_DIM);
    if (key_is(key, n, "default_threshold"))
        return read_double(j, &h->default_threshold, &h->seen, K_THRESHOLD);
    if (key_is(key, n, "impact_radius"))
        return read_double(j, &h->impact_radius, &h->seen, K_RADIUS);
    if (key_is(key, n, "fragment_names")) {
        h->seen |= K_NAMES;
        h->names_at = j->p;
        h->name_bad = 0;
        return parse_names(j, h, NULL, NULL);
    }
    if (key_is(key, n, "transform")) {
        int first = 1, more, count = 0;
        unsigned ok = 0;
        if (j_peek(j) != '[')
            return j_skip(j);
        if (!j_open(j, '['))
            return 0;
        while ((more = j_next_item(j, &first)) == 1) {
            double v = 0;
            unsigned one = 0;
            if (!read_double(j, &v, &one, 1))
                return 0;
            if (count < 16)
                h->transform[count] = v;
            ok += one;
            count++;
        }
        if (more == 0 && count == 16 && ok == 16)
            h->seen |= K_TRANSFORM;
        return more == 0;
    }
    if (key_is(key, n, "counts"))
        return parse_object_of(j, h, 0);
    if (key_is(key, n, "buffer"))
        return parse_object_of(j, h, 1);
    if (key_is(key, n, "arrays"))
        return parse_object_of(j, h, 2);
    return j_skip(j);
}

/* The objects "counts" (which = 0), "buffer" (1) and "arrays" (2). */
static int parse_object_of(jp *j, header *h, int which)
{
    int first = 1, more, i;
    char key[32];
    size_t n;
    if (j_peek(j) != '{')
        return j_skip(j);
    if (!j_open(j, '{'))
        return 0;
    h->seen |= which == 0 ? K_COUNTS : which == 1 ? K_BUFFER : K_ARRAYS;
    while ((more = j_next_key(j, &first, key, sizeof key, &n)) == 1) {
        int handled = 0;
        for (i = 0; which == 0 && i < 4 && !handled; i++)
            if (key_is(key, n, COUNT_NAMES[i])) {
                unsigned bit = 0;
                handled = 1;
                if (!read_int(j, &h->counts[i], &bit, 1u << i))
                    return 0;
                h->counts_seen |= bit;
            }
        for (i = 0; which == 2 && i < A_COUNT && !handled; i++)
            if (key_is(key, n, ARRAY_NAMES[i])) {
                handled = 1;
                if (!parse_array_entry(j, &h->arrays[i]))
                    return 0;
            }
        if (which == 1 && key_is(key, n, "uri") && j_peek(j) == '"') {
            handled = 1;
            if (!j_string(j, h->uri, URI_MAX, &h->uri_length, NULL))
                return 0;
            h->seen |= K_URI;
        } else if (which == 1 && key_is(key, n, "byte_length")) {
            handled = 1;
            if (!read_int(j, &h->byte_length, &h->seen, K_LENGTH))
                return 0;
        } else if (which == 1 && key_is(key, n, "crc32")) {
            handled = 1;
            if (!read_int(j, &h->crc32, &h->seen, K_CRC))
                return 0;
        }
        if (!handled && !j_skip(j))
            return 0;
    }
    return more == 0;
}

static fr_status parse_header(const void *data, size_t size, header *h, char *msg, size_t cap)
{
    jp j;
    int first = 1, more;
    char key[32];
    size_t n;
    memset(h, 0, sizeof *h);
    if (data == NULL)
        return fail(msg, cap, FR_ERR_ARGUMENT, "no header data");
    j.p = (const unsigned char *)data;
    j.end = h->text_end = j.p + size;
    j.depth = 0;
    if (j_peek(&j) != '{' || !j_open(&j, '{'))
        return fail(msg, cap, FR_ERR_JSON, "header is not a JSON object");
    while ((more = j_next_key(&j, &first, key, sizeof key, &n)) == 1)
        if (!parse_top_key(&j, h, key, n))
            return fail(msg, cap, FR_ERR_JSON, "header is not valid JSON (near byte %ld)",
                        (long)(j.p - (const unsigned char *)data));
    j_ws(&j);
    if (more != 0 || j.p != j.end)
        return fail(msg, cap, FR_ERR_JSON, "header is not valid JSON (near byte %ld)",
                    (long)(j.p - (const unsigned char *)data));
    if (!(h->seen & K_FORMAT) || !h->format_ok)
        return fail(msg, cap, FR_ERR_FORMAT, "not a fracture runtime file (expected \"format\": \"fracture-modes-runtime\")");
    if (!(h->seen & K_VERSION) || h->version < 1 || h->version > FR_FORMAT_VERSION)
        return fail(msg, cap, FR_ERR_FORMAT, "runtime file version is not supported (this reader knows 1..%d)",
                    FR_FORMAT_VERSION);
    return FR_OK;
}

static int uri_ok(const header *h)
{
    size_t i;
    if (!(h->seen & K_URI) || h->uri_length == 0 || h->uri_length > URI_MAX)
        return 0;
    if (key_is(h->uri, h->uri_length, ".") || key_is(h->uri, h->uri_length, ".."))
        return 0;
    for (i = 0; i < h->uri_length; i++)
        if (h->uri[i] == '/' || h->uri[i] == '\\' || h->uri[i] == ':' || h->uri[i] == 0)
            return 0;
    return 1;
}

fr_status fr_header_uri(const void *data, size_t size, char *uri, size_t uri_size)
{
    header h;
    fr_status status;
    if (uri == NULL || uri_size == 0)
        return FR_ERR_ARGUMENT;
    uri[0] = 0;
    status = parse_header(data, size, &h, NULL, 0);
    if (status != FR_OK)
        return status;
    if (!uri_ok(&h))
        return FR_ERR_HEADER;
    if (h.uri_length >= uri_size)
        return FR_ERR_ARGUMENT;
    memcpy(uri, h.uri, h.uri_length);
    uri[h.uri_length] = 0;
    return FR_OK;
}

/* ------------------------------------------------------------------ validation */

typedef struct kd_node {
    double lo[3], hi[3];
    int32_t begin, end, left, right; /* a leaf when left < 0 */
} kd_node;

struct fr_runtime {
    fr_allocator allocator;
    int32_t s, k, p, e, d;
    double default_threshold, impact_radius, transform[16];
    float *sites, *B, *areas;
    double *Wd; /* (k, p, d) W in double */
    int32_t *edges;
    char *names;
    int32_t *name_offsets;
    double *kd_points; /* (s, 3) sites in tree order */
    int32_t *kd_index; /* site index of each tree-order point */
    kd_node *kd_nodes;
    int32_t *whole;    /* groups of the whole graph (no edge broken) */
    int32_t whole_groups;
    /* Spanning forest in DFS preorder ("positions"): a subtree is a range of positions. */
    int32_t *pos;         /* (p,) position of each fragment */
    int32_t *parent_pos;  /* (p,) by position: position of the parent (itself for a root) */
    uint8_t *root_head;   /* (p,) by position: 1 for a tree's root */
    int32_t *identity;    /* (p,) 0, 1, 2, ...: initial union-find parents */
    int32_t *tree_child;  /* (e,) position of the child a tree edge leads to, -1 for other edges */
    int32_t *order;       /* (e,) edges in test order: the num_tree spanning-tree edges first */
    int32_t *ends;        /* (e, 2) (P, Q) of each edge in test order */
    int32_t *child_at;    /* (num_tree,) tree_child of each tree edge in test order */
    double *edge_bound;   /* (e,) in test order: |W[:, P] - W[:, Q]| + slack * (|W[:, P]| + |W[:, Q]|) */
    int32_t num_tree;
    int32_t *end_pos;     /* (e, 2) positions of each edge's ends, in test order */
    void *scratch;        /* the built-in workspace */
};

typedef struct dims {
    int64_t s, k, p, e, d;
} dims;

static uint32_t read_u32(const unsigned char *p)
{
    return (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24;
}

static float read_f32(const unsigned char *p)
{
    uint32_t u = read_u32(p);
    float f;
    memcpy(&f, &u, sizeof f);
    return f;
}

static int32_t read_i32(const unsigned char *p)
{
    uint32_t u = read_u32(p);
    return u <= 0x7FFFFFFFu ? (int32_t)u : -(int32_t)(~u) - 1;
}

static uint32_t crc32_of(const unsigned char *data, size_t size)
{
    uint32_t table[256], crc = 0xFFFFFFFFu;
    size_t i;
    for (i = 0; i < 256; i++) {
        uint32_t c = (uint32_t)i;
        int b;
        for (b = 0; b < 8; b++)
            c = (c & 1u) ? 0xEDB88320u ^ (c >> 1) : c >> 1;
        table[i] = c;
    }
    for (i = 0; i < size; i++)
        crc = table[(crc ^ data[i]) & 0xFFu] ^ (crc >> 8);
    return crc ^ 0xFFFFFFFFu;
}

static const char *missing_key(const header *h)
{
    static const struct { unsigned bit; const char *name; } REQUIRED[] = {
        {K_DIM, "dim"}, {K_COUNTS, "counts"}, {K_NAMES, "fragment_names"}, {K_TRANSFORM, "transform (16 numbers)"},
        {K_THRESHOLD, "default_threshold"}, {K_RADIUS, "impact_radius"}, {K_BUFFER, "buffer"},
        {K_LENGTH, "buffer.byte_length"}, {K_ARRAYS, "arrays"}};
    size_t i;
    for (i = 0; i < sizeof REQUIRED / sizeof REQUIRED[0]; i++)
        if (!(h->seen & REQUIRED[i].bit))
            return REQUIRED[i].name;
    return NULL;
}

/* Each array entry: present, right dtype and rank, byte_length = 4 * product(shape), inside the file. */
static fr_status check_arrays(const header *h, size_t binary_size, char *msg, size_t cap)
{
    int i, r;
    for (i = 0; i < A_COUNT; i++) {
        const array_entry *a = &h->arrays[i];
        uint64_t count = 1;
        if (!a->present || a->dtype == DT_NONE || !a->has_offset || !a->has_length || a->rank < 0)
            return fail(msg, cap, FR_ERR_HEADER, "array '%s' entry is missing or malformed", ARRAY_NAMES[i]);
        if (a->dtype != ARRAY_DTYPE[i])
            return fail(msg, cap, FR_ERR_HEADER, "array '%s' has the wrong dtype", ARRAY_NAMES[i]);
        if (a->rank != ARRAY_RANK[i])
            return fail(msg, cap, FR_ERR_SIZE, "array '%s' has %d dimensions, expected %d", ARRAY_NAMES[i], a->rank,
                        ARRAY_RANK[i]);
        for (r = 0; r < a->rank; r++) {
            if (a->shape[r] < 0)
                return fail(msg, cap, FR_ERR_SIZE, "array '%s' has a negative or non-integer size", ARRAY_NAMES[i]);
            /* Saturate: a product beyond the file cannot match its byte_length anyway. */
            count = (a->shape[r] != 0 && count > (UINT64_C(1) << 40) / (uint64_t)a->shape[r])
                        ? (UINT64_C(1) << 40) + 1 : count * (uint64_t)a->shape[r];
        }
        if (a->length < 0 || count * 4 != (uint64_t)a->length)
            return fail(msg, cap, FR_ERR_SIZE, "array '%s': shape and byte_length do not agree", ARRAY_NAMES[i]);
        if (a->offset < 0 || a->offset % 16 != 0 || (uint64_t)a->offset > binary_size
            || (uint64_t)a->length > binary_size - (uint64_t)a->offset)
            return fail(msg, cap, FR_ERR_SIZE, "array '%s' lies outside the binary file or is not 16-byte aligned",
                        ARRAY_NAMES[i]);
    }
    return FR_OK;
}

/* Shapes against each other, `dim` and `counts`; fills *dm. */
static fr_status check_shapes(const header *h, dims *dm, char *msg, size_t cap)
{
    const int64_t *sites = h->arrays[A_SITES].shape, *B = h->arrays[A_B].shape, *W = h->arrays[A_W].shape;
    const int64_t *edges = h->arrays[A_EDGES].shape, *areas = h->arrays[A_AREAS].shape;
    int i;
    dm->s = sites[0];
    dm->k = W[0];
    dm->p = W[1];
    dm->d = W[2];
    dm->e = edges[0];
    if (dm->d != 1 && dm->d != 3)
        return fail(msg, cap, FR_ERR_SIZE, "W must have d = 1 or 3, got %ld", (long)dm->d);
    if (sites[1] != 3 || B[0] != dm->s || B[1] != dm->k || B[2] != dm->d || edges[1] != 2 || areas[0] != dm->e)
        return fail(msg, cap, FR_ERR_SIZE, "array shapes do not agree with each other");
    if (dm->s < 1 || dm->k < 1 || dm->p < 1)
        return fail(msg, cap, FR_ERR_SIZE, "need at least one site, mode and fragment");
    if (dm->s > INT32_MAX || dm->k > INT32_MAX || dm->p > INT32_MAX || dm->e > INT32_MAX)
        return fail(msg, cap, FR_ERR_SIZE, "counts beyond 2^31");
    if (h->dim != dm->d)
        return fail(msg, cap, FR_ERR_SIZE, "header says dim = %ld but W has d = %ld", (long)h->dim, (long)dm->d);
    if (h->counts_seen != 15u || h->counts[0] != dm->s || h->counts[1] != dm->k || h->counts[2] != dm->p
        || h->counts[3] != dm->e)
        return fail(msg, cap, FR_ERR_SIZE, "header counts do not match the arrays");
    if (h->name_bad || h->name_count != dm->p)
        return fail(msg, cap, FR_ERR_HEADER, "fragment_names must be %ld strings without U+0000", (long)dm->p);
    if (!isfinite(h->default_threshold) || h->default_threshold < 0)
        return fail(msg, cap, FR_ERR_HEADER, "default_threshold must be a finite number >= 0");
    for (i = 0; i < 16; i++)
        if (!isfinite(h->transform[i]))
            return fail(msg, cap, FR_ERR_HEADER, "transform must be 16 finite numbers");
    if (!isfinite(h->impact_radius))
        return fail(msg, cap, FR_ERR_HEADER, "impact_radius must be finite");
    return FR_OK;
}

/* Finite floats and edges with 0 <= P < Q < p, read straight from the binary. */
static fr_status check_data(const header *h, const unsigned char *bin, const dims *dm, char *msg, size_t cap)
{
    static const int FLOAT_ARRAYS[4] = {A_SITES, A_B, A_W, A_AREAS};
    int a;
    int64_t i;
    for (a = 0; a < 4; a++) {
        const array_entry *entry = &h->arrays[FLOAT_ARRAYS[a]];
        const unsigned char *p = bin + entry->offset;
        for (i = 0; i < entry->length / 4; i++)
            if ((read_u32(p + 4 * i) & 0x7F800000u) == 0x7F800000u)
                return fail(msg, cap, FR_ERR_DATA, "array '%s' has non-finite values", ARRAY_NAMES[FLOAT_ARRAYS[a]]);
    }
    for (i = 0; i < dm->e; i++) {
        const unsigned char *p = bin + h->arrays[A_EDGES].offset + 8 * i;
        int32_t P = read_i32(p), Q = read_i32(p + 4);
        if (P < 0 || P >= Q || Q >= dm->p)
            return fail(msg, cap, FR_ERR_DATA, "edge %ld is (%ld, %ld): edges must be (P, Q) with 0 <= P < Q < %ld",
                        (long)i, (long)P, (long)Q, (long)dm->p);
    }
    return FR_OK;
}

static fr_status check_header(const header *h, const void *binary, size_t binary_size, unsigned flags, dims *dm,
                              char *msg, size_t cap)
{
    const char *missing = missing_key(h);
    fr_status status;
    if (missing != NULL)
        return fail(msg, cap, FR_ERR_HEADER, "runtime header is missing or has a malformed entry: %s", missing);
    if (!uri_ok(h))
        return fail(msg, cap, FR_ERR_HEADER, "buffer.uri must be a plain file name next to the header");
    if (h->byte_length < 0 || (uint64_t)h->byte_length != binary_size)
        return fail(msg, cap, FR_ERR_SIZE, "binary file has %lu bytes but the header says %ld (truncated or from "
                    "another bake)", (unsigned long)binary_size, (long)h->byte_length);
    if ((h->seen & K_CRC) && (h->crc32 < 0 || h->crc32 > 0xFFFFFFFFll))
        return fail(msg, cap, FR_ERR_HEADER, "buffer.crc32 must be a 32-bit unsigned integer");
    if ((h->seen & K_CRC) && !(flags & FR_LOAD_SKIP_CRC)
        && crc32_of((const unsigned char *)binary, binary_size) != (uint32_t)h->crc32)
        return fail(msg, cap, FR_ERR_CRC, "binary file does not match its header (crc32 differs; from another bake?)");
    status = check_arrays(h, binary_size, msg, cap);
    if (status == FR_OK)
        status = check_shapes(h, dm, msg, cap);
    if (status == FR_OK)
        status = check_data(h, (const unsigned char *)binary, dm, msg, cap);
    return status;
}

/* ------------------------------------------------------------------ load */

static void *default_alloc(void *user, size_t size)
{
    (void)user;
    return malloc(size);
}

static void default_free(void *user, void *ptr)
{
    (void)user;
    free(ptr);
}

/* Bump allocation inside one block: each piece 16-byte aligned. Sizes in 64 bits to catch overflow. */
static uint64_t take(uint64_t *cursor, uint64_t bytes)
{
    uint64_t at = (*cursor + 15u) & ~(uint64_t)15u;
    *cursor = at + bytes;
    return at;
}

typedef struct workspace_layout {
    uint64_t alpha, disp, head, broken, piece, uf, first, size;
} workspace_layout;

static workspace_layout workspace_plan(int64_t k, int64_t p, int64_t e, int64_t d)
{
    workspace_layout w;
    uint64_t cursor = 0;
    w.alpha = take(&cursor, 8u * (uint64_t)k);
    w.disp = take(&cursor, 8u * (uint64_t)p * (uint64_t)d);
    w.head = take(&cursor, (uint64_t)p);
    w.broken = take(&cursor, (uint64_t)e);
    w.piece = take(&cursor, 4u * (uint64_t)p);
    w.uf = take(&cursor, 4u * (uint64_t)p);
    w.first = take(&cursor, 4u * (uint64_t)p);
    w.size = take(&cursor, 0);
    return w;
}

/* Offsets of every array in the runtime's block (after the struct itself). */
typedef struct block_layout {
    uint64_t sites, B, W, areas, edges, edge_bound, names, name_offsets, kd_points, kd_index, kd_nodes, whole;
    uint64_t pos, parent_pos, root_head, identity, tree_child, order, ends, end_pos, child_at, scratch, size;
    uint64_t kd_capacity;
} block_layout;

static block_layout block_plan(const dims *dm, int64_t name_bytes)
{
    block_layout b;
    uint64_t s = (uint64_t)dm->s, k = (uint64_t)dm->k, p = (uint64_t)dm->p, e = (uint64_t)dm->e, d = (uint64_t)dm->d;
    uint64_t cursor = sizeof(struct fr_runtime);
    b.kd_capacity = s / 2 + 2;
    b.sites = take(&cursor, 12u * s);
    b.B = take(&cursor, 4u * s * k * d);
    b.W = take(&cursor, 8u * k * p * d);
    b.areas = take(&cursor, 4u * e);
    b.edges = take(&cursor, 8u * e);
    b.edge_bound = take(&cursor, 8u * e);
    b.names = take(&cursor, (uint64_t)name_bytes);
    b.name_offsets = take(&cursor, 4u * p);
    b.kd_points = take(&cursor, 24u * s);
    b.kd_index = take(&cursor, 4u * s);
    b.kd_nodes = take(&cursor, sizeof(kd_node) * b.kd_capacity);
    b.whole = take(&cursor, 4u * p);
    b.pos = take(&cursor, 4u * p);
    b.parent_pos = take(&cursor, 4u * p);
    b.root_head = take(&cursor, p);
    b.identity = take(&cursor, 4u * p);
    b.tree_child = take(&cursor, 4u * e);
    b.order = take(&cursor, 4u * e);
    b.ends = take(&cursor, 8u * e);
    b.child_at = take(&cursor, 4u * e);
    b.end_pos = take(&cursor, 8u * e);
    b.scratch = take(&cursor, workspace_plan(dm->k, dm->p, dm->e, dm->d).size);
    b.size = take(&cursor, 0);
    return b;
}

static void copy_arrays(fr_runtime *rt, const header *h, const unsigned char *bin)
{
    float *floats[3];
    static const int FLOAT_ARRAYS[3] = {A_SITES, A_B, A_AREAS};
    int a;
    int64_t i;
    floats[0] = rt->sites;
    floats[1] = rt->B;
    floats[2] = rt->areas;
    for (a = 0; a < 3; a++) {
        const array_entry *entry = &h->arrays[FLOAT_ARRAYS[a]];
        for (i = 0; i < entry->length / 4; i++)
            floats[a][i] = read_f32(bin + entry->offset + 4 * i);
    }
    for (i = 0; i < h->arrays[A_W].length / 4; i++)
        rt->Wd[i] = read_f32(bin + h->arrays[A_W].offset + 4 * i);
    for (i = 0; i < 2 * (int64_t)rt->e; i++)
        rt->edges[i] = read_i32(bin + h->arrays[A_EDGES].offset + 4 * i);
}

/*
 * Per edge, a constant c with |jump'| <= |alpha'| * c for the computed jump (Cauchy-Schwarz
 * on W[:, P] - W[:, Q], plus the rounding of both displacements), so fr_project can skip
 * the edges that surely hold without computing any displacement.
 */
static void edge_bounds(fr_runtime *rt)
{
    int32_t m, i, c, k = rt->k, p = rt->p, d = rt->d;
    for (m = 0; m < rt->e; m++) {
        int32_t P = rt->ends[2 * m], Q = rt->ends[2 * m + 1];
        double diff2 = 0, wp2 = 0, wq2 = 0;
        for (i = 0; i < k; i++)
            for (c = 0; c < d; c++) {
                double wp = rt->Wd[((size_t)i * p + P) * d + c], wq = rt->Wd[((size_t)i * p + Q) * d + c];
                diff2 += (wp - wq) * (wp - wq); /* float32 - float32 is exact in double */
                wp2 += wp * wp;
                wq2 += wq * wq;
            }
        rt->edge_bound[m] = (sqrt(diff2) + BOUND_SLACK * (sqrt(wp2) + sqrt(wq2))) * (1.0 + BOUND_SLACK);
    }
}

/* Reorder idx[0..n) so that idx[nth] has the nth smallest coordinate on `axis` (quickselect). */
static void kd_select(int32_t *idx, int32_t n, int32_t nth, const float *sites, int axis)
{
    int32_t lo = 0, hi = n - 1;
    while (hi > lo) {
        float pivot = sites[3 * idx[lo + (hi - lo) / 2] + axis];
        int32_t i = lo, j = hi;
        while (i <= j) {
            while (sites[3 * idx[i] + axis] < pivot) i++;
            while (sites[3 * idx[j] + axis] > pivot) j--;
            if (i <= j) {
                int32_t t = idx[i];
                idx[i++] = idx[j];
                idx[j--] = t;
            }
        }
        if (nth <= j) hi = j;
        else if (nth >= i) lo = i;
        else break;
    }
}

/* Build the subtree over kd_index[begin, end); any split is correct (pruning uses exact boxes). */
static int32_t kd_build(fr_runtime *rt, int32_t begin, int32_t end, int32_t *count)
{
    int32_t id = (*count)++, i, mid;
    int c, axis = 0;
    kd_node *node = &rt->kd_nodes[id];
    for (c = 0; c < 3; c++) {
        node->lo[c] = node->hi[c] = rt->sites[3 * rt->kd_index[begin] + c];
        for (i = begin + 1; i < end; i++) {
            double v = rt->sites[3 * rt->kd_index[i] + c];
            node->lo[c] = v < node->lo[c] ? v : node->lo[c];
            node->hi[c] = v > node->hi[c] ? v : node->hi[c];
        }
        if (node->hi[c] - node->lo[c] > node->hi[axis] - node->lo[axis])
            axis = c;
    }
    node->begin = begin;
    node->end = end;
    node->left = node->right = -1;
    if (end - begin <= KD_LEAF)
        return id;
    mid = begin + (end - begin) / 2;
    kd_select(rt->kd_index + begin, end - begin, mid - begin, rt->sites, axis);
    node->left = kd_build(rt, begin, mid, count);
    rt->kd_nodes[id].right = kd_build(rt, mid, end, count);
    return id;
}

static void build_kd_tree(fr_runtime *rt)
{
    int32_t i, count = 0;
    int c;
    for (i = 0; i < rt->s; i++)
        rt->kd_index[i] = i;
    kd_build(rt, 0, rt->s, &count);
    for (i = 0; i < rt->s; i++)
        for (c = 0; c < 3; c++)
            rt->kd_points[3 * i + c] = rt->sites[3 * rt->kd_index[i] + c];
}

static int32_t uf_find(int32_t *parent, int32_t a)
{
    while (parent[a] != a) {
        parent[a] = parent[parent[a]]; /* path halving */
        a = parent[a];
    }
    return a;
}

/* Hook the larger root under the smaller, so every root is its component's smallest member. */
static void uf_union(int32_t *parent, int32_t a, int32_t b)
{
    a = uf_find(parent, a);
    b = uf_find(parent, b);
    if (a < b) parent[b] = a;
    else if (b < a) parent[a] = b;
}

/*
 * Spanning forest (breadth-first, so subtrees stay small) numbered in depth-first
 * preorder, so each subtree is a contiguous range of positions. `temp` holds
 * 7p + 2 + 4e ints for the adjacency, the queue and the tree's child lists.
 */
static void build_forest(fr_runtime *rt, int32_t *temp)
{
    int32_t p = rt->p, e = rt->e, *start = temp, *adj = start + p + 1, *queue = adj + 4 * e;
    int32_t *child_start = queue + p, *children = child_start + p + 1, *next = children + p, *stack = next + p;
    int32_t *parent = stack + p, m, v, head, tail, counter = 0;
    memset(start, 0, sizeof(int32_t) * ((size_t)p + 1));
    memset(child_start, 0, sizeof(int32_t) * ((size_t)p + 1));
    for (m = 0; m < e; m++) {
        start[rt->edges[2 * m] + 1]++;
        start[rt->edges[2 * m + 1] + 1]++;
        rt->tree_child[m] = -1;
    }
    for (v = 0; v < p; v++) {
        start[v + 1] += start[v];
        next[v] = start[v];
        parent[v] = -2; /* unvisited */
    }
    for (m = 0; m < e; m++) {
        int32_t P = rt->edges[2 * m], Q = rt->edges[2 * m + 1];
        adj[2 * next[P]] = Q;
        adj[2 * next[P]++ + 1] = m;
        adj[2 * next[Q]] = P;
        adj[2 * next[Q]++ + 1] = m;
    }
    for (v = 0; v < p; v++) { /* breadth-first trees; parent[w] = the edge to w's parent, -1 for a root */
        if (parent[v] != -2)
            continue;
        parent[v] = -1;
        queue[0] = v;
        for (head = 0, tail = 1; head < tail; head++) {
            int32_t u = queue[head], a;
            for (a = start[u]; a < start[u + 1]; a++)
                if (parent[adj[2 * a]] == -2) {
                    parent[adj[2 * a]] = adj[2 * a + 1];
                    queue[tail++] = adj[2 * a];
                    child_start[u + 1]++;
                }
        }
    }
    for (v = 0; v < p; v++) {
        child_start[v + 1] += child_start[v];
        next[v] = child_start[v];
    }
    for (v = 0; v < p; v++)
        if (parent[v] >= 0) {
            int32_t up = rt->edges[2 * parent[v]] == v ? rt->edges[2 * parent[v] + 1] : rt->edges[2 * parent[v]];
            children[next[up]++] = v;
        }
    for (v = 0; v < p; v++) { /* preorder numbering of each tree */
        int32_t top = 1;
        if (parent[v] != -1)
            continue;
        stack[0] = v;
        while (top > 0) {
            int32_t u = stack[--top], c;
            rt->pos[u] = counter;
            rt->root_head[counter] = parent[u] < 0;
            rt->parent_pos[counter] = counter;
            if (parent[u] >= 0) {
                int32_t P = rt->edges[2 * parent[u]], Q = rt->edges[2 * parent[u] + 1];
                rt->tree_child[parent[u]] = counter;
                rt->parent_pos[counter] = rt->pos[P == u ? Q : P]; /* numbered before u */
            }
            rt->identity[counter] = counter;
            counter++;
            for (c = child_start[u + 1] - 1; c >= child_start[u]; c--)
                stack[top++] = children[c];
        }
    }
    rt->num_tree = 0; /* test order: tree edges first */
    for (m = 0; m < e; m++)
        if (rt->tree_child[m] >= 0) {
            rt->child_at[rt->num_tree] = rt->tree_child[m];
            rt->order[rt->num_tree++] = m;
        }
    for (m = 0, v = rt->num_tree; m < e; m++)
        if (rt->tree_child[m] < 0)
            rt->order[v++] = m;
    for (m = 0; m < e; m++) {
        rt->ends[2 * m] = rt->edges[2 * rt->order[m]];
        rt->ends[2 * m + 1] = rt->edges[2 * rt->order[m] + 1];
        rt->end_pos[2 * m] = rt->pos[rt->ends[2 * m]];
        rt->end_pos[2 * m + 1] = rt->pos[rt->ends[2 * m + 1]];
    }
    for (v = 0; v < p; v++)
        rt->whole[v] = v;
    for (m = 0; m < e; m++)
        uf_union(rt->whole, rt->edges[2 * m], rt->edges[2 * m + 1]);
    rt->whole_groups = 0;
    for (v = 0; v < p; v++) {
        rt->whole[v] = uf_find(rt->whole, v);
        rt->whole_groups += rt->whole[v] == v;
    }
}

static void decode_names(fr_runtime *rt, header *h, int64_t name_bytes)
{
    jp j;
    j.p = h->names_at;
    j.end = h->text_end;
    j.depth = 0;
    h->name_bytes = name_bytes;
    (void)parse_names(&j, h, rt->names, rt->name_offsets);
}

fr_status fr_load(const void *header_data, size_t header_size, const void *binary, size_t binary_size,
                  unsigned flags, const fr_allocator *allocator, fr_runtime **out, char *message, size_t message_size)
{
    header h;
    dims dm = {0, 0, 0, 0, 0};
    block_layout b;
    fr_allocator al;
    fr_status status;
    unsigned char *block;
    int32_t *temp;
    fr_runtime *rt;
    if (message != NULL && message_size > 0)
        message[0] = 0;
    if (out == NULL || (binary == NULL && binary_size > 0) || header_data == NULL)
        return fail(message, message_size, FR_ERR_ARGUMENT, "fr_load: NULL argument");
    *out = NULL;
    status = parse_header(header_data, header_size, &h, message, message_size);
    if (status == FR_OK)
        status = check_header(&h, binary, binary_size, flags, &dm, message, message_size);
    if (status != FR_OK)
        return status;
    al.alloc = allocator != NULL && allocator->alloc != NULL ? allocator->alloc : default_alloc;
    al.free = allocator != NULL && allocator->free != NULL ? allocator->free : default_free;
    al.user = allocator != NULL ? allocator->user : NULL;
    b = block_plan(&dm, h.name_bytes);
    if (b.size > (uint64_t)(SIZE_MAX / 2) || (block = (unsigned char *)al.alloc(al.user, (size_t)b.size)) == NULL)
        return fail(message, message_size, FR_ERR_MEMORY, "out of memory (%lu bytes)", (unsigned long)b.size);
    temp = (int32_t *)al.alloc(al.user, sizeof(int32_t) * (7 * (size_t)dm.p + 2 + 4 * (size_t)dm.e));
    if (temp == NULL) {
        al.free(al.user, block);
        return fail(message, message_size, FR_ERR_MEMORY, "out of memory");
    }
    rt = (fr_runtime *)block;
    memset(rt, 0, sizeof *rt);
    rt->allocator = al;
    rt->s = (int32_t)dm.s, rt->k = (int32_t)dm.k, rt->p = (int32_t)dm.p, rt->e = (int32_t)dm.e, rt->d = (int32_t)dm.d;
    rt->default_threshold = h.default_threshold;
    rt->impact_radius = h.impact_radius;
    memcpy(rt->transform, h.transform, sizeof rt->transform);
    rt->sites = (float *)(block + b.sites);
    rt->B = (float *)(block + b.B);
    rt->Wd = (double *)(block + b.W);
    rt->areas = (float *)(block + b.areas);
    rt->edges = (int32_t *)(block + b.edges);
    rt->edge_bound = (double *)(block + b.edge_bound);
    rt->names = (char *)(block + b.names);
    rt->name_offsets = (int32_t *)(block + b.name_offsets);
    rt->kd_points = (double *)(block + b.kd_points);
    rt->kd_index = (int32_t *)(block + b.kd_index);
    rt->kd_nodes = (kd_node *)(block + b.kd_nodes);
    rt->whole = (int32_t *)(block + b.whole);
    rt->pos = (int32_t *)(block + b.pos);
    rt->parent_pos = (int32_t *)(block + b.parent_pos);
    rt->root_head = block + b.root_head;
    rt->identity = (int32_t *)(block + b.identity);
    rt->tree_child = (int32_t *)(block + b.tree_child);
    rt->order = (int32_t *)(block + b.order);
    rt->ends = (int32_t *)(block + b.ends);
    rt->child_at = (int32_t *)(block + b.child_at);
    rt->end_pos = (int32_t *)(block + b.end_pos);
    rt->scratch = block + b.scratch;
    copy_arrays(rt, &h, (const unsigned char *)binary);
    decode_names(rt, &h, h.name_bytes);
    build_kd_tree(rt);
    build_forest(rt, temp);
    edge_bounds(rt);
    al.free(al.user, temp);
    *out = rt;
    return FR_OK;
}

void fr_free(fr_runtime *rt)
{
    if (rt != NULL)
        rt->allocator.free(rt->allocator.user, rt);
}

fr_info fr_get_info(const fr_runtime *rt)
{
    fr_info info;
    memset(&info, 0, sizeof info);
    if (rt == NULL)
        return info;
    info.sites = rt->s;
    info.modes = rt->k;
    info.fragments = rt->p;
    info.edges = rt->e;
    info.dim = rt->d;
    info.default_threshold = rt->default_threshold;
    info.impact_radius = rt->impact_radius;
    memcpy(info.transform, rt->transform, sizeof info.transform);
    return info;
}

const char *fr_fragment_name(const fr_runtime *rt, int32_t fragment)
{
    if (rt == NULL || fragment < 0 || fragment >= rt->p)
        return NULL;
    return rt->names + rt->name_offsets[fragment];
}

const int32_t *fr_edges(const fr_runtime *rt) { return rt != NULL ? rt->edges : NULL; }
const float *fr_edge_areas(const fr_runtime *rt) { return rt != NULL ? rt->areas : NULL; }
const float *fr_sites(const fr_runtime *rt) { return rt != NULL ? rt->sites : NULL; }

/* ------------------------------------------------------------------ projection */

size_t fr_workspace_size(const fr_runtime *rt)
{
    return rt != NULL ? (size_t)workspace_plan(rt->k, rt->p, rt->e, rt->d).size : 0;
}

/* Squared distance from (x, y, z) to a box, computed like a site's so it never exceeds one inside. */
static double box_distance2(const kd_node *node, double x, double y, double z)
{
    double dx = x < node->lo[0] ? node->lo[0] - x : x > node->hi[0] ? x - node->hi[0] : 0.0;
    double dy = y < node->lo[1] ? node->lo[1] - y : y > node->hi[1] ? y - node->hi[1] : 0.0;
    double dz = z < node->lo[2] ? node->lo[2] - z : z > node->hi[2] ? z - node->hi[2] : 0.0;
    return dx * dx + dy * dy + dz * dz;
}

/* Section 4 step 1 with a k-d tree: a box is skipped only when strictly farther than the best, so ties keep the smallest index. */
static int32_t kd_nearest(const fr_runtime *rt, double x, double y, double z)
{
    int32_t stack[KD_STACK], best_index = INT32_MAX, top = 1;
    double bounds[KD_STACK], best = INFINITY;
    stack[0] = 0;
    bounds[0] = box_distance2(&rt->kd_nodes[0], x, y, z);
    while (top > 0) {
        const kd_node *node;
        top--;
        if (bounds[top] > best)
            continue;
        node = &rt->kd_nodes[stack[top]];
        if (node->left < 0) {
            int32_t i;
            for (i = node->begin; i < node->end; i++) {
                const double *q = rt->kd_points + 3 * (size_t)i;
                double dx = q[0] - x, dy = q[1] - y, dz = q[2] - z;
                double d2 = dx * dx + dy * dy + dz * dz;
                if (d2 < best || (d2 == best && rt->kd_index[i] < best_index)) {
                    best = d2;
                    best_index = rt->kd_index[i];
                }
            }
        } else {
            double a = box_distance2(&rt->kd_nodes[node->left], x, y, z);
            double b = box_distance2(&rt->kd_nodes[node->right], x, y, z);
            int32_t near = a <= b ? node->left : node->right, far = a <= b ? node->right : node->left;
            stack[top] = far; /* pushed first: the nearer box is searched first */
            bounds[top++] = a <= b ? b : a;
            stack[top] = near;
            bounds[top++] = a <= b ? a : b;
        }
    }
    return best_index;
}

int32_t fr_nearest_site(const fr_runtime *rt, const double point[3])
{
    if (rt == NULL || point == NULL || !isfinite(point[0]) || !isfinite(point[1]) || !isfinite(point[2]))
        return -1;
    return kd_nearest(rt, point[0], point[1], point[2]);
}

/* Steps 2-3: alpha' of the impulse scaled by m = max |n_c| (m > 0). */
static void mode_coefficients(const fr_runtime *rt, int32_t site, const double n[3], double *alpha)
{
    int32_t i, k = rt->k;
    const float *B = rt->B + (size_t)site * (size_t)k * (size_t)rt->d;
    if (rt->d == 1) {
        double length = sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
        for (i = 0; i < k; i++)
            alpha[i] = (double)B[i] * length;
    } else {
        for (i = 0; i < k; i++)
            alpha[i] = (double)B[3 * i] * n[0] + (double)B[3 * i + 1] * n[1] + (double)B[3 * i + 2] * n[2];
    }
}

/*
 * Step 4: disp'[j, c] = sum over i of alpha'[i] W[i, j, c], each sum in mode order.
 * Eight outputs at a time keep eight independent sums in registers (no dependency
 * chain, and compilers vectorize it), with W stored in double.
 */
static void displacements(const fr_runtime *rt, const double *alpha, double *disp)
{
    size_t n = (size_t)rt->p * (size_t)rt->d, k = (size_t)rt->k, i, j = 0, c;
    const double *W = rt->Wd;
    for (; j + 8 <= n; j += 8) {
        double s0 = 0, s1 = 0, s2 = 0, s3 = 0, s4 = 0, s5 = 0, s6 = 0, s7 = 0;
        for (i = 0; i < k; i++) {
            const double a = alpha[i], *w = W + i * n + j;
            s0 += a * w[0];
            s1 += a * w[1];
            s2 += a * w[2];
            s3 += a * w[3];
            s4 += a * w[4];
            s5 += a * w[5];
            s6 += a * w[6];
            s7 += a * w[7];
        }
        disp[j] = s0, disp[j + 1] = s1, disp[j + 2] = s2, disp[j + 3] = s3;
        disp[j + 4] = s4, disp[j + 5] = s5, disp[j + 6] = s6, disp[j + 7] = s7;
    }
    for (c = j; c < n; c++) {
        double sum = 0;
        for (i = 0; i < k; i++)
            sum += alpha[i] * W[i * n + c];
        disp[c] = sum;
    }
}

/* |jump'| of the edge (P, Q): |disp'[P] - disp'[Q]| (d = 1) or its Euclidean norm (d = 3). */
static double jump_norm(const double *disp, int32_t d, int32_t P, int32_t Q)
{
    if (d == 1)
        return fabs(disp[P] - disp[Q]);
    else {
        const double *a = disp + 3 * (size_t)P, *b = disp + 3 * (size_t)Q;
        double j0 = a[0] - b[0], j1 = a[1] - b[1], j2 = a[2] - b[2];
        return sqrt(j0 * j0 + j1 * j1 + j2 * j2);
    }
}

/* Whether some edge might break: |jump'| <= |alpha'| * edge_bound[m] for every edge (see edge_bounds). */
static int any_edge_may_break(const fr_runtime *rt, const double *alpha, double t)
{
    int32_t i, m;
    double norm2 = 0.0, norm;
    for (i = 0; i < rt->k; i++)
        norm2 += alpha[i] * alpha[i];
    norm = sqrt(norm2) * (1.0 + BOUND_SLACK);
    for (m = 0; m < rt->e; m++)
        if (!(norm * rt->edge_bound[m] <= t))
            return 1;
    return 0;
}

/* Pointers into the caller's (or the built-in) workspace. */
typedef struct scratch {
    double *alpha, *disp;
    uint8_t *head, *broken;
    int32_t *piece, *uf, *first;
} scratch;

static int32_t uf_root(int32_t *uf, int32_t a)
{
    while (uf[a] != a)
        a = uf[a] = uf[uf[a]]; /* path halving */
    return a;
}

/*
 * Steps 5 and 6 once the displacements are known. Edges are tested in the order
 * of build_forest: spanning-tree edges first. A broken tree edge makes its child
 * the head of a subtree; since a parent precedes its children in preorder, one
 * forward pass labels every position with its subtree's head. Unbroken non-tree
 * edges then join subtrees (union-find on heads), and the group of a fragment is
 * the first fragment met in its component in increasing order. Branch-free where
 * a shattering hit makes the branches unpredictable. Returns the number of groups.
 */
static int32_t break_and_group(const fr_runtime *rt, double t, const scratch *w, int32_t *groups,
                               int32_t *num_broken)
{
    /* Everything in locals: stores through uint8_t may alias anything, so fields would be reloaded. */
    const int32_t e = rt->e, p = rt->p, d = rt->d, num_tree = rt->num_tree, *ends = rt->ends, *order = rt->order;
    const int32_t *child = rt->child_at, *parent_pos = rt->parent_pos, *end_pos = rt->end_pos, *pos = rt->pos;
    const double *disp = w->disp;
    uint8_t *broken = w->broken, *head = w->head;
    int32_t *piece = w->piece, *uf = w->uf, *first = w->first, r, j, v, count = 0, groups_count = 0;
    memcpy(head, rt->root_head, (size_t)p);
    for (r = 0; r < num_tree; r++) {
        const int cut = jump_norm(disp, d, ends[2 * r], ends[2 * r + 1]) > t;
        broken[order[r]] = (uint8_t)cut;
        head[child[r]] = (uint8_t)cut;
        count += cut;
    }
    for (j = 0; j < p; j++)
        piece[j] = head[j] ? j : piece[parent_pos[j]];
    memcpy(uf, rt->identity, sizeof(int32_t) * (size_t)p);
    for (; r < e; r++) {
        const int cut = jump_norm(disp, d, ends[2 * r], ends[2 * r + 1]) > t;
        broken[order[r]] = (uint8_t)cut;
        count += cut;
        if (!cut) {
            int32_t a = uf_root(uf, piece[end_pos[2 * r]]), b = uf_root(uf, piece[end_pos[2 * r + 1]]);
            uf[a > b ? a : b] = a > b ? b : a;
        }
    }
    memset(first, 0xFF, sizeof(int32_t) * (size_t)p); /* -1 */
    for (v = 0; v < p; v++) {
        const int32_t c = uf_root(uf, piece[pos[v]]);
        if (first[c] < 0) {
            first[c] = v;
            groups_count++;
        }
        groups[v] = first[c];
    }
    *num_broken = count;
    return groups_count;
}

fr_status fr_project(const fr_runtime *rt, const double point[3], const double impulse[3], double threshold,
                     void *workspace, fr_impact *out)
{
    workspace_layout layout;
    unsigned char *base;
    scratch w;
    double n[3], m = 0.0;
    int32_t i, c, breaks = 0;
    if (rt == NULL || point == NULL || impulse == NULL || out == NULL || out->groups == NULL)
        return FR_ERR_ARGUMENT;
    for (c = 0; c < 3; c++) {
        if (!isfinite(point[c]) || !isfinite(impulse[c]))
            return FR_ERR_INPUT;
        m = fabs(impulse[c]) > m ? fabs(impulse[c]) : m;
    }
    if (isnan(threshold) || threshold < 0)
        return FR_ERR_INPUT;
    layout = workspace_plan(rt->k, rt->p, rt->e, rt->d);
    base = workspace != NULL ? (unsigned char *)workspace : (unsigned char *)rt->scratch;
    w.alpha = (double *)(base + layout.alpha);
    w.disp = (double *)(base + layout.disp);
    w.head = base + layout.head;
    w.broken = out->broken != NULL ? out->broken : base + layout.broken;
    w.piece = (int32_t *)(base + layout.piece);
    w.uf = (int32_t *)(base + layout.uf);
    w.first = (int32_t *)(base + layout.first);
    out->site = kd_nearest(rt, point[0], point[1], point[2]);
    if (m == 0.0) { /* step 2: a zero impulse breaks nothing */
        memset(w.alpha, 0, sizeof(double) * (size_t)rt->k);
    } else {
        for (c = 0; c < 3; c++)
            n[c] = impulse[c] / m;
        mode_coefficients(rt, out->site, n, w.alpha);
        breaks = any_edge_may_break(rt, w.alpha, threshold / m);
    }
    if (breaks || out->displacement != NULL)
        displacements(rt, w.alpha, w.disp);
    if (breaks) {
        out->num_groups = break_and_group(rt, threshold / m, &w, out->groups, &out->num_broken);
    } else { /* nothing breaks: the components of the whole graph */
        if (rt->e > 0)
            memset(w.broken, 0, (size_t)rt->e);
        memcpy(out->groups, rt->whole, sizeof(int32_t) * (size_t)rt->p);
        out->num_groups = rt->whole_groups;
        out->num_broken = 0;
    }
    if (out->displacement != NULL)
        for (i = 0; i < rt->p * rt->d; i++)
            out->displacement[i] = m * w.disp[i];
    if (out->alpha != NULL)
        for (i = 0; i < rt->k; i++)
            out->alpha[i] = m * w.alpha[i];
    return FR_OK;
}
