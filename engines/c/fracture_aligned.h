/*
 * fracture_aligned.h - aligned fracture at runtime (C99, libc and libm only).
 *
 * Reads the companion file `<stem>.aligned.json` + `<stem>.aligned.bin` that `fracture bake`
 * writes with `--set aligned.enabled=true` (docs/FORMAT.md section 13 of the fracture
 * repository) and cuts the asset where it is hit: a fracture pattern (Voronoi cells, finer
 * near its centre) is placed at the hit point, oriented by the impulse, and intersected with
 * the asset's convex pieces. Pieces inside one cell stay whole; the others are clipped by the
 * cells they meet. The parts in one cell form a new fragment: convex, closed parts ready as
 * collision shapes, its triangles cut along the cells with the interior material on the new
 * faces, its volume and centre of mass. Deterministic; a call allocates nothing: everything
 * goes into an arena the caller gives.
 *
 * Independent of fracture_runtime.h (a game that does not cut at the hit never loads this).
 * MIT licence, Copyright (c) fracture developers (see LICENSE next to this file).
 *
 *   fra_data *data;
 *   char why[FRA_MESSAGE_SIZE];
 *   if (fra_load(json, json_size, bin, bin_size, 0, &data, why, sizeof why) != FRA_OK) { log(why); }
 *   size_t size = fra_arena_hint(data);
 *   void *arena = malloc(size);                       // once; reuse it for every hit
 *   fra_result r;
 *   double point[3] = {...}, impulse[3] = {...};
 *   fra_status s = fra_fracture(data, 0, point, impulse, fra_get_info(data).default_scale, arena, size, &r);
 *   if (s == FRA_ERR_ARENA) { ... grow the arena (fra_result.arena_needed says at least how much) }
 *   for (int32_t f = 0; f < r.fragment_count; ++f) { ... r.fragments[f] ... }
 */
#ifndef FRACTURE_ALIGNED_H
#define FRACTURE_ALIGNED_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#define FRA_FORMAT_VERSION 1 /* the `fracture-aligned` version this reader understands */
#define FRA_MESSAGE_SIZE 192

typedef enum fra_status {
    FRA_OK = 0,
    FRA_ERR_ARGUMENT, /* a NULL pointer */
    FRA_ERR_JSON,     /* the header is not valid JSON */
    FRA_ERR_FORMAT,   /* not a `fracture-aligned` file, or another version */
    FRA_ERR_HEADER,   /* a header entry is missing or has the wrong type or value */
    FRA_ERR_SIZE,     /* binary size, array sizes, offsets or shapes disagree */
    FRA_ERR_CRC,      /* the binary's CRC-32 differs from the header's */
    FRA_ERR_DATA,     /* a value out of range (offsets, indices, non-finite numbers) */
    FRA_ERR_MEMORY,   /* malloc returned NULL (fra_load only) */
    FRA_ERR_INPUT,    /* fra_fracture: non-finite point, zero direction, bad scale or pattern */
    FRA_ERR_ARENA,    /* fra_fracture: the arena is too small (see fra_result.arena_needed) */
    FRA_ERR_LIMIT     /* fra_fracture: a clipped part outgrew its working buffers (degenerate geometry) */
} fra_status;

const char *fra_status_string(fra_status status);

#define FRA_LOAD_SKIP_CRC 1u

typedef struct fra_data fra_data;

/* Parse and validate the header and the binary (both may be freed after the call). */
fra_status fra_load(const void *header, size_t header_size, const void *binary, size_t binary_size,
                    unsigned flags, fra_data **out, char *message, size_t message_size);
void fra_free(fra_data *data);

/* The binary file name (`buffer.uri`) of a header: a plain file name beside it (256 bytes always suffice). */
fra_status fra_header_uri(const void *header, size_t header_size, char *uri, size_t uri_size);

typedef struct fra_info {
    int32_t pieces, triangles, patterns, materials, interior_material;
    double default_scale; /* model units per pattern unit the bake suggests */
    double uv_scale;      /* model units per UV unit of the box projection on new faces */
} fra_info;

