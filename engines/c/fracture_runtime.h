/*
 * fracture_runtime.h - reader of the `fracture` impact-projection file (C99, libc only).
 *
 * Loads `<stem>.fracture.json` + `<stem>.fracture.bin` from memory (the engine owns
 * file I/O), validates them, and answers "which fragments break off" for a hit in
 * about a microsecond, without allocating. Specification: docs/FORMAT.md of the
 * fracture repository (format version 1, and version 2 with feature "stress": the
 * stress criterion of section 11). Usable from C and C++.
 *
 * MIT licence, Copyright (c) fracture developers (see LICENSE next to this file).
 *
 *   fr_runtime *rt;
 *   char why[FR_MESSAGE_SIZE];
 *   if (fr_load(json, json_size, bin, bin_size, 0, NULL, &rt, why, sizeof why) != FR_OK) { log(why); }
 *   int32_t groups[...];                      // fr_info(rt).fragments entries
 *   fr_impact out = {0};
 *   out.groups = groups;
 *   double point[3] = {...}, impulse[3] = {...};
 *   if (fr_project(rt, point, impulse, fr_info(rt).default_threshold, NULL, &out) == FR_OK) {
 *       // fragments j with equal groups[j] move together; groups[j] == j starts a group
 *   }
 *   fr_free(rt);
 */
#ifndef FRACTURE_RUNTIME_H
#define FRACTURE_RUNTIME_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#define FR_FORMAT_VERSION 2  /* highest file format version this reader understands (2: feature "stress") */
#define FR_MESSAGE_SIZE 192  /* enough for any message fr_load writes */

typedef enum fr_status {
    FR_OK = 0,
    FR_ERR_ARGUMENT,  /* a NULL pointer or a missing output array */
    FR_ERR_JSON,      /* the header is not valid JSON (or not UTF-8) */
    FR_ERR_FORMAT,    /* not a fracture runtime file, or a version this reader does not know */
    FR_ERR_HEADER,    /* a header entry is missing or has the wrong type or value */
    FR_ERR_SIZE,      /* binary size, array sizes, offsets or shapes disagree */
    FR_ERR_CRC,       /* the binary's CRC-32 differs from the header's */
    FR_ERR_DATA,      /* a non-finite value or an edge index out of range in the binary */
    FR_ERR_MEMORY,    /* the allocator returned NULL */
    FR_ERR_INPUT      /* fr_project: non-finite point or impulse, NaN or negative threshold */
} fr_status;

/* A short English name of a status ("ok", "invalid JSON header", ...). */
const char *fr_status_string(fr_status status);

/* Custom allocation for fr_load / fr_free (one block per runtime); NULL means malloc/free. */
typedef struct fr_allocator {
    void *(*alloc)(void *user, size_t size);
    void (*free)(void *user, void *ptr);
    void *user;
} fr_allocator;

#define FR_LOAD_SKIP_CRC 1u  /* fr_load flag: do not check buffer.crc32 */
#define FR_LOAD_COMPACT 2u   /* fr_load flag: no per-site jump table (see fr_load) */

typedef struct fr_runtime fr_runtime;

/*
 * Parse and validate a runtime file, copy what projection needs and build its
 * spatial index. `header` and `binary` may be freed after the call returns.
 * On error *out is NULL and, if `message` is not NULL, a one-line reason
 * (NUL-terminated, at most message_size bytes) is written there.
 *
 * For a d = 1 file, fr_load also tabulates per contact site the edges' jumps in
 * ascending order and the order in which they join fragments: a projection is
 * then a bisection and one pass over at most p merges, whatever breaks. The table
 * takes (10 e + 10 p) bytes per site (6 MB for a vase with s = 1002, p = 189,
 * e = 435) and about 10 ms per MB to build; it is skipped when it would exceed
 * FR_TABLE_MAX_BYTES (16 MiB unless the source is compiled with another value), for
 * d = 3 files, for the stress criterion (which does not use it) and with the flag
 * FR_LOAD_COMPACT. Without it a projection computes
 * the displacements and tests every edge (several times slower on files with
 * hundreds of edges). Both give the same answers. fr_memory_size tells the total.
 */
