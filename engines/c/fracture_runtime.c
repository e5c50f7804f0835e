/*
 * fracture_runtime.c - reader of the `fracture` impact-projection file (C99, libc only).
 * See fracture_runtime.h for the API and docs/FORMAT.md for the format and algorithm.
 *
 * MIT licence, Copyright (c) fracture developers.
 *
 * Layout of this file: JSON (a small validating parser for the header), header
 * (the keys of docs/FORMAT.md section 1), load (validation, one allocation, the
 * k-d tree, the whole graph's groups and the d = 1 jump table), project (section 4,
 * no allocation).
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
#define KD_LEAF 16
#define KD_STACK 96
#define BOUND_SLACK 1e-9 /* far above the rounding of a k-term sum in double for any k << 1e6 */
#if defined(__cplusplus) || (defined(_MSC_VER) && !defined(__STDC_VERSION__))
#define restrict __restrict /* the source also compiles as C++, and as C by MSVC before /std:c11 */
#endif
#if defined(__GNUC__) || defined(__clang__)
#define NOINLINE __attribute__((noinline))
#elif defined(_MSC_VER)
#define NOINLINE __declspec(noinline)
#else
#define NOINLINE
#endif
#ifndef FR_TABLE_MAX_BYTES
#define FR_TABLE_MAX_BYTES (16u << 20) /* largest d = 1 jump table fr_load builds (see wants_table) */
#endif

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
    case FR_ERR_STATE: return "invalid damage state (not e healths in [0, 1])";
    case FR_ERR_FRAGMENT: return "the struck fragment is not shown (split, or inside an unbroken parent)";
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

/*
 * The five arrays of section 2, the four of the stress criterion (section 11, only with feature "stress"),
 * then those of section 12: anchored (feature "anchors") and the optional crack arrays (version 2).
 */
enum {
    A_SITES, A_B, A_W, A_EDGES, A_AREAS, A_PTR, A_BONDS, A_GAIN, A_STRENGTH, A_ANCHORED, A_CRACK_PTR, A_CRACK_SEGMENTS,
    /* Section 14 (feature "levels"): every body's data, concatenated; then its stress and crack arrays. */
    A_PARENT, A_BODY_FRAGMENT, A_BODY_CHILD_PTR, A_BODY_SITE_PTR, A_BODY_SITES, A_BODY_B, A_BODY_W, A_BODY_EDGE_PTR,
    A_BODY_EDGES, A_BODY_AREAS, A_BODY_PTR, A_BODY_BONDS, A_BODY_GAIN, A_BODY_STRENGTH, A_BODY_CRACK_PTR,
    A_BODY_CRACK_SEGMENTS, A_COUNT
};
#define A_REQUIRED 5
enum { DT_NONE, DT_F32, DT_I32, DT_OTHER };
static const char *const ARRAY_NAMES[A_COUNT] = {"sites", "B", "W", "edges", "edge_areas", "site_bonds_ptr",
                                                 "site_bonds", "site_bond_gain", "bond_strength", "anchored",
                                                 "crack_ptr", "crack_segments", "parent", "body_fragment",
                                                 "body_child_ptr", "body_site_ptr", "body_sites", "body_B", "body_W",
                                                 "body_edge_ptr", "body_edges", "body_edge_areas",
                                                 "body_site_bonds_ptr", "body_site_bonds", "body_site_bond_gain",
                                                 "body_bond_strength", "body_crack_ptr", "body_crack_segments"};
static const int ARRAY_RANK[A_COUNT] = {2, 3, 3, 2, 1, 1, 1, 2, 1, 1, 1, 3, 1, 1, 1, 1, 2, 3, 3, 1, 2, 1, 1, 1, 2, 1, 1, 3};
static const int ARRAY_DTYPE[A_COUNT] = {DT_F32, DT_F32, DT_F32, DT_I32, DT_F32, DT_I32, DT_I32, DT_F32, DT_F32,
                                         DT_I32, DT_I32, DT_F32, DT_I32, DT_I32, DT_I32, DT_I32, DT_F32, DT_F32,
                                         DT_F32, DT_I32, DT_I32, DT_F32, DT_I32, DT_I32, DT_F32, DT_F32, DT_I32,
                                         DT_F32};
/* counts.site_bonds (index 4) only with the stress criterion, counts.crack_segments (5) with the crack arrays;
 * 6.. with feature "levels" (section 14.1) */
#define COUNT_KEYS 13
enum { C_BODIES = 6, C_ALL_FRAGMENTS, C_BODY_SITES, C_BODY_MODES, C_BODY_EDGES, C_BODY_SITE_BONDS,
       C_BODY_CRACK_SEGMENTS };
static const char *const COUNT_NAMES[COUNT_KEYS] = {"sites", "modes", "fragments", "edges", "site_bonds",
                                                    "crack_segments", "bodies", "all_fragments", "body_sites",
                                                    "body_modes", "body_edges", "body_site_bonds",
                                                    "body_crack_segments"};
#define NAME_MAX_SHOWN 64 /* bytes of an unknown feature or criterion name kept for the message */
enum { CRIT_MODES, CRIT_STRESS, CRIT_OTHER };

enum {
    K_FORMAT = 1, K_VERSION = 2, K_DIM = 4, K_COUNTS = 8, K_NAMES = 16, K_TRANSFORM = 32, K_THRESHOLD = 64,
    K_RADIUS = 128, K_BUFFER = 256, K_ARRAYS = 512, K_URI = 1024, K_LENGTH = 2048, K_CRC = 4096,
    K_FEATURES = 8192, K_CRITERION = 16384, K_DAMAGE = 32768, K_CHILD_NAMES = 65536, K_LEVELS = 131072
};

typedef struct array_entry {
    int present, dtype, rank, has_offset, has_length;
    int64_t shape[3], offset, length;
} array_entry;

typedef struct header {
    unsigned seen, counts_seen;
    int format_ok, shape_bad;
    int64_t version, dim, counts[COUNT_KEYS], byte_length, crc32;
    double transform[16], default_threshold, impact_radius;
    char uri[URI_MAX + 1];
    size_t uri_length;
    const unsigned char *names_at, *text_end; /* where the fragment_names array starts; end of the header */
    int64_t name_count, name_bytes;
    int name_bad; /* a name is not a string or holds U+0000 */
    array_entry arrays[A_COUNT];
    /* Version 2 (section 11): features and criterion. */
    int features_bad;     /* `features` is not a list of strings */
    int feature_count, has_stress, has_anchors, has_damage;
    int has_cracks;       /* version 2 and the table lists crack_ptr or crack_segments (set by check_arrays) */
    int feature_unknown;  /* a feature this reader does not implement; its name in unknown_name */
    char unknown_name[NAME_MAX_SHOWN + 1];
    int criterion;        /* CRIT_*; CRIT_MODES when absent */
    int criterion_bad;    /* `criterion` is not a string */
    char criterion_name[NAME_MAX_SHOWN + 1];
    /* Section 12: the `damage` object (K_DAMAGE when seen). */
    int damage_bad;       /* `damage` is not an object */
    unsigned damage_keys; /* 1: crack_level is a number, 2: damage_rate is a number */
    double crack_level, damage_rate;
    /* Section 14: feature "levels". */
    int has_levels, has_body_cracks, is_view; /* is_view: a body's view made by this reader (version 2, no features) */
    const unsigned char *child_names_at, *levels_at; /* the child_names array and the levels object, re-read later */
    int64_t child_name_count;
    int child_name_bad;
} header;

/* A name read by j_string into a buffer of NAME_MAX_SHOWN bytes: NUL-terminated, truncated if longer. */
static void terminate_name(char *buf, size_t length)
{
    buf[length < NAME_MAX_SHOWN ? length : NAME_MAX_SHOWN] = 0;
}

/* "features": a list of strings; records the ones this reader implements and the first name it does not know. */
static int parse_features(jp *j, header *h)
{
    int first = 1, more;
    h->seen |= K_FEATURES;
    if (j_peek(j) != '[') {
        h->features_bad = 1;
        return j_skip(j);
    }
    if (!j_open(j, '['))
        return 0;
    while ((more = j_next_item(j, &first)) == 1) {
        char name[NAME_MAX_SHOWN + 1];
        size_t n;
        int nul = 0;
        if (j_peek(j) != '"') {
            h->features_bad = 1;
            if (!j_skip(j))
                return 0;
            continue;
        }
        if (!j_string(j, name, NAME_MAX_SHOWN, &n, &nul))
            return 0;
        terminate_name(name, n);
        h->feature_count++;
        if (!nul && key_is(name, n, "stress")) {
            h->has_stress = 1;
        } else if (!nul && key_is(name, n, "anchors")) {
            h->has_anchors = 1;
        } else if (!nul && key_is(name, n, "damage")) {
            h->has_damage = 1;
        } else if (!nul && key_is(name, n, "levels")) {
            h->has_levels = 1;
        } else if (!h->feature_unknown) {
            h->feature_unknown = 1;
            memcpy(h->unknown_name, name, sizeof name);
        }
    }
    return more == 0;
}

/* "criterion": "modes" or "stress"; anything else is kept by name for the message. */
static int parse_criterion(jp *j, header *h)
{
    size_t n;
    int nul = 0;
    h->seen |= K_CRITERION;
    if (j_peek(j) != '"') {
        h->criterion_bad = 1;
        return j_skip(j);
    }
    if (!j_string(j, h->criterion_name, NAME_MAX_SHOWN, &n, &nul))
        return 0;
    terminate_name(h->criterion_name, n);
    h->criterion_bad = 0;
    h->criterion = nul ? CRIT_OTHER : key_is(h->criterion_name, n, "modes") ? CRIT_MODES
                 : key_is(h->criterion_name, n, "stress") ? CRIT_STRESS : CRIT_OTHER;
    return 1;
}

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

