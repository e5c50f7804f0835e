/*
 * fracture_runtime.h - reader of the `fracture` impact-projection file (C99, libc only).
 *
 * Loads `<stem>.fracture.json` + `<stem>.fracture.bin` from memory (the engine owns
 * file I/O), validates them, and answers "which fragments break off" for a hit in
 * about a microsecond, without allocating. Specification: docs/FORMAT.md of the
 * fracture repository (format version 1, and version 2 with the features "stress":
 * the stress criterion of section 11, "anchors" and "damage": structures and damage
 * that adds up over hits, section 12, with the optional crack arrays, and "levels":
 * fragments that break again, section 14). Usable from C and C++.
 *
 * MIT licence, Copyright (c) fracture developers (see LICENSE next to this file).
 *
 *   fr_runtime *rt;
 *   char why[FR_MESSAGE_SIZE];
 *   if (fr_load(json, json_size, bin, bin_size, 0, NULL, &rt, why, sizeof why) != FR_OK) { log(why); }
 *   int32_t groups[...];                      // fr_get_info(rt).fragments entries
 *   fr_impact out = {0};
 *   out.groups = groups;
 *   double point[3] = {...}, impulse[3] = {...};
 *   if (fr_project(rt, point, impulse, fr_get_info(rt).default_threshold, NULL, &out) == FR_OK) {
 *       // fragments j with equal groups[j] move together; groups[j] == j starts a group
 *   }
 *   fr_free(rt);
 *
 * With damage that adds up (section 12), keep one state per object and hit it instead:
 *
 *   double *health = malloc(sizeof(double) * fr_get_info(rt).edges);  // e bond healths
 *   fr_new_state(rt, health);                                            // all 1.0
 *   if (fr_hit(rt, health, point, impulse, threshold, NULL, &out) == FR_OK) { ... }
 */
#ifndef FRACTURE_RUNTIME_H
#define FRACTURE_RUNTIME_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#define FR_FORMAT_VERSION 2  /* highest file format version this reader understands (2: the features below) */
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
    FR_ERR_INPUT,     /* fr_project, fr_hit: non-finite point or impulse, NaN or negative threshold */
    FR_ERR_STATE,     /* fr_hit and the state functions: a damage state that is not e values in [0, 1] */
    FR_ERR_FRAGMENT   /* fr_hit_piece: the struck fragment is not shown (split, or inside an unbroken parent) */
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

/* fr_info.features: the version-2 features the file lists (docs/FORMAT.md sections 11 and 12). */
#define FR_FEATURE_STRESS 1   /* criterion "stress" */
#define FR_FEATURE_ANCHORS 2  /* fragments bonded to the world (fr_anchored) */
#define FR_FEATURE_DAMAGE 4   /* hits below a bond's strength crack it and lower its health (fr_hit) */
#define FR_FEATURE_LEVELS 8   /* fragments that break again: bodies, object states, fr_hit_piece (section 14) */

typedef struct fr_info {
    int32_t sites, modes, fragments, edges, dim;  /* s, k, p, e, d */
    int32_t criterion;   /* FR_CRITERION_MODES or FR_CRITERION_STRESS, from the file */
    int32_t site_bonds;  /* stress criterion: entries of the per-site bond lists (counts.site_bonds); else 0 */
    int32_t features;    /* FR_FEATURE_* bits; 0 for a version-1 file */
    int32_t crack_segments; /* n: segments of the optional crack arrays (fr_crack_segments); 0 without them */
    double crack_level;  /* feature "damage": c in (0, 1]; 1 without it */
    double damage_rate;  /* feature "damage": r >= 0; 0 without it */
    double default_threshold;
    double impact_radius;
    double transform[16];  /* row-major, normalized bake coordinates -> model space (informational) */
} fr_info;

fr_info fr_get_info(const fr_runtime *rt);
const char *fr_fragment_name(const fr_runtime *rt, int32_t fragment);  /* UTF-8; NULL if out of range */
const int32_t *fr_edges(const fr_runtime *rt);    /* (e, 2): P < Q */
const float *fr_edge_areas(const fr_runtime *rt); /* (e,) */
const float *fr_sites(const fr_runtime *rt);      /* (s, 3), model space */

