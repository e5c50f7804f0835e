/*
 * fracture_aligned_check - drive fracture_aligned.c from the command line (tests and bench).
 *
 *   fracture_aligned_check [--full] [--time N] HEADER.aligned.json BINARY.aligned.bin < hits
 *
 * Each input line is a hit: `pattern px py pz dx dy dz scale`. Each output line is one JSON
 * object: {"status": "ok", "fragments": [...]} with, per fragment, its cell, volume, centre of
 * mass, parts (piece, whole, corners, faces, volume, centroid), whole pieces, the number of new
 * triangles, all its triangles (whole pieces' included), the area of the new triangles and of
 * those with the interior material; with --full also every cut part's corners, loops, planes and
 * new flags. With --time N each hit runs N times and the line gives the median microseconds.
 */
#include "../fracture_aligned.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

static void *read_file(const char *path, size_t *size) {
    FILE *f = fopen(path, "rb");
    if (!f) return NULL;
    fseek(f, 0, SEEK_END);
    long n = ftell(f);
    fseek(f, 0, SEEK_SET);
    void *data = malloc(n > 0 ? (size_t)n : 1);
    if (data && fread(data, 1, (size_t)n, f) != (size_t)n) { free(data); data = NULL; }
    fclose(f);
    *size = (size_t)n;
    return data;
}

static double now_us(void) {
    struct timespec t;
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t); /* CPU time: the bench machine is shared */
    return (double)t.tv_sec * 1e6 + (double)t.tv_nsec * 1e-3;
}

static int cmp_double(const void *a, const void *b) {
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

static double tri_area(const fra_triangle *t) {
    const double *a = t->corner[0], *b = t->corner[1], *c = t->corner[2];
    double u[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]}, v[3] = {c[0] - a[0], c[1] - a[1], c[2] - a[2]};
    double x = u[1] * v[2] - u[2] * v[1], y = u[2] * v[0] - u[0] * v[2], z = u[0] * v[1] - u[1] * v[0];
    return 0.5 * sqrt((x * x + y * y) + z * z);
}

static void print_result(const fra_data *data, const fra_result *r, int full) {
    fra_info info = fra_get_info(data);
    printf("{\"status\": \"ok\", \"fragments\": [");
    for (int32_t f = 0; f < r->fragment_count; ++f) {
        const fra_fragment *fr = &r->fragments[f];
        int32_t total = fr->triangle_count;
        for (int32_t i = 0; i < fr->whole_count; ++i) {
            fra_piece piece;
            fra_get_piece(data, r->whole_pieces[fr->whole_first + i], &piece);
            total += piece.triangle_count;
        }
        double area = 0, interior = 0;
        for (int32_t i = 0; i < fr->triangle_count; ++i) {
            const fra_triangle *t = &r->triangles[r->triangle_order[fr->triangle_first + i]];
            double a = tri_area(t);
            area += a;
            if (t->material == info.interior_material) interior += a;
        }
        printf("%s{\"cell\": %d, \"volume\": %.17g, \"center_of_mass\": [%.17g, %.17g, %.17g], \"whole_pieces\": [",
               f ? ", " : "", fr->cell, fr->volume, fr->center_of_mass[0], fr->center_of_mass[1], fr->center_of_mass[2]);
        for (int32_t i = 0; i < fr->whole_count; ++i) printf("%s%d", i ? ", " : "", r->whole_pieces[fr->whole_first + i]);
        printf("], \"new_triangles\": %d, \"triangles\": %d, \"new_area\": %.17g, \"interior_area\": %.17g, \"parts\": [",
               fr->triangle_count, total, area, interior);
        for (int32_t i = 0; i < fr->part_count; ++i) {
            const fra_part *p = &r->parts[fr->part_first + i];
            printf("%s{\"piece\": %d, \"whole\": %s, \"vertices\": %d, \"faces\": %d, \"volume\": %.17g, "
                   "\"centroid\": [%.17g, %.17g, %.17g]", i ? ", " : "", p->piece, p->whole ? "true" : "false",
                   p->vertex_count, p->face_count, p->volume, p->centroid[0], p->centroid[1], p->centroid[2]);
            if (full && !p->whole) {
                printf(", \"corners\": [");
                for (int32_t v = 0; v < p->vertex_count; ++v) {
                    const double *x = r->vertices + 3 * (p->vertex_first + v);
                    printf("%s[%.17g, %.17g, %.17g]", v ? ", " : "", x[0], x[1], x[2]);
                }
                printf("], \"loops\": [");
                for (int32_t g = 0; g < p->face_count; ++g) {
                    int32_t face = p->face_first + g;
                    printf("%s[", g ? ", " : "");
                    for (int32_t l = r->face_loop_offsets[face]; l < r->face_loop_offsets[face + 1]; ++l)
                        printf("%s%d", l > r->face_loop_offsets[face] ? ", " : "", r->face_loops[l]);
                    printf("]");
                }
                printf("], \"planes\": [");
                for (int32_t g = 0; g < p->face_count; ++g) {
                    const double *pl = r->face_planes + 4 * (p->face_first + g);
                    printf("%s[%.17g, %.17g, %.17g, %.17g]", g ? ", " : "", pl[0], pl[1], pl[2], pl[3]);
                }
                printf("], \"new\": [");
                for (int32_t g = 0; g < p->face_count; ++g) printf("%s%d", g ? ", " : "", r->face_new[p->face_first + g]);
                printf("]");
            }
            printf("}");
        }
        printf("]}");
    }
    printf("]}\n");
}

