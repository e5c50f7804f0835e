/*
 * fracture_aligned.c - aligned fracture at runtime (see fracture_aligned.h; docs/FORMAT.md section 13).
 * MIT licence, Copyright (c) fracture developers.
 *
 * Every sum and product is written in the order docs/FORMAT.md sections 13.3-13.4 states, in double
 * precision, so the results match the Python reference and the JavaScript reader to the last bit
 * on the conformance vectors. Compile without -ffast-math and without FMA contraction
 * (-ffp-contract=off; plain -std=c99 already implies it with GCC).
 */
#include "fracture_aligned.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#ifdef __FAST_MATH__
#error "fracture_aligned.c needs IEEE arithmetic: do not compile it with -ffast-math"
#endif

#define EPS_RELATIVE 1e-9
#define KEEP_RELATIVE 1e-9
#define UV_AXIS_TIE 1e-9
#define MAX_DEPTH 64

/* ------------------------------------------------------------------------------------------ JSON */

enum { J_NULL, J_BOOL, J_NUM, J_STR, J_ARR, J_OBJ };

typedef struct jnode {
    int type;
    const char *start; /* strings: after the quote; numbers: the text */
    size_t len;
    int integral;      /* number without fraction or exponent */
    int64_t ivalue;    /* its value when integral and it fits */
    int32_t first, next, count; /* children (arrays, objects: key then value), siblings */
} jnode;

typedef struct jparser {
    const char *s, *end;
    jnode *nodes;
    int32_t used, cap;
    int depth;
} jparser;

static void j_ws(jparser *p) {
    while (p->s < p->end && (*p->s == ' ' || *p->s == '\t' || *p->s == '\n' || *p->s == '\r')) p->s++;
}

static int32_t j_new(jparser *p, int type) {
    if (p->used >= p->cap) return -1;
    jnode *n = &p->nodes[p->used];
    memset(n, 0, sizeof *n);
    n->type = type;
    n->first = n->next = -1;
    return p->used++;
}

static int j_hex(char c) {
    if (c >= '0' && c <= '9') return c - '0';
    if (c >= 'a' && c <= 'f') return c - 'a' + 10;
    if (c >= 'A' && c <= 'F') return c - 'A' + 10;
    return -1;
}

static int32_t j_value(jparser *p);

static int32_t j_string(jparser *p) {
    int32_t id = j_new(p, J_STR);
    if (id < 0) return -1;
    p->s++; /* the opening quote */
    const char *start = p->s;
    while (p->s < p->end && *p->s != '"') {
        unsigned char c = (unsigned char)*p->s;
        if (c < 0x20) return -1;
        if (c == '\\') {
            p->s++;
            if (p->s >= p->end) return -1;
            if (*p->s == 'u') {
                if (p->end - p->s < 5) return -1;
                for (int k = 1; k <= 4; ++k)
                    if (j_hex(p->s[k]) < 0) return -1;
                p->s += 4;
            } else if (!strchr("\"\\/bfnrt", *p->s)) {
                return -1;
            }
        }
        p->s++;
    }
    if (p->s >= p->end) return -1;
    p->nodes[id].start = start;
    p->nodes[id].len = (size_t)(p->s - start);
    p->s++;
    return id;
}

static int32_t j_number(jparser *p) {
    int32_t id = j_new(p, J_NUM);
    if (id < 0) return -1;
    const char *start = p->s;
    int integral = 1, negative = 0;
    int64_t value = 0;
    int fits = 1;
    if (*p->s == '-') { negative = 1; p->s++; }
    if (p->s >= p->end || *p->s < '0' || *p->s > '9') return -1;
    if (*p->s == '0' && p->s + 1 < p->end && p->s[1] >= '0' && p->s[1] <= '9') return -1;
    while (p->s < p->end && *p->s >= '0' && *p->s <= '9') {
        if (value > (INT64_MAX - 9) / 10) fits = 0; else value = value * 10 + (*p->s - '0');
        p->s++;
    }
    if (p->s < p->end && *p->s == '.') {
        integral = 0;
        p->s++;
        if (p->s >= p->end || *p->s < '0' || *p->s > '9') return -1;
        while (p->s < p->end && *p->s >= '0' && *p->s <= '9') p->s++;
    }
    if (p->s < p->end && (*p->s == 'e' || *p->s == 'E')) {
        integral = 0;
        p->s++;
        if (p->s < p->end && (*p->s == '+' || *p->s == '-')) p->s++;
        if (p->s >= p->end || *p->s < '0' || *p->s > '9') return -1;
        while (p->s < p->end && *p->s >= '0' && *p->s <= '9') p->s++;
    }
    jnode *n = &p->nodes[id];
    n->start = start;
    n->len = (size_t)(p->s - start);
    n->integral = integral && fits;
    n->ivalue = negative ? -value : value;
    return id;
}

static int32_t j_container(jparser *p, int type) {
    int32_t id = j_new(p, type);
    if (id < 0 || ++p->depth > MAX_DEPTH) return -1;
    char close = type == J_ARR ? ']' : '}';
    p->s++;
    j_ws(p);
    int32_t last = -1;
    if (p->s < p->end && *p->s == close) {
        p->s++;
        p->depth--;
        return id;
    }
    for (;;) {
        j_ws(p);
        int32_t key = -1;
        if (type == J_OBJ) {
            if (p->s >= p->end || *p->s != '"') return -1;
            key = j_string(p);
            if (key < 0) return -1;
            j_ws(p);
            if (p->s >= p->end || *p->s != ':') return -1;
            p->s++;
            j_ws(p);
        }
        int32_t value = j_value(p);
        if (value < 0) return -1;
        if (key >= 0) {
            p->nodes[key].next = value;
            if (last < 0) p->nodes[id].first = key; else p->nodes[last].next = key;
        } else {
            if (last < 0) p->nodes[id].first = value; else p->nodes[last].next = value;
        }
        last = value;
        p->nodes[id].count++;
        j_ws(p);
        if (p->s < p->end && *p->s == ',') { p->s++; continue; }
        if (p->s < p->end && *p->s == close) { p->s++; break; }
        return -1;
    }
    p->depth--;
    return id;
}

static int j_word(jparser *p, const char *word) {
    size_t n = strlen(word);
    if ((size_t)(p->end - p->s) < n || memcmp(p->s, word, n) != 0) return 0;
    p->s += n;
    return 1;
}

static int32_t j_value(jparser *p) {
    j_ws(p);
    if (p->s >= p->end) return -1;
    switch (*p->s) {
    case '{': return j_container(p, J_OBJ);
    case '[': return j_container(p, J_ARR);
    case '"': return j_string(p);
    case 't': return j_word(p, "true") ? j_new(p, J_BOOL) : -1;
    case 'f': return j_word(p, "false") ? j_new(p, J_BOOL) : -1;
    case 'n': return j_word(p, "null") ? j_new(p, J_NULL) : -1;
    default: return j_number(p);
    }
}

/* The member `key` of object `obj` (keys compared as raw text: the ones used here have no escapes). */
static const jnode *j_get(const jparser *p, const jnode *obj, const char *key) {
    if (!obj || obj->type != J_OBJ) return NULL;
    size_t n = strlen(key);
    for (int32_t k = obj->first; k >= 0; k = p->nodes[p->nodes[k].next].next) {
        const jnode *kn = &p->nodes[k];
        if (kn->len == n && memcmp(kn->start, key, n) == 0) return &p->nodes[kn->next];
    }
    return NULL;
}

static int j_int(const jnode *n, int64_t *out) {
    if (!n || n->type != J_NUM || !n->integral || n->ivalue < 0) return 0;
    *out = n->ivalue;
    return 1;
}

static void put_utf8(char **w, uint32_t c) {
    unsigned char *o = (unsigned char *)*w;
    if (c < 0x80) { *o++ = (unsigned char)c; }
    else if (c < 0x800) { *o++ = (unsigned char)(0xC0 | (c >> 6)); *o++ = (unsigned char)(0x80 | (c & 0x3F)); }
    else if (c < 0x10000) {
        *o++ = (unsigned char)(0xE0 | (c >> 12)); *o++ = (unsigned char)(0x80 | ((c >> 6) & 0x3F));
        *o++ = (unsigned char)(0x80 | (c & 0x3F));
    } else {
        *o++ = (unsigned char)(0xF0 | (c >> 18)); *o++ = (unsigned char)(0x80 | ((c >> 12) & 0x3F));
        *o++ = (unsigned char)(0x80 | ((c >> 6) & 0x3F)); *o++ = (unsigned char)(0x80 | (c & 0x3F));
    }
    *w = (char *)o;
}

/* Decode a JSON string into `out` (at least n->len + 1 bytes); 0 on a lone surrogate. */
static int j_decode(const jnode *n, char *out) {
    const char *s = n->start, *end = n->start + n->len;
    char *w = out;
    while (s < end) {
        if (*s != '\\') { *w++ = *s++; continue; }
        s++;
        char c = *s++;
        if (c == 'u') {
            uint32_t u = (uint32_t)((j_hex(s[0]) << 12) | (j_hex(s[1]) << 8) | (j_hex(s[2]) << 4) | j_hex(s[3]));
            s += 4;
            if (u >= 0xD800 && u < 0xDC00) {
                if (end - s < 6 || s[0] != '\\' || s[1] != 'u') return 0;
                uint32_t lo = (uint32_t)((j_hex(s[2]) << 12) | (j_hex(s[3]) << 8) | (j_hex(s[4]) << 4) | j_hex(s[5]));
                if (lo < 0xDC00 || lo >= 0xE000) return 0;
                s += 6;
                u = 0x10000 + ((u - 0xD800) << 10) + (lo - 0xDC00);
            } else if (u >= 0xDC00 && u < 0xE000) {
                return 0;
            }
            put_utf8(&w, u);
        } else {
            *w++ = c == 'b' ? '\b' : c == 'f' ? '\f' : c == 'n' ? '\n' : c == 'r' ? '\r' : c == 't' ? '\t' : c;
        }
    }
    *w = 0;
    return 1;
}

static int j_parse(jparser *p, const char *text, size_t size) {
    p->s = text;
    p->end = text + size;
    p->used = 0;
    p->depth = 0;
    p->cap = (int32_t)(size / 2 + 16);
    p->nodes = (jnode *)malloc((size_t)p->cap * sizeof(jnode));
    if (!p->nodes) return -2;
    int32_t root = j_value(p);
    j_ws(p);
    if (root != 0 || p->s != p->end) return -1;
    return 0;
}

/* ------------------------------------------------------------------------------------------ CRC */

static uint32_t crc32_of(const unsigned char *data, size_t size) {
    uint32_t table[256];
    for (uint32_t i = 0; i < 256; ++i) {
        uint32_t c = i;
        for (int k = 0; k < 8; ++k) c = (c & 1) ? 0xEDB88320u ^ (c >> 1) : c >> 1;
        table[i] = c;
    }
    uint32_t crc = 0xFFFFFFFFu;
    for (size_t i = 0; i < size; ++i) crc = table[(crc ^ data[i]) & 0xFF] ^ (crc >> 8);
    return crc ^ 0xFFFFFFFFu;
}

/* ------------------------------------------------------------------------------------------ data */

enum { A_SETTINGS, A_PIECE_FRAGMENT, A_PIECE_SPHERE, A_PIECE_VERTEX_OFFSETS, A_PIECE_VERTICES, A_PIECE_FACE_OFFSETS,
       A_FACE_PLANES, A_FACE_LOOP_OFFSETS, A_FACE_LOOPS, A_PIECE_TRIANGLE_OFFSETS, A_TRIANGLE_POSITIONS,
       A_TRIANGLE_NORMALS, A_TRIANGLE_UVS, A_TRIANGLE_MATERIALS, A_PATTERN_SITE_OFFSETS, A_PATTERN_SITES,
       A_CELL_NEIGHBOR_OFFSETS, A_CELL_NEIGHBORS, A_CELL_PLANES, A_BOUNDARY_PLANES, A_CELL_BOUNDARY_OFFSETS,
       A_CELL_BOUNDARY, A_COUNT };

static const struct { const char *name; int is_float; int ndim; int32_t trailing[2]; } LAYOUT[A_COUNT] = {
    {"settings", 1, 1, {0, 0}}, {"piece_fragment", 0, 1, {0, 0}}, {"piece_sphere", 1, 2, {4, 0}},
    {"piece_vertex_offsets", 0, 1, {0, 0}}, {"piece_vertices", 1, 2, {3, 0}}, {"piece_face_offsets", 0, 1, {0, 0}},
    {"face_planes", 1, 2, {4, 0}}, {"face_loop_offsets", 0, 1, {0, 0}}, {"face_loops", 0, 1, {0, 0}},
    {"piece_triangle_offsets", 0, 1, {0, 0}}, {"triangle_positions", 1, 3, {3, 3}},
    {"triangle_normals", 1, 3, {3, 3}}, {"triangle_uvs", 1, 3, {3, 2}}, {"triangle_materials", 0, 1, {0, 0}},
    {"pattern_site_offsets", 0, 1, {0, 0}}, {"pattern_sites", 1, 2, {3, 0}},
    {"cell_neighbor_offsets", 0, 1, {0, 0}}, {"cell_neighbors", 0, 1, {0, 0}}, {"cell_planes", 1, 2, {4, 0}},
    {"boundary_planes", 1, 2, {4, 0}}, {"cell_boundary_offsets", 0, 1, {0, 0}}, {"cell_boundary", 0, 1, {0, 0}},
};