fra_info fra_get_info(const fra_data *data);
const char *fra_material_name(const fra_data *data, int32_t material); /* UTF-8, NULL if out of range */
int32_t fra_pattern_sites(const fra_data *data, int32_t pattern);     /* cells of a pattern; 0 if none */

/* A stored piece (what a whole part of a result is): corners, faces and its triangles in the file. */
typedef struct fra_piece {
    int32_t fragment;         /* the baked fragment it comes from */
    int32_t vertex_count;
    const float *vertices;    /* (vertex_count, 3), model space */
    int32_t face_count;
    const float *face_planes; /* (face_count, 4): outward unit normal, offset (n . x <= h inside) */
    const int32_t *face_loop_offsets; /* (face_count + 1,) into face_loops, relative to the piece's first face */
    const int32_t *face_loops;        /* corner indices (0 .. vertex_count - 1), counter-clockwise from outside */
    int32_t triangle_first, triangle_count; /* its triangles in fra_triangles() */
    double volume, centroid[3];
} fra_piece;

fra_status fra_get_piece(const fra_data *data, int32_t piece, fra_piece *out);

/* Every stored triangle: positions and normals (T, 3, 3), uvs (T, 3, 2), materials (T,). */
typedef struct fra_triangles_view {
    int32_t count;
    const float *positions, *normals, *uvs;
    const int32_t *materials;
} fra_triangles_view;
fra_triangles_view fra_triangles(const fra_data *data);

/* One corner of a result triangle: x, y, z, nx, ny, nz, u, v. */
typedef struct fra_triangle {
    double corner[3][8];
    int32_t material;
    int32_t fragment; /* index into fra_result.fragments */
} fra_triangle;

typedef struct fra_part {
    int32_t piece;
    int32_t whole;         /* 1: the stored piece unchanged (fra_get_piece); no vertices or faces below */
    int32_t vertex_first;  /* into fra_result.vertices (cut parts) */
    int32_t vertex_count;
    int32_t face_first;    /* into fra_result.face_planes / face_new / face_loop_offsets */
    int32_t face_count;
    double volume, centroid[3];
} fra_part;

typedef struct fra_fragment {
    int32_t cell;                         /* the pattern cell that made it */
    int32_t part_first, part_count;       /* into fra_result.parts, in piece order */
    int32_t whole_first, whole_count;     /* into fra_result.whole_pieces: pieces kept whole */
    int32_t triangle_first, triangle_count; /* into fra_result.triangle_order */
    double volume, center_of_mass[3];
} fra_fragment;

typedef struct fra_result {
    int32_t fragment_count, part_count, whole_count, vertex_count, face_count, loop_count, triangle_count;
    fra_fragment *fragments;     /* in increasing cell order */
    fra_part *parts;
    int32_t *whole_pieces;
    double *vertices;            /* (vertex_count, 3) corners of the cut parts */
    double *face_planes;         /* (face_count, 4) */
    int32_t *face_new;           /* (face_count,) 1: a face made by the cut (interior material) */
    int32_t *face_loop_offsets;  /* (face_count + 1,) into face_loops */
    int32_t *face_loops;         /* corner indices relative to the part's vertex_first */
    fra_triangle *triangles;     /* the new triangles (of cut pieces, and the new faces) */
    int32_t *triangle_order;     /* fragment f's triangles: triangles[triangle_order[f.triangle_first + i]] */
    size_t arena_used;           /* bytes of the arena this call used */
    size_t arena_needed;         /* with FRA_ERR_ARENA: a size that is at least needed (try twice it) */
} fra_result;

/* A generous arena size for one call with the file's patterns (the call says when it needs more). */
size_t fra_arena_hint(const fra_data *data);

/*
 * Cut the asset at `point` (model space) with pattern `pattern` oriented along `direction` (the
 * impulse; only its direction matters) at `scale` model units per pattern unit. Fills `out`; every
 * pointer in it points into `arena`, valid until the arena is reused.
 */
fra_status fra_fracture(const fra_data *data, int32_t pattern, const double point[3], const double direction[3],
                        double scale, void *arena, size_t arena_size, fra_result *out);

#ifdef __cplusplus
}
#endif

#endif