int main(int argc, char **argv) {
    int full = 0, repeat = 0, arg = 1;
    for (; arg < argc && strncmp(argv[arg], "--", 2) == 0; ++arg) {
        if (strcmp(argv[arg], "--full") == 0) full = 1;
        else if (strcmp(argv[arg], "--time") == 0 && arg + 1 < argc) repeat = atoi(argv[++arg]);
        else { fprintf(stderr, "unknown option %s\n", argv[arg]); return 2; }
    }
    if (argc - arg != 2) {
        fprintf(stderr, "usage: fracture_aligned_check [--full] [--time N] HEADER BINARY < hits\n");
        return 2;
    }
    size_t header_size, binary_size;
    void *header = read_file(argv[arg], &header_size), *binary = read_file(argv[arg + 1], &binary_size);
    if (!header || !binary) { fprintf(stderr, "cannot read the files\n"); return 2; }
    fra_data *data;
    char why[FRA_MESSAGE_SIZE];
    fra_status s = fra_load(header, header_size, binary, binary_size, 0, &data, why, sizeof why);
    free(header);
    free(binary);
    if (s != FRA_OK) {
        printf("{\"status\": \"error\", \"error\": \"%s\", \"message\": \"%s\"}\n", fra_status_string(s), why);
        return 1;
    }
    size_t size = fra_arena_hint(data);
    void *arena = malloc(size);
    int pattern;
    double p[3], d[3], scale;
    double *times = repeat > 0 ? (double *)malloc(sizeof(double) * (size_t)repeat) : NULL;
    while (scanf("%d %lf %lf %lf %lf %lf %lf %lf", &pattern, &p[0], &p[1], &p[2], &d[0], &d[1], &d[2], &scale) == 8) {
        fra_result r;
        s = fra_fracture(data, pattern, p, d, scale, arena, size, &r);
        while (s == FRA_ERR_ARENA) {
            free(arena);
            size = r.arena_needed;
            arena = malloc(size);
            if (!arena) return 3;
            s = fra_fracture(data, pattern, p, d, scale, arena, size, &r);
        }
        if (s != FRA_OK) {
            printf("{\"status\": \"error\", \"error\": \"%s\"}\n", fra_status_string(s));
            continue;
        }
        if (repeat > 0) {
            for (int i = 0; i < repeat; ++i) {
                double t0 = now_us();
                fra_fracture(data, pattern, p, d, scale, arena, size, &r);
                times[i] = now_us() - t0;
            }
            qsort(times, (size_t)repeat, sizeof(double), cmp_double);
            printf("{\"status\": \"ok\", \"us\": %.3f, \"fragments\": %d, \"parts\": %d, \"triangles\": %d, "
                   "\"arena_used\": %zu}\n", times[repeat / 2], r.fragment_count, r.part_count, r.triangle_count,
                   r.arena_used);
        } else {
            print_result(data, &r, full);
        }
        fflush(stdout);
    }
    free(times);
    free(arena);
    fra_free(data);
    return 0;
}