/* (p,) 1 where the fragment is bonded to the world, else 0; NULL without feature "anchors". */
const int32_t *fr_anchored(const fr_runtime *rt);

/*
 * Where bond `bond`'s fault meets the outer surface, for drawing a cracked bond: *count
 * line segments of 2 points x 3 coordinates (model space), i.e. 6 * *count floats. NULL
 * and *count = 0 when the file has no crack arrays, the bond has no segment or is out of range.
 */
const float *fr_crack_segments(const fr_runtime *rt, int32_t bond, int32_t *count);

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
    uint8_t *cracked;      /* [e] optional: 1 if bond m holds but is cracked (fr_project: 0 without "damage") */
    uint8_t *anchored;     /* [p] optional: 1 if fragment j's group holds an anchored fragment (keep it static) */
    int32_t site;          /* out: nearest contact site */
    int32_t num_groups;    /* out: number of groups */
    int32_t num_broken;    /* out: number of broken edges */
    int32_t num_cracked;   /* out: number of cracked bonds (counted whether or not `cracked` is given) */
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
 * either way. The groups follow from the broken bonds in both cases. On a file with
 * feature "damage" this is fr_hit on a fresh state that is then thrown away (it lives in
 * the workspace), so it also answers `cracked`; `anchored` is answered for every file.
 */
fr_status fr_project(const fr_runtime *rt, const double point[3], const double impulse[3], double threshold,
                     void *workspace, fr_impact *out);

/*
 * Damage state (docs/FORMAT.md section 12.3): `health`, e doubles owned by the game, one
 * array per object. A bond is broken when its health is 0; a valid state holds e finite
 * values in [0, 1]. Save it as e little-endian doubles (fr_state_to_bytes) to load it on
 * any reader and machine (fr_state_from_bytes).
 */
void fr_new_state(const fr_runtime *rt, double *health);  /* all 1.0: no bond damaged */
/* FR_ERR_STATE unless count == e and every value is in [0, 1] (NaN is not). */
fr_status fr_check_state(const fr_runtime *rt, const double *health, size_t count);
/* health -> 8 e bytes (little-endian doubles). */
void fr_state_to_bytes(const fr_runtime *rt, const double *health, unsigned char *bytes);
/* 8 e bytes -> health, checked: FR_ERR_STATE (health untouched) for another size or invalid values. */
fr_status fr_state_from_bytes(const fr_runtime *rt, const void *bytes, size_t size, double *health);

/*
 * One hit on an object whose damage state is `health` (section 12.4), updated in place; the
 * arguments and answers are fr_project's. Every bond the hit loads above the crack level
 * c times its limit is cracked and loses q (load - c) of its health (q = r / (1 - c); load
 * = its measure over its limit, 1 = at its strength); above its limit it breaks (health 0).
 * `broken` then lists every broken bond (this hit's and earlier ones'), `cracked` the bonds
 * that hold but were loaded above c by this hit or weakened before, and the groups are
 * those of the bonds that hold. Bonds to the world never break; `anchored` says which
 * fragments stay held by it. Refused hits leave `health` as it was: FR_ERR_INPUT as
 * fr_project, FR_ERR_STATE for an invalid state. On a file without feature "damage" a state
 * only remembers broken bonds (c = 1, r = 0). Does not allocate; same workspace rules as
 * fr_project.
 */
fr_status fr_hit(const fr_runtime *rt, double *health, const double point[3], const double impulse[3],
                 double threshold, void *workspace, fr_impact *out);

/*
 * Levels (docs/FORMAT.md section 14, feature "levels"). A *body* is a set of fragments (its children)
 * with its own impact data: body 0 is the whole asset (the runtime itself, its p level-1 fragments),
 * body b >= 1 breaks fragment fr_body_fragment(rt, b) into fragments fr_body_first(rt, b) ..
 * fr_body_first(rt, b + 1) - 1. Fragments are numbered over every level (global index g < p_all).
 * fr_body(rt, b) is body b's view, a runtime of its own (sites, modes, bonds among its children in
 * local indices, its level's default threshold, the children's names): fr_project and fr_hit run on
 * it unchanged. Without levels there is one body (0) and p_all = p. Views belong to `rt`.
 */