struct fra_data {
    void *array[A_COUNT];  /* each a copy, 4-byte aligned */
    int32_t rows[A_COUNT]; /* first dimension */
    int32_t P, T, Q, M, interior;
    char **materials;
    double *piece_mass;    /* (P, 4): volume, centroid */
    double *piece_tri_radius; /* (P,): the farthest corner of the piece's triangles from its sphere's centre */
    double *tri_sphere;       /* (T, 4): each stored triangle's corners' mean and their largest distance to it */
    int32_t *corner_id;       /* (T, 3): each triangle corner's position among the distinct ones of its piece */
    int32_t *piece_corner_ids; /* (P,): the number of distinct corners of each piece's triangles */
    int32_t max_faces, max_vertices, max_degree, max_sites, max_corner_ids;
};

#define F32(d, a) ((const float *)(d)->array[a])
#define I32(d, a) ((const int32_t *)(d)->array[a])

const char *fra_status_string(fra_status status) {
    switch (status) {
    case FRA_OK: return "ok";
    case FRA_ERR_ARGUMENT: return "invalid argument";
    case FRA_ERR_JSON: return "invalid JSON header";
    case FRA_ERR_FORMAT: return "not a fracture-aligned file of a known version";
    case FRA_ERR_HEADER: return "invalid header entry";
    case FRA_ERR_SIZE: return "sizes do not agree";
    case FRA_ERR_CRC: return "CRC-32 mismatch";
    case FRA_ERR_DATA: return "invalid data";
    case FRA_ERR_MEMORY: return "out of memory";
    case FRA_ERR_INPUT: return "invalid hit";
    case FRA_ERR_ARENA: return "arena too small";
    case FRA_ERR_LIMIT: return "clip buffers exceeded";
    }
    return "unknown status";
}

static fra_status fail(fra_status status, char *message, size_t size, const char *text) {
    if (message && size) {
        size_t n = strlen(text);
        if (n >= size) n = size - 1;
        memcpy(message, text, n);
        message[n] = 0;
    }
    return status;
}

void fra_free(fra_data *d) {
    if (!d) return;
    for (int a = 0; a < A_COUNT; ++a) free(d->array[a]);
    if (d->materials)
        for (int32_t m = 0; m < d->M; ++m) free(d->materials[m]);
    free(d->materials);
    free(d->piece_mass);
    free(d->piece_tri_radius);
    free(d->tri_sphere);
    free(d->corner_id);
    free(d->piece_corner_ids);
    free(d);
}

static int offsets_ok(const int32_t *off, int32_t count, int32_t rows, int32_t end) {
    if (rows != count + 1 || off[0] != 0 || off[count] != end) return 0;
    for (int32_t i = 0; i < count; ++i)
        if (off[i + 1] < off[i]) return 0;
    return 1;
}

static void piece_mass(const fra_data *d, int32_t k, double out[4]);
static double dot3(const double *a, const double *b);

typedef struct corner_key {
    float x[3];
    int32_t corner; /* index into the (T * 3) corners */
} corner_key;

static int compare_corners(const void *pa, const void *pb) {
    const corner_key *a = (const corner_key *)pa, *b = (const corner_key *)pb;
    for (int c = 0; c < 3; ++c)
        if (a->x[c] != b->x[c]) return a->x[c] < b->x[c] ? -1 : 1;
    return (a->corner > b->corner) - (a->corner < b->corner);
}

/* corner_id: the triangles of a piece share corners (about six each); numbered here, the cut finds each distinct
 * corner's nearest cell once per piece instead of once per triangle. Equal positions (by value) share a number. */
static fra_status number_corners(fra_data *d) {
    const int32_t *pt = I32(d, A_PIECE_TRIANGLE_OFFSETS);
    const float *tp = F32(d, A_TRIANGLE_POSITIONS);
    size_t corners = 3 * (size_t)d->T;
    d->corner_id = (int32_t *)malloc((corners > 0 ? corners : 1) * sizeof(int32_t));
    d->piece_corner_ids = (int32_t *)malloc((size_t)d->P * sizeof(int32_t));
    corner_key *keys = (corner_key *)malloc((corners > 0 ? corners : 1) * sizeof(corner_key));
    if (!d->corner_id || !d->piece_corner_ids || !keys) { free(keys); return FRA_ERR_MEMORY; }
    d->max_corner_ids = 0;
    for (int32_t k = 0; k < d->P; ++k) {
        size_t first = 3 * (size_t)pt[k], count = 3 * (size_t)(pt[k + 1] - pt[k]);
        for (size_t i = 0; i < count; ++i) {
            memcpy(keys[i].x, tp + 3 * (first + i), sizeof keys[i].x);
            keys[i].corner = (int32_t)(first + i);
        }
        qsort(keys, count, sizeof(corner_key), compare_corners);
        int32_t ids = 0;
        for (size_t i = 0; i < count; ++i) {
            const float *x = keys[i].x, *y = i > 0 ? keys[i - 1].x : x;
            ids += x[0] != y[0] || x[1] != y[1] || x[2] != y[2];
            d->corner_id[keys[i].corner] = ids;
        }
        d->piece_corner_ids[k] = count > 0 ? ids + 1 : 0;
        if (d->piece_corner_ids[k] > d->max_corner_ids) d->max_corner_ids = d->piece_corner_ids[k];
    }
    free(keys);
    return FRA_OK;
}

static fra_status validate(fra_data *d, char *message, size_t size) {
    for (int a = 0; a < A_COUNT; ++a)
        if (LAYOUT[a].is_float) {
            int64_t n = d->rows[a];
            for (int t = 0; t < LAYOUT[a].ndim - 1; ++t) n *= LAYOUT[a].trailing[t];
            for (int64_t i = 0; i < n; ++i)
                if (!isfinite(F32(d, a)[i])) return fail(FRA_ERR_DATA, message, size, "a value is not finite");
        }
    int32_t P = d->rows[A_PIECE_FRAGMENT], Q = d->rows[A_PATTERN_SITE_OFFSETS] - 1;
    int32_t V = d->rows[A_PIECE_VERTICES], F = d->rows[A_FACE_PLANES], L = d->rows[A_FACE_LOOPS];
    int32_t T = d->rows[A_TRIANGLE_MATERIALS], S = d->rows[A_PATTERN_SITES], N = d->rows[A_CELL_NEIGHBORS];
    if (P < 1 || Q < 1) return fail(FRA_ERR_DATA, message, size, "the file needs at least one piece and one pattern");
    if (d->rows[A_SETTINGS] != 2 || !(F32(d, A_SETTINGS)[0] > 0) || !(F32(d, A_SETTINGS)[1] > 0))
        return fail(FRA_ERR_DATA, message, size, "settings must hold 2 values > 0");
    if (d->rows[A_PIECE_SPHERE] != P || d->rows[A_CELL_PLANES] != N || d->rows[A_TRIANGLE_POSITIONS] != T ||
        d->rows[A_TRIANGLE_NORMALS] != T || d->rows[A_TRIANGLE_UVS] != T)
        return fail(FRA_ERR_SIZE, message, size, "array lengths do not agree");
    if (!offsets_ok(I32(d, A_PIECE_VERTEX_OFFSETS), P, d->rows[A_PIECE_VERTEX_OFFSETS], V) ||
        !offsets_ok(I32(d, A_PIECE_FACE_OFFSETS), P, d->rows[A_PIECE_FACE_OFFSETS], F) ||
        !offsets_ok(I32(d, A_FACE_LOOP_OFFSETS), F, d->rows[A_FACE_LOOP_OFFSETS], L) ||
        !offsets_ok(I32(d, A_PIECE_TRIANGLE_OFFSETS), P, d->rows[A_PIECE_TRIANGLE_OFFSETS], T) ||
        !offsets_ok(I32(d, A_PATTERN_SITE_OFFSETS), Q, d->rows[A_PATTERN_SITE_OFFSETS], S) ||
        !offsets_ok(I32(d, A_CELL_NEIGHBOR_OFFSETS), S, d->rows[A_CELL_NEIGHBOR_OFFSETS], N))
        return fail(FRA_ERR_DATA, message, size, "an offsets array does not start at 0, grow and end at its count");
    for (int32_t t = 0; t < T; ++t)
        if (I32(d, A_TRIANGLE_MATERIALS)[t] < 0 || I32(d, A_TRIANGLE_MATERIALS)[t] >= d->M)
            return fail(FRA_ERR_DATA, message, size, "a triangle's material is out of range");
    const int32_t *pv = I32(d, A_PIECE_VERTEX_OFFSETS), *pf = I32(d, A_PIECE_FACE_OFFSETS);
    const int32_t *fl = I32(d, A_FACE_LOOP_OFFSETS), *loops = I32(d, A_FACE_LOOPS);
    d->max_faces = d->max_vertices = 0;
    for (int32_t k = 0; k < P; ++k) {
        int32_t nv = pv[k + 1] - pv[k], nf = pf[k + 1] - pf[k];
        if (I32(d, A_PIECE_FRAGMENT)[k] < 0 || !(F32(d, A_PIECE_SPHERE)[4 * k + 3] > 0))
            return fail(FRA_ERR_DATA, message, size, "piece_fragment < 0 or a piece_sphere radius not > 0");
        if (nv < 4 || nv > 255 || nf < 4)
            return fail(FRA_ERR_DATA, message, size, "a piece needs 4 to 255 vertices and at least 4 faces");
        if (nv > d->max_vertices) d->max_vertices = nv;
        if (nf > d->max_faces) d->max_faces = nf;
        for (int32_t f = pf[k]; f < pf[k + 1]; ++f) {
            if (fl[f + 1] - fl[f] < 3 || fl[f + 1] - fl[f] > 1024)
                return fail(FRA_ERR_DATA, message, size, "a face loop has fewer than 3 corners");
            for (int32_t i = fl[f]; i < fl[f + 1]; ++i)
                if (loops[i] < 0 || loops[i] >= nv)
                    return fail(FRA_ERR_DATA, message, size, "a face loop's corner is out of range");
        }
    }
    const int32_t *ps = I32(d, A_PATTERN_SITE_OFFSETS), *cn = I32(d, A_CELL_NEIGHBOR_OFFSETS);
    const float *sites = F32(d, A_PATTERN_SITES);
    d->max_degree = d->max_sites = 0;
    for (int32_t q = 0; q < Q; ++q) {
        int32_t lo = ps[q], hi = ps[q + 1];
        if (hi - lo < 1) return fail(FRA_ERR_DATA, message, size, "a pattern has no sites");
        if (hi - lo > d->max_sites) d->max_sites = hi - lo;
        for (int32_t i = lo; i < hi; ++i) {
            if (cn[i + 1] - cn[i] > d->max_degree) d->max_degree = cn[i + 1] - cn[i];
            for (int32_t e = cn[i]; e < cn[i + 1]; ++e) {
                int32_t j = I32(d, A_CELL_NEIGHBORS)[e];
                if (j < 0 || j >= hi - lo || j == i - lo)
                    return fail(FRA_ERR_DATA, message, size, "a cell's neighbour is out of range");
            }
            for (int32_t j = lo; j < i; ++j)
                if (sites[3 * i] == sites[3 * j] && sites[3 * i + 1] == sites[3 * j + 1] &&
                    sites[3 * i + 2] == sites[3 * j + 2])
                    return fail(FRA_ERR_DATA, message, size, "a pattern has two equal sites");
        }
    }
    int32_t B = d->rows[A_BOUNDARY_PLANES];
    const float *bp = F32(d, A_BOUNDARY_PLANES);
    if (B != 0 && B < 4) return fail(FRA_ERR_DATA, message, size, "boundary_planes must be none or at least 4");
    if (!offsets_ok(I32(d, A_CELL_BOUNDARY_OFFSETS), S, d->rows[A_CELL_BOUNDARY_OFFSETS], d->rows[A_CELL_BOUNDARY]))
        return fail(FRA_ERR_DATA, message, size, "cell_boundary_offsets does not start at 0, grow and end at its count");
    for (int32_t e = 0; e < d->rows[A_CELL_BOUNDARY]; ++e)
        if (I32(d, A_CELL_BOUNDARY)[e] < 0 || I32(d, A_CELL_BOUNDARY)[e] >= B)
            return fail(FRA_ERR_DATA, message, size, "a cell's boundary plane is out of range");
    for (int32_t b = 0; b < B; ++b) {
        double n[3] = {bp[4 * b], bp[4 * b + 1], bp[4 * b + 2]};
        if (fabs(sqrt((n[0] * n[0] + n[1] * n[1]) + n[2] * n[2]) - 1.0) > 1e-5)
            return fail(FRA_ERR_DATA, message, size, "a boundary plane's normal is not of unit length");
        for (int32_t i = 0; i < S; ++i) {
            double x[3] = {sites[3 * i], sites[3 * i + 1], sites[3 * i + 2]};
            if (!(dot3(n, x) < bp[4 * b + 3])) return fail(FRA_ERR_DATA, message, size, "a site lies outside the boundary");
        }
    }
    d->P = P;
    d->T = T;
    d->Q = Q;
    d->piece_mass = (double *)malloc((size_t)P * 4 * sizeof(double));
    if (!d->piece_mass) return fail(FRA_ERR_MEMORY, message, size, "out of memory");
    for (int32_t k = 0; k < P; ++k) piece_mass(d, k, d->piece_mass + 4 * k);
    d->piece_tri_radius = (double *)malloc((size_t)P * sizeof(double));
    if (!d->piece_tri_radius) return fail(FRA_ERR_MEMORY, message, size, "out of memory");
    const int32_t *pt = I32(d, A_PIECE_TRIANGLE_OFFSETS);
    const float *tp = F32(d, A_TRIANGLE_POSITIONS), *sphere = F32(d, A_PIECE_SPHERE);
    for (int32_t k = 0; k < P; ++k) {
        double R = 0;
        for (int32_t i = 9 * pt[k]; i < 9 * pt[k + 1]; i += 3) {
            double dx = (double)tp[i] - sphere[4 * k], dy = (double)tp[i + 1] - sphere[4 * k + 1];
            double dz = (double)tp[i + 2] - sphere[4 * k + 2], dd = sqrt((dx * dx + dy * dy) + dz * dz);
            if (dd > R) R = dd;
        }
        d->piece_tri_radius[k] = R;
    }
    d->tri_sphere = (double *)malloc((size_t)(T > 0 ? T : 1) * 4 * sizeof(double));
    if (!d->tri_sphere) return fail(FRA_ERR_MEMORY, message, size, "out of memory");
    for (int32_t t = 0; t < T; ++t) {
        const float *x = tp + 9 * (size_t)t;
        double *ts = d->tri_sphere + 4 * (size_t)t, R = 0;
        for (int c = 0; c < 3; ++c) ts[c] = (((double)x[c] + (double)x[3 + c]) + (double)x[6 + c]) / 3.0;
        for (int q = 0; q < 3; ++q) {
            double dx = (double)x[3 * q] - ts[0], dy = (double)x[3 * q + 1] - ts[1], dz = (double)x[3 * q + 2] - ts[2];
            double dd = sqrt((dx * dx + dy * dy) + dz * dz);
            if (dd > R) R = dd;
        }
        ts[3] = R;
    }
    if (number_corners(d) != FRA_OK) return fail(FRA_ERR_MEMORY, message, size, "out of memory");
    return FRA_OK;
}