fr_status fr_load(const void *header, size_t header_size, const void *binary, size_t binary_size,
                  unsigned flags, const fr_allocator *allocator, fr_runtime **out,
                  char *message, size_t message_size);

/* Release a runtime (NULL is fine). */
void fr_free(fr_runtime *rt);

/* Bytes held by a runtime (its one allocation; see FR_LOAD_COMPACT); 0 for NULL. */
size_t fr_memory_size(const fr_runtime *rt);

/*
 * The binary file name (`buffer.uri`) of a header, to find the file to read before
 * fr_load: a plain file name in the header's directory. Written NUL-terminated
 * into `uri` (capacity `uri_size`, 256 is always enough).
 */
fr_status fr_header_uri(const void *header, size_t header_size, char *uri, size_t uri_size);

/* fr_info.criterion: how a hit decides which bonds break (docs/FORMAT.md sections 4 and 11). */
#define FR_CRITERION_MODES 0   /* the jumps of the fracture modes (version 1) */
#define FR_CRITERION_STRESS 1  /* the stress criterion (version 2, feature "stress") */

typedef struct fr_info {
    int32_t sites, modes, fragments, edges, dim;  /* s, k, p, e, d */
    int32_t criterion;   /* FR_CRITERION_MODES or FR_CRITERION_STRESS, from the file */
    int32_t site_bonds;  /* stress criterion: entries of the per-site bond lists (counts.site_bonds); else 0 */
    double default_threshold;
    double impact_radius;
    double transform[16];  /* row-major, normalized bake coordinates -> model space (informational) */
} fr_info;

fr_info fr_get_info(const fr_runtime *rt);
const char *fr_fragment_name(const fr_runtime *rt, int32_t fragment);  /* UTF-8; NULL if out of range */
const int32_t *fr_edges(const fr_runtime *rt);    /* (e, 2): P < Q */
const float *fr_edge_areas(const fr_runtime *rt); /* (e,) */
const float *fr_sites(const fr_runtime *rt);      /* (s, 3), model space */

/* Index of the contact site nearest to `point` (smallest index on exact ties); -1 if not finite. */
int32_t fr_nearest_site(const fr_runtime *rt, const double point[3]);

/*
 * Result arrays of one impact, all provided by the caller (sizes from fr_get_info).
 * Only `groups` is required; leave the others NULL to skip them.
 */
typedef struct fr_impact {
    int32_t *groups;       /* [p] group of each fragment: the smallest fragment index in it */
    uint8_t *broken;       /* [e] optional: 1 if edge m broke */
    double *alpha;         /* [k] optional: mode coefficients */
    double *displacement;  /* [p * d] optional: fragment displacements (row-major, model axes) */
    int32_t site;          /* out: nearest contact site */
    int32_t num_groups;    /* out: number of groups */
    int32_t num_broken;    /* out: number of broken edges */
} fr_impact;

/* Bytes of scratch memory fr_project needs (align it to 16 bytes). */
size_t fr_workspace_size(const fr_runtime *rt);

/*
 * Project a hit: point (model space), impulse (model axes, any unit) and threshold
 * (same unit; +INFINITY is unbreakable). Does not allocate. `workspace` is
 * fr_workspace_size(rt) bytes of scratch (16-byte aligned); NULL uses one built
 * into `rt`, which is then not safe to call from several threads at once.
 * FR_ERR_INPUT for a non-finite point or impulse or a NaN or negative threshold.
 * The file's criterion decides which bonds break: the modes' jumps (section 4) or, for a
 * version-2 file with criterion "stress", each bond the nearest site lists breaks when its
 * tensile gain exceeds its strength (section 11); alpha and displacement are the modes'
 * either way. The groups follow from the broken bonds in both cases.
 */
fr_status fr_project(const fr_runtime *rt, const double point[3], const double impulse[3], double threshold,
                     void *workspace, fr_impact *out);

#ifdef __cplusplus
}
#endif

#endif /* FRACTURE_RUNTIME_H */