typedef struct fr_levels_info {
    int32_t bodies;        /* nb, body 0 included (1 without levels) */
    int32_t all_fragments; /* p_all */
    int32_t state_size;    /* e + E: doubles in an object state */
    int32_t max_children;  /* largest child count of a body (body 0's is p) */
    int32_t max_bonds;     /* largest bond count of a body (body 0's is e) */
    int32_t count;         /* the deepest level (1 without levels) */
} fr_levels_info;

fr_levels_info fr_get_levels_info(const fr_runtime *rt);
const fr_runtime *fr_body(const fr_runtime *rt, int32_t body);     /* NULL out of range; body 0: rt */
int32_t fr_body_fragment(const fr_runtime *rt, int32_t body);      /* -1 for body 0 (or out of range) */
int32_t fr_body_first(const fr_runtime *rt, int32_t body);         /* first child; body == bodies: p_all */
int32_t fr_body_of(const fr_runtime *rt, int32_t fragment);        /* the body breaking it, -1: none (a leaf) */
int32_t fr_body_holding(const fr_runtime *rt, int32_t fragment);   /* the body whose child it is; -1 out of range */
int32_t fr_parent(const fr_runtime *rt, int32_t fragment);         /* -1 at level 1 (or out of range) */
int32_t fr_state_offset(const fr_runtime *rt, int32_t body);       /* body's healths in an object state */
const char *fr_any_fragment_name(const fr_runtime *rt, int32_t fragment); /* any level; NULL out of range */

/* Object state (section 14.4): state_size doubles, every body's bond healths (body 0's first). */
void fr_new_object_state(const fr_runtime *rt, double *health);
fr_status fr_check_object_state(const fr_runtime *rt, const double *health, size_t count);

/*
 * Pieces (section 14.4): rigid bodies of sibling fragments. Caller-provided arrays, sized p_all (offsets
 * p_all + 1); piece i holds fragments[offsets[i] .. offsets[i+1]-1] (global, ascending), children of
 * bodies[i]; anchored[i]: keep it static. `bodies` and `anchored` may be NULL.
 */
typedef struct fr_pieces {
    int32_t *fragments, *offsets, *bodies;
    uint8_t *anchored;
    int32_t count; /* out */
} fr_pieces;

/* Every piece of an object (body by body, by first fragment); FR_ERR_STATE for an invalid state. Workspace as
 * fr_hit_piece's. */
fr_status fr_object_pieces(const fr_runtime *rt, const double *health, void *workspace, fr_pieces *out);

/*
 * Hit the piece holding the shown fragment `struck` (section 14.5): point and impulse in the asset's
 * model space (the piece's rigid transform undone), threshold NULL for each body's default. `health` is
 * the object state, updated in place (refused hits leave it unchanged: FR_ERR_INPUT, FR_ERR_STATE,
 * FR_ERR_FRAGMENT). `body` answers for the body holding `struck` (local indices, arrays sized
 * max_children / max_bonds; after the hit: broken = every broken bond, groups over all its children);
 * `child` for struck's own body when it has one (child_body >= 0). `pieces`: what struck's piece became.
 * Does not allocate; workspace: fr_piece_workspace_size(rt) bytes (16-byte aligned) or NULL for the
 * runtime's own (not thread-safe; only a file with levels has one: pass a workspace otherwise).
 * The caller's `body.alpha` / `body.displacement` (optional) need the largest modes / children * d of
 * any body. Cost: two body hits plus union-finds over the struck piece's body (0.5 us at level 2).
 */
typedef struct fr_piece_hit {
    fr_impact body, child; /* groups required in both (sized max_children) */
    int32_t body_index, child_body, split;
    fr_pieces pieces;
} fr_piece_hit;

size_t fr_piece_workspace_size(const fr_runtime *rt);
fr_status fr_hit_piece(const fr_runtime *rt, double *health, int32_t struck, const double point[3],
                       const double impulse[3], const double *threshold, void *workspace, fr_piece_hit *out);

#ifdef __cplusplus
}
#endif

#endif /* FRACTURE_RUNTIME_H */