static fra_status load_arrays(fra_data *d, const jparser *jp, const jnode *table, const unsigned char *bin,
                              size_t bin_size, char *message, size_t size) {
    for (int a = 0; a < A_COUNT; ++a) {
        const jnode *e = j_get(jp, table, LAYOUT[a].name);
        const jnode *dtype = j_get(jp, e, "dtype"), *shape = j_get(jp, e, "shape");
        int64_t offset, length, dims[3] = {0, 0, 0};
        if (!e || !dtype || dtype->type != J_STR || !shape || shape->type != J_ARR ||
            !j_int(j_get(jp, e, "byte_offset"), &offset) || !j_int(j_get(jp, e, "byte_length"), &length))
            return fail(FRA_ERR_HEADER, message, size, "an array entry is missing or malformed");
        const char *want = LAYOUT[a].is_float ? "float32" : "int32";
        if (dtype->len != strlen(want) || memcmp(dtype->start, want, dtype->len) != 0)
            return fail(FRA_ERR_HEADER, message, size, "an array has the wrong dtype");
        if (shape->count != LAYOUT[a].ndim) return fail(FRA_ERR_SIZE, message, size, "an array has the wrong rank");
        int32_t c = 0;
        for (int32_t k = shape->first; k >= 0; k = jp->nodes[k].next, ++c)
            if (!j_int(&jp->nodes[k], &dims[c]) || dims[c] > 0x3FFFFFFF)
                return fail(FRA_ERR_SIZE, message, size, "an array shape entry is not a whole number");
        for (int t = 1; t < LAYOUT[a].ndim; ++t)
            if (dims[t] != LAYOUT[a].trailing[t - 1]) return fail(FRA_ERR_SIZE, message, size, "an array has the wrong shape");
        int64_t count = dims[0];
        for (int t = 1; t < LAYOUT[a].ndim; ++t) count *= dims[t];
        if (length != 4 * count || offset % 16 != 0 || (uint64_t)offset > bin_size ||
            (uint64_t)length > bin_size - (uint64_t)offset)
            return fail(FRA_ERR_SIZE, message, size, "an array's offset or length does not fit the binary file");
        d->rows[a] = (int32_t)dims[0];
        d->array[a] = malloc(length > 0 ? (size_t)length : 4);
        if (!d->array[a]) return fail(FRA_ERR_MEMORY, message, size, "out of memory");
        /* little-endian file; this reader assumes a little-endian machine like every engine target */
        memcpy(d->array[a], bin + offset, (size_t)length);
    }
    return FRA_OK;
}

fra_status fra_load(const void *header, size_t header_size, const void *binary, size_t binary_size,
                    unsigned flags, fra_data **out, char *message, size_t message_size) {
    if (!out) return FRA_ERR_ARGUMENT;
    *out = NULL;
    if (!header || (!binary && binary_size)) return fail(FRA_ERR_ARGUMENT, message, message_size, "NULL argument");
    jparser jp;
    int parsed = j_parse(&jp, (const char *)header, header_size);
    if (parsed == -2) return fail(FRA_ERR_MEMORY, message, message_size, "out of memory");
    fra_status status = FRA_OK;
    fra_data *d = NULL;
    const jnode *root = &jp.nodes[0];
    int64_t version, byte_length, crc, interior;
    const jnode *format, *buffer, *table, *materials;
    if (parsed != 0) { status = fail(FRA_ERR_JSON, message, message_size, "the header is not valid JSON"); goto done; }
    format = j_get(&jp, root, "format");
    if (!format || format->type != J_STR || format->len != 16 || memcmp(format->start, "fracture-aligned", 16) != 0) {
        status = fail(FRA_ERR_FORMAT, message, message_size, "not a fracture-aligned file");
        goto done;
    }
    if (!j_int(j_get(&jp, root, "version"), &version) || version != FRA_FORMAT_VERSION) {
        status = fail(FRA_ERR_FORMAT, message, message_size, "fracture-aligned version not supported (this reader knows 1)");
        goto done;
    }
    buffer = j_get(&jp, root, "buffer");
    table = j_get(&jp, root, "arrays");
    materials = j_get(&jp, root, "materials");
    if (!buffer || !table || table->type != J_OBJ || !materials || materials->type != J_ARR ||
        !j_int(j_get(&jp, buffer, "byte_length"), &byte_length) ||
        !j_int(j_get(&jp, root, "interior_material"), &interior)) {
        status = fail(FRA_ERR_HEADER, message, message_size, "the header misses buffer, arrays, materials or interior_material");
        goto done;
    }
    if ((uint64_t)byte_length != binary_size) {
        status = fail(FRA_ERR_SIZE, message, message_size, "the binary file's size differs from buffer.byte_length");
        goto done;
    }
    if (j_get(&jp, buffer, "crc32") && !(flags & FRA_LOAD_SKIP_CRC)) {
        if (!j_int(j_get(&jp, buffer, "crc32"), &crc) ||
            crc32_of((const unsigned char *)binary, binary_size) != (uint32_t)crc) {
            status = fail(FRA_ERR_CRC, message, message_size, "the binary file does not match its header (crc32)");
            goto done;
        }
    }
    d = (fra_data *)calloc(1, sizeof *d);
    if (!d) { status = fail(FRA_ERR_MEMORY, message, message_size, "out of memory"); goto done; }
    d->M = materials->count;
    d->materials = (char **)calloc((size_t)(d->M > 0 ? d->M : 1), sizeof(char *));
    if (!d->materials) { status = fail(FRA_ERR_MEMORY, message, message_size, "out of memory"); goto done; }
    {
        int32_t m = 0;
        for (int32_t k = materials->first; k >= 0; k = jp.nodes[k].next, ++m) {
            const jnode *name = &jp.nodes[k];
            if (name->type != J_STR) { status = fail(FRA_ERR_HEADER, message, message_size, "a material name is not a string"); goto done; }
            d->materials[m] = (char *)malloc(name->len + 1);
            if (!d->materials[m]) { status = fail(FRA_ERR_MEMORY, message, message_size, "out of memory"); goto done; }
            if (!j_decode(name, d->materials[m])) { status = fail(FRA_ERR_JSON, message, message_size, "a lone surrogate in a material name"); goto done; }
        }
    }
    if (d->M < 1 || interior >= d->M) {
        status = fail(FRA_ERR_HEADER, message, message_size, "interior_material must index materials");
        goto done;
    }
    d->interior = (int32_t)interior;
    status = load_arrays(d, &jp, table, (const unsigned char *)binary, binary_size, message, message_size);
    if (status == FRA_OK) status = validate(d, message, message_size);
done:
    free(jp.nodes);
    if (status != FRA_OK) { fra_free(d); return status; }
    *out = d;
    return FRA_OK;
}

fra_status fra_header_uri(const void *header, size_t header_size, char *uri, size_t uri_size) {
    if (!header || !uri || uri_size == 0) return FRA_ERR_ARGUMENT;
    jparser jp;
    int parsed = j_parse(&jp, (const char *)header, header_size);
    if (parsed == -2) return FRA_ERR_MEMORY;
    fra_status status = FRA_ERR_JSON;
    if (parsed == 0) {
        const jnode *u = j_get(&jp, j_get(&jp, &jp.nodes[0], "buffer"), "uri");
        status = FRA_ERR_HEADER;
        if (u && u->type == J_STR && u->len + 1 <= uri_size && j_decode(u, uri)) {
            size_t n = strlen(uri);
            if (n > 0 && !strchr(uri, '/') && !strchr(uri, '\\') && !strchr(uri, ':') && strcmp(uri, ".") != 0 &&
                strcmp(uri, "..") != 0 && n == u->len)
                status = FRA_OK;
        }
    }
    free(jp.nodes);
    return status;
}

fra_info fra_get_info(const fra_data *d) {
    fra_info info;
    memset(&info, 0, sizeof info);
    if (!d) return info;
    info.pieces = d->P;
    info.triangles = d->T;
    info.patterns = d->Q;
    info.materials = d->M;
    info.interior_material = d->interior;
    info.uv_scale = F32(d, A_SETTINGS)[0];
    info.default_scale = F32(d, A_SETTINGS)[1];
    return info;
}

const char *fra_material_name(const fra_data *d, int32_t m) {
    return d && m >= 0 && m < d->M ? d->materials[m] : NULL;
}

int32_t fra_pattern_sites(const fra_data *d, int32_t q) {
    return d && q >= 0 && q < d->Q ? I32(d, A_PATTERN_SITE_OFFSETS)[q + 1] - I32(d, A_PATTERN_SITE_OFFSETS)[q] : 0;
}

fra_status fra_get_piece(const fra_data *d, int32_t k, fra_piece *out) {
    if (!d || !out || k < 0 || k >= d->P) return FRA_ERR_ARGUMENT;
    const int32_t *pv = I32(d, A_PIECE_VERTEX_OFFSETS), *pf = I32(d, A_PIECE_FACE_OFFSETS);
    const int32_t *pt = I32(d, A_PIECE_TRIANGLE_OFFSETS), *fl = I32(d, A_FACE_LOOP_OFFSETS);
    out->fragment = I32(d, A_PIECE_FRAGMENT)[k];
    out->vertex_count = pv[k + 1] - pv[k];
    out->vertices = F32(d, A_PIECE_VERTICES) + 3 * (size_t)pv[k];
    out->face_count = pf[k + 1] - pf[k];
    out->face_planes = F32(d, A_FACE_PLANES) + 4 * (size_t)pf[k];
    out->face_loop_offsets = fl + pf[k];
    out->face_loops = I32(d, A_FACE_LOOPS);
    out->triangle_first = pt[k];
    out->triangle_count = pt[k + 1] - pt[k];
    out->volume = d->piece_mass[4 * k];
    for (int c = 0; c < 3; ++c) out->centroid[c] = d->piece_mass[4 * k + 1 + c];
    return FRA_OK;
}