/* "damage" (section 12.1): an object with the numbers crack_level and damage_rate; checked by check_damage. */
static int parse_damage(jp *j, header *h)
{
    int first = 1, more;
    char key[16];
    size_t n;
    h->seen |= K_DAMAGE;
    h->damage_bad = 0;
    h->damage_keys = 0;
    if (j_peek(j) != '{') {
        h->damage_bad = 1;
        return j_skip(j);
    }
    if (!j_open(j, '{'))
        return 0;
    while ((more = j_next_key(j, &first, key, sizeof key, &n)) == 1) {
        int ok = 1;
        if (key_is(key, n, "crack_level"))
            ok = read_double(j, &h->crack_level, &h->damage_keys, 1);
        else if (key_is(key, n, "damage_rate"))
            ok = read_double(j, &h->damage_rate, &h->damage_keys, 2);
        else
            ok = j_skip(j);
        if (!ok)
            return 0;
    }
    return more == 0;
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
    if (key_is(key, n, "features")) {
        /* duplicate keys: the last wins */
        h->features_bad = h->feature_count = h->has_stress = h->has_anchors = h->has_damage = h->feature_unknown = 0;
        h->has_levels = 0;
        return parse_features(j, h);
    }
    if (key_is(key, n, "damage"))
        return parse_damage(j, h);
    if (key_is(key, n, "child_names")) { /* counted here, copied into each body's view (section 14.3) */
        header names;
        memset(&names, 0, sizeof names);
        h->seen |= K_CHILD_NAMES;
        h->child_names_at = j->p;
        if (!parse_names(j, &names, NULL, NULL))
            return 0;
        h->child_name_count = names.name_count;
        h->child_name_bad = names.name_bad;
        return 1;
    }
    if (key_is(key, n, "levels")) { /* read by load_levels */
        h->seen |= K_LEVELS;
        h->levels_at = j->p;
        return j_skip(j);
    }
    if (key_is(key, n, "criterion"))
        return parse_criterion(j, h);
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
        for (i = 0; which == 0 && i < COUNT_KEYS && !handled; i++)
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

/*
 * Section 11: version 2 lists the features it needs (refused by name when unknown) and a criterion.
 * Version 1 ignores both keys (they were unknown keys then). Like the reference reader, a file that
 * lists "stress" must use criterion "stress": the stress arrays come with the criterion.
 */
static fr_status check_features(header *h, char *msg, size_t cap)
{
    if (h->version < 2) {
        h->has_stress = h->has_anchors = h->has_damage = h->has_levels = 0;
        h->criterion = CRIT_MODES;
        return FR_OK;
    }
    if (h->features_bad)
        return fail(msg, cap, FR_ERR_HEADER, "runtime header 'features' must be a list of strings");
    if (h->feature_count == 0 && !h->is_view)
        return fail(msg, cap, FR_ERR_FORMAT, "runtime file version %d lists no features; a file without any is "
                    "version 1", (int)h->version);
    if (h->feature_unknown)
        return fail(msg, cap, FR_ERR_FORMAT, "runtime file needs feature '%s', which this reader does not implement",
                    h->unknown_name);
    if (h->criterion_bad)
        return fail(msg, cap, FR_ERR_HEADER, "runtime header 'criterion' must be a string");
    if (h->criterion == CRIT_OTHER)
        return fail(msg, cap, FR_ERR_FORMAT, "runtime file needs criterion '%s', which this reader does not "
                    "implement", h->criterion_name);
    if (h->criterion == CRIT_STRESS && !h->has_stress)
        return fail(msg, cap, FR_ERR_FORMAT, "runtime file has criterion 'stress' but does not list feature 'stress'");
    if (h->criterion != CRIT_STRESS && h->has_stress)
        return fail(msg, cap, FR_ERR_FORMAT, "runtime file lists feature 'stress' but its criterion is 'modes' (the "
                    "stress arrays come with criterion 'stress')");
    return FR_OK;
}

static fr_status parse_header(const void *data, size_t size, header *h, int is_view, char *msg, size_t cap)
{
    jp j;
    int first = 1, more;
    char key[32];
    size_t n;
    memset(h, 0, sizeof *h);
    h->is_view = is_view;
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
    return check_features(h, msg, cap);
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
    status = parse_header(data, size, &h, 0, NULL, 0);
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
    int32_t *edges;    /* (e, 2) as in the file */
    char *names;
    int32_t *name_offsets;
    double *kd_points; /* (s, 3) sites in tree order */
    int32_t *kd_index; /* site index of each tree-order point */
    kd_node *kd_nodes;
    int32_t *whole;    /* groups of the whole graph (no edge broken) */
    int32_t whole_groups;
    int32_t *identity; /* (p,) 0, 1, 2, ...: initial union-find parents */
    int32_t row;       /* p * d rounded up to a multiple of 16 */
    double *Wd;        /* (k, row) W in double, zero padding */
    double max_bound;  /* largest per-edge bound (see edge_bounds) */
    double *jumps;     /* (s, e) d = 1 jump table, each row ascending (see build_jump_table); NULL if not built */
    uint16_t *jump_edge; /* (s, e) the edge of each entry of `jumps` */
    /* Per site, the merges of Kruskal's algorithm over its row (see build_merges), p entries each: */
    uint16_t *merge_at;     /* (s, p) position in the row of each merge's edge (ascending) */
    uint16_t *merge_child;  /* (s, p, 2) the two clusters each merge joins: fragment j, or p + earlier merge */
    int32_t *merge_label;   /* (s, p) smallest fragment of each merge's cluster */
    int32_t merges;         /* merges per site: p minus the whole graph's number of groups */
    /* Criterion "stress" (section 11; NULL and 0 otherwise): site v's bonds are entries bond_ptr[v] .. bond_ptr[v+1]-1. */
    int32_t criterion;      /* FR_CRITERION_MODES or FR_CRITERION_STRESS */
    int32_t nnz;            /* entries of site_bonds */
    int32_t *bond_ptr;      /* (s + 1,) */
    int32_t *bond_edge;     /* (nnz,) edge of each entry */
    float *bond_gain;       /* (nnz, 3) G: tensile force per unit impulse along x, y, z */
    float *bond_strength;   /* (e,) S */
    /* Section 12. */
    int32_t features;       /* FR_FEATURE_* */
    int32_t *anchored;      /* (p,) 0/1; NULL without feature "anchors" */
    double crack_level;     /* c; 1 without feature "damage" (a state then only remembers broken bonds) */
    double damage_rate;     /* r; 0 without feature "damage" */
    double damage_q;        /* q = r / (1 - c), once per file (0 when c == 1) */
    int32_t segments;       /* crack segments n; 0 without the crack arrays */
    int32_t *crack_ptr;     /* (e + 1,) bond m's segments are crack_ptr[m] .. crack_ptr[m+1]-1; NULL without */
    float *crack_segments;  /* (n, 2, 3) */
    size_t bytes;      /* size of the block */
    void *scratch;     /* the built-in workspace */
    struct fr_levels *levels; /* section 14: the bodies (NULL without feature "levels"; see fracture_levels part) */
};

typedef struct dims {
    int64_t s, k, p, e, d;
    int64_t nnz;  /* site_bonds entries; 0 without the stress criterion */
    int stress;   /* criterion "stress" */
    int anchors;  /* feature "anchors": the anchored array */
    int cracks;   /* the crack arrays */
    int64_t segments; /* crack_segments entries; 0 without the crack arrays */
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

/* Whether the file must hold array i: the required five and those of the features it lists. */
static int array_needed(const header *h, int i)
{
    if (i < A_REQUIRED)
        return 1;
    if (i <= A_STRENGTH)
        return h->has_stress;
    if (i == A_ANCHORED)
        return h->has_anchors;
    if (i <= A_CRACK_SEGMENTS)
        return h->has_cracks;
    if (i <= A_BODY_AREAS)
        return h->has_levels;
    if (i <= A_BODY_STRENGTH)
        return h->has_levels && h->has_stress;
    return h->has_body_cracks;
}

/*
 * Each array entry the file needs: present, right dtype and rank, byte_length = 4 * product(shape), inside
 * the file. The crack arrays (drawing only) come together: a version-2 table that lists one needs both.
 */
static fr_status check_arrays(header *h, size_t binary_size, char *msg, size_t cap)
{
    int i, r;
    h->has_cracks = h->version >= 2 && (h->arrays[A_CRACK_PTR].present || h->arrays[A_CRACK_SEGMENTS].present);
    if (h->has_cracks && !(h->arrays[A_CRACK_PTR].present && h->arrays[A_CRACK_SEGMENTS].present))
        return fail(msg, cap, FR_ERR_HEADER, "the crack arrays come together: %s missing",
                    h->arrays[A_CRACK_PTR].present ? "crack_segments" : "crack_ptr");
    h->has_body_cracks = h->has_levels
                         && (h->arrays[A_BODY_CRACK_PTR].present || h->arrays[A_BODY_CRACK_SEGMENTS].present);
    for (i = 0; i < A_COUNT; i++) {
        const array_entry *a = &h->arrays[i];
        uint64_t count = 1;
        if (!array_needed(h, i))
            continue;
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

/* Section 12.1: with feature "damage", the object `damage` with 0 < crack_level <= 1 and a finite damage_rate >= 0. */
static fr_status check_damage(const header *h, char *msg, size_t cap)
{
    if (!h->has_damage)
        return FR_OK;
    if (!(h->seen & K_DAMAGE) || h->damage_bad)
        return fail(msg, cap, FR_ERR_HEADER, "the feature 'damage' needs a header object 'damage'");
    if (!(h->damage_keys & 1u) || !isfinite(h->crack_level))
        return fail(msg, cap, FR_ERR_HEADER, "damage.crack_level must be a finite number");
    if (!(h->damage_keys & 2u) || !isfinite(h->damage_rate))
        return fail(msg, cap, FR_ERR_HEADER, "damage.damage_rate must be a finite number");
    if (!(h->crack_level > 0 && h->crack_level <= 1))
        return fail(msg, cap, FR_ERR_HEADER, "damage.crack_level must be in (0, 1], got %g", h->crack_level);
    if (h->damage_rate < 0)
        return fail(msg, cap, FR_ERR_HEADER, "damage.damage_rate must be >= 0, got %g", h->damage_rate);
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
    if ((h->counts_seen & 15u) != 15u || h->counts[0] != dm->s || h->counts[1] != dm->k || h->counts[2] != dm->p
        || h->counts[3] != dm->e)
        return fail(msg, cap, FR_ERR_SIZE, "header counts do not match the arrays");
    dm->stress = h->has_stress;
    dm->nnz = 0;
    if (dm->stress) {
        const int64_t *ptr = h->arrays[A_PTR].shape, *bonds = h->arrays[A_BONDS].shape;
        const int64_t *gain = h->arrays[A_GAIN].shape, *strength = h->arrays[A_STRENGTH].shape;
        dm->nnz = bonds[0];
        if (dm->nnz > INT32_MAX)
            return fail(msg, cap, FR_ERR_SIZE, "counts beyond 2^31");
        if (ptr[0] != dm->s + 1 || gain[0] != dm->nnz || gain[1] != 3 || strength[0] != dm->e)
            return fail(msg, cap, FR_ERR_SIZE, "stress arrays must be site_bonds_ptr (s + 1), site_bonds (nnz), "
                        "site_bond_gain (nnz, 3) and bond_strength (e)");
        if (!(h->counts_seen & 16u) || h->counts[4] != dm->nnz)
            return fail(msg, cap, FR_ERR_SIZE, "header counts.site_bonds does not match the arrays");
    }
    dm->anchors = h->has_anchors;
    if (dm->anchors && h->arrays[A_ANCHORED].shape[0] != dm->p)
        return fail(msg, cap, FR_ERR_SIZE, "array anchored has shape [%ld], expected [%ld]",
                    (long)h->arrays[A_ANCHORED].shape[0], (long)dm->p);
    dm->cracks = h->has_cracks;
    dm->segments = 0;
    if (dm->cracks) {
        const int64_t *ptr = h->arrays[A_CRACK_PTR].shape, *segments = h->arrays[A_CRACK_SEGMENTS].shape;
        dm->segments = segments[0];
        if (dm->segments > INT32_MAX)
            return fail(msg, cap, FR_ERR_SIZE, "counts beyond 2^31");
        if (ptr[0] != dm->e + 1 || segments[1] != 2 || segments[2] != 3)
            return fail(msg, cap, FR_ERR_SIZE, "crack arrays must be crack_ptr (e + 1) and crack_segments (n, 2, 3)");
        if (!(h->counts_seen & 32u) || h->counts[5] != dm->segments)
            return fail(msg, cap, FR_ERR_SIZE, "header counts.crack_segments does not match the arrays");
    }
    if (h->name_bad || h->name_count != dm->p)
        return fail(msg, cap, FR_ERR_HEADER, "fragment_names must be %ld strings without U+0000", (long)dm->p);
    if (!isfinite(h->default_threshold) || h->default_threshold < 0)
        return fail(msg, cap, FR_ERR_HEADER, "default_threshold must be a finite number >= 0");
    for (i = 0; i < 16; i++)
        if (!isfinite(h->transform[i]))
            return fail(msg, cap, FR_ERR_HEADER, "transform must be 16 finite numbers");
    if (!isfinite(h->impact_radius))
        return fail(msg, cap, FR_ERR_HEADER, "impact_radius must be finite");
    return check_damage(h, msg, cap);
}

/*
 * Section 11's validation of the stress arrays, read straight from the binary: site_bonds_ptr starts at
 * 0, never decreases and ends at nnz; site_bonds are edge indices, strictly ascending within a site;
 * site_bond_gain and bond_strength finite, bond_strength >= 0.
 */
static fr_status check_stress_data(const header *h, const unsigned char *bin, const dims *dm, char *msg, size_t cap)
{
    const unsigned char *ptr = bin + h->arrays[A_PTR].offset, *bonds = bin + h->arrays[A_BONDS].offset;
    const unsigned char *gain = bin + h->arrays[A_GAIN].offset, *strength = bin + h->arrays[A_STRENGTH].offset;
    int64_t v, i;
    if (read_i32(ptr) != 0 || read_i32(ptr + 4 * dm->s) != dm->nnz)
        return fail(msg, cap, FR_ERR_DATA, "site_bonds_ptr must start at 0, never decrease and end at %ld",
                    (long)dm->nnz);
    for (v = 0; v < dm->s; v++)
        if (read_i32(ptr + 4 * (v + 1)) < read_i32(ptr + 4 * v))
            return fail(msg, cap, FR_ERR_DATA, "site_bonds_ptr must start at 0, never decrease and end at %ld",
                        (long)dm->nnz);
    for (v = 0; v < dm->s; v++) {
        const int32_t lo = read_i32(ptr + 4 * v), hi = read_i32(ptr + 4 * (v + 1));
        for (i = lo; i < hi; i++) { /* 0 <= lo <= hi <= nnz: the pointers never decrease from 0 to nnz */
            const int32_t edge = read_i32(bonds + 4 * i);
            if (edge < 0 || edge >= dm->e)
                return fail(msg, cap, FR_ERR_DATA, "site_bonds must be bond indices in 0..%ld", (long)dm->e - 1);
            if (i > lo && edge <= read_i32(bonds + 4 * (i - 1)))
                return fail(msg, cap, FR_ERR_DATA, "site_bonds must be strictly ascending within each site");
        }
    }
    for (i = 0; i < 3 * dm->nnz; i++)
        if ((read_u32(gain + 4 * i) & 0x7F800000u) == 0x7F800000u)
            return fail(msg, cap, FR_ERR_DATA, "arrays site_bond_gain and bond_strength must be finite");
    for (i = 0; i < dm->e; i++) {
        const float value = read_f32(strength + 4 * i);
        if ((read_u32(strength + 4 * i) & 0x7F800000u) == 0x7F800000u)
            return fail(msg, cap, FR_ERR_DATA, "arrays site_bond_gain and bond_strength must be finite");
        if (value < 0)
            return fail(msg, cap, FR_ERR_DATA, "bond_strength must be >= 0");
    }
    return FR_OK;
}

/*
 * Section 12.2's validation, read straight from the binary: anchored holds only 0 and 1; crack_ptr starts
 * at 0, never decreases and ends at n; every crack_segments coordinate is finite.
 */
static fr_status check_structure_data(const header *h, const unsigned char *bin, const dims *dm, char *msg,
                                      size_t cap)
{
    int64_t i;
    if (dm->anchors)
        for (i = 0; i < dm->p; i++) {
            const int32_t flag = read_i32(bin + h->arrays[A_ANCHORED].offset + 4 * i);
            if (flag != 0 && flag != 1)
                return fail(msg, cap, FR_ERR_DATA, "array anchored must hold only 0 and 1");
        }
    if (dm->cracks) {
        const unsigned char *ptr = bin + h->arrays[A_CRACK_PTR].offset;
        const unsigned char *segments = bin + h->arrays[A_CRACK_SEGMENTS].offset;
        int bad = read_i32(ptr) != 0 || read_i32(ptr + 4 * dm->e) != dm->segments;
        for (i = 0; i < dm->e && !bad; i++)
            bad = read_i32(ptr + 4 * (i + 1)) < read_i32(ptr + 4 * i);
        if (bad)
            return fail(msg, cap, FR_ERR_DATA, "crack_ptr must start at 0, never decrease and end at %ld",
                        (long)dm->segments);
        for (i = 0; i < 6 * dm->segments; i++)
            if ((read_u32(segments + 4 * i) & 0x7F800000u) == 0x7F800000u)
                return fail(msg, cap, FR_ERR_DATA, "array crack_segments must be finite");
    }
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
    if (dm->stress) {
        fr_status status = check_stress_data(h, bin, dm, msg, cap);
        if (status != FR_OK)
            return status;
    }
    return check_structure_data(h, bin, dm, msg, cap);
}

static fr_status check_header(header *h, const void *binary, size_t binary_size, unsigned flags, dims *dm,
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
    uint64_t alpha, disp, cut, uf, health, holding, size;
} workspace_layout;

static int64_t round_up(int64_t n, int64_t multiple) { return (n + multiple - 1) / multiple * multiple; }

static workspace_layout workspace_plan(int64_t k, int64_t p, int64_t e, int64_t d)
{
    workspace_layout w;
    uint64_t cursor = 0;
    w.alpha = take(&cursor, 8u * (uint64_t)k);
    w.disp = take(&cursor, 8u * (uint64_t)round_up(p * d, 16));
    w.cut = take(&cursor, (uint64_t)e);
    w.uf = take(&cursor, 8u * (uint64_t)p); /* union-find parents, or table_groups' 2p labels */
    w.health = take(&cursor, 8u * (uint64_t)e); /* fr_project's fresh damage state */
    w.holding = take(&cursor, 4u * (uint64_t)e); /* fr_hit: the bonds that hold */
    w.size = take(&cursor, 0);
    return w;
}

/*
 * Whether fr_load builds the d = 1 jump table: (10 e + 10 p) bytes per site, at most
 * FR_TABLE_MAX_BYTES in all (compile with -DFR_TABLE_MAX_BYTES=... to change the limit).
 */
static int wants_table(const dims *dm, unsigned flags)
{
    return !dm->stress && dm->d == 1 && dm->e > 0 && dm->e <= 65535 && dm->p <= 32767 && (flags & FR_LOAD_COMPACT) == 0 &&
           (uint64_t)(10 * dm->e + 10 * dm->p) <= (uint64_t)FR_TABLE_MAX_BYTES / (uint64_t)dm->s;
}

/* Offsets of every array in the runtime's block (after the struct itself). */
typedef struct block_layout {
    uint64_t sites, B, W, areas, edges, names, name_offsets, kd_points, kd_index, kd_nodes, whole, identity;
    uint64_t jumps, jump_edge, merge_at, merge_child, merge_label, bond_ptr, bond_edge, bond_gain, bond_strength;
    uint64_t anchored, crack_ptr, crack_segments, scratch, size, kd_capacity;
} block_layout;

static block_layout block_plan(const dims *dm, int64_t name_bytes, int table)
{
    block_layout b;
    uint64_t s = (uint64_t)dm->s, k = (uint64_t)dm->k, p = (uint64_t)dm->p, e = (uint64_t)dm->e, d = (uint64_t)dm->d;
    uint64_t cursor = sizeof(struct fr_runtime);
    b.kd_capacity = 4u * s / KD_LEAF + 2; /* a leaf holds at least KD_LEAF / 2 sites */
    b.sites = take(&cursor, 12u * s);
    b.B = take(&cursor, 4u * s * k * d);
    b.W = take(&cursor, 8u * k * (uint64_t)round_up(dm->p * dm->d, 16));
    b.areas = take(&cursor, 4u * e);
    b.edges = take(&cursor, 8u * e);
    b.names = take(&cursor, (uint64_t)name_bytes);
    b.name_offsets = take(&cursor, 4u * p);
    b.kd_points = take(&cursor, 24u * s);
    b.kd_index = take(&cursor, 4u * s);
    b.kd_nodes = take(&cursor, sizeof(kd_node) * b.kd_capacity);
    b.whole = take(&cursor, 4u * p);
    b.identity = take(&cursor, 4u * p);
    b.jumps = take(&cursor, table ? 8u * s * e : 0u);
    b.jump_edge = take(&cursor, table ? 2u * s * e : 0u);
    b.merge_at = take(&cursor, table ? 2u * s * p : 0u);
    b.merge_child = take(&cursor, table ? 4u * s * p : 0u);
    b.merge_label = take(&cursor, table ? 4u * s * p : 0u);
    b.bond_ptr = take(&cursor, dm->stress ? 4u * (s + 1) : 0u);
    b.bond_edge = take(&cursor, 4u * (uint64_t)dm->nnz);
    b.bond_gain = take(&cursor, 12u * (uint64_t)dm->nnz);
    b.bond_strength = take(&cursor, dm->stress ? 4u * e : 0u);
    b.anchored = take(&cursor, dm->anchors ? 4u * p : 0u);
    b.crack_ptr = take(&cursor, dm->cracks ? 4u * (e + 1) : 0u);
    b.crack_segments = take(&cursor, 24u * (uint64_t)dm->segments);
    b.scratch = take(&cursor, workspace_plan(dm->k, dm->p, dm->e, dm->d).size);
    b.size = take(&cursor, 0);
    return b;
}

static void copy_arrays(fr_runtime *rt, const header *h, const unsigned char *bin)
{
    float *floats[3];
    static const int FLOAT_ARRAYS[3] = {A_SITES, A_B, A_AREAS};
    int a;
    int64_t i, j, n = (int64_t)rt->p * rt->d;
    floats[0] = rt->sites;
    floats[1] = rt->B;
    floats[2] = rt->areas;
    for (a = 0; a < 3; a++) {
        const array_entry *entry = &h->arrays[FLOAT_ARRAYS[a]];
        for (i = 0; i < entry->length / 4; i++)
            floats[a][i] = read_f32(bin + entry->offset + 4 * i);
    }
    for (i = 0; i < rt->k; i++)
        for (j = 0; j < rt->row; j++)
            rt->Wd[i * rt->row + j] = j < n ? read_f32(bin + h->arrays[A_W].offset + 4 * (i * n + j)) : 0.0;
    for (i = 0; i < 2 * (int64_t)rt->e; i++)
        rt->edges[i] = read_i32(bin + h->arrays[A_EDGES].offset + 4 * i);
    if (rt->criterion == FR_CRITERION_STRESS) {
        for (i = 0; i <= (int64_t)rt->s; i++)
            rt->bond_ptr[i] = read_i32(bin + h->arrays[A_PTR].offset + 4 * i);
        for (i = 0; i < (int64_t)rt->nnz; i++)
            rt->bond_edge[i] = read_i32(bin + h->arrays[A_BONDS].offset + 4 * i);
        for (i = 0; i < 3 * (int64_t)rt->nnz; i++)
            rt->bond_gain[i] = read_f32(bin + h->arrays[A_GAIN].offset + 4 * i);
        for (i = 0; i < (int64_t)rt->e; i++)
            rt->bond_strength[i] = read_f32(bin + h->arrays[A_STRENGTH].offset + 4 * i);
    }
    if (rt->anchored != NULL)
        for (i = 0; i < (int64_t)rt->p; i++)
            rt->anchored[i] = read_i32(bin + h->arrays[A_ANCHORED].offset + 4 * i);
    if (rt->crack_ptr != NULL) {
        for (i = 0; i <= (int64_t)rt->e; i++)
            rt->crack_ptr[i] = read_i32(bin + h->arrays[A_CRACK_PTR].offset + 4 * i);
        for (i = 0; i < 6 * (int64_t)rt->segments; i++)
            rt->crack_segments[i] = read_f32(bin + h->arrays[A_CRACK_SEGMENTS].offset + 4 * i);
    }
}

/*
 * The largest over edges of a constant c with |jump'| <= |alpha'| * c for the computed
 * jump (Cauchy-Schwarz on W[:, P] - W[:, Q], plus the rounding of both displacements),
 * so fr_project can skip the edge pass without computing any displacement.
 */
static void edge_bounds(fr_runtime *rt)
{
    int32_t m, i, c, k = rt->k, d = rt->d;
    rt->max_bound = 0.0;
    for (m = 0; m < rt->e; m++) {
        const double *wp = rt->Wd + (size_t)rt->edges[2 * m] * d, *wq = rt->Wd + (size_t)rt->edges[2 * m + 1] * d;
        double diff2 = 0, wp2 = 0, wq2 = 0, bound;
        for (i = 0; i < k; i++, wp += rt->row, wq += rt->row)
            for (c = 0; c < d; c++) {
                diff2 += (wp[c] - wq[c]) * (wp[c] - wq[c]);
                wp2 += wp[c] * wp[c];
                wq2 += wq[c] * wq[c];
            }
        bound = (sqrt(diff2) + BOUND_SLACK * (sqrt(wp2) + sqrt(wq2))) * (1.0 + BOUND_SLACK);
        rt->max_bound = bound > rt->max_bound ? bound : rt->max_bound;
    }
}

/* Union-find root with path halving; parents are never larger than their child (see unite). */
static int32_t uf_root(int32_t *uf, int32_t a)
{
    while (uf[a] != a)
        a = uf[a] = uf[uf[a]];
    return a;
}

/* Step 6, one unbroken edge: hook the larger root under the smaller, so every parent is smaller than its child. */
static void unite(int32_t *uf, int32_t P, int32_t Q)
{
    const int32_t a = uf_root(uf, P), b = uf_root(uf, Q);
    uf[a > b ? a : b] = a > b ? b : a;
}

/*
 * Step 6 after every unite: since parents are smaller, one forward pass turns each
 * entry into its root, the component's smallest fragment (the group id). Returns
 * the number of groups.
 */
static int32_t label(int32_t *uf, int32_t p, int32_t *groups)
{
    int32_t j, count = 0;
    for (j = 0; j < p; j++) {
        const int32_t root = uf[uf[j]]; /* uf[j] <= j is a root already */
        uf[j] = root;
        groups[j] = root;
        count += root == j;
    }
    return count;
}

typedef struct jump_entry {
    double value;
    int32_t edge;
} jump_entry;

/*
 * Stable least-significant-digit radix sort of n entries by value (non-negative
 * doubles, whose bit patterns order like their values), a byte per pass, skipping
 * the bytes every entry shares. `spare` holds n entries. Returns the sorted array.
 */
static jump_entry *sort_entries(jump_entry *a, jump_entry *spare, int32_t n)
{
    uint32_t count[8][256];
    int32_t i, byte;
    memset(count, 0, sizeof count);
    for (i = 0; i < n; i++) {
        uint64_t bits;
        memcpy(&bits, &a[i].value, sizeof bits);
        for (byte = 0; byte < 8; byte++)
            count[byte][(bits >> (8 * byte)) & 255u]++;
    }
    for (byte = 0; byte < 8 && n > 0; byte++) {
        uint32_t start[256], total = 0;
        uint64_t first;
        int digit;
        jump_entry *t;
        memcpy(&first, &a[0].value, sizeof first);
        if (count[byte][(first >> (8 * byte)) & 255u] == (uint32_t)n)
            continue; /* this byte is the same in every entry */
        for (digit = 0; digit < 256; digit++) {
            start[digit] = total;
            total += count[byte][digit];
        }
        for (i = 0; i < n; i++) {
            uint64_t bits;
            memcpy(&bits, &a[i].value, sizeof bits);
            spare[start[(bits >> (8 * byte)) & 255u]++] = a[i];
        }
        t = a, a = spare, spare = t;
    }
    return a;
}

/*
 * Step 4: disp'[j, c] = sum over i of alpha'[i] W[i, j, c], each sum in mode order.
 * Sixteen outputs at a time: sixteen independent sums that compilers keep in vector
 * registers (GCC and Clang vectorize this at -O2, as long as it is not inlined into
 * fr_project); rows of W are padded to a multiple of 16, so there is no remainder loop.
 */
NOINLINE static void displacements(const double *restrict W, size_t n, size_t k, const double *restrict alpha,
                          double *restrict disp)
{
    size_t i, j;
    for (j = 0; j < n; j += 16) {
        double s[16] = {0};
        const double *w = W + j;
        for (i = 0; i < k; i++, w += n) {
            const double a = alpha[i];
            s[0] += a * w[0], s[1] += a * w[1], s[2] += a * w[2], s[3] += a * w[3];
            s[4] += a * w[4], s[5] += a * w[5], s[6] += a * w[6], s[7] += a * w[7];
            s[8] += a * w[8], s[9] += a * w[9], s[10] += a * w[10], s[11] += a * w[11];
            s[12] += a * w[12], s[13] += a * w[13], s[14] += a * w[14], s[15] += a * w[15];
        }
        memcpy(disp + j, s, sizeof s);
    }
}

/* Temporary memory of build_jump_table. */
typedef struct table_temp {
    double *diff;        /* (k, round_up(e, 16)) W[i, P] - W[i, Q], zero padding */
    double *row;         /* (round_up(e, 16),) J[v, :] */
    double *b;           /* (k,) B[v] in double */
    jump_entry *entries; /* (2e,) one row being sorted, and the sort's spare room */
    int32_t *uf;         /* (p,) */
    int32_t *cluster;    /* (p,) dendrogram node of each root: fragment j, or p + merge */
} table_temp;

/* Lay out a table_temp in `base` (NULL: only the size); returns its size in bytes. */
static uint64_t table_temp_at(const dims *dm, unsigned char *base, table_temp *tt)
{
    const uint64_t e16 = (uint64_t)round_up(dm->e, 16);
    uint64_t cursor = 0, diff = take(&cursor, 8u * (uint64_t)dm->k * e16), row = take(&cursor, 8u * e16);
    uint64_t b = take(&cursor, 8u * (uint64_t)dm->k);
    uint64_t entries = take(&cursor, 2u * sizeof(jump_entry) * (uint64_t)dm->e);
    uint64_t uf = take(&cursor, 4u * (uint64_t)dm->p), cluster = take(&cursor, 4u * (uint64_t)dm->p);
    if (base != NULL) {
        tt->diff = (double *)(base + diff);
        tt->row = (double *)(base + row);
        tt->b = (double *)(base + b);
        tt->entries = (jump_entry *)(base + entries);
        tt->uf = (int32_t *)(base + uf);
        tt->cluster = (int32_t *)(base + cluster);
    }
    return take(&cursor, 0);
}

/*
 * Kruskal's algorithm over site v's sorted row: merge r joins two clusters with the
 * edge at row position merge_at[r]. The edges that hold for a hit are a prefix of the
 * row, so the groups are the clusters of the merges inside that prefix (a prefix of
 * the merges): fr_project labels them in one pass over this dendrogram, without any
 * union-find. Returns the number of merges.
 */
static int32_t build_merges(fr_runtime *rt, int32_t v, const table_temp *tmp)
{
    const size_t base = (size_t)v * (size_t)rt->p;
    uint16_t *at = rt->merge_at + base, *child = rt->merge_child + 2 * base;
    int32_t *label = rt->merge_label + base, pos, j, count = 0;
    for (j = 0; j < rt->p; j++) {
        tmp->uf[j] = tmp->cluster[j] = j;
        at[j] = child[2 * j] = child[2 * j + 1] = 0;
        label[j] = 0;
    }
    for (pos = 0; pos < rt->e; pos++) {
        const int32_t m = rt->jump_edge[(size_t)v * rt->e + pos];
        const int32_t a = uf_root(tmp->uf, rt->edges[2 * m]), b = uf_root(tmp->uf, rt->edges[2 * m + 1]);
        if (a == b)
            continue;
        at[count] = (uint16_t)pos;
        child[2 * count] = (uint16_t)tmp->cluster[a];
        child[2 * count + 1] = (uint16_t)tmp->cluster[b];
        label[count] = a < b ? a : b; /* roots are their component's smallest fragment */
        tmp->uf[a < b ? b : a] = a < b ? a : b;
        tmp->cluster[a < b ? a : b] = rt->p + count++;
    }
    return count;
}

/*
 * The d = 1 jump table: for each site v, the values |J[v, m]| with J[v, m] = sum over i
 * of B[v, i] (W[i, P] - W[i, Q]) in ascending order, and their edges. |jump'| of edge
 * m for a hit at site v is |n'| |J[v, m]| (section 4 allows this regrouping: B[v] @ W
 * tabulated per site, with per-edge differences), and x -> |n'| x rounds monotonically,
 * so the edges that hold are a prefix of the row, found by bisection.
 */
static void build_jump_table(fr_runtime *rt, const table_temp *tmp)
{
    const int32_t k = rt->k, e = rt->e, e16 = (int32_t)round_up(e, 16);
    int32_t v, m, i;
    const jump_entry *sorted;
    for (i = 0; i < k; i++)
        for (m = 0; m < e16; m++)
            tmp->diff[(size_t)i * e16 + m] = m >= e ? 0.0 : rt->Wd[(size_t)i * rt->row + rt->edges[2 * m]] -
                                                           rt->Wd[(size_t)i * rt->row + rt->edges[2 * m + 1]];
    for (v = 0; v < rt->s; v++) {
        for (i = 0; i < k; i++)
            tmp->b[i] = rt->B[(size_t)v * k + i];
        displacements(tmp->diff, (size_t)e16, (size_t)k, tmp->b, tmp->row); /* J[v, m], sums in mode order */
        for (m = 0; m < e; m++) {
            tmp->entries[m].value = fabs(tmp->row[m]);
            tmp->entries[m].edge = m;
        }
        sorted = sort_entries(tmp->entries, tmp->entries + e, e); /* stable: ties stay in edge order */
        for (m = 0; m < e; m++) {
            rt->jumps[(size_t)v * e + m] = sorted[m].value;
            rt->jump_edge[(size_t)v * e + m] = (uint16_t)sorted[m].edge;
        }
        rt->merges = build_merges(rt, v, tmp); /* the same for every site: p minus the whole graph's groups */
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

/* Groups of the whole graph (nothing broken) and the identity array, once at load. */
static void whole_groups(fr_runtime *rt)
{
    int32_t m, j;
    for (j = 0; j < rt->p; j++)
        rt->identity[j] = j;
    memcpy(rt->whole, rt->identity, sizeof(int32_t) * (size_t)rt->p);
    for (m = 0; m < rt->e; m++)
        unite(rt->whole, rt->edges[2 * m], rt->edges[2 * m + 1]);
    rt->whole_groups = label(rt->whole, rt->p, rt->whole);
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

static fr_status load_levels(fr_runtime *rt, const header *h, const unsigned char *bin, unsigned flags, char *msg,
                             size_t cap);

/* fr_load of a runtime file, or (is_view) of a body's view that load_levels made (section 14.3). */
static fr_status load_file(const void *header_data, size_t header_size, const void *binary, size_t binary_size,
                           unsigned flags, const fr_allocator *allocator, int is_view, fr_runtime **out, char *message,
                           size_t message_size)
{
    header h;
    dims dm;
    block_layout b;
    fr_allocator al;
    fr_status status;
    unsigned char *block;
    unsigned char *temp = NULL;
    table_temp tt = {NULL, NULL, NULL, NULL, NULL, NULL};
    fr_runtime *rt;
    int table;
    memset(&dm, 0, sizeof dm);
    if (message != NULL && message_size > 0)
        message[0] = 0;
    if (out == NULL || (binary == NULL && binary_size > 0) || header_data == NULL)
        return fail(message, message_size, FR_ERR_ARGUMENT, "fr_load: NULL argument");
    *out = NULL;
    status = parse_header(header_data, header_size, &h, is_view, message, message_size);
    if (status == FR_OK)
        status = check_header(&h, binary, binary_size, flags, &dm, message, message_size);
    if (status != FR_OK)
        return status;
    al.alloc = allocator != NULL && allocator->alloc != NULL ? allocator->alloc : default_alloc;
    al.free = allocator != NULL && allocator->free != NULL ? allocator->free : default_free;
    al.user = allocator != NULL ? allocator->user : NULL;
    table = wants_table(&dm, flags);
    b = block_plan(&dm, h.name_bytes, table);
    if (b.size > (uint64_t)(SIZE_MAX / 2) || (block = (unsigned char *)al.alloc(al.user, (size_t)b.size)) == NULL)
        return fail(message, message_size, FR_ERR_MEMORY, "out of memory (%lu bytes)", (unsigned long)b.size);
    if (table && (temp = (unsigned char *)al.alloc(al.user, (size_t)table_temp_at(&dm, NULL, &tt))) == NULL) {
        al.free(al.user, block);
        return fail(message, message_size, FR_ERR_MEMORY, "out of memory");
    }
    rt = (fr_runtime *)block;
    memset(rt, 0, sizeof *rt);
    rt->allocator = al;
    rt->s = (int32_t)dm.s, rt->k = (int32_t)dm.k, rt->p = (int32_t)dm.p, rt->e = (int32_t)dm.e, rt->d = (int32_t)dm.d;
    rt->row = (int32_t)round_up(dm.p * dm.d, 16);
    rt->bytes = (size_t)b.size;
    rt->default_threshold = h.default_threshold;
    rt->impact_radius = h.impact_radius;
    memcpy(rt->transform, h.transform, sizeof rt->transform);
    rt->sites = (float *)(block + b.sites);
    rt->B = (float *)(block + b.B);
    rt->Wd = (double *)(block + b.W);
    rt->areas = (float *)(block + b.areas);
    rt->edges = (int32_t *)(block + b.edges);
    rt->names = (char *)(block + b.names);
    rt->name_offsets = (int32_t *)(block + b.name_offsets);
    rt->kd_points = (double *)(block + b.kd_points);
    rt->kd_index = (int32_t *)(block + b.kd_index);
    rt->kd_nodes = (kd_node *)(block + b.kd_nodes);
    rt->whole = (int32_t *)(block + b.whole);
    rt->identity = (int32_t *)(block + b.identity);
    rt->jumps = table ? (double *)(block + b.jumps) : NULL;
    rt->jump_edge = table ? (uint16_t *)(block + b.jump_edge) : NULL;
    rt->merge_at = table ? (uint16_t *)(block + b.merge_at) : NULL;
    rt->merge_child = table ? (uint16_t *)(block + b.merge_child) : NULL;
    rt->merge_label = table ? (int32_t *)(block + b.merge_label) : NULL;
    rt->criterion = dm.stress ? FR_CRITERION_STRESS : FR_CRITERION_MODES;
    rt->nnz = (int32_t)dm.nnz;
    rt->bond_ptr = dm.stress ? (int32_t *)(block + b.bond_ptr) : NULL;
    rt->bond_edge = dm.stress ? (int32_t *)(block + b.bond_edge) : NULL;
    rt->bond_gain = dm.stress ? (float *)(block + b.bond_gain) : NULL;
    rt->bond_strength = dm.stress ? (float *)(block + b.bond_strength) : NULL;
    rt->features = (dm.stress ? FR_FEATURE_STRESS : 0) | (dm.anchors ? FR_FEATURE_ANCHORS : 0)
                 | (h.has_damage ? FR_FEATURE_DAMAGE : 0);
    rt->anchored = dm.anchors ? (int32_t *)(block + b.anchored) : NULL;
    rt->crack_level = h.has_damage ? h.crack_level : 1.0;
    rt->damage_rate = h.has_damage ? h.damage_rate : 0.0;
    rt->damage_q = rt->crack_level == 1.0 ? 0.0 : rt->damage_rate / (1.0 - rt->crack_level);
    rt->segments = (int32_t)dm.segments;
    rt->crack_ptr = dm.cracks ? (int32_t *)(block + b.crack_ptr) : NULL;
    rt->crack_segments = dm.cracks ? (float *)(block + b.crack_segments) : NULL;
    rt->scratch = block + b.scratch;
    copy_arrays(rt, &h, (const unsigned char *)binary);
    decode_names(rt, &h, h.name_bytes);
    build_kd_tree(rt);
    whole_groups(rt);
    edge_bounds(rt);
    if (table) {
        (void)table_temp_at(&dm, temp, &tt);
        build_jump_table(rt, &tt);
        al.free(al.user, temp);
    }
    if (h.has_levels) {
        rt->features |= FR_FEATURE_LEVELS;
        status = load_levels(rt, &h, (const unsigned char *)binary, flags, message, message_size);
        if (status != FR_OK) {
            fr_free(rt);
            return status;
        }
    }
    *out = rt;
    return FR_OK;
}

fr_status fr_load(const void *header_data, size_t header_size, const void *binary, size_t binary_size,
                  unsigned flags, const fr_allocator *allocator, fr_runtime **out, char *message, size_t message_size)
{
    return load_file(header_data, header_size, binary, binary_size, flags, allocator, 0, out, message, message_size);
}

static void free_levels(fr_runtime *rt);

void fr_free(fr_runtime *rt)
{
    if (rt != NULL) {
        free_levels(rt);
        rt->allocator.free(rt->allocator.user, rt);
    }
}

static size_t levels_memory(const fr_runtime *rt);

size_t fr_memory_size(const fr_runtime *rt) { return rt != NULL ? rt->bytes + levels_memory(rt) : 0; }

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
    info.criterion = rt->criterion;
    info.site_bonds = rt->nnz;
    info.features = rt->features;
    info.crack_segments = rt->segments;
    info.crack_level = rt->crack_level;
    info.damage_rate = rt->damage_rate;
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
const int32_t *fr_anchored(const fr_runtime *rt) { return rt != NULL ? rt->anchored : NULL; }

const float *fr_crack_segments(const fr_runtime *rt, int32_t bond, int32_t *count)
{
    int32_t n;
    if (count != NULL)
        *count = 0;
    if (rt == NULL || rt->crack_ptr == NULL || bond < 0 || bond >= rt->e)
        return NULL;
    n = rt->crack_ptr[bond + 1] - rt->crack_ptr[bond];
    if (count != NULL)
        *count = n;
    return n > 0 ? rt->crack_segments + 6 * (size_t)rt->crack_ptr[bond] : NULL;
}

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

/* Steps 2-3: alpha' of the impulse scaled by m = max |n_c| (m > 0); `length` is |n'| (used when d = 1). */
static void mode_coefficients(const fr_runtime *rt, int32_t site, const double n[3], double length, double *alpha)
{
    int32_t i, k = rt->k;
    const float *B = rt->B + (size_t)site * (size_t)k * (size_t)rt->d;
    if (rt->d == 1) {
        for (i = 0; i < k; i++)
            alpha[i] = (double)B[i] * length;
    } else {
        for (i = 0; i < k; i++)
            alpha[i] = (double)B[3 * i] * n[0] + (double)B[3 * i + 1] * n[1] + (double)B[3 * i + 2] * n[2];
    }
}

/* Step 5 from the jump table (d = 1): the number of edges that hold, |n'| |J[v, m]| <= t (a prefix of the row). */
static int32_t table_holding(const fr_runtime *rt, int32_t site, double length, double t)
{
    const double *row = rt->jumps + (size_t)site * (size_t)rt->e;
    int32_t lo = 0, hi = rt->e;
    while (lo < hi) {
        const int32_t mid = lo + (hi - lo) / 2;
        if (length * row[mid] <= t)
            lo = mid + 1;
        else
            hi = mid;
    }
    return lo;
}

/* Step 5: |jump'| of edge m from the displacements, |disp'[P] - disp'[Q]| (Euclidean norm when d = 3). */
static double edge_jump(const fr_runtime *rt, const double *disp, int32_t m)
{
    const int32_t P = rt->edges[2 * m], Q = rt->edges[2 * m + 1];
    if (rt->d == 1)
        return fabs(disp[P] - disp[Q]);
    {
        const double *a = disp + 3 * (size_t)P, *b = disp + 3 * (size_t)Q;
        const double j0 = a[0] - b[0], j1 = a[1] - b[1], j2 = a[2] - b[2];
        return sqrt(j0 * j0 + j1 * j1 + j2 * j2);
    }
}

/* Step 5 from the displacements: cut[m] = |jump'| > t. */
static void direct_cuts(const fr_runtime *rt, const double *disp, double t, uint8_t *cut)
{
    int32_t m;
    for (m = 0; m < rt->e; m++)
        cut[m] = (uint8_t)(edge_jump(rt, disp, m) > t);
}

/* Pointers into the caller's (or the built-in) workspace. */
typedef struct scratch {
    double *alpha, *disp;
    uint8_t *cut;
    int32_t *uf;
    double *health;   /* fr_project's fresh damage state */
    int32_t *holding; /* fr_hit: indices of the bonds that hold */
} scratch;

/*
 * Steps 5-6 with the jump table: the edges that hold are the row's first `holding`,
 * so the merges done are the first `done` (those inside that prefix) and the groups
 * are the clusters they form. label[0, p) starts as each fragment's own index and
 * label[p + r] as merge r's smallest fragment; top-down over the done merges (a
 * merge's parent comes later), each passes its label on to its two children.
 * Returns the number of groups.
 */
/* The number of site v's merges whose edge lies in the first `holding` positions of its row (a prefix of them). */
static int32_t merges_done(const fr_runtime *rt, int32_t site, int32_t holding)
{
    const uint16_t *at = rt->merge_at + (size_t)site * (size_t)rt->p;
    int32_t lo = 0, hi = rt->merges;
    while (lo < hi) {
        const int32_t mid = lo + (hi - lo) / 2;
        if (at[mid] < holding)
            lo = mid + 1;
        else
            hi = mid;
    }
    return lo;
}

/* The groups of site v's first `done` merges, labelled top-down (see table_groups); `label` holds 2p entries. */
static int32_t merge_groups(const fr_runtime *rt, int32_t site, int32_t done, int32_t *label, int32_t *groups)
{
    const size_t base = (size_t)site * (size_t)rt->p;
    const uint16_t *child = rt->merge_child + 2 * base;
    const int32_t p = rt->p;
    int32_t r;
    memcpy(label, rt->identity, sizeof(int32_t) * (size_t)p);
    memcpy(label + p, rt->merge_label + base, sizeof(int32_t) * (size_t)done);
    for (r = done - 1; r >= 0; r--) {
        const int32_t value = label[p + r];
        label[child[2 * r]] = value;
        label[child[2 * r + 1]] = value;
    }
    memcpy(groups, label, sizeof(int32_t) * (size_t)p);
    return p - done;
}

static int32_t table_groups(const fr_runtime *rt, int32_t site, double length, double t, const scratch *w,
                            fr_impact *out)
{
    const uint16_t *order = rt->jump_edge + (size_t)site * (size_t)rt->e;
    const int32_t holding = table_holding(rt, site, length, t);
    int32_t j;
    if (out->broken != NULL) {
        memset(out->broken, 1, (size_t)rt->e);
        for (j = 0; j < holding; j++)
            out->broken[order[j]] = 0;
    }
    out->num_broken = rt->e - holding;
    return merge_groups(rt, site, merges_done(rt, site, holding), w->uf, out->groups);
}

/* Steps 5-6 from the displacements. Returns the number of groups. */
static int32_t direct_groups(const fr_runtime *rt, double t, const scratch *w, fr_impact *out)
{
    const int32_t *edges = rt->edges;
    int32_t m, count = 0;
    direct_cuts(rt, w->disp, t, w->cut);
    memcpy(w->uf, rt->identity, sizeof(int32_t) * (size_t)rt->p);
    for (m = 0; m < rt->e; m++) {
        count += w->cut[m];
        if (!w->cut[m])
            unite(w->uf, edges[2 * m], edges[2 * m + 1]);
    }
    if (out->broken != NULL && rt->e > 0)
        memcpy(out->broken, w->cut, (size_t)rt->e);
    out->num_broken = count;
    return label(w->uf, rt->p, out->groups);
}

/*
 * Section 11, criterion "stress": bond e of site v's list breaks when g > t * S[e] with
 * g = (G0 n'0 + G1 n'1) + G2 n'2 (in this order, unfused); every other bond holds. Then step 6
 * over the bonds that hold. Returns the number of groups.
 */
static int32_t stress_groups(const fr_runtime *rt, int32_t site, const double n[3], double t, const scratch *w,
                             fr_impact *out)
{
    const int32_t *edges = rt->edges, lo = rt->bond_ptr[site], hi = rt->bond_ptr[site + 1];
    int32_t j, m, count = 0;
    if (rt->e > 0)
        memset(w->cut, 0, (size_t)rt->e);
    for (j = lo; j < hi; j++) {
        const float *G = rt->bond_gain + 3 * (size_t)j;
        const int32_t edge = rt->bond_edge[j];
        const double g = (double)G[0] * n[0] + (double)G[1] * n[1] + (double)G[2] * n[2];
        if (g > t * (double)rt->bond_strength[edge]) { /* strictly greater; t = inf never breaks */
            w->cut[edge] = 1;
            count++;
        }
    }
    if (out->broken != NULL && rt->e > 0)
        memcpy(out->broken, w->cut, (size_t)rt->e);
    out->num_broken = count;
    if (count == 0) {
        memcpy(out->groups, rt->whole, sizeof(int32_t) * (size_t)rt->p);
        return rt->whole_groups;
    }
    memcpy(w->uf, rt->identity, sizeof(int32_t) * (size_t)rt->p);
    for (m = 0; m < rt->e; m++)
        if (!w->cut[m])
            unite(w->uf, edges[2 * m], edges[2 * m + 1]);
    return label(w->uf, rt->p, out->groups);
}

/* A hit's inputs after section 4 steps 1-2 (section 12.4 step 1): n' = n / m, t = T / m, |n'|; all 0 when m == 0. */
typedef struct scaled_hit {
    double n[3], m, t, length;
} scaled_hit;

/* Validate the inputs (FR_ERR_INPUT: non-finite point or impulse, NaN or negative threshold) and scale them. */
static fr_status scale_hit(const double point[3], const double impulse[3], double threshold, scaled_hit *s)
{
    int c;
    memset(s, 0, sizeof *s);
    for (c = 0; c < 3; c++) {
        if (!isfinite(point[c]) || !isfinite(impulse[c]))
            return FR_ERR_INPUT;
        s->m = fabs(impulse[c]) > s->m ? fabs(impulse[c]) : s->m;
    }
    if (isnan(threshold) || threshold < 0)
        return FR_ERR_INPUT;
    if (s->m != 0.0) { /* step 2: a zero impulse breaks nothing (everything stays 0) */
        for (c = 0; c < 3; c++)
            s->n[c] = impulse[c] / s->m;
        s->t = threshold / s->m;
        s->length = sqrt(s->n[0] * s->n[0] + s->n[1] * s->n[1] + s->n[2] * s->n[2]);
    }
    return FR_OK;
}

static scratch scratch_at(const fr_runtime *rt, void *workspace)
{
    const workspace_layout layout = workspace_plan(rt->k, rt->p, rt->e, rt->d);
    unsigned char *base = workspace != NULL ? (unsigned char *)workspace : (unsigned char *)rt->scratch;
    scratch w;
    w.alpha = (double *)(base + layout.alpha);
    w.disp = (double *)(base + layout.disp);
    w.cut = base + layout.cut;
    w.uf = (int32_t *)(base + layout.uf);
    w.health = (double *)(base + layout.health);
    w.holding = (int32_t *)(base + layout.holding);
    return w;
}

/*
 * The optional outputs alpha = m alpha' and displacement = m disp' (section 4, "Output"), computing
 * alpha' and disp' unless the path that decided the groups already did (have_alpha, have_disp).
 */
static void mode_outputs(const fr_runtime *rt, int32_t site, const scaled_hit *s, const scratch *w, int have_alpha,
                         int have_disp, fr_impact *out)
{
    int32_t i;
    if (out->alpha == NULL && out->displacement == NULL)
        return;
    if (!have_alpha && s->m == 0.0)
        memset(w->alpha, 0, sizeof(double) * (size_t)rt->k);
    else if (!have_alpha)
        mode_coefficients(rt, site, s->n, s->length, w->alpha);
    if (out->displacement != NULL) {
        if (!have_disp)
            displacements(rt->Wd, (size_t)rt->row, (size_t)rt->k, w->alpha, w->disp);
        for (i = 0; i < rt->p * rt->d; i++)
            out->displacement[i] = s->m * w->disp[i];
    }
    if (out->alpha != NULL)
        for (i = 0; i < rt->k; i++)
            out->alpha[i] = s->m * w->alpha[i];
}

/*
 * Section 12.4 step 4, `anchored`: 1 for the fragments whose group holds a fragment bonded to the world.
 * A group id is its smallest fragment, so the first pass marks group ids and the second, in fragment
 * order, copies each group's mark to its members (groups[j] <= j, and a group id keeps its own mark).
 */
static void anchored_groups(const fr_runtime *rt, const int32_t *groups, uint8_t *anchored)
{
    int32_t j;
    memset(anchored, 0, (size_t)rt->p);
    if (rt->anchored == NULL)
        return;
    for (j = 0; j < rt->p; j++)
        if (rt->anchored[j])
            anchored[groups[j]] = 1;
    for (j = 0; j < rt->p; j++)
        anchored[j] = anchored[groups[j]];
}

fr_status fr_project(const fr_runtime *rt, const double point[3], const double impulse[3], double threshold,
                     void *workspace, fr_impact *out)
{
    scaled_hit s;
    scratch w;
    fr_status status;
    int32_t i, breaks = 0, have_alpha = 0, have_disp = 0;
    if (rt == NULL || point == NULL || impulse == NULL || out == NULL || out->groups == NULL)
        return FR_ERR_ARGUMENT;
    status = scale_hit(point, impulse, threshold, &s);
    if (status != FR_OK)
        return status;
    w = scratch_at(rt, workspace);
    if (rt->features & FR_FEATURE_DAMAGE) { /* section 12.4: a hit on a fresh state that is then thrown away */
        fr_new_state(rt, w.health);
        return fr_hit(rt, w.health, point, impulse, threshold, workspace, out);
    }
    out->site = kd_nearest(rt, point[0], point[1], point[2]);
    if (s.m != 0.0) {
        if (rt->criterion == FR_CRITERION_STRESS) {
            out->num_groups = stress_groups(rt, out->site, s.n, s.t, &w, out); /* the modes decide nothing */
        } else if (rt->jumps != NULL) {
            breaks = !(s.length * rt->jumps[(size_t)out->site * (size_t)rt->e + (size_t)rt->e - 1] <= s.t);
        } else {
            double norm2 = 0.0;
            mode_coefficients(rt, out->site, s.n, s.length, w.alpha);
            have_alpha = 1;
            for (i = 0; i < rt->k; i++)
                norm2 += w.alpha[i] * w.alpha[i];
            breaks = !(sqrt(norm2) * (1.0 + BOUND_SLACK) * rt->max_bound <= s.t);
        }
    }
    if (rt->criterion == FR_CRITERION_STRESS && s.m != 0.0) {
        /* groups done by stress_groups */
    } else if (breaks && rt->jumps != NULL) {
        out->num_groups = table_groups(rt, out->site, s.length, s.t, &w, out);
    } else if (breaks) {
        displacements(rt->Wd, (size_t)rt->row, (size_t)rt->k, w.alpha, w.disp);
        have_disp = 1;
        out->num_groups = direct_groups(rt, s.t, &w, out);
    } else { /* nothing breaks: the components of the whole graph */
        if (out->broken != NULL && rt->e > 0)
            memset(out->broken, 0, (size_t)rt->e);
        memcpy(out->groups, rt->whole, sizeof(int32_t) * (size_t)rt->p);
        out->num_groups = rt->whole_groups;
        out->num_broken = 0;
    }
    mode_outputs(rt, out->site, &s, &w, have_alpha, have_disp, out);
    if (out->cracked != NULL && rt->e > 0) /* nothing cracks without feature "damage" */
        memset(out->cracked, 0, (size_t)rt->e);
    out->num_cracked = 0;
    if (out->anchored != NULL)
        anchored_groups(rt, out->groups, out->anchored);
    return FR_OK;
}

/* ------------------------------------------------------------------ damage (section 12) */

void fr_new_state(const fr_runtime *rt, double *health)
{
    int32_t m;
    if (rt != NULL && health != NULL)
        for (m = 0; m < rt->e; m++)
            health[m] = 1.0;
}

fr_status fr_check_state(const fr_runtime *rt, const double *health, size_t count)
{
    int32_t m, ok = 1;
    if (rt == NULL || (health == NULL && rt->e > 0))
        return FR_ERR_ARGUMENT;
    if (count != (size_t)rt->e)
        return FR_ERR_STATE;
    for (m = 0; m < rt->e; m++)
        ok &= (health[m] >= 0.0) & (health[m] <= 1.0); /* NaN fails both */
    return ok ? FR_OK : FR_ERR_STATE;
}

void fr_state_to_bytes(const fr_runtime *rt, const double *health, unsigned char *bytes)
{
    int32_t m, b;
    if (rt == NULL || health == NULL || bytes == NULL)
        return;
    for (m = 0; m < rt->e; m++) {
        uint64_t u;
        memcpy(&u, health + m, sizeof u);
        for (b = 0; b < 8; b++)
            bytes[8 * (size_t)m + (size_t)b] = (unsigned char)(u >> (8 * b));
    }
}

static double read_f64(const unsigned char *p)
{
    uint64_t u = 0;
    double v;
    int b;
    for (b = 7; b >= 0; b--)
        u = u << 8 | p[b];
    memcpy(&v, &u, sizeof v);
    return v;
}

fr_status fr_state_from_bytes(const fr_runtime *rt, const void *bytes, size_t size, double *health)
{
    const unsigned char *p = (const unsigned char *)bytes;
    int32_t m;
    if (rt == NULL || (rt->e > 0 && (bytes == NULL || health == NULL)))
        return FR_ERR_ARGUMENT;
    if (size != 8u * (size_t)rt->e)
        return FR_ERR_STATE;
    for (m = 0; m < rt->e; m++) { /* all checked before any is written: a refused state leaves `health` alone */
        const double v = read_f64(p + 8 * (size_t)m);
        if (!(v >= 0.0 && v <= 1.0))
            return FR_ERR_STATE;
    }
    for (m = 0; m < rt->e; m++)
        health[m] = read_f64(p + 8 * (size_t)m);
    return FR_OK;
}

/*
 * Section 12.4 step 3 for one bond whose measure a exceeds c times its limit b (now_cracked; a bond at or
 * below that keeps its health, and a > b implies it): a > b breaks it (health 0), otherwise it loses
 * q (a / b - c), never going below 0. A broken bond stays broken.
 */
static void crack_bond(const fr_runtime *rt, double *health, uint8_t *cracked, int32_t m, double a, double b)
{
    double h = health[m];
    cracked[m] = 1;
    if (h > 0) {
        if (a > b)
            h = 0;
        else
            h = h - rt->damage_q * (a / b - rt->crack_level); /* 0 < b < inf here: a / b is finite */
        health[m] = h < 0 ? 0 : h;
    }
}

/* Section 12.4 steps 2-3, criterion "stress": a = g for the bonds site v lists (0, never cracked, for the others), b = t S. */
static void stress_damage(const fr_runtime *rt, int32_t site, const scaled_hit *s, uint8_t *cracked, double *health)
{
    int32_t j;
    for (j = rt->bond_ptr[site]; j < rt->bond_ptr[site + 1]; j++) {
        const float *G = rt->bond_gain + 3 * (size_t)j;
        const int32_t m = rt->bond_edge[j];
        const double g = (double)G[0] * s->n[0] + (double)G[1] * s->n[1] + (double)G[2] * s->n[2];
        const double b = s->t * (double)rt->bond_strength[m];
        if (g > rt->crack_level * b)
            crack_bond(rt, health, cracked, m, g, b);
    }
}

/*
 * Section 12.4 steps 2-3, criterion "modes" with the jump table (d = 1): a = |n'| |J[v, m]|, b = t. The
 * bonds with a <= c t are a prefix of the site's row (as for t in table_holding): only the rest crack.
 */
static void table_damage(const fr_runtime *rt, int32_t site, const scaled_hit *s, uint8_t *cracked, double *health)
{
    const double *row = rt->jumps + (size_t)site * (size_t)rt->e;
    const uint16_t *order = rt->jump_edge + (size_t)site * (size_t)rt->e;
    int32_t pos;
    for (pos = table_holding(rt, site, s->length, rt->crack_level * s->t); pos < rt->e; pos++)
        crack_bond(rt, health, cracked, order[pos], s->length * row[pos], s->t);
}

/* Section 12.4 steps 2-3, criterion "modes" from the displacements: a = |jump'| (section 4 step 5), b = t. */
static void direct_damage(const fr_runtime *rt, const double *disp, double t, uint8_t *cracked, double *health)
{
    const double ct = rt->crack_level * t;
    int32_t m;
    for (m = 0; m < rt->e; m++) {
        const double a = edge_jump(rt, disp, m);
        if (a > ct)
            crack_bond(rt, health, cracked, m, a, t);
    }
}

/*
 * Section 12.4 step 4 after every bond is updated: broken = health <= 0, cracked = holds and (cracked by
 * this hit or health < 1), then the groups over the bonds that hold. w->cut holds now_cracked on entry; it
 * gets broken in bit 0 and cracked in bit 1. Returns the number of groups.
 *
 * With the jump table the bonds that hold all lie in the prefix of site v's row that this hit leaves
 * standing (the others broke now). When none of the merges done in that prefix is broken (by an earlier
 * hit or by cracks), the other broken bonds of the prefix only close cycles: the groups are the merges'
 * (as in table_groups). Otherwise a union-find over the bonds that hold.
 */
static int32_t damage_answers(const fr_runtime *rt, int32_t site, const scaled_hit *s, const double *restrict health,
                              const scratch *w, fr_impact *out)
{
    /* Locals: a store through a uint8_t pointer may alias anything, which would reload every field per bond. */
    uint8_t *restrict cut = w->cut, *restrict cracked_out = out->cracked, *restrict broken_out = out->broken;
    int32_t *restrict holding = w->holding;
    const int32_t e = rt->e;
    int32_t m, broken = 0, cracked = 0, count = 0;
    for (m = 0; m < e; m++) {
        const int is_broken = health[m] <= 0, is_cracked = (is_broken ^ 1) & (cut[m] | (health[m] < 1));
        cut[m] = (uint8_t)(is_broken | is_cracked << 1);
        broken += is_broken;
        cracked += is_cracked;
    }
    if (cracked_out != NULL)
        for (m = 0; m < e; m++)
            cracked_out[m] = (uint8_t)(cut[m] >> 1);
    if (broken_out != NULL)
        for (m = 0; m < e; m++)
            broken_out[m] = (uint8_t)(cut[m] & 1);
    out->num_broken = broken;
    out->num_cracked = cracked;
    if (broken == 0) {
        memcpy(out->groups, rt->whole, sizeof(int32_t) * (size_t)rt->p);
        return rt->whole_groups;
    }
    if (rt->jumps != NULL) {
        const uint16_t *at = rt->merge_at + (size_t)site * (size_t)rt->p;
        const uint16_t *order = rt->jump_edge + (size_t)site * (size_t)rt->e;
        const int32_t done = merges_done(rt, site, table_holding(rt, site, s->length, s->t));
        int32_t r;
        for (r = 0; r < done && health[order[at[r]]] > 0; r++)
            continue;
        if (r == done)
            return merge_groups(rt, site, done, w->uf, out->groups);
    }
    for (m = 0; m < e; m++) { /* the bonds that hold, without a branch on an unpredictable flag */
        holding[count] = m;
        count += ~cut[m] & 1;
    }
    memcpy(w->uf, rt->identity, sizeof(int32_t) * (size_t)rt->p);
    for (m = 0; m < count; m++)
        unite(w->uf, rt->edges[2 * holding[m]], rt->edges[2 * holding[m] + 1]);
    return label(w->uf, rt->p, out->groups);
}

fr_status fr_hit(const fr_runtime *rt, double *health, const double point[3], const double impulse[3],
                 double threshold, void *workspace, fr_impact *out)
{
    scaled_hit s;
    scratch w;
    fr_status status;
    int have_alpha = 0, have_disp = 0;
    if (rt == NULL || (health == NULL && rt->e > 0) || point == NULL || impulse == NULL || out == NULL
        || out->groups == NULL)
        return FR_ERR_ARGUMENT;
    status = scale_hit(point, impulse, threshold, &s);
    if (status == FR_OK)
        status = fr_check_state(rt, health, (size_t)rt->e);
    if (status != FR_OK) /* before any change: a refused hit leaves the state as it was */
        return status;
    w = scratch_at(rt, workspace);
    out->site = kd_nearest(rt, point[0], point[1], point[2]);
    if (rt->e > 0)
        memset(w.cut, 0, (size_t)rt->e); /* now_cracked */
    if (s.m != 0.0) { /* m == 0: nothing changes (step 1) */
        if (rt->criterion == FR_CRITERION_STRESS) {
            stress_damage(rt, out->site, &s, w.cut, health);
        } else if (rt->jumps != NULL) {
            table_damage(rt, out->site, &s, w.cut, health);
        } else {
            mode_coefficients(rt, out->site, s.n, s.length, w.alpha);
            displacements(rt->Wd, (size_t)rt->row, (size_t)rt->k, w.alpha, w.disp);
            have_alpha = have_disp = 1;
            direct_damage(rt, w.disp, s.t, w.cut, health);
        }
    }
    out->num_groups = damage_answers(rt, out->site, &s, health, &w, out);
    mode_outputs(rt, out->site, &s, &w, have_alpha, have_disp, out);
    if (out->anchored != NULL)
        anchored_groups(rt, out->groups, out->anchored);
    return FR_OK;
}

/* ------------------------------------------------------------------ levels (section 14) */

#define LEVELS_MAX 64 /* deepest level this reader accepts (a bake writes 2) */

typedef struct fr_levels {
    int32_t nb, p_all, E, count, max_children, max_bonds;
    int32_t *parent;        /* (p_all,) */
    int32_t *level;         /* (p_all,) 1 at level 1 */
    int32_t *body_fragment; /* (nb,) -1 for body 0 */
    int32_t *child_ptr;     /* (nb + 1,) global first child of each body */
    int32_t *site_ptr;      /* (nb + 1,) rows of body_sites */
    int32_t *edge_ptr;      /* (nb + 1,) rows of body_edges */
    int32_t *state_ptr;     /* (nb + 1,) where each body's healths start in an object state */
    int32_t *body_of;       /* (p_all,) the body breaking fragment g, or -1 */
    int32_t *holding;       /* (p_all,) the body whose child g is */
    double thresholds[LEVELS_MAX], radii[LEVELS_MAX];
    int32_t radius_count;
    fr_runtime **views;     /* (nb,) views[0] is NULL: body 0 is the runtime itself */
    size_t bytes, scratch_bytes;
    void *scratch;          /* the built-in piece workspace */
} fr_levels;

static void free_levels(fr_runtime *rt)
{
    fr_levels *lv = rt->levels;
    int32_t b;
    if (lv == NULL)
        return;
    for (b = 1; b < lv->nb; b++)
        fr_free(lv->views[b]);
    if (lv->scratch != NULL)
        rt->allocator.free(rt->allocator.user, lv->scratch);
    rt->allocator.free(rt->allocator.user, lv);
    rt->levels = NULL;
}

static size_t levels_memory(const fr_runtime *rt)
{
    const fr_levels *lv = rt->levels;
    size_t total;
    int32_t b;
    if (lv == NULL)
        return 0;
    total = lv->bytes + lv->scratch_bytes;
    for (b = 1; b < lv->nb; b++)
        total += fr_memory_size(lv->views[b]);
    return total;
}

/* The header's `levels` object (section 14.1): count, thresholds, the optional impact_radii. */
static fr_status read_levels_object(const header *h, fr_levels *lv, char *msg, size_t cap)
{
    jp j;
    int first = 1, more, count_ok = 0, thresholds_seen = 0;
    int64_t count = 0, n_thresholds = 0;
    char key[16];
    size_t n;
    j.p = h->levels_at;
    j.end = h->text_end;
    j.depth = 0;
    if (j_peek(&j) != '{' || !j_open(&j, '{'))
        return fail(msg, cap, FR_ERR_HEADER, "the header's 'levels' must be an object");
    while ((more = j_next_key(&j, &first, key, sizeof key, &n)) == 1) {
        if (key_is(key, n, "count")) {
            unsigned ok = 0;
            if (!read_int(&j, &count, &ok, 1))
                return fail(msg, cap, FR_ERR_JSON, "header is not valid JSON");
            count_ok = ok != 0;
        } else if (key_is(key, n, "thresholds") || key_is(key, n, "impact_radii")) {
            const int radii = key_is(key, n, "impact_radii");
            double *into = radii ? lv->radii : lv->thresholds;
            int f = 1, m;
            int64_t items = 0, good = 0;
            if (j_peek(&j) != '[') {
                if (!j_skip(&j))
                    return fail(msg, cap, FR_ERR_JSON, "header is not valid JSON");
                continue;
            }
            if (!j_open(&j, '['))
                return fail(msg, cap, FR_ERR_JSON, "header is not valid JSON");
            while ((m = j_next_item(&j, &f)) == 1) {
                double v = 0;
                unsigned ok = 0;
                if (!read_double(&j, &v, &ok, 1))
                    return fail(msg, cap, FR_ERR_JSON, "header is not valid JSON");
                if (items < LEVELS_MAX)
                    into[items] = v;
                good += ok != 0 && (radii || (isfinite(v) && v >= 0));
                items++;
            }
            if (m < 0)
                return fail(msg, cap, FR_ERR_JSON, "header is not valid JSON");
            if (radii) {
                lv->radius_count = good == items && items <= LEVELS_MAX ? (int32_t)items : 0;
            } else {
                thresholds_seen = 1;
                n_thresholds = good == items ? items : -1;
            }
        } else if (!j_skip(&j)) {
            return fail(msg, cap, FR_ERR_JSON, "header is not valid JSON");
        }
    }
    if (more != 0)
        return fail(msg, cap, FR_ERR_JSON, "header is not valid JSON");
    if (!count_ok || count != lv->count)
        return fail(msg, cap, FR_ERR_HEADER, "levels.count must be the deepest level, %ld", (long)lv->count);
    if (!thresholds_seen || n_thresholds != count)
        return fail(msg, cap, FR_ERR_HEADER, "levels.thresholds must list %ld finite numbers >= 0, one per level",
                    (long)count);
    if (lv->thresholds[0] != h->default_threshold)
        return fail(msg, cap, FR_ERR_HEADER, "levels.thresholds[0] must be default_threshold");
    return FR_OK;
}

/* Whether ptr (n + 1 entries, read from the binary) starts at `first`, never decreases and ends at `end`. */
static int ptr_ok(const unsigned char *ptr, int64_t n, int64_t first, int64_t end)
{
    int64_t i;
    if (read_i32(ptr) != first || read_i32(ptr + 4 * n) != end)
        return 0;
    for (i = 0; i < n; i++)
        if (read_i32(ptr + 4 * (i + 1)) < read_i32(ptr + 4 * i))
            return 0;
    return 1;
}

/* Section 14.1-14.2: the levels counts and shapes against each other. */
static fr_status check_level_shapes(const header *h, const fr_runtime *rt, char *msg, size_t cap)
{
    const array_entry *A = h->arrays;
    const int64_t nb = A[A_BODY_FRAGMENT].shape[0], p_all = A[A_PARENT].shape[0], S = A[A_BODY_SITES].shape[0];
    const int64_t K = A[A_BODY_B].shape[1], E = A[A_BODY_EDGES].shape[0], C = p_all - rt->p;
    const unsigned want = (1u << C_BODIES) | (1u << C_ALL_FRAGMENTS) | (1u << C_BODY_SITES) | (1u << C_BODY_MODES)
                          | (1u << C_BODY_EDGES);
    if ((h->counts_seen & want) != want || h->counts[C_BODIES] != nb || h->counts[C_ALL_FRAGMENTS] != p_all
        || h->counts[C_BODY_SITES] != S || h->counts[C_BODY_MODES] != K || h->counts[C_BODY_EDGES] != E)
        return fail(msg, cap, FR_ERR_SIZE, "header counts of the levels arrays do not match the arrays");
    if (p_all <= rt->p || nb < 2 || p_all > INT32_MAX || S > INT32_MAX || E > INT32_MAX)
        return fail(msg, cap, FR_ERR_SIZE, "a file with levels has more fragments than level 1 and at least two bodies");
    if (!(h->seen & K_LEVELS))
        return fail(msg, cap, FR_ERR_HEADER, "the feature 'levels' needs a header object 'levels'");
    if (!(h->seen & K_CHILD_NAMES) || h->child_name_bad || h->child_name_count != C)
        return fail(msg, cap, FR_ERR_HEADER, "child_names must be %ld strings without U+0000", (long)C);
    if (A[A_BODY_CHILD_PTR].shape[0] != nb + 1 || A[A_BODY_SITE_PTR].shape[0] != nb + 1
        || A[A_BODY_EDGE_PTR].shape[0] != nb + 1 || A[A_BODY_SITES].shape[1] != 3 || K < 1
        || A[A_BODY_B].shape[2] != rt->d || A[A_BODY_W].shape[0] != K || A[A_BODY_W].shape[1] != C
        || A[A_BODY_W].shape[2] != rt->d || A[A_BODY_EDGES].shape[1] != 2 || A[A_BODY_AREAS].shape[0] != E)
        return fail(msg, cap, FR_ERR_SIZE, "levels array shapes do not agree with each other");
    if (h->has_stress && (A[A_BODY_PTR].shape[0] != S + 1 || A[A_BODY_GAIN].shape[0] != A[A_BODY_BONDS].shape[0]
                          || A[A_BODY_GAIN].shape[1] != 3 || A[A_BODY_STRENGTH].shape[0] != E
                          || !(h->counts_seen & (1u << C_BODY_SITE_BONDS))
                          || h->counts[C_BODY_SITE_BONDS] != A[A_BODY_BONDS].shape[0]))
        return fail(msg, cap, FR_ERR_SIZE, "levels stress arrays do not agree with each other or counts");
    if (h->has_body_cracks && (A[A_BODY_CRACK_PTR].shape[0] != E + 1 || A[A_BODY_CRACK_SEGMENTS].shape[1] != 2
                               || A[A_BODY_CRACK_SEGMENTS].shape[2] != 3
                               || !(h->counts_seen & (1u << C_BODY_CRACK_SEGMENTS))
                               || h->counts[C_BODY_CRACK_SEGMENTS] != A[A_BODY_CRACK_SEGMENTS].shape[0]))
        return fail(msg, cap, FR_ERR_SIZE, "levels crack arrays do not agree with each other or counts");
    return FR_OK;
}

/* Section 14.2: the parent tree, the bodies' fragments and the offset tables, read into lv. */
static fr_status check_level_tree(const header *h, const fr_runtime *rt, const unsigned char *bin, fr_levels *lv,
                                  char *msg, size_t cap)
{
    const array_entry *A = h->arrays;
    const int32_t p = rt->p, nb = lv->nb, p_all = lv->p_all;
    int32_t g, b;
    for (g = 0; g < p_all; g++)
        lv->parent[g] = read_i32(bin + A[A_PARENT].offset + 4 * g);
    for (b = 0; b < nb; b++)
        lv->body_fragment[b] = read_i32(bin + A[A_BODY_FRAGMENT].offset + 4 * b);
    for (b = 0; b <= nb; b++) {
        lv->child_ptr[b] = read_i32(bin + A[A_BODY_CHILD_PTR].offset + 4 * b);
        lv->site_ptr[b] = read_i32(bin + A[A_BODY_SITE_PTR].offset + 4 * b);
        lv->edge_ptr[b] = read_i32(bin + A[A_BODY_EDGE_PTR].offset + 4 * b);
    }
    for (g = 0; g < p_all; g++) {
        const int32_t up = lv->parent[g];
        if (g < p ? up != -1 : up < 0 || up >= g)
            return fail(msg, cap, FR_ERR_DATA, "parent must be -1 for the level-1 fragments and a smaller fragment "
                        "index for every other");
        lv->level[g] = up < 0 ? 1 : lv->level[up] + 1;
        lv->count = lv->level[g] > lv->count ? lv->level[g] : lv->count;
    }
    if (lv->body_fragment[0] != -1 || lv->body_fragment[1] < 0 || lv->body_fragment[nb - 1] >= p_all)
        return fail(msg, cap, FR_ERR_DATA, "body_fragment must be -1 for body 0, then fragment indices strictly "
                    "increasing");
    for (b = 2; b < nb; b++)
        if (lv->body_fragment[b] <= lv->body_fragment[b - 1])
            return fail(msg, cap, FR_ERR_DATA, "body_fragment must be -1 for body 0, then fragment indices strictly "
                        "increasing");
    if (!ptr_ok(bin + A[A_BODY_CHILD_PTR].offset, nb, 0, p_all) || lv->child_ptr[1] != p)
        return fail(msg, cap, FR_ERR_DATA, "body_child_ptr must start at 0, then %ld, never decrease and end at %ld",
                    (long)p, (long)p_all);
    for (b = 0; b < nb; b++)
        if (lv->child_ptr[b + 1] - lv->child_ptr[b] < 2)
            return fail(msg, cap, FR_ERR_DATA, "every body must have at least 2 children (body %ld)", (long)b);
    for (b = 1; b < nb; b++)
        for (g = lv->child_ptr[b]; g < lv->child_ptr[b + 1]; g++)
            if (lv->parent[g] != lv->body_fragment[b])
                return fail(msg, cap, FR_ERR_DATA, "parent of every child must be the fragment of the body that "
                            "holds it");
    if (!ptr_ok(bin + A[A_BODY_SITE_PTR].offset, nb, 0, A[A_BODY_SITES].shape[0])
        || !ptr_ok(bin + A[A_BODY_EDGE_PTR].offset, nb, 0, A[A_BODY_EDGES].shape[0]) || lv->site_ptr[1] != 0
        || lv->edge_ptr[1] != 0)
        return fail(msg, cap, FR_ERR_DATA, "body_site_ptr and body_edge_ptr must start at 0 (body 0 has no rows), "
                    "never decrease and end at their arrays' lengths");
    for (b = 1; b < nb; b++)
        if (lv->site_ptr[b + 1] <= lv->site_ptr[b])
            return fail(msg, cap, FR_ERR_DATA, "every body but body 0 needs at least one site (body %ld)", (long)b);
    if (h->has_stress && !ptr_ok(bin + A[A_BODY_PTR].offset, A[A_BODY_SITES].shape[0], 0, A[A_BODY_BONDS].shape[0]))
        return fail(msg, cap, FR_ERR_DATA, "body_site_bonds_ptr must start at 0, never decrease and end at N");
    if (h->has_body_cracks
        && !ptr_ok(bin + A[A_BODY_CRACK_PTR].offset, lv->E, 0, A[A_BODY_CRACK_SEGMENTS].shape[0]))
        return fail(msg, cap, FR_ERR_DATA, "body_crack_ptr must start at 0, never decrease and end at n");
    for (b = 1; b < nb && rt->anchored != NULL; b++)
        if (lv->body_fragment[b] < p && rt->anchored[lv->body_fragment[b]] == 1)
            return fail(msg, cap, FR_ERR_DATA, "an anchored fragment cannot be broken further (it has a body)");
    return FR_OK;
}

typedef struct text {
    char *at;
    size_t length, capacity;
} text;

/* Append to a text (integers and fixed words only: no locale-dependent output). */
static void put(text *t, const char *format, ...)
{
    va_list args;
    int n;
    va_start(args, format);
    n = vsnprintf(t->at + t->length, t->capacity - t->length, format, args);
    va_end(args);
    if (n > 0)
        t->length = t->length + (size_t)n < t->capacity ? t->length + (size_t)n : t->capacity - 1;
}

static void put_array(text *t, const char *name, const char *dtype, int64_t offset, int64_t length, int rank,
                      int64_t a, int64_t b, int64_t c)
{
    put(t, "%s\"%s\":{\"dtype\":\"%s\",\"byte_offset\":%ld,\"byte_length\":%ld,\"shape\":[%ld", t->at[t->length - 1] == '{'
        ? "" : ",", name, dtype, (long)offset, (long)length, (long)a);
    if (rank > 1)
        put(t, ",%ld", (long)b);
    if (rank > 2)
        put(t, ",%ld", (long)c);
    put(t, "]}");
}

static void write_i32(unsigned char *p, int32_t value)
{
    const uint32_t u = (uint32_t)value;
    p[0] = (unsigned char)u, p[1] = (unsigned char)(u >> 8), p[2] = (unsigned char)(u >> 16), p[3] = (unsigned char)(u >> 24);
}

/*
 * Body b's view (section 14.3) as a runtime file of its own, loaded by load_file (so it passes every check of
 * sections 2, 11 and 12): the rows of its sites, B, bonds, stress and crack arrays, its columns of body_W, its
 * children's names copied as they are written in the header. Thresholds, radius, transform and damage are set
 * on the loaded view (no number is printed).
 */
static fr_status make_view(fr_runtime *rt, const header *h, const unsigned char *bin, fr_levels *lv, int32_t b,
                           unsigned flags, char *msg, size_t cap)
{
    const array_entry *A = h->arrays;
    const int64_t p = rt->p, d = rt->d, K = A[A_BODY_B].shape[1], C = lv->p_all - p;
    const int64_t s0 = lv->site_ptr[b], s1 = lv->site_ptr[b + 1], g0 = lv->child_ptr[b] - p;
    const int64_t g1 = lv->child_ptr[b + 1] - p, e0 = lv->edge_ptr[b], e1 = lv->edge_ptr[b + 1];
    const int64_t sb = s1 - s0, cb = g1 - g0, eb = e1 - e0;
    const int stress = h->has_stress, cracks = h->has_body_cracks;
    int64_t n0 = 0, nn = 0, c0 = 0, nc = 0, at[11], len[11], cursor = 0, i, k;
    int a, first = 1, more;
    unsigned char *binary;
    text t;
    jp j;
    fr_status status;
    char why[FR_MESSAGE_SIZE];
    fr_runtime *view = NULL;
    const int level = lv->level[lv->body_fragment[b]] + 1;
    if (stress) {
        n0 = read_i32(bin + A[A_BODY_PTR].offset + 4 * s0);
        nn = read_i32(bin + A[A_BODY_PTR].offset + 4 * s1) - n0;
    }
    if (cracks) {
        c0 = read_i32(bin + A[A_BODY_CRACK_PTR].offset + 4 * e0);
        nc = read_i32(bin + A[A_BODY_CRACK_PTR].offset + 4 * e1) - c0;
    }
    len[0] = 12 * sb, len[1] = 4 * sb * K * d, len[2] = 4 * K * cb * d, len[3] = 8 * eb, len[4] = 4 * eb;
    len[5] = stress ? 4 * (sb + 1) : 0, len[6] = 4 * nn, len[7] = 12 * nn, len[8] = stress ? 4 * eb : 0;
    len[9] = cracks ? 4 * (eb + 1) : 0, len[10] = 24 * nc;
    for (a = 0; a < 11; a++) {
        at[a] = cursor;
        cursor = round_up(cursor + len[a], 16);
    }
    t.capacity = (size_t)(h->text_end - h->child_names_at) + 4096;
    t.length = 0;
    t.at = (char *)rt->allocator.alloc(rt->allocator.user, t.capacity);
    binary = (unsigned char *)rt->allocator.alloc(rt->allocator.user, (size_t)cursor + 16);
    if (t.at == NULL || binary == NULL) {
        if (t.at != NULL)
            rt->allocator.free(rt->allocator.user, t.at);
        if (binary != NULL)
            rt->allocator.free(rt->allocator.user, binary);
        return fail(msg, cap, FR_ERR_MEMORY, "out of memory");
    }
    memset(binary, 0, (size_t)cursor + 16);
    memcpy(binary + at[0], bin + A[A_BODY_SITES].offset + 12 * s0, (size_t)len[0]);
    memcpy(binary + at[1], bin + A[A_BODY_B].offset + 4 * s0 * K * d, (size_t)len[1]);
    for (k = 0; k < K; k++)
        memcpy(binary + at[2] + 4 * k * cb * d, bin + A[A_BODY_W].offset + 4 * (k * C * d + g0 * d),
               (size_t)(4 * cb * d));
    memcpy(binary + at[3], bin + A[A_BODY_EDGES].offset + 8 * e0, (size_t)len[3]);
    memcpy(binary + at[4], bin + A[A_BODY_AREAS].offset + 4 * e0, (size_t)len[4]);
    if (stress) {
        for (i = 0; i <= sb; i++)
            write_i32(binary + at[5] + 4 * i, (int32_t)(read_i32(bin + A[A_BODY_PTR].offset + 4 * (s0 + i)) - n0));
        memcpy(binary + at[6], bin + A[A_BODY_BONDS].offset + 4 * n0, (size_t)len[6]);
        memcpy(binary + at[7], bin + A[A_BODY_GAIN].offset + 12 * n0, (size_t)len[7]);
        memcpy(binary + at[8], bin + A[A_BODY_STRENGTH].offset + 4 * e0, (size_t)len[8]);
    }
    if (cracks) {
        for (i = 0; i <= eb; i++)
            write_i32(binary + at[9] + 4 * i,
                      (int32_t)(read_i32(bin + A[A_BODY_CRACK_PTR].offset + 4 * (e0 + i)) - c0));
        memcpy(binary + at[10], bin + A[A_BODY_CRACK_SEGMENTS].offset + 24 * c0, (size_t)len[10]);
    }
    put(&t, "{\"format\":\"fracture-modes-runtime\",\"version\":2,\"features\":[%s%s%s],\"criterion\":\"%s\","
        "\"dim\":%ld,\"counts\":{\"sites\":%ld,\"modes\":%ld,\"fragments\":%ld,\"edges\":%ld", stress ? "\"stress\"" : "",
        stress && h->has_damage ? "," : "", h->has_damage ? "\"damage\"" : "", stress ? "stress" : "modes", (long)d,
        (long)sb, (long)K, (long)cb, (long)eb);
    if (stress)
        put(&t, ",\"site_bonds\":%ld", (long)nn);
    if (cracks)
        put(&t, ",\"crack_segments\":%ld", (long)nc);
    put(&t, "},\"transform\":[1,0,0,0,0,1,0,0,0,0,1,0,0,0,0,1],\"default_threshold\":0,\"impact_radius\":0,");
    if (h->has_damage)
        put(&t, "\"damage\":{\"crack_level\":1,\"damage_rate\":0},");
    put(&t, "\"fragment_names\":[");
    j.p = h->child_names_at, j.end = h->text_end, j.depth = 0;
    (void)j_open(&j, '['); /* parsed once already: a list of strings */
    for (i = 0; i < g1 && (more = j_next_item(&j, &first)) == 1; i++) {
        const unsigned char *start;
        j_ws(&j);
        start = j.p;
        (void)j_skip(&j);
        if (i >= g0 && t.length + (size_t)(j.p - start) + 2 < t.capacity) {
            if (i > g0)
                t.at[t.length++] = ',';
            memcpy(t.at + t.length, start, (size_t)(j.p - start));
            t.length += (size_t)(j.p - start);
        }
    }
    put(&t, "],\"buffer\":{\"uri\":\"view.fracture.bin\",\"byte_length\":%ld},\"arrays\":{", (long)cursor);
    put_array(&t, "sites", "float32", at[0], len[0], 2, sb, 3, 0);
    put_array(&t, "B", "float32", at[1], len[1], 3, sb, K, d);
    put_array(&t, "W", "float32", at[2], len[2], 3, K, cb, d);
    put_array(&t, "edges", "int32", at[3], len[3], 2, eb, 2, 0);
    put_array(&t, "edge_areas", "float32", at[4], len[4], 1, eb, 0, 0);
    if (stress) {
        put_array(&t, "site_bonds_ptr", "int32", at[5], len[5], 1, sb + 1, 0, 0);
        put_array(&t, "site_bonds", "int32", at[6], len[6], 1, nn, 0, 0);
        put_array(&t, "site_bond_gain", "float32", at[7], len[7], 2, nn, 3, 0);
        put_array(&t, "bond_strength", "float32", at[8], len[8], 1, eb, 0, 0);
    }
    if (cracks) {
        put_array(&t, "crack_ptr", "int32", at[9], len[9], 1, eb + 1, 0, 0);
        put_array(&t, "crack_segments", "float32", at[10], len[10], 3, nc, 2, 3);
    }
    put(&t, "}}");
    status = load_file(t.at, t.length, binary, (size_t)cursor, flags | FR_LOAD_SKIP_CRC, &rt->allocator, 1, &view, why,
                       sizeof why);
    rt->allocator.free(rt->allocator.user, t.at);
    rt->allocator.free(rt->allocator.user, binary);
    if (status != FR_OK)
        return fail(msg, cap, status, "body %ld: %s", (long)b, why);
    view->default_threshold = lv->thresholds[level - 1];
    view->impact_radius = lv->radius_count >= level ? lv->radii[level - 1] : rt->impact_radius;
    memcpy(view->transform, rt->transform, sizeof view->transform);
    view->crack_level = rt->crack_level;
    view->damage_rate = rt->damage_rate;
    view->damage_q = rt->damage_q;
    lv->views[b] = view;
    return FR_OK;
}

/* Bytes of the piece workspace of a runtime with levels (see piece_scratch). */
typedef struct piece_layout {
    uint64_t view, trial, cracked, groups, uf, order, cursor, keep, split, open, size;
} piece_layout;

static piece_layout piece_plan(const fr_runtime *rt)
{
    piece_layout w;
    uint64_t cursor = 0, view = fr_workspace_size(rt);
    int32_t b, nb = rt->levels != NULL ? rt->levels->nb : 1, p_all = rt->levels != NULL ? rt->levels->p_all : rt->p;
    int32_t c = rt->levels != NULL ? rt->levels->max_children : rt->p;
    int32_t e = rt->levels != NULL ? rt->levels->max_bonds : rt->e;
    for (b = 1; b < nb; b++)
        view = fr_workspace_size(rt->levels->views[b]) > view ? fr_workspace_size(rt->levels->views[b]) : view;
    w.view = take(&cursor, view);
    w.trial = take(&cursor, 8u * (uint64_t)e);
    w.cracked = take(&cursor, (uint64_t)e);
    w.groups = take(&cursor, 4u * (uint64_t)c);
    w.uf = take(&cursor, 4u * (uint64_t)c);
    w.order = take(&cursor, 4u * (uint64_t)c);
    w.cursor = take(&cursor, 4u * (uint64_t)c);
    w.keep = take(&cursor, (uint64_t)c);
    w.split = take(&cursor, (uint64_t)p_all);
    w.open = take(&cursor, (uint64_t)p_all);
    w.size = take(&cursor, 0);
    return w;
}

static fr_status load_levels(fr_runtime *rt, const header *h, const unsigned char *bin, unsigned flags, char *msg,
                             size_t cap)
{
    const int64_t nb = h->arrays[A_BODY_FRAGMENT].shape[0], p_all = h->arrays[A_PARENT].shape[0];
    uint64_t cursor = sizeof(fr_levels), o_parent, o_level, o_frag, o_child, o_site, o_edge, o_state, o_of, o_hold, o_views;
    unsigned char *block;
    fr_levels *lv;
    fr_status status = check_level_shapes(h, rt, msg, cap);
    int32_t b, g;
    if (status != FR_OK)
        return status;
    o_parent = take(&cursor, 4u * (uint64_t)p_all);
    o_level = take(&cursor, 4u * (uint64_t)p_all);
    o_frag = take(&cursor, 4u * (uint64_t)nb);
    o_child = take(&cursor, 4u * (uint64_t)(nb + 1));
    o_site = take(&cursor, 4u * (uint64_t)(nb + 1));
    o_edge = take(&cursor, 4u * (uint64_t)(nb + 1));
    o_state = take(&cursor, 4u * (uint64_t)(nb + 1));
    o_of = take(&cursor, 4u * (uint64_t)p_all);
    o_hold = take(&cursor, 4u * (uint64_t)p_all);
    o_views = take(&cursor, sizeof(fr_runtime *) * (uint64_t)nb);
    cursor = take(&cursor, 0);
    if (cursor > (uint64_t)(SIZE_MAX / 2) || (block = (unsigned char *)rt->allocator.alloc(rt->allocator.user,
                                                                                           (size_t)cursor)) == NULL)
        return fail(msg, cap, FR_ERR_MEMORY, "out of memory");
    memset(block, 0, (size_t)cursor);
    lv = (fr_levels *)block;
    rt->levels = lv; /* freed by fr_free from here on */
    lv->bytes = (size_t)cursor;
    lv->nb = (int32_t)nb, lv->p_all = (int32_t)p_all, lv->E = (int32_t)h->arrays[A_BODY_EDGES].shape[0];
    lv->parent = (int32_t *)(block + o_parent), lv->level = (int32_t *)(block + o_level);
    lv->body_fragment = (int32_t *)(block + o_frag), lv->child_ptr = (int32_t *)(block + o_child);
    lv->site_ptr = (int32_t *)(block + o_site), lv->edge_ptr = (int32_t *)(block + o_edge);
    lv->state_ptr = (int32_t *)(block + o_state), lv->body_of = (int32_t *)(block + o_of);
    lv->holding = (int32_t *)(block + o_hold), lv->views = (fr_runtime **)(block + o_views);
    status = check_level_tree(h, rt, bin, lv, msg, cap);
    if (status == FR_OK && lv->count > LEVELS_MAX)
        status = fail(msg, cap, FR_ERR_DATA, "more than %d levels", LEVELS_MAX);
    if (status == FR_OK)
        status = read_levels_object(h, lv, msg, cap);
    if (status != FR_OK)
        return status;
    for (g = 0; g < lv->p_all; g++)
        lv->body_of[g] = -1, lv->holding[g] = 0;
    lv->max_children = rt->p, lv->max_bonds = rt->e;
    for (b = 1; b < (int32_t)nb; b++) {
        lv->body_of[lv->body_fragment[b]] = b;
        for (g = lv->child_ptr[b]; g < lv->child_ptr[b + 1]; g++)
            lv->holding[g] = b;
        lv->state_ptr[b] = rt->e + lv->edge_ptr[b];
        status = make_view(rt, h, bin, lv, b, flags, msg, cap); /* views not made yet are NULL: fr_free skips them */
        if (status != FR_OK)
            return status;
        lv->max_children = lv->views[b]->p > lv->max_children ? lv->views[b]->p : lv->max_children;
        lv->max_bonds = lv->views[b]->e > lv->max_bonds ? lv->views[b]->e : lv->max_bonds;
    }
    lv->state_ptr[0] = 0;
    lv->state_ptr[nb] = rt->e + lv->E;
    lv->scratch_bytes = (size_t)piece_plan(rt).size;
    lv->scratch = rt->allocator.alloc(rt->allocator.user, lv->scratch_bytes + 16);
    if (lv->scratch == NULL)
        return fail(msg, cap, FR_ERR_MEMORY, "out of memory");
    return FR_OK;
}

/* ---- the levels API */

fr_levels_info fr_get_levels_info(const fr_runtime *rt)
{
    fr_levels_info info;
    memset(&info, 0, sizeof info);
    if (rt == NULL)
        return info;
    if (rt->levels == NULL) {
        info.bodies = 1, info.all_fragments = rt->p, info.state_size = rt->e;
        info.max_children = rt->p, info.max_bonds = rt->e, info.count = 1;
        return info;
    }
    info.bodies = rt->levels->nb, info.all_fragments = rt->levels->p_all, info.state_size = rt->e + rt->levels->E;
    info.max_children = rt->levels->max_children, info.max_bonds = rt->levels->max_bonds;
    info.count = rt->levels->count;
    return info;
}

const fr_runtime *fr_body(const fr_runtime *rt, int32_t body)
{
    if (rt == NULL || body < 0 || body >= (rt->levels != NULL ? rt->levels->nb : 1))
        return NULL;
    return body == 0 ? rt : rt->levels->views[body];
}

int32_t fr_body_fragment(const fr_runtime *rt, int32_t body)
{
    return rt != NULL && rt->levels != NULL && body > 0 && body < rt->levels->nb ? rt->levels->body_fragment[body] : -1;
}

int32_t fr_body_first(const fr_runtime *rt, int32_t body)
{
    if (rt == NULL || body < 0)
        return -1;
    if (rt->levels == NULL)
        return body == 0 ? 0 : body == 1 ? rt->p : -1;
    return body <= rt->levels->nb ? rt->levels->child_ptr[body] : -1;
}

int32_t fr_body_of(const fr_runtime *rt, int32_t fragment)
{
    return rt != NULL && rt->levels != NULL && fragment >= 0 && fragment < rt->levels->p_all
               ? rt->levels->body_of[fragment] : -1;
}

int32_t fr_body_holding(const fr_runtime *rt, int32_t fragment)
{
    if (rt == NULL || fragment < 0 || fragment >= fr_get_levels_info(rt).all_fragments)
        return -1;
    return rt->levels != NULL ? rt->levels->holding[fragment] : 0;
}

int32_t fr_parent(const fr_runtime *rt, int32_t fragment)
{
    return rt != NULL && rt->levels != NULL && fragment >= 0 && fragment < rt->levels->p_all
               ? rt->levels->parent[fragment] : -1;
}

int32_t fr_state_offset(const fr_runtime *rt, int32_t body)
{
    if (rt == NULL || body < 0)
        return -1;
    if (rt->levels == NULL)
        return body == 0 ? 0 : body == 1 ? rt->e : -1;
    return body <= rt->levels->nb ? rt->levels->state_ptr[body] : -1;
}

const char *fr_any_fragment_name(const fr_runtime *rt, int32_t fragment)
{
    int32_t b = fr_body_holding(rt, fragment);
    if (b < 0)
        return NULL;
    return fr_fragment_name(fr_body(rt, b), fragment - fr_body_first(rt, b));
}

void fr_new_object_state(const fr_runtime *rt, double *health)
{
    int32_t m, n = fr_get_levels_info(rt).state_size;
    if (health != NULL)
        for (m = 0; m < n; m++)
            health[m] = 1.0;
}

fr_status fr_check_object_state(const fr_runtime *rt, const double *health, size_t count)
{
    const int32_t n = fr_get_levels_info(rt).state_size;
    int32_t m, ok = 1;
    if (rt == NULL || (health == NULL && n > 0))
        return FR_ERR_ARGUMENT;
    if (count != (size_t)n)
        return FR_ERR_STATE;
    for (m = 0; m < n; m++)
        ok &= (health[m] >= 0.0) & (health[m] <= 1.0);
    return ok ? FR_OK : FR_ERR_STATE;
}

size_t fr_piece_workspace_size(const fr_runtime *rt) { return rt != NULL ? (size_t)piece_plan(rt).size : 0; }

typedef struct piece_scratch {
    void *view;
    double *trial;
    uint8_t *cracked, *keep, *split, *open;
    int32_t *groups, *uf, *order, *cursor;
} piece_scratch;

static piece_scratch piece_scratch_at(const fr_runtime *rt, void *workspace)
{
    const piece_layout w = piece_plan(rt);
    unsigned char *base = (unsigned char *)(workspace != NULL ? workspace
                                            : rt->levels != NULL ? rt->levels->scratch : NULL);
    piece_scratch s;
    s.view = base + w.view;
    s.trial = (double *)(base + w.trial);
    s.cracked = base + w.cracked, s.keep = base + w.keep, s.split = base + w.split, s.open = base + w.open;
    s.groups = (int32_t *)(base + w.groups), s.uf = (int32_t *)(base + w.uf);
    s.order = (int32_t *)(base + w.order), s.cursor = (int32_t *)(base + w.cursor);
    return s;
}

/* Groups (into `groups`, the smallest local index) of a body's children over its bonds with health > 0 between
 * two kept children (keep NULL: all); returns the number of groups. */
static int32_t body_components(const fr_runtime *view, const double *health, const uint8_t *keep, int32_t *groups)
{
    int32_t m;
    memcpy(groups, view->identity, sizeof(int32_t) * (size_t)view->p);
    for (m = 0; m < view->e; m++) {
        const int32_t P = view->edges[2 * m], Q = view->edges[2 * m + 1];
        if (health[m] > 0 && (keep == NULL || (keep[P] && keep[Q])))
            unite(groups, P, Q);
    }
    return label(groups, view->p, groups);
}

static int is_split(const fr_runtime *rt, const double *health, int32_t fragment, int32_t *uf)
{
    const int32_t b = rt->levels->body_of[fragment];
    return b >= 0 && body_components(rt->levels->views[b], health + rt->levels->state_ptr[b], NULL, uf) >= 2;
}

/* Append the pieces of body b's kept children (components over bonds that hold between two kept ones). */
static void emit_pieces(const fr_runtime *rt, const double *health, int32_t body, const uint8_t *keep,
                        const piece_scratch *s, fr_pieces *out)
{
    const fr_runtime *view = fr_body(rt, body);
    const int32_t first = fr_body_first(rt, body), c = view->p, start = out->count;
    int32_t j, count = 0;
    (void)body_components(view, health + fr_state_offset(rt, body), keep, s->groups);
    for (j = 0; j < c; j++)
        if (keep[j] && s->groups[j] == j) {
            s->order[j] = count;
            out->offsets[start + count + 1] = 0;
            if (out->bodies != NULL)
                out->bodies[start + count] = body;
            if (out->anchored != NULL)
                out->anchored[start + count] = 0;
            count++;
        }
    for (j = 0; j < c; j++)
        if (keep[j])
            out->offsets[start + s->order[s->groups[j]] + 1]++;
    for (j = 0; j < count; j++) {
        out->offsets[start + j + 1] += out->offsets[start + j];
        s->cursor[j] = out->offsets[start + j];
    }
    for (j = 0; j < c; j++)
        if (keep[j]) {
            const int32_t piece = s->order[s->groups[j]];
            out->fragments[s->cursor[piece]++] = first + j;
            if (out->anchored != NULL && body == 0 && rt->anchored != NULL && rt->anchored[j])
                out->anchored[start + piece] = 1;
        }
    out->count += count;
}

/* Split flags of every fragment with a body, and `open` (every ancestor split) of every fragment. */
static void split_and_open(const fr_runtime *rt, const double *health, const piece_scratch *s)
{
    const fr_levels *lv = rt->levels;
    int32_t b, g;
    if (lv == NULL) {
        memset(s->split, 0, (size_t)rt->p);
        memset(s->open, 1, (size_t)rt->p);
        return;
    }
    memset(s->split, 0, (size_t)lv->p_all);
    for (b = 1; b < lv->nb; b++)
        s->split[lv->body_fragment[b]] = (uint8_t)is_split(rt, health, lv->body_fragment[b], s->uf);
    for (g = 0; g < lv->p_all; g++)
        s->open[g] = (uint8_t)(g < rt->p || (s->open[lv->parent[g]] && s->split[lv->parent[g]]));
}

fr_status fr_object_pieces(const fr_runtime *rt, const double *health, void *workspace, fr_pieces *out)
{
    piece_scratch s;
    int32_t b, j;
    if (rt == NULL || out == NULL || out->fragments == NULL || out->offsets == NULL)
        return FR_ERR_ARGUMENT;
    if (fr_check_object_state(rt, health, (size_t)fr_get_levels_info(rt).state_size) != FR_OK)
        return FR_ERR_STATE;
    if (rt->levels == NULL && workspace == NULL) /* no built-in piece workspace without levels */
        return FR_ERR_ARGUMENT;
    s = piece_scratch_at(rt, workspace);
    split_and_open(rt, health, &s);
    out->count = 0;
    out->offsets[0] = 0;
    for (b = 0; b < fr_get_levels_info(rt).bodies; b++) {
        const int32_t first = fr_body_first(rt, b), c = fr_body(rt, b)->p;
        for (j = 0; j < c; j++)
            s.keep[j] = (uint8_t)(s.open[first + j] && !s.split[first + j]);
        emit_pieces(rt, health, b, s.keep, &s, out);
    }
    return FR_OK;
}

fr_status fr_hit_piece(const fr_runtime *rt, double *health, int32_t struck, const double point[3],
                       const double impulse[3], const double *threshold, void *workspace, fr_piece_hit *out)
{
    const fr_levels *lv;
    const fr_runtime *view, *child_view;
    piece_scratch s;
    fr_impact trial_out;
    fr_status status;
    double *hb;
    int32_t b, first, j, m, root, up, child_body, broken = 0, cracked = 0;
    if (rt == NULL || health == NULL || point == NULL || impulse == NULL || out == NULL || out->body.groups == NULL
        || out->pieces.fragments == NULL || out->pieces.offsets == NULL || (rt->levels == NULL && workspace == NULL))
        return FR_ERR_ARGUMENT;
    lv = rt->levels;
    if (fr_check_object_state(rt, health, (size_t)fr_get_levels_info(rt).state_size) != FR_OK)
        return FR_ERR_STATE;
    if (struck < 0 || struck >= fr_get_levels_info(rt).all_fragments)
        return FR_ERR_FRAGMENT;
    s = piece_scratch_at(rt, workspace);
    /* Step 1: struck is shown: not split, every ancestor split. */
    if (lv != NULL) {
        if (is_split(rt, health, struck, s.uf))
            return FR_ERR_FRAGMENT;
        for (up = lv->parent[struck]; up >= 0; up = lv->parent[up])
            if (!is_split(rt, health, up, s.uf))
                return FR_ERR_FRAGMENT;
    }
    /* Step 2: the piece G holding struck among its shown siblings, and body b's hit on a copy of its healths. */
    b = fr_body_holding(rt, struck);
    view = fr_body(rt, b);
    first = fr_body_first(rt, b);
    hb = health + fr_state_offset(rt, b);
    for (j = 0; j < view->p; j++)
        s.keep[j] = (uint8_t)(lv == NULL || !is_split(rt, health, first + j, s.uf));
    (void)body_components(view, hb, s.keep, s.groups);
    root = s.groups[struck - first];
    for (j = 0; j < view->p; j++)
        s.keep[j] = (uint8_t)(s.keep[j] && s.groups[j] == root);
    if (view->e > 0)
        memcpy(s.trial, hb, sizeof(double) * (size_t)view->e);
    trial_out = out->body;
    trial_out.groups = s.groups;
    trial_out.broken = NULL;
    trial_out.cracked = s.cracked;
    trial_out.anchored = NULL;
    status = fr_hit(view, s.trial, point, impulse, threshold != NULL ? *threshold : view->default_threshold, s.view,
                    &trial_out);
    if (status != FR_OK) /* inputs refused before anything changed */
        return status;
    for (m = 0; m < view->e; m++) {
        const int within = s.keep[view->edges[2 * m]] && s.keep[view->edges[2 * m + 1]];
        int is_broken, is_cracked;
        if (within)
            hb[m] = s.trial[m];
        is_broken = hb[m] <= 0;
        is_cracked = !is_broken && ((s.cracked[m] && within) || hb[m] < 1);
        broken += is_broken;
        cracked += is_cracked;
        if (out->body.broken != NULL)
            out->body.broken[m] = (uint8_t)is_broken;
        if (out->body.cracked != NULL)
            out->body.cracked[m] = (uint8_t)is_cracked;
    }
    out->body.site = trial_out.site;
    out->body.num_broken = broken;
    out->body.num_cracked = cracked;
    out->body.num_groups = body_components(view, hb, NULL, out->body.groups);
    if (out->body.anchored != NULL)
        anchored_groups(view, out->body.groups, out->body.anchored);
    out->body_index = b;
    /* Step 3: struck's own body, on all its bonds. */
    child_body = fr_body_of(rt, struck);
    out->child_body = child_body;
    out->split = 0;
    if (child_body >= 0) {
        fr_impact child = out->child;
        child_view = lv->views[child_body];
        if (child.groups == NULL)
            child.groups = s.uf;
        (void)fr_hit(child_view, health + lv->state_ptr[child_body], point, impulse,
                     threshold != NULL ? *threshold : child_view->default_threshold, s.view, &child);
        if (out->child.groups == NULL)
            child.groups = NULL;
        out->child = child;
        out->split = child.num_groups >= 2;
    }
    /* Step 4: the pieces that replace G. */
    out->pieces.count = 0;
    out->pieces.offsets[0] = 0;
    if (out->split)
        s.keep[struck - first] = 0;
    emit_pieces(rt, health, b, s.keep, &s, &out->pieces);
    if (out->split) {
        const int32_t cfirst = lv->child_ptr[child_body];
        for (j = 0; j < lv->views[child_body]->p; j++)
            s.keep[j] = (uint8_t)!is_split(rt, health, cfirst + j, s.uf);
        emit_pieces(rt, health, child_body, s.keep, &s, &out->pieces);
    }
    return FR_OK;
}