fra_triangles_view fra_triangles(const fra_data *d) {
    fra_triangles_view v;
    memset(&v, 0, sizeof v);
    if (!d) return v;
    v.count = d->T;
    v.positions = F32(d, A_TRIANGLE_POSITIONS);
    v.normals = F32(d, A_TRIANGLE_NORMALS);
    v.uvs = F32(d, A_TRIANGLE_UVS);
    v.materials = I32(d, A_TRIANGLE_MATERIALS);
    return v;
}

/* ------------------------------------------------------------------------------------ geometry */

static double dot3(const double *a, const double *b) { return (a[0] * b[0] + a[1] * b[1]) + a[2] * b[2]; }

static int smallest_axis(const double *n) {
    int axis = 0;
    if (fabs(n[1]) < fabs(n[axis])) axis = 1;
    if (fabs(n[2]) < fabs(n[axis])) axis = 2;
    return axis;
}

/* Unit axes a, b with a x b = n (docs/FORMAT.md sections 13.3-13.4). */
static void plane_basis(const double *n, double *a, double *b) {
    int axis = smallest_axis(n);
    double k = n[axis];
    double t[3] = {-(k * n[0]), -(k * n[1]), -(k * n[2])};
    t[axis] = 1.0 - k * n[axis];
    double length = sqrt((t[0] * t[0] + t[1] * t[1]) + t[2] * t[2]);
    a[0] = t[0] / length;
    a[1] = t[1] / length;
    a[2] = t[2] / length;
    b[0] = n[1] * a[2] - n[2] * a[1];
    b[1] = n[2] * a[0] - n[0] * a[2];
    b[2] = n[0] * a[1] - n[1] * a[0];
}

static void box_uv(const double *x, const double *n, double uv_scale, double *uv) {
    double ax = fabs(n[0]), ay = fabs(n[1]), az = fabs(n[2]);
    double mx = ax > ay ? ax : ay;
    if (az > mx) mx = az;
    int axis = ax >= mx - UV_AXIS_TIE ? 0 : (ay >= mx - UV_AXIS_TIE ? 1 : 2);
    double sign = n[axis] < 0 ? -1.0 : 1.0;
    static const int U[3] = {1, 0, 0}, V[3] = {2, 2, 1};
    double u = x[U[axis]] * sign * (axis == 1 ? -1.0 : 1.0);
    uv[0] = u / uv_scale;
    uv[1] = x[V[axis]] / uv_scale;
}

typedef struct poly {
    int32_t nv, nf, nl;
    double *v;         /* (vcap, 3) */
    double *plane;     /* (fcap, 4) */
    int32_t *isnew;    /* (fcap,) */
    int32_t *loop_off; /* (fcap + 1,) */
    int32_t *loops;    /* (lcap,) */
} poly;

static void poly_mass(const poly *p, double *volume, double *centroid) {
    const double *o = p->v;
    double six = 0, sx = 0, sy = 0, sz = 0;
    for (int32_t f = 0; f < p->nf; ++f) {
        const int32_t *loop = p->loops + p->loop_off[f];
        int32_t count = p->loop_off[f + 1] - p->loop_off[f];
        const double *p0 = p->v + 3 * loop[0];
        double a[3] = {p0[0] - o[0], p0[1] - o[1], p0[2] - o[2]};
        for (int32_t q = 1; q + 1 < count; ++q) {
            const double *p1 = p->v + 3 * loop[q], *p2 = p->v + 3 * loop[q + 1];
            double b[3] = {p1[0] - o[0], p1[1] - o[1], p1[2] - o[2]};
            double c[3] = {p2[0] - o[0], p2[1] - o[1], p2[2] - o[2]};
            double det = (a[0] * (b[1] * c[2] - b[2] * c[1]) + a[1] * (b[2] * c[0] - b[0] * c[2])) +
                         a[2] * (b[0] * c[1] - b[1] * c[0]);
            six += det;
            sx += det * ((a[0] + b[0]) + c[0]);
            sy += det * ((a[1] + b[1]) + c[1]);
            sz += det * ((a[2] + b[2]) + c[2]);
        }
    }
    *volume = six / 6.0;
    if (six == 0.0) {
        *volume = 0.0;
        centroid[0] = o[0]; centroid[1] = o[1]; centroid[2] = o[2];
        return;
    }
    double quad = 4.0 * six;
    centroid[0] = o[0] + sx / quad;
    centroid[1] = o[1] + sy / quad;
    centroid[2] = o[2] + sz / quad;
}

/* The stored piece k as a polyhedron in doubles (into buffers large enough). */
static void piece_poly(const fra_data *d, int32_t k, poly *p) {
    const int32_t *pv = I32(d, A_PIECE_VERTEX_OFFSETS), *pf = I32(d, A_PIECE_FACE_OFFSETS);
    const int32_t *fl = I32(d, A_FACE_LOOP_OFFSETS), *loops = I32(d, A_FACE_LOOPS);
    const float *v = F32(d, A_PIECE_VERTICES), *planes = F32(d, A_FACE_PLANES);
    p->nv = pv[k + 1] - pv[k];
    p->nf = pf[k + 1] - pf[k];
    for (int32_t i = 0; i < 3 * p->nv; ++i) p->v[i] = v[3 * (size_t)pv[k] + (size_t)i];
    p->nl = 0;
    p->loop_off[0] = 0;
    for (int32_t f = 0; f < p->nf; ++f) {
        for (int c = 0; c < 4; ++c) p->plane[4 * f + c] = planes[4 * (size_t)(pf[k] + f) + (size_t)c];
        p->isnew[f] = 0;
        for (int32_t i = fl[pf[k] + f]; i < fl[pf[k] + f + 1]; ++i) p->loops[p->nl++] = loops[i];
        p->loop_off[f + 1] = p->nl;
    }
}

static void piece_mass(const fra_data *d, int32_t k, double out[4]) {
    const int32_t *pv = I32(d, A_PIECE_VERTEX_OFFSETS), *pf = I32(d, A_PIECE_FACE_OFFSETS);
    const int32_t *fl = I32(d, A_FACE_LOOP_OFFSETS);
    int32_t nv = pv[k + 1] - pv[k], nf = pf[k + 1] - pf[k], nl = fl[pf[k + 1]] - fl[pf[k]];
    poly p;
    p.v = (double *)malloc(sizeof(double) * 3 * (size_t)nv);
    p.plane = (double *)malloc(sizeof(double) * 4 * (size_t)nf);
    p.isnew = (int32_t *)malloc(sizeof(int32_t) * (size_t)nf);
    p.loop_off = (int32_t *)malloc(sizeof(int32_t) * (size_t)(nf + 1));
    p.loops = (int32_t *)malloc(sizeof(int32_t) * (size_t)nl);
    out[0] = out[1] = out[2] = out[3] = 0;
    if (p.v && p.plane && p.isnew && p.loop_off && p.loops) {
        piece_poly(d, k, &p);
        poly_mass(&p, out, out + 1);
    }
    free(p.v); free(p.plane); free(p.isnew); free(p.loop_off); free(p.loops);
}

/* ------------------------------------------------------------------------------------------ arena */

typedef struct arena {
    unsigned char *base;
    size_t low, high; /* [low, high) is free */
} arena;

static void *take_low(arena *a, size_t bytes) {
    size_t start = (a->low + 15) & ~(size_t)15;
    if (start > a->high || bytes > a->high - start) return NULL;
    a->low = start + bytes;
    return a->base + start;
}

typedef struct work {
    int32_t vcap, fcap, lcap, ccap;
    poly buf[3];        /* base, and two to clip back and forth */
    double *dist;
    int32_t *side, *renumber, *used, *points, *cross; /* cross: (lcap, 3) hi, next record, new index */
    int32_t *cross_head; /* (vcap,) per lower corner, its first crossing record (-1: none) */
    double *keys;       /* (vcap, 3): x, y, index */
    double *corners[2]; /* (ccap, 8) polygon corners */
    double *cdist;      /* (ccap,) */
    int32_t *cside;     /* (ccap,) */
} work;

static int alloc_poly(arena *a, poly *p, int32_t vcap, int32_t fcap, int32_t lcap) {
    p->v = (double *)take_low(a, sizeof(double) * 3 * (size_t)vcap);
    p->plane = (double *)take_low(a, sizeof(double) * 4 * (size_t)fcap);
    p->isnew = (int32_t *)take_low(a, sizeof(int32_t) * (size_t)fcap);
    p->loop_off = (int32_t *)take_low(a, sizeof(int32_t) * (size_t)(fcap + 1));
    p->loops = (int32_t *)take_low(a, sizeof(int32_t) * (size_t)lcap);
    return p->v && p->plane && p->isnew && p->loop_off && p->loops;
}

/* ------------------------------------------------------------------------------------------ clip */

static int before(const double *p, const double *q) {
    int hp = (p[1] < 0.0 || (p[1] == 0.0 && p[0] < 0.0)) ? 1 : 0;
    int hq = (q[1] < 0.0 || (q[1] == 0.0 && q[0] < 0.0)) ? 1 : 0;
    if (hp != hq) return hp < hq;
    double cross = p[0] * q[1] - p[1] * q[0];
    if (cross != 0.0) return cross > 0.0;
    double dp = p[0] * p[0] + p[1] * p[1], dq = q[0] * q[0] + q[1] * q[1];
    if (dp != dq) return dp < dq;
    return p[2] < q[2];
}

enum { CLIP_SAME = 0, CLIP_EMPTY = 1, CLIP_DONE = 2, CLIP_OVERFLOW = -1 };

/* The part of `src` where n . x - h <= 0, into `dst` (docs/FORMAT.md sections 13.3-13.4; aligned_clip.py). */
/* The crossing of edge (a, b) of a clip, made once per edge from its lower corner lo to the higher hi (the
 * crossings made at lo are a list from cross_head[lo]); returns its new corner's index, -1 when out of room. */
static int32_t clip_crossing(const double *sv, const double *dist, int32_t *cross, int32_t *cross_head, double *dv,
                             int32_t a, int32_t b, int32_t *nv, int32_t *ncross, int32_t vcap, int32_t lcap) {
    int32_t lo = a < b ? a : b, hi = a < b ? b : a;
    for (int32_t c = cross_head[lo]; c >= 0; c = cross[3 * c + 1])
        if (cross[3 * c] == hi) return cross[3 * c + 2];
    if (*nv >= vcap || *ncross >= lcap) return -1;
    const double *x = sv + 3 * lo, *y = sv + 3 * hi;
    double t_cut = dist[lo] / (dist[lo] - dist[hi]);
    int32_t index = (*nv)++;
    dv[3 * index] = x[0] + (y[0] - x[0]) * t_cut;
    dv[3 * index + 1] = x[1] + (y[1] - x[1]) * t_cut;
    dv[3 * index + 2] = x[2] + (y[2] - x[2]) * t_cut;
    int32_t record = (*ncross)++;
    cross[3 * record] = hi;
    cross[3 * record + 1] = cross_head[lo];
    cross[3 * record + 2] = index;
    cross_head[lo] = record;
    return index;
}

/* `axes`, when the caller keeps the plane's cap axes across clips: 7 doubles, a flag (0 until found), then the axes a
 * and b of plane_basis; NULL: found for this clip alone. */
static int clip_poly(work *w, const poly *src, poly *dst, const double *plane, double *axes, double eps) {
    /* the arrays as restrict locals: a store through one no longer makes the compiler reload the others */
    const double *restrict sv = src->v, *restrict splane = src->plane;
    const int32_t *restrict sloops = src->loops, *restrict soff = src->loop_off, *restrict sisnew = src->isnew;
    double *restrict dv = dst->v, *restrict dplane = dst->plane, *restrict dist = w->dist;
    int32_t *restrict dloops = dst->loops, *restrict doff = dst->loop_off, *restrict disnew = dst->isnew;
    int32_t *restrict side = w->side, *restrict renumber = w->renumber, *restrict used = w->used;
    int32_t *restrict cross = w->cross, *restrict cross_head = w->cross_head, *restrict points = w->points;
    const int32_t snv = src->nv, snf = src->nf, vcap = w->vcap, fcap = w->fcap, lcap = w->lcap;
    const double n0 = plane[0], n1 = plane[1], n2 = plane[2], h = plane[3];
    int32_t first_beyond = 0; /* a quick pass first: about half the clips leave the polyhedron unchanged */
    while (first_beyond < snv) {
        const double *x = sv + 3 * first_beyond;
        if (((n0 * x[0] + n1 * x[1]) + n2 * x[2]) - h > eps) break;
        first_beyond++;
    }
    if (first_beyond == snv) return CLIP_SAME;
    /* A corner lies beyond: the distances, sides and kept corners in one pass, without a branch (a dropped corner
     * is copied and then overwritten). All for nothing only when nothing is left (no corner of side -1): rare. */
    int minus = 0, zero = 0;
    int32_t nv = 0, ncross = 0;
    for (int32_t i = 0; i < snv; ++i) {
        const double *x = sv + 3 * i;
        double s = ((n0 * x[0] + n1 * x[1]) + n2 * x[2]) - h;
        int above = s > eps, below = s < -eps;
        dist[i] = s;
        side[i] = above - below;
        minus |= below;
        zero |= above == below;
        cross_head[i] = -1;
        renumber[i] = above ? -1 : nv;
        dv[3 * nv] = x[0];
        dv[3 * nv + 1] = x[1];
        dv[3 * nv + 2] = x[2];
        nv += !above;
    }
    if (!minus) return CLIP_EMPTY;
    int32_t kept_vertices = nv, nf = 0, nl = 0, dropped = 0;
    doff[0] = 0;
    for (int32_t f = 0; f < snf; ++f) {
        const int32_t *loop = sloops + soff[f];
        int32_t count = soff[f + 1] - soff[f], start = nl;
        if (nf + 2 > fcap) return CLIP_OVERFLOW;
        int tight = nl + 2 * count > lcap; /* each edge adds two entries at most: else no check per edge */
        if (!tight) { /* most faces have no corner beyond: their corners renumbered, in one pass without branches */
            int32_t any = 0, all = -1;
            for (int32_t t = 0; t < count; ++t) {
                int32_t r = renumber[loop[t]];
                dloops[nl + t] = r;
                any |= r; /* negative when a corner is dropped (side 1) */
                all &= r; /* negative when every corner is */
            }
            if (all < 0) continue; /* wholly beyond: dropped, and no crossing made */
            if (any >= 0) {
                nl += count;
                memcpy(dplane + 4 * nf, splane + 4 * f, 4 * sizeof(double));
                disnew[nf] = sisnew[f];
                doff[++nf] = nl;
                continue;
            }
        }
        int32_t crossings_before = ncross;
        for (int32_t t = 0; t < count; ++t) { /* the edges (loop[t], loop[t + 1]) in loop order, the closing one last */
            int32_t a = loop[t], b = loop[t + 1 < count ? t + 1 : 0], sa = side[a];
            if (tight && nl + 2 > lcap) return CLIP_OVERFLOW;
            dloops[nl] = renumber[a]; /* kept when its side is <= 0 (written either way: no branch) */
            nl += sa <= 0;
            if (sa * side[b] == -1) {
                int32_t index = clip_crossing(sv, dist, cross, cross_head, dv, a, b, &nv, &ncross, vcap, lcap);
                if (index < 0) return CLIP_OVERFLOW;
                dloops[nl++] = index;
            }
        }
        if (nl - start >= 3) {
            memcpy(dplane + 4 * nf, splane + 4 * f, 4 * sizeof(double));
            disnew[nf] = sisnew[f];
            doff[++nf] = nl;
        } else {
            dropped |= ncross > crossings_before; /* (a face with crossings is never dropped: checked all the same) */
            nl = start;
        }
    }
    /* The cap's corners: those of side 0 that a kept face uses, then the crossings that one uses. Without a corner
     * of side 0, and unless a dropped face made a crossing (it cannot: a face with one has a corner of side -1 and
     * two crossings), that is every crossing. */
    int32_t npoints = 0;
    if (zero || dropped) {
        for (int32_t i = 0; i < nv; ++i) used[i] = 0;
        for (int32_t i = 0; i < nl; ++i) used[dloops[i]] = 1;
        for (int32_t i = 0; i < snv; ++i)
            if (side[i] == 0 && used[renumber[i]]) points[npoints++] = renumber[i];
        for (int32_t i = kept_vertices; i < nv; ++i)
            if (used[i]) points[npoints++] = i;
    } else {
        for (int32_t i = kept_vertices; i < nv; ++i) points[npoints++] = i;
    }
    dst->nv = nv;
    if (npoints >= 3) {
        if (nl + npoints > lcap) return CLIP_OVERFLOW;
        double cx = 0, cy = 0, cz = 0, own[7];
        double *restrict keys = w->keys;
        for (int32_t i = 0; i < npoints; ++i) {
            const double *x = dv + 3 * points[i];
            cx = cx + x[0]; cy = cy + x[1]; cz = cz + x[2];
        }
        cx = cx / npoints; cy = cy / npoints; cz = cz / npoints;
        if (!axes) { /* nowhere to keep them: found for this clip only */
            own[0] = 0.0;
            axes = own;
        }
        if (axes[0] == 0.0) {
            plane_basis(plane, axes + 1, axes + 4);
            axes[0] = 1.0;
        }
        const double *a = axes + 1, *b = axes + 4;
        for (int32_t i = 0; i < npoints; ++i) {
            const double *x = dv + 3 * points[i];
            double dd[3] = {x[0] - cx, x[1] - cy, x[2] - cz};
            double *key = keys + 3 * i;
            key[0] = dot3(dd, a);
            key[1] = dot3(dd, b);
            key[2] = (double)points[i];
        }
        for (int32_t j = 1; j < npoints; ++j) {
            double item[3] = {keys[3 * j], keys[3 * j + 1], keys[3 * j + 2]};
            int32_t k = j - 1;
            while (k >= 0 && before(item, keys + 3 * k)) {
                memcpy(keys + 3 * (k + 1), keys + 3 * k, 3 * sizeof(double));
                k--;
            }
            memcpy(keys + 3 * (k + 1), item, 3 * sizeof(double));
        }
        for (int32_t i = 0; i < npoints; ++i) dloops[nl++] = (int32_t)keys[3 * i + 2];
        memcpy(dplane + 4 * nf, plane, 4 * sizeof(double));
        disnew[nf] = 1;
        doff[++nf] = nl;
    }
    dst->nf = nf;
    dst->nl = nl;
    return CLIP_DONE;
}

/* Sutherland-Hodgman of a convex polygon (`count` corners of 8 values) by the plane (n, h), into both sides at once:
 * `near` the part where n . x - h <= 0, `far` the part where -n . x + h <= 0 (the clip by the flipped plane, whose
 * distances are the exact negations: IEEE rounding is symmetric, so the sides swap and each crossing is the same
 * point, made once from the edge's first corner in loop order). Each count: the number of corners, 0 when nothing is
 * left, -2 when nothing lies beyond (the polygon unchanged, not copied); returns -1 when a buffer is too small. With
 * `tags`, each copied corner's tag goes along (-1 where it equals `drop_near` or `drop_far`; -1 for crossings). */
static int clip_both(const work *w, const double *in, const int32_t *tags, int32_t count, const double *plane,
                     double eps, double *near, int32_t *near_tags, int32_t drop_near, int32_t *nnear, double *far,
                     int32_t *far_tags, int32_t drop_far, int32_t *nfar) {
    int plus = 0, minus = 0;
    double *dist = w->cdist;
    int32_t *side = w->cside;
    if (count > w->ccap) return -1;
    for (int32_t i = 0; i < count; ++i) {
        dist[i] = dot3(plane, in + 8 * i) - plane[3];
        side[i] = dist[i] > eps ? 1 : (dist[i] < -eps ? -1 : 0);
        plus |= side[i] == 1;
        minus |= side[i] == -1;
    }
    if (!plus || !minus) { /* one side unchanged, the other empty (both unchanged when every corner is on the plane) */
        *nnear = plus ? 0 : -2;
        *nfar = minus ? 0 : -2;
        if (tags) {
            for (int32_t i = 0; i < count; ++i) {
                near_tags[i] = tags[i] == drop_near ? -1 : tags[i];
                far_tags[i] = tags[i] == drop_far ? -1 : tags[i];
            }
        }
        return 0;
    }
    int32_t n = 0, m = 0;
    for (int32_t t = 0; t < count; ++t) {
        int32_t u = t + 1 < count ? t + 1 : 0;
        if (n + 2 > w->ccap || m + 2 > w->ccap) return -1;
        if (side[t] <= 0) {
            memcpy(near + 8 * n, in + 8 * t, 8 * sizeof(double));
            if (tags) near_tags[n] = tags[t] == drop_near ? -1 : tags[t];
            n++;
        }
        if (side[t] >= 0) {
            memcpy(far + 8 * m, in + 8 * t, 8 * sizeof(double));
            if (tags) far_tags[m] = tags[t] == drop_far ? -1 : tags[t];
            m++;
        }
        if (side[t] * side[u] == -1) {
            const double *a = in + 8 * t, *b = in + 8 * u;
            double weight = dist[t] / (dist[t] - dist[u]);
            double *p = near + 8 * n;
            for (int c = 0; c < 8; ++c) p[c] = a[c] + (b[c] - a[c]) * weight;
            double length = sqrt((p[3] * p[3] + p[4] * p[4]) + p[5] * p[5]);
            if (length > 0.0) {
                p[3] = p[3] / length;
                p[4] = p[4] / length;
                p[5] = p[5] / length;
            }
            memcpy(far + 8 * m, p, 8 * sizeof(double));
            if (tags) near_tags[n] = far_tags[m] = -1;
            n++;
            m++;
        }
    }
    *nnear = n;
    *nfar = m;
    return 0;
}

/* ------------------------------------------------------------------------------------------ cut */

typedef struct part_record {
    int32_t cell, piece, whole, nv, nf, nl;
    int64_t size; /* bytes of the record, this header included */
    double volume, centroid[3];
} part_record; /* then v (nv, 3), plane (nf, 4) doubles, isnew (nf), loop_off (nf + 1), loops (nl) int32 */

typedef struct hit {
    const fra_data *d;
    arena *a;
    work *w;
    int32_t S;
    double *sites;   /* (S, 3) placed */
    const int32_t *nb_off, *nb; /* neighbours of the pattern's cells (offsets relative to the pattern) */
    double *planes;  /* (N, 4): the bisector of each neighbour entry */
    double *axes;    /* (N, 7): a flag, then its cap axes for clip_poly once found (most are used by many pieces) */
    double *split;       /* the split stack of split_polygon: corners */
    size_t split_used, split_cap;
    int32_t *split_tags;  /* the corners' nearest cells (one per corner of `split`: at split_used / 8) */
    int32_t *split_cells; /* and candidate cells */
    size_t split_cells_used, split_cells_cap;
    int32_t B;           /* boundary planes */
    double *boundary;    /* (B, 4) placed */
    double *ts;          /* (B,) the piece's centre against each */
    int32_t *near_walls; /* (B,) those that may cut the piece's triangles */
    int32_t *cand, *inner;
    const int32_t *wall_off, *walls; /* per cell (offsets relative to the pattern), its boundary planes */
    double *tri_a, *tri_b, *tri_c; /* (ccap, 8) polygon buffers for the triangles */
    int32_t *tri_tags;             /* (ccap,) their corners' nearest cells for split_polygon */
    int32_t *corner_tags;          /* (max_corner_ids,) the nearest kept cell of each corner of the piece (-1: not yet) */
    int32_t *cells, *kept; /* cells: the triangles made in each cell so far */
    double *dists;
    unsigned char *parts_begin;
    size_t tri_count;
    int32_t outer_tris;  /* the triangles made in the rest of the object so far */
    int overflow, limit;
} hit;

static void bisector(const double *wi, const double *wj, double *plane, int *bad) {
    double n[3] = {wj[0] - wi[0], wj[1] - wi[1], wj[2] - wi[2]};
    double length = sqrt((n[0] * n[0] + n[1] * n[1]) + n[2] * n[2]);
    if (length == 0.0) {
        *bad = 1;
        plane[0] = plane[1] = plane[2] = plane[3] = 0.0;
        return;
    }
    double unit[3] = {n[0] / length, n[1] / length, n[2] / length};
    double mid[3] = {(wi[0] + wj[0]) * 0.5, (wi[1] + wj[1]) * 0.5, (wi[2] + wj[2]) * 0.5};
    plane[0] = unit[0];
    plane[1] = unit[1];
    plane[2] = unit[2];
    plane[3] = dot3(unit, mid);
}

static int32_t nearest(const hit *h, const double *x, const int32_t *cells, int32_t count) {
    int32_t best = cells[0];
    double best_d = INFINITY;
    for (int32_t k = 0; k < count; ++k) {
        const double *w = h->sites + 3 * cells[k];
        double dx = x[0] - w[0], dy = x[1] - w[1], dz = x[2] - w[2];
        double dd = (dx * dx + dy * dy) + dz * dz;
        if (dd < best_d) { best = cells[k]; best_d = dd; }
    }
    return best;
}

static part_record *push_part(hit *h, int32_t cell, int32_t piece, int whole, const poly *p, double volume,
                              const double *centroid) {
    int32_t nv = whole ? 0 : p->nv, nf = whole ? 0 : p->nf, nl = whole ? 0 : p->nl;
    size_t bytes = sizeof(part_record) + sizeof(double) * (3 * (size_t)nv + 4 * (size_t)nf) +
                   sizeof(int32_t) * ((size_t)nf + (size_t)nf + 1 + (size_t)nl);
    bytes = (bytes + 15) & ~(size_t)15;
    size_t start = h->a->low;
    if (bytes > h->a->high - start) { h->overflow = 1; return NULL; }
    part_record *r = (part_record *)(h->a->base + start);
    h->a->low = start + bytes;
    r->cell = cell; r->piece = piece; r->whole = whole; r->nv = nv; r->nf = nf; r->nl = nl;
    r->size = (int64_t)bytes;
    r->volume = volume;
    r->centroid[0] = centroid[0]; r->centroid[1] = centroid[1]; r->centroid[2] = centroid[2];
    if (!whole) {
        double *v = (double *)(r + 1), *pl = v + 3 * nv;
        int32_t *isnew = (int32_t *)(pl + 4 * nf), *off = isnew + nf, *loops = off + nf + 1;
        memcpy(v, p->v, sizeof(double) * 3 * (size_t)nv);
        memcpy(pl, p->plane, sizeof(double) * 4 * (size_t)nf);
        memcpy(isnew, p->isnew, sizeof(int32_t) * (size_t)nf);
        memcpy(off, p->loop_off, sizeof(int32_t) * (size_t)(nf + 1));
        memcpy(loops, p->loops, sizeof(int32_t) * (size_t)nl);
    }
    return r;
}

static void push_whole(hit *h, int32_t cell, int32_t piece) {
    const double *m = h->d->piece_mass + 4 * piece;
    push_part(h, cell, piece, 1, NULL, m[0], m + 1);
}

static void push_triangle(hit *h, int32_t cell, int32_t material, const double *a, const double *b, const double *c) {
    size_t need = sizeof(fra_triangle);
    if (h->a->high < h->a->low + need) { h->overflow = 1; return; }
    h->a->high -= need;
    fra_triangle *t = (fra_triangle *)(h->a->base + h->a->high);
    memcpy(t->corner[0], a, 8 * sizeof(double));
    memcpy(t->corner[1], b, 8 * sizeof(double));
    memcpy(t->corner[2], c, 8 * sizeof(double));
    t->material = material;
    t->fragment = cell; /* the cell until the fragments are numbered */
    h->tri_count++;
    if (cell < h->S) h->cells[cell]++; else h->outer_tris++;
}

static void push_polygon(hit *h, int32_t cell, int32_t material, const double *corners, int32_t count) {
    for (int32_t q = 1; q + 1 < count; ++q)
        push_triangle(h, cell, material, corners, corners + 8 * q, corners + 8 * (q + 1));
}

/* `src` clipped by planes (4 doubles each) in order, skipping those the piece's sphere lies inside; `axes`: 7 doubles
 * per plane for clip_poly, or NULL. Returns the result (src itself, or a work buffer other than src) or NULL when
 * nothing is left. */
static const poly *clip_by(hit *h, const poly *src, const double *planes, double *axes, int32_t count,
                           const double *c, double r, double eps) {
    work *w = h->w;
    const poly *cur = src;
    for (int32_t e = 0; e < count; ++e) {
        const double *plane = planes + 4 * e;
        if (dot3(plane, c) - plane[3] < -r) continue;
        poly *next = cur == &w->buf[1] ? &w->buf[2] : &w->buf[1];
        int res = clip_poly(w, cur, next, plane, axes ? axes + 7 * e : NULL, eps);
        if (res == CLIP_OVERFLOW) { h->limit = 1; return NULL; }
        if (res == CLIP_EMPTY) return NULL;
        if (res == CLIP_DONE) cur = next;
    }
    return cur;
}

static int push_kept(hit *h, int32_t cell, int32_t k, const poly *p, double keep, int32_t *nrec) {
    double volume, centroid[3];
    poly_mass(p, &volume, centroid);
    if (volume > keep) {
        if (!push_part(h, cell, k, 0, p, volume, centroid)) return 0;
        (*nrec)++;
    }
    return 1;
}

/* A convex polygon into the Voronoi cells of `cells`' sites (docs/FORMAT.md section 13.4, step 7): whole when
 * every corner has the same nearest site, else split by the bisector of the cells of corner 0 and of the first
 * other corner, each side going on without the other cell. Buffers come from the hit's split stack.
 * `tags[q]`: corner q's nearest cell among `cells` when already known, else -1 (found here when needed). A corner
 * copied to a side keeps its tag unless it was the cell that side goes on without (the nearest of a list is
 * still the nearest of the list without another of its cells: the same answer as finding it again). */
static void split_polygon(hit *h, const double *polygon, int32_t *tags, int32_t count, const int32_t *cells,
                          int32_t ncells, double eps, int32_t material) {
    if (tags[0] < 0) tags[0] = nearest(h, polygon, cells, ncells);
    int32_t first = tags[0], other = -1;
    for (int32_t q = 1; q < count && other < 0; ++q) {
        if (tags[q] < 0) tags[q] = nearest(h, polygon + 8 * q, cells, ncells);
        if (tags[q] != first) other = tags[q];
    }
    if (other < 0) { push_polygon(h, first, material, polygon, count); return; }
    size_t mark_d = h->split_used, mark_i = h->split_cells_used, corners = 2 * (size_t)count + 2;
    if (h->split_used + 2 * 8 * corners > h->split_cap || h->split_cells_used + 2 * (size_t)ncells > h->split_cells_cap) {
        h->limit = 1;
        return;
    }
    double *near = h->split + h->split_used, *far = near + 8 * corners;
    int32_t *near_tags = h->split_tags + h->split_used / 8, *far_tags = near_tags + corners;
    int32_t *near_cells = h->split_cells + h->split_cells_used, *far_cells = near_cells + ncells;
    h->split_used += 2 * 8 * corners;
    h->split_cells_used += 2 * (size_t)ncells;
    double plane[4];
    int bad = 0;
    bisector(h->sites + 3 * first, h->sites + 3 * other, plane, &bad);
    int32_t nnear, nfar;
    if (clip_both(h->w, polygon, tags, count, plane, eps, near, near_tags, other, &nnear, far, far_tags, first,
                  &nfar) < 0) {
        h->limit = 1;
        return;
    }
    const double *near_poly = nnear == -2 ? polygon : near;
    if (nnear == -2) nnear = count;
    const double *far_poly = nfar == -2 ? polygon : far;
    if (nfar == -2) nfar = count;
    int32_t nn = 0, nf = 0;
    for (int32_t k = 0; k < ncells; ++k) {
        if (cells[k] != other) near_cells[nn++] = cells[k];
        if (cells[k] != first) far_cells[nf++] = cells[k];
    }
    if (nnear >= 3) split_polygon(h, near_poly, near_tags, nnear, near_cells, nn, eps, material);
    if (nfar >= 3 && !h->limit) split_polygon(h, far_poly, far_tags, nfar, far_cells, nf, eps, material);
    h->split_used = mark_d;
    h->split_cells_used = mark_i;
}

/* Piece k against the placed pattern (docs/FORMAT.md section 13.4). */
static void cut_piece(hit *h, int32_t k) {
    const fra_data *d = h->d;
    work *w = h->w;
    const float *sphere = F32(d, A_PIECE_SPHERE) + 4 * (size_t)k;
    double c[3] = {sphere[0], sphere[1], sphere[2]}, r = sphere[3];
    int32_t outer = h->S, B = h->B, straddle = 0;
    for (int32_t b = 0; b < B; ++b) {
        double t = dot3(h->boundary + 4 * b, c) - h->boundary[4 * b + 3];
        h->ts[b] = t;
        if (t > r) { push_whole(h, outer, k); return; }
        if (t >= -r) straddle = 1;
    }
    double best = INFINITY;
    for (int32_t i = 0; i < h->S; ++i) {
        const double *s = h->sites + 3 * i;
        double dx = c[0] - s[0], dy = c[1] - s[1], dz = c[2] - s[2];
        h->dists[i] = sqrt((dx * dx + dy * dy) + dz * dz);
        if (h->dists[i] < best) best = h->dists[i];
    }
    double bound = best + 2.0 * r;
    int32_t ncells = 0;
    for (int32_t i = 0; i < h->S; ++i)
        if (h->dists[i] <= bound) h->cand[ncells++] = i;
    const int32_t *pv = I32(d, A_PIECE_VERTEX_OFFSETS);
    const float *pvx = F32(d, A_PIECE_VERTICES) + 3 * (size_t)pv[k];
    int32_t nvert = pv[k + 1] - pv[k];
    if (!straddle) {
        if (ncells > 1) {
            double x[3] = {pvx[0], pvx[1], pvx[2]};
            int32_t first = nearest(h, x, h->cand, ncells), same = 1;
            for (int32_t i = 1; i < nvert && same; ++i) {
                double y[3] = {pvx[3 * i], pvx[3 * i + 1], pvx[3 * i + 2]};
                same = nearest(h, y, h->cand, ncells) == first;
            }
            if (same) { h->cand[0] = first; ncells = 1; }
        }
        if (ncells == 1) { push_whole(h, h->cand[0], k); return; }
    }
    double eps = EPS_RELATIVE * r, keep = KEEP_RELATIVE * d->piece_mass[4 * k];
    poly *base = &w->buf[0];
    piece_poly(d, k, base);
    unsigned char *record_start = h->a->base + h->a->low;
    size_t low_before = h->a->low;
    int32_t nrec = 0, nkept = 0, has_outer = 0, witness = 0; /* witness: a corner inside the last plane tested */
    for (int32_t n = 0; n < ncells; ++n) {
        int32_t i = h->cand[n], empty = 0;
        const double *planes = h->planes + 4 * h->nb_off[i];
        int32_t nplanes = h->nb_off[i + 1] - h->nb_off[i];
        for (int32_t e = 0; e < nplanes && !empty; ++e) empty = dot3(planes + 4 * e, c) - planes[4 * e + 3] > r;
        for (int32_t e = 0; e < nplanes && !empty; ++e) { /* or every corner lies beyond a plane */
            const double *plane = planes + 4 * e;
            if (dot3(plane, base->v + 3 * witness) - plane[3] <= eps) continue; /* the last corner found inside */
            empty = 1;
            for (int32_t v = 0; v < base->nv && empty; ++v)
                if (v != witness && dot3(plane, base->v + 3 * v) - plane[3] <= eps) { witness = v; empty = 0; }
        }
        if (empty) continue;
        const poly *cur = clip_by(h, base, planes, h->axes + 7 * h->nb_off[i], nplanes, c, r, eps);
        for (int32_t e = h->wall_off[i]; cur && straddle && e < h->wall_off[i + 1]; ++e)
            cur = clip_by(h, cur, h->boundary + 4 * h->walls[e], NULL, 1, c, r, eps); /* the boundary planes of cell i */
        if (h->limit) return;
        if (cur) {
            int32_t before_count = nrec;
            if (!push_kept(h, i, k, cur, keep, &nrec)) return;
            if (nrec > before_count) h->kept[nkept++] = i;
        }
    }
    if (straddle) { /* the parts beyond each boundary plane in turn: the rest of the object */
        const poly *cur = base;
        for (int32_t b = 0; b < B; ++b) {
            if (h->ts[b] < -r) continue;
            const double *plane = h->boundary + 4 * b;
            double flipped[4] = {-plane[0], -plane[1], -plane[2], -plane[3]};
            poly *next = cur == &w->buf[1] ? &w->buf[2] : &w->buf[1];
            int res = clip_poly(w, cur, next, flipped, NULL, eps);
            if (res == CLIP_OVERFLOW) { h->limit = 1; return; }
            if (res != CLIP_EMPTY) {
                int32_t before_count = nrec;
                if (!push_kept(h, outer, k, res == CLIP_SAME ? cur : next, keep, &nrec)) return;
                if (nrec > before_count) has_outer = 1;
            }
            res = clip_poly(w, cur, next, plane, NULL, eps); /* `next` is free again: what lay beyond is recorded */
            if (res == CLIP_OVERFLOW) { h->limit = 1; return; }
            if (res == CLIP_EMPTY) break;
            if (res == CLIP_DONE) cur = next;
        }
    }
    if (nrec <= 1) {
        int32_t cell;
        if (nrec == 1) {
            cell = ((part_record *)record_start)->cell;
        } else {
            double x[3] = {pvx[0], pvx[1], pvx[2]};
            cell = nearest(h, x, h->cand, ncells);
        }
        h->a->low = low_before;
        push_whole(h, cell, k);
        return;
    }
    /* the piece's triangles: beyond the boundary to the rest, inside it cut along the kept cells */
    const int32_t *pt = I32(d, A_PIECE_TRIANGLE_OFFSETS);
    const float *pos = F32(d, A_TRIANGLE_POSITIONS), *nrm = F32(d, A_TRIANGLE_NORMALS), *uvs = F32(d, A_TRIANGLE_UVS);
    const int32_t *mat = I32(d, A_TRIANGLE_MATERIALS);
    double *polygon = h->tri_a, *spare = h->tri_b, *beyond = h->tri_c;
    /* With a part in the rest, the boundary planes in order cut the triangles; a plane that every corner of every
     * triangle of the piece lies inside of (beyond eps, with a margin for rounding: sphere (c, R) of the triangles'
     * corners, |n| <= 1 + 1e-5) leaves each one unchanged, and is skipped. */
    for (int32_t i = 0; i < d->piece_corner_ids[k]; ++i) h->corner_tags[i] = -1;
    int32_t nwalls = 0;
    if (has_outer) {
        double R = d->piece_tri_radius[k];
        double margin = 1e-4 * R + 1e-12 * ((fabs(c[0]) + fabs(c[1])) + fabs(c[2]) + 2.0 * R);
        for (int32_t b = 0; b < B; ++b)
            if (!(h->ts[b] + R + (margin + 1e-12 * fabs(h->boundary[4 * b + 3])) < -eps)) h->near_walls[nwalls++] = b;
    }
    for (int32_t t = pt[k]; t < pt[k + 1]; ++t) {
        for (int q = 0; q < 3; ++q) {
            double *corner = polygon + 8 * q;
            for (int e = 0; e < 3; ++e) {
                corner[e] = pos[9 * (size_t)t + 3 * (size_t)q + (size_t)e];
                corner[3 + e] = nrm[9 * (size_t)t + 3 * (size_t)q + (size_t)e];
            }
            corner[6] = uvs[6 * (size_t)t + 2 * (size_t)q];
            corner[7] = uvs[6 * (size_t)t + 2 * (size_t)q + 1];
        }
        int32_t count = 3, whole = 1; /* whole: still the stored triangle, inside its sphere (ts, tr) */
        const double *ts = d->tri_sphere + 4 * (size_t)t;
        double tr = 0.0, tmargin = 0.0;
        if (nwalls > 0) { /* (only then: no boundary plane, no sphere to read) */
            tr = ts[3];
            tmargin = 1e-4 * tr + 1e-12 * ((fabs(ts[0]) + fabs(ts[1])) + fabs(ts[2]) + 2.0 * tr);
        }
        for (int32_t n = 0; n < nwalls && count > 0; ++n) {
            const double *plane = h->boundary + 4 * h->near_walls[n];
            if (whole) { /* the sides clip_both would find, from the sphere when it lies clear of the plane */
                double st = dot3(plane, ts) - plane[3], slack = tr + (tmargin + 1e-12 * fabs(plane[3]));
                if (st + slack < -eps) continue; /* every corner inside: nothing beyond, the polygon unchanged */
                if (st - slack > eps) { push_polygon(h, outer, mat[t], polygon, count); count = 0; break; } /* all beyond */
            }
            int32_t nb, got; /* the polygon beyond the plane (to the rest) and inside it */
            if (clip_both(w, polygon, NULL, count, plane, eps, spare, NULL, -1, &got, beyond, NULL, -1, &nb) < 0) {
                h->limit = 1;
                return;
            }
            if (nb == -2) push_polygon(h, outer, mat[t], polygon, count);
            else if (nb >= 3) push_polygon(h, outer, mat[t], beyond, nb);
            if (got == -2) continue;
            count = got;
            whole = 0;
            double *swap = polygon;
            polygon = spare;
            spare = swap;
        }
        if (count < 3) continue;
        if (nkept == 0) { push_polygon(h, outer, mat[t], polygon, count); continue; }
        for (int32_t q = 0; q < count; ++q) h->tri_tags[q] = -1;
        if (whole) /* still the stored triangle: its corners' nearest cells, each found once per piece */
            for (int q = 0; q < 3; ++q) {
                int32_t id = d->corner_id[3 * (size_t)t + (size_t)q];
                if (h->corner_tags[id] < 0) h->corner_tags[id] = nearest(h, polygon + 8 * q, h->kept, nkept);
                h->tri_tags[q] = h->corner_tags[id];
            }
        split_polygon(h, polygon, h->tri_tags, count, h->kept, nkept, eps, mat[t]);
        if (h->limit) return;
    }
    /* the new faces of every part: interior material, box-projected UVs */
    double uv_scale = F32(d, A_SETTINGS)[0];
    for (unsigned char *at = record_start; at < h->a->base + h->a->low;) {
        part_record *rec = (part_record *)at;
        const double *v = (const double *)(rec + 1), *pl = v + 3 * rec->nv;
        const int32_t *isnew = (const int32_t *)(pl + 4 * rec->nf), *off = isnew + rec->nf, *loops = off + rec->nf + 1;
        for (int32_t f = 0; f < rec->nf; ++f) {
            if (!isnew[f]) continue;
            int32_t count = off[f + 1] - off[f];
            if (count > w->ccap) { h->limit = 1; return; }
            double *corners = w->corners[0];
            for (int32_t q = 0; q < count; ++q) {
                const double *x = v + 3 * loops[off[f] + q];
                double *corner = corners + 8 * q;
                corner[0] = x[0]; corner[1] = x[1]; corner[2] = x[2];
                corner[3] = pl[4 * f]; corner[4] = pl[4 * f + 1]; corner[5] = pl[4 * f + 2];
                box_uv(x, pl + 4 * f, uv_scale, corner + 6);
            }
            push_polygon(h, rec->cell, d->interior, corners, count);
        }
        at += rec->size;
    }
}

static size_t split_bytes(int32_t S, int32_t B) {
    size_t levels = (size_t)(S < 128 ? S : 128) + 1;
    return sizeof(double) * levels * 2 * 8 * (2 * (size_t)(3 + B + (int32_t)levels) + 2) +
           sizeof(int32_t) * levels * 2 * (2 * (size_t)(3 + B + (int32_t)levels) + 2) +
           sizeof(int32_t) * levels * 2 * (size_t)(S + 1);
}

static size_t scratch_bytes(const fra_data *d, int32_t *vcap, int32_t *fcap, int32_t *lcap, int32_t *ccap) {
    *fcap = d->max_faces + d->max_degree + 8;
    *vcap = 2 * *fcap + d->max_vertices + 64;
    *lcap = 2 * (*vcap + *fcap) + 64;
    *ccap = d->max_sites + 64;
    if (*ccap < 1024) *ccap = 1024; /* new faces: one corner per polyhedron vertex at most */
    if (*ccap < *vcap) *ccap = *vcap;
    size_t poly_bytes = sizeof(double) * (3 * (size_t)*vcap + 4 * (size_t)*fcap) +
                        sizeof(int32_t) * (2 * (size_t)*fcap + 1 + (size_t)*lcap) + 5 * 16;
    int32_t N = d->rows[A_CELL_NEIGHBORS], S = d->max_sites;
    return 3 * poly_bytes + sizeof(double) * ((size_t)*vcap * 4 + 2 * 8 * (size_t)*ccap) +
           sizeof(int32_t) * ((size_t)*vcap * 5 + 3 * (size_t)*lcap) + sizeof(double) * (3 * (size_t)S + (size_t)S) +
           sizeof(int32_t) * 7 * (size_t)S + sizeof(double) * 11 * (size_t)N + 48 * 16 +
           split_bytes(S, d->rows[A_BOUNDARY_PLANES]) +
           sizeof(double) * (3 * 8 * (size_t)*ccap + 5 * (size_t)d->rows[A_BOUNDARY_PLANES]) +
           sizeof(int32_t) * ((size_t)*ccap + (size_t)d->rows[A_BOUNDARY_PLANES] + (size_t)d->max_corner_ids) +
           sizeof(work) +
           sizeof(hit);
}

size_t fra_arena_hint(const fra_data *d) {
    if (!d) return 0;
    int32_t vcap, fcap, lcap, ccap;
    size_t scratch = scratch_bytes(d, &vcap, &fcap, &lcap, &ccap);
    size_t per_part = sizeof(part_record) + sizeof(double) * 3 * 2 * (size_t)d->max_vertices +
                      sizeof(double) * 4 * (size_t)(d->max_faces + 8) + 64 * sizeof(int32_t) * (size_t)d->max_faces;
    size_t parts = (size_t)d->P * 4 + 256;
    size_t triangles = 4 * (size_t)d->T + 4096;
    return scratch + 2 * parts * (per_part + sizeof(fra_part)) + triangles * (sizeof(fra_triangle) + 2 * sizeof(int32_t)) +
           (size_t)d->max_sites * sizeof(fra_fragment);
}

static void *grab(arena *a, size_t bytes, int *ok) {
    void *p = take_low(a, bytes ? bytes : 1);
    if (!p) *ok = 0;
    return p;
}

static fra_status setup(const fra_data *d, int32_t q, const double *point, const double *direction, double scale,
                        arena *a, hit *h, work *w) {
    int ok = 1;
    int32_t vcap, fcap, lcap, ccap;
    scratch_bytes(d, &vcap, &fcap, &lcap, &ccap);
    w->vcap = vcap; w->fcap = fcap; w->lcap = lcap; w->ccap = ccap;
    for (int b = 0; b < 3; ++b) ok &= alloc_poly(a, &w->buf[b], vcap, fcap, lcap);
    w->dist = (double *)grab(a, sizeof(double) * (size_t)vcap, &ok);
    w->side = (int32_t *)grab(a, sizeof(int32_t) * (size_t)vcap, &ok);
    w->renumber = (int32_t *)grab(a, sizeof(int32_t) * (size_t)vcap, &ok);
    w->used = (int32_t *)grab(a, sizeof(int32_t) * (size_t)vcap, &ok);
    w->points = (int32_t *)grab(a, sizeof(int32_t) * (size_t)vcap, &ok);
    w->cross = (int32_t *)grab(a, sizeof(int32_t) * 3 * (size_t)lcap, &ok);
    w->cross_head = (int32_t *)grab(a, sizeof(int32_t) * (size_t)vcap, &ok);
    w->keys = (double *)grab(a, sizeof(double) * 3 * (size_t)vcap, &ok);
    w->corners[0] = (double *)grab(a, sizeof(double) * 8 * (size_t)ccap, &ok);
    w->corners[1] = (double *)grab(a, sizeof(double) * 8 * (size_t)ccap, &ok);
    w->cdist = (double *)grab(a, sizeof(double) * (size_t)ccap, &ok);
    w->cside = (int32_t *)grab(a, sizeof(int32_t) * (size_t)ccap, &ok);
    int32_t lo = I32(d, A_PATTERN_SITE_OFFSETS)[q], hi = I32(d, A_PATTERN_SITE_OFFSETS)[q + 1];
    const int32_t *nb_off = I32(d, A_CELL_NEIGHBOR_OFFSETS) + lo;
    int32_t N = nb_off[hi - lo] - nb_off[0];
    h->S = hi - lo;
    h->sites = (double *)grab(a, sizeof(double) * 3 * (size_t)h->S, &ok);
    h->dists = (double *)grab(a, sizeof(double) * (size_t)h->S, &ok);
    h->cells = (int32_t *)grab(a, sizeof(int32_t) * (size_t)h->S, &ok);
    for (int32_t i = 0; ok && i < h->S; ++i) h->cells[i] = 0;
    h->kept = (int32_t *)grab(a, sizeof(int32_t) * (size_t)h->S, &ok);
    h->planes = (double *)grab(a, sizeof(double) * 4 * (size_t)N, &ok);
    h->axes = (double *)grab(a, sizeof(double) * 7 * (size_t)N, &ok);
    for (int32_t e = 0; ok && e < N; ++e) h->axes[7 * e] = 0.0;
    size_t levels = (size_t)(h->S < 128 ? h->S : 128) + 1;
    h->split_cap = levels * 2 * 8 * (2 * (size_t)(3 + d->rows[A_BOUNDARY_PLANES] + (int32_t)levels) + 2);
    h->split_cells_cap = levels * 2 * (size_t)(h->S + 1);
    h->split = (double *)grab(a, sizeof(double) * h->split_cap, &ok);
    h->split_tags = (int32_t *)grab(a, sizeof(int32_t) * (h->split_cap / 8), &ok);
    h->split_cells = (int32_t *)grab(a, sizeof(int32_t) * h->split_cells_cap, &ok);
    int32_t *local_off = (int32_t *)grab(a, sizeof(int32_t) * (size_t)(h->S + 1), &ok);
    h->B = d->rows[A_BOUNDARY_PLANES];
    int32_t *wall_off = (int32_t *)grab(a, sizeof(int32_t) * (size_t)(h->S + 1), &ok);
    h->boundary = (double *)grab(a, sizeof(double) * 4 * (size_t)h->B, &ok);
    h->ts = (double *)grab(a, sizeof(double) * (size_t)h->B, &ok);
    h->near_walls = (int32_t *)grab(a, sizeof(int32_t) * (size_t)h->B, &ok);
    h->cand = (int32_t *)grab(a, sizeof(int32_t) * (size_t)h->S, &ok);
    h->inner = (int32_t *)grab(a, sizeof(int32_t) * (size_t)h->S, &ok);
    h->tri_a = (double *)grab(a, sizeof(double) * 8 * (size_t)ccap, &ok);
    h->tri_b = (double *)grab(a, sizeof(double) * 8 * (size_t)ccap, &ok);
    h->tri_c = (double *)grab(a, sizeof(double) * 8 * (size_t)ccap, &ok);
    h->tri_tags = (int32_t *)grab(a, sizeof(int32_t) * (size_t)ccap, &ok);
    h->corner_tags = (int32_t *)grab(a, sizeof(int32_t) * (size_t)d->max_corner_ids, &ok);
    if (!ok) return FRA_ERR_ARENA;
    /* the frame: d = direction / max |component|, normalized; (u, v) = plane_basis(d) */
    double m = fabs(direction[0]);
    if (fabs(direction[1]) > m) m = fabs(direction[1]);
    if (fabs(direction[2]) > m) m = fabs(direction[2]);
    double s[3] = {direction[0] / m, direction[1] / m, direction[2] / m};
    double length = sqrt((s[0] * s[0] + s[1] * s[1]) + s[2] * s[2]);
    double dn[3] = {s[0] / length, s[1] / length, s[2] / length}, u[3], v[3];
    plane_basis(dn, u, v);
    const float *x = F32(d, A_PATTERN_SITES) + 3 * (size_t)lo;
    for (int32_t i = 0; i < h->S; ++i) {
        double t0 = scale * (double)x[3 * i], t1 = scale * (double)x[3 * i + 1], t2 = scale * (double)x[3 * i + 2];
        for (int c = 0; c < 3; ++c) h->sites[3 * i + c] = point[c] + ((t0 * u[c] + t1 * v[c]) + t2 * dn[c]);
    }
    const float *bp = F32(d, A_BOUNDARY_PLANES);
    for (int32_t b = 0; b < h->B; ++b) { /* n' = (n0 u + n1 v) + n2 d, h' = scale h + n' . point */
        double n[3] = {bp[4 * b], bp[4 * b + 1], bp[4 * b + 2]}, *out = h->boundary + 4 * b;
        for (int c = 0; c < 3; ++c) out[c] = (n[0] * u[c] + n[1] * v[c]) + n[2] * dn[c];
        out[3] = scale * (double)bp[4 * b + 3] + dot3(out, point);
    }
    for (int32_t i = 0; i <= h->S; ++i) local_off[i] = nb_off[i] - nb_off[0];
    const int32_t *bo = I32(d, A_CELL_BOUNDARY_OFFSETS) + lo;
    for (int32_t i = 0; i <= h->S; ++i) wall_off[i] = bo[i] - bo[0];
    h->wall_off = wall_off;
    h->walls = I32(d, A_CELL_BOUNDARY) + bo[0];
    h->nb_off = local_off;
    h->nb = I32(d, A_CELL_NEIGHBORS) + nb_off[0];
    int bad = 0;
    for (int32_t i = 0; i < h->S; ++i)
        for (int32_t e = local_off[i]; e < local_off[i + 1]; ++e)
            bisector(h->sites + 3 * i, h->sites + 3 * h->nb[e], h->planes + 4 * e, &bad);
    return bad ? FRA_ERR_INPUT : FRA_OK;
}

fra_status fra_fracture(const fra_data *d, int32_t q, const double point[3], const double direction[3], double scale,
                        void *arena_memory, size_t arena_size, fra_result *out) {
    if (!d || !point || !direction || !arena_memory || !out) return FRA_ERR_ARGUMENT;
    memset(out, 0, sizeof *out);
    double m = fabs(direction[0]);
    if (fabs(direction[1]) > m) m = fabs(direction[1]);
    if (fabs(direction[2]) > m) m = fabs(direction[2]);
    if (q < 0 || q >= d->Q || !isfinite(point[0]) || !isfinite(point[1]) || !isfinite(point[2]) || !isfinite(m) ||
        !(m > 0.0) || !isfinite(scale) || !(scale > 0.0))
        return FRA_ERR_INPUT;
    arena a = {(unsigned char *)arena_memory, 0, arena_size & ~(size_t)15};
    hit h;
    work w;
    memset(&h, 0, sizeof h);
    memset(&w, 0, sizeof w);
    h.d = d;
    h.a = &a;
    h.w = &w;
    fra_status status = setup(d, q, point, direction, scale, &a, &h, &w);
    if (status == FRA_ERR_ARENA) { out->arena_needed = 2 * arena_size + 4096; return status; }
    if (status != FRA_OK) return status;
    a.low = (a.low + 15) & ~(size_t)15;
    h.parts_begin = a.base + a.low;
    size_t tri_top = a.high;
    for (int32_t k = 0; k < d->P && !h.overflow && !h.limit; ++k) cut_piece(&h, k);
    if (h.limit) return FRA_ERR_LIMIT;
    if (h.overflow) { out->arena_needed = 2 * arena_size + 4096; return FRA_ERR_ARENA; }
    /* count per cell, then lay out the result in the space between the two streams */
    unsigned char *parts_end = a.base + a.low;
    int32_t S = h.S + 1 /* the cells, then the rest of the object */, nparts = 0, nwhole = 0, nvert = 0, nface = 0, nloop = 0, nfrag = 0;
    int ok = 1;
    int32_t *cell_parts = (int32_t *)grab(&a, sizeof(int32_t) * (size_t)S, &ok);
    int32_t *cell_tris = (int32_t *)grab(&a, sizeof(int32_t) * (size_t)S, &ok);
    int32_t *cell_frag = (int32_t *)grab(&a, sizeof(int32_t) * (size_t)S, &ok);
    if (!ok) { out->arena_needed = 2 * arena_size + 4096; return FRA_ERR_ARENA; }
    int32_t *cell_whole = (int32_t *)h.dists; /* (S,) doubles, free now: room for S + 1 counts */
    for (int32_t i = 0; i < S; ++i) {
        cell_parts[i] = cell_whole[i] = 0;
        cell_tris[i] = i < h.S ? h.cells[i] : h.outer_tris; /* counted as they were made */
    }
    for (unsigned char *at = h.parts_begin; at < parts_end; at += ((part_record *)at)->size) {
        part_record *r = (part_record *)at;
        cell_parts[r->cell]++;
        cell_whole[r->cell] += r->whole;
        nparts++;
        nwhole += r->whole;
        nvert += r->nv;
        nface += r->nf;
        nloop += r->nl;
    }
    size_t ntri = h.tri_count;
    fra_triangle *tris = (fra_triangle *)(a.base + tri_top - ntri * sizeof(fra_triangle));
    for (int32_t i = 0; i < S; ++i) cell_frag[i] = cell_parts[i] ? nfrag++ : -1;
    out->fragments = (fra_fragment *)grab(&a, sizeof(fra_fragment) * (size_t)nfrag, &ok);
    out->parts = (fra_part *)grab(&a, sizeof(fra_part) * (size_t)nparts, &ok);
    out->whole_pieces = (int32_t *)grab(&a, sizeof(int32_t) * (size_t)nwhole, &ok);
    out->vertices = (double *)grab(&a, sizeof(double) * 3 * (size_t)nvert, &ok);
    out->face_planes = (double *)grab(&a, sizeof(double) * 4 * (size_t)nface, &ok);
    out->face_new = (int32_t *)grab(&a, sizeof(int32_t) * (size_t)nface, &ok);
    out->face_loop_offsets = (int32_t *)grab(&a, sizeof(int32_t) * (size_t)(nface + 1), &ok);
    out->face_loops = (int32_t *)grab(&a, sizeof(int32_t) * (size_t)nloop, &ok);
    out->triangle_order = (int32_t *)grab(&a, sizeof(int32_t) * ntri, &ok);
    if (!ok) { out->arena_needed = 2 * arena_size + 4096; return FRA_ERR_ARENA; }
    /* fragments: parts, whole pieces and triangles by cell, each in the order they were made */
    int32_t part_at = 0, whole_at = 0, tri_at = 0;
    for (int32_t i = 0; i < S; ++i) {
        if (cell_frag[i] < 0) continue;
        fra_fragment *f = &out->fragments[cell_frag[i]];
        f->cell = i;
        f->part_first = part_at;
        f->whole_first = whole_at;
        f->triangle_first = tri_at;
        f->part_count = f->whole_count = f->triangle_count = 0;
        part_at += cell_parts[i];
        tri_at += cell_tris[i];
        f->whole_count = cell_whole[i];
        cell_whole[i] = whole_at; /* now: the next free slot */
        whole_at += f->whole_count;
        cell_tris[i] = f->triangle_first; /* now: the next free slot */
        cell_parts[i] = f->part_first;
    }
    for (unsigned char *at = h.parts_begin; at < parts_end; at += ((part_record *)at)->size)
        if (((part_record *)at)->whole) out->whole_pieces[cell_whole[((part_record *)at)->cell]++] = ((part_record *)at)->piece;
    int32_t vert_at = 0, face_at = 0, loop_at = 0;
    out->face_loop_offsets[0] = 0;
    for (unsigned char *at = h.parts_begin; at < parts_end; at += ((part_record *)at)->size) {
        part_record *r = (part_record *)at;
        fra_part *p = &out->parts[cell_parts[r->cell]++];
        p->piece = r->piece;
        p->whole = r->whole;
        p->volume = r->volume;
        p->centroid[0] = r->centroid[0]; p->centroid[1] = r->centroid[1]; p->centroid[2] = r->centroid[2];
        p->vertex_first = r->whole ? -1 : vert_at;
        p->vertex_count = r->nv;
        p->face_first = r->whole ? -1 : face_at;
        p->face_count = r->nf;
        if (!r->whole) {
            const double *v = (const double *)(r + 1), *pl = v + 3 * r->nv;
            const int32_t *isnew = (const int32_t *)(pl + 4 * r->nf), *off = isnew + r->nf, *loops = off + r->nf + 1;
            memcpy(out->vertices + 3 * vert_at, v, sizeof(double) * 3 * (size_t)r->nv);
            memcpy(out->face_planes + 4 * face_at, pl, sizeof(double) * 4 * (size_t)r->nf);
            memcpy(out->face_new + face_at, isnew, sizeof(int32_t) * (size_t)r->nf);
            for (int32_t f = 0; f < r->nf; ++f) out->face_loop_offsets[face_at + f + 1] = loop_at + off[f + 1];
            memcpy(out->face_loops + loop_at, loops, sizeof(int32_t) * (size_t)r->nl);
            vert_at += r->nv;
            face_at += r->nf;
            loop_at += r->nl;
        }
    }
    for (size_t p = 0; p < ntri; ++p) {
        size_t index = ntri - 1 - p; /* made p-th: pushed downwards from the top */
        int32_t cell = tris[index].fragment;
        out->triangle_order[cell_tris[cell]++] = (int32_t)index;
        tris[index].fragment = cell_frag[cell];
    }
    for (int32_t f = 0; f < nfrag; ++f) {
        fra_fragment *fr = &out->fragments[f];
        fr->part_count = (f + 1 < nfrag ? out->fragments[f + 1].part_first : nparts) - fr->part_first;
        fr->triangle_count = (f + 1 < nfrag ? out->fragments[f + 1].triangle_first : (int32_t)ntri) - fr->triangle_first;
        double volume = 0, moment[3] = {0, 0, 0};
        for (int32_t i = fr->part_first; i < fr->part_first + fr->part_count; ++i) {
            volume += out->parts[i].volume;
            for (int c = 0; c < 3; ++c) moment[c] += out->parts[i].volume * out->parts[i].centroid[c];
        }
        fr->volume = volume;
        for (int c = 0; c < 3; ++c) fr->center_of_mass[c] = volume > 0 ? moment[c] / volume : 0.0;
    }
    out->fragment_count = nfrag;
    out->part_count = nparts;
    out->whole_count = nwhole;
    out->vertex_count = nvert;
    out->face_count = nface;
    out->loop_count = nloop;
    out->triangle_count = (int32_t)ntri;
    out->triangles = tris;
    out->arena_used = a.low + ((arena_size & ~(size_t)15) - tri_top) + ntri * sizeof(fra_triangle);
    return FRA_OK;
}
