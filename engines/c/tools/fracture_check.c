/*
 * fracture_check - conformance driver of the C reader (used by the fracture tests).
 *
 *   fracture_check HEADER BINARY [--names] [--describe] [--skip-crc] [--compact] [--structure] < impacts
 *   fracture_check --sweep HEADER BINARY
 *
 * Impacts, one per line: the IEEE-754 bits of point x y z, impulse x y z and the
 * threshold as 16 hex digits each ("-" for the file's default threshold). Answers:
 *   ok <site> <num_groups> g <groups...> b <broken edges...> a <alpha bits...> d <displacement bits...>
 *   error <status>
 * A file that does not load prints "load-error <message>" and exits with status 2.
 * Each impact is projected twice, once asking for every output and once for the groups
 * only (with a caller workspace): an answer that differs prints "error inconsistent".
 * --compact loads with FR_LOAD_COMPACT (no jump table: the other projection path).
 *
 * Damage states (docs/FORMAT.md section 12): the line "start new" (fr_new_state) or "start
 * <e health bits...>" (loaded through fr_state_from_bytes) sets the state; every impact
 * after it is an fr_hit on that state instead of an fr_project. A state that does not load
 * prints "start-error <status>" and the previous one stays. --structure prints after every
 * answer the line
 *   structure c <cracked bonds...> y <anchored flag of each fragment...> h <health bits...>
 * (c and y empty for a refused impact, h only with a state, saved through fr_state_to_bytes).
 * --describe prints, after the names, what fr_get_info, fr_anchored and fr_crack_segments give:
 *   describe f <features bits> c <crack_level bits> r <damage_rate bits> y <anchored flags, or -> n <segments
 *   of each bond...> s <coordinates of every bond's segments, as double bits...>
 *
 * Levels (docs/FORMAT.md section 14): "body <b> <impact>" answers a stateless impact on body b's view
 * (fr_project on fr_body, local indices, with its --structure line); "object new" or "object <health
 * bits...>" sets an object state (else "object-error <status>"); "hit <struck> <impact>" is fr_hit_piece on it:
 *   piece ok <body> <site> <child_body> <child_site> <split> b <broken...> c <child broken...>
 *     p <fragments of each piece, comma-separated...> y <anchored flag of each piece...> h <health bits...>
 *   piece error <status> h <health bits...>
 * where the pieces are every piece of the object after the hit (fr_object_pieces). --children prints
 * "children <hex of each child name...>" (fragments p .. p_all - 1) after the names.
 *
 * --sweep loads every truncation of the header, many of the binary, and thousands of deterministic
 * mutations (31 in 32 with FR_LOAD_COMPACT), projecting a few hits on whatever loads: run under AddressSanitizer
 * and UBSan, it shows a damaged file is an error code and never a bad memory access.
 *
 * MIT licence, Copyright (c) fracture developers.
 */
#include "../fracture_runtime.h"
#include "tool_common.h"

#include <inttypes.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* A fragment name as " <hex of its UTF-8 bytes>", "-" for the empty name (names may hold any character). */
static void print_hex_name(const char *name)
{
    const unsigned char *s = (const unsigned char *)name;
    printf(" ");
    if (*s == 0)
        printf("-");
    for (; *s; s++)
        printf("%02x", *s);
}

static void print_bits(double v)
{
    uint64_t u;
    memcpy(&u, &v, sizeof u);
    printf(" %016" PRIx64, u);
}

/*
 * Whether a groups-only projection (caller workspace, no optional output) agrees with `full`; with a
 * state, a groups-only hit on a copy of the state before the hit (`before`) must also leave `after`.
 */
static int same_groups(const fr_runtime *rt, const double point[3], const double impulse[3], double threshold,
                       const fr_impact *full, const double *before, const double *after)
{
    fr_info info = fr_get_info(rt);
    int32_t *groups = (int32_t *)malloc(sizeof(int32_t) * (size_t)info.fragments);
    double *copy = (double *)malloc(sizeof(double) * (size_t)info.edges + 1);
    void *workspace = malloc(fr_workspace_size(rt) + 1);
    fr_impact out;
    int same = groups != NULL && copy != NULL && workspace != NULL;
    memset(&out, 0, sizeof out);
    out.groups = groups;
    if (same && before != NULL) {
        memcpy(copy, before, sizeof(double) * (size_t)info.edges);
        same = fr_hit(rt, copy, point, impulse, threshold, workspace, &out) == FR_OK &&
               memcmp(copy, after, sizeof(double) * (size_t)info.edges) == 0;
    } else if (same) {
        same = fr_project(rt, point, impulse, threshold, workspace, &out) == FR_OK;
    }
    same = same && out.site == full->site && out.num_groups == full->num_groups &&
           out.num_broken == full->num_broken && out.num_cracked == full->num_cracked &&
           memcmp(groups, full->groups, sizeof(int32_t) * (size_t)info.fragments) == 0;
    free(groups);
    free(copy);
    free(workspace);
    return same;
}

/* The --structure line of an answer (`out` NULL for a refused impact); the state as its saved bytes. */
static void print_structure(const fr_runtime *rt, const fr_impact *out, const double *health)
{
    fr_info info = fr_get_info(rt);
    unsigned char *bytes = (unsigned char *)malloc(8 * (size_t)info.edges + 1);
    int j, b;
    printf("structure c");
    for (j = 0; out != NULL && j < info.edges; j++)
        if (out->cracked[j])
            printf(" %d", j);
    printf(" y");
    for (j = 0; out != NULL && j < info.fragments; j++)
        printf(" %d", out->anchored[j]);
    if (health != NULL && bytes != NULL) {
        printf(" h");
        fr_state_to_bytes(rt, health, bytes);
        for (j = 0; j < info.edges; j++) {
            uint64_t u = 0;
            for (b = 7; b >= 0; b--)
                u = u << 8 | bytes[8 * j + b];
            printf(" %016" PRIx64, u);
        }
    }
    printf("\n");
    free(bytes);
}

/* A "start" line: a fresh state, or e health bits loaded as the little-endian bytes a game saves. */
static void start_state(const fr_runtime *rt, char *line, double *health)
{
    fr_info info = fr_get_info(rt);
    size_t n = 0, capacity = 8 * (size_t)info.edges + 8;
    unsigned char *bytes = (unsigned char *)malloc(capacity);
    char *token = strtok(line + 5, " \t\r\n");
    fr_status status = FR_ERR_MEMORY;
    if (token != NULL && strcmp(token, "new") == 0) {
        fr_new_state(rt, health);
        status = FR_OK;
    } else if (bytes != NULL) {
        for (; token != NULL; token = strtok(NULL, " \t\r\n"), n += 8) {
            double v = from_bits(token);
            uint64_t u;
            int b;
            memcpy(&u, &v, sizeof u);
            for (b = 0; b < 8 && n + 8 <= capacity; b++)
                bytes[n + (size_t)b] = (unsigned char)(u >> (8 * b));
        }
        status = n <= capacity ? fr_state_from_bytes(rt, bytes, n, health) : FR_ERR_STATE;
    }
    if (status != FR_OK)
        printf("start-error %s\n", fr_status_string(status));
    free(bytes);
}

/* One impact line: fr_project, or fr_hit on `health` when a state was started. */
static int answer(const fr_runtime *rt, char *line, double *health, int structure)
{
    fr_info info = fr_get_info(rt);
    char *tokens[7];
    int n = 0, j;
    double point[3], impulse[3], threshold;
    fr_impact out;
    fr_status status;
    int32_t *groups = (int32_t *)malloc(sizeof(int32_t) * (size_t)info.fragments);
    uint8_t *broken = (uint8_t *)malloc((size_t)info.edges + 1);
    uint8_t *cracked = (uint8_t *)malloc((size_t)info.edges + 1);
    uint8_t *anchored = (uint8_t *)malloc((size_t)info.fragments);
    double *alpha = (double *)malloc(sizeof(double) * (size_t)info.modes);
    double *disp = (double *)malloc(sizeof(double) * (size_t)info.fragments * (size_t)info.dim);
    double *before = (double *)malloc(sizeof(double) * (size_t)info.edges + 1);
    char *token;
    for (token = strtok(line, " \t\r\n"); token != NULL && n < 7; token = strtok(NULL, " \t\r\n"))
        tokens[n++] = token;
    if (n < 7 || groups == NULL || broken == NULL || cracked == NULL || anchored == NULL || alpha == NULL
        || disp == NULL || before == NULL) {
        free(groups), free(broken), free(cracked), free(anchored), free(alpha), free(disp), free(before);
        return n == 0 ? 0 : -1;
    }
    for (j = 0; j < 3; j++) {
        point[j] = from_bits(tokens[j]);
        impulse[j] = from_bits(tokens[3 + j]);
    }
    threshold = strcmp(tokens[6], "-") == 0 ? info.default_threshold : from_bits(tokens[6]);
    memset(&out, 0, sizeof out);
    out.groups = groups;
    out.broken = broken;
    out.alpha = alpha;
    out.displacement = disp;
    out.cracked = cracked;
    out.anchored = anchored;
    if (health != NULL) {
        memcpy(before, health, sizeof(double) * (size_t)info.edges);
        status = fr_hit(rt, health, point, impulse, threshold, NULL, &out);
    } else {
        status = fr_project(rt, point, impulse, threshold, NULL, &out);
    }
    if (status == FR_OK && !same_groups(rt, point, impulse, threshold, &out, health != NULL ? before : NULL, health)) {
        printf("error inconsistent\n");
    } else if (status != FR_OK) {
        printf("error %s\n", fr_status_string(status));
    } else {
        printf("ok %ld %ld g", (long)out.site, (long)out.num_groups);
        for (j = 0; j < info.fragments; j++)
            printf(" %ld", (long)groups[j]);
        printf(" b");
        for (j = 0; j < info.edges; j++)
            if (broken[j])
                printf(" %d", j);
        printf(" a");
        for (j = 0; j < info.modes; j++)
            print_bits(alpha[j]);
        printf(" d");
        for (j = 0; j < info.fragments * info.dim; j++)
            print_bits(disp[j]);
        printf("\n");
    }
    if (structure)
        print_structure(rt, status == FR_OK ? &out : NULL, health);
    free(groups), free(broken), free(cracked), free(anchored), free(alpha), free(disp), free(before);
    return 1;
}

static void print_health(const double *health, int32_t n)
{
    int32_t j;
    printf(" h");
    for (j = 0; j < n; j++)
        print_bits(health[j]);
    printf("\n");
}

/* A "hit" line: fr_hit_piece on the object state, then every piece (fr_object_pieces). */
static int hit_piece(const fr_runtime *rt, char *line, double *health)
{
    static unsigned calls = 0;
    const fr_levels_info lv = fr_get_levels_info(rt);
    char *tokens[8];
    int n = 0, j, i;
    double point[3], impulse[3], threshold;
    fr_piece_hit out;
    fr_pieces all;
    fr_status status;
    void *workspace = malloc(fr_piece_workspace_size(rt) + 16);
    int32_t *groups = (int32_t *)malloc(sizeof(int32_t) * (size_t)lv.max_children);
    int32_t *child_groups = (int32_t *)malloc(sizeof(int32_t) * (size_t)lv.max_children);
    uint8_t *broken = (uint8_t *)malloc((size_t)lv.max_bonds + 1), *child_broken = (uint8_t *)malloc((size_t)lv.max_bonds + 1);
    int32_t *fragments = (int32_t *)malloc(sizeof(int32_t) * (size_t)lv.all_fragments * 4);
    uint8_t *anchored = (uint8_t *)malloc((size_t)lv.all_fragments);
    char *token;
    for (token = strtok(line + 4, " \t\r\n"); token != NULL && n < 8; token = strtok(NULL, " \t\r\n"))
        tokens[n++] = token;
    if (n < 8 || workspace == NULL || groups == NULL || child_groups == NULL || broken == NULL || child_broken == NULL
        || fragments == NULL || anchored == NULL) {
        free(workspace), free(groups), free(child_groups), free(broken), free(child_broken), free(fragments), free(anchored);
        return -1;
    }
    for (j = 0; j < 3; j++) {
        point[j] = from_bits(tokens[1 + j]);
        impulse[j] = from_bits(tokens[4 + j]);
    }
    threshold = strcmp(tokens[7], "-") == 0 ? 0.0 : from_bits(tokens[7]);
    memset(&out, 0, sizeof out);
    out.body.groups = groups;
    out.body.broken = broken;
    out.child.groups = child_groups;
    out.child.broken = child_broken;
    out.pieces.fragments = fragments;
    out.pieces.offsets = fragments + lv.all_fragments;
    status = fr_hit_piece(rt, health, (int32_t)atol(tokens[0]), point, impulse, strcmp(tokens[7], "-") == 0 ? NULL
                          : &threshold, (calls++ % 2) ? workspace : NULL, &out); /* both scratch paths */
    if (status != FR_OK) {
        printf("piece error %s", fr_status_string(status));
    } else {
        const fr_runtime *body = fr_body(rt, out.body_index), *child = fr_body(rt, out.child_body);
        printf("piece ok %d %d %d %d %d b", (int)out.body_index, (int)out.body.site, (int)out.child_body,
               out.child_body >= 0 ? (int)out.child.site : -1, (int)out.split);
        for (j = 0; j < fr_get_info(body).edges; j++)
            if (broken[j])
                printf(" %d", j);
        printf(" c");
        for (j = 0; child != NULL && j < fr_get_info(child).edges; j++)
            if (child_broken[j])
                printf(" %d", j);
        memset(&all, 0, sizeof all);
        all.fragments = fragments;
        all.offsets = fragments + lv.all_fragments;
        all.anchored = anchored;
        printf(" p");
        if (fr_object_pieces(rt, health, workspace, &all) == FR_OK) {
            for (i = 0; i < all.count; i++)
                for (j = all.offsets[i]; j < all.offsets[i + 1]; j++)
                    printf("%s%d", j == all.offsets[i] ? " " : ",", (int)all.fragments[j]);
            printf(" y");
            for (i = 0; i < all.count; i++)
                printf(" %d", (int)all.anchored[i]);
        }
    }
    print_health(health, lv.state_size);
    free(workspace), free(groups), free(child_groups), free(broken), free(child_broken), free(fragments), free(anchored);
    return 1;
}

/* An "object" line: a fresh object state or one given as health bits (refused: "object-error", state kept). */
static void object_state(const fr_runtime *rt, char *line, double *health)
{
    const int32_t size = fr_get_levels_info(rt).state_size;
    double *values = (double *)malloc(sizeof(double) * (size_t)size + 8);
    char *token = strtok(line + 6, " \t\r\n");
    size_t n = 0;
    if (values == NULL)
        return;
    if (token != NULL && strcmp(token, "new") == 0) {
        fr_new_object_state(rt, health);
        free(values);
        return;
    }
    for (; token != NULL; token = strtok(NULL, " \t\r\n"), n++)
        if (n < (size_t)size)
            values[n] = from_bits(token);
    if (fr_check_object_state(rt, values, n) == FR_OK)
        memcpy(health, values, sizeof(double) * n);
    else
        printf("object-error %s\n", fr_status_string(FR_ERR_STATE));
    free(values);
}

/* The --describe line: section 12's data through the accessors. */
static void describe(const fr_runtime *rt)
{
    fr_info info = fr_get_info(rt);
    const int32_t *anchored = fr_anchored(rt);
    int32_t j, count, c;
    printf("describe f %d c", (int)info.features);
    print_bits(info.crack_level);
    printf(" r");
    print_bits(info.damage_rate);
    printf(anchored != NULL ? " y" : " y -");
    for (j = 0; anchored != NULL && j < info.fragments; j++)
        printf(" %d", (int)anchored[j]);
    printf(" n");
    for (j = 0; j < info.edges; j++) {
        (void)fr_crack_segments(rt, j, &count);
        printf(" %d", (int)count);
    }
    printf(" s");
    for (j = 0; j < info.edges; j++) {
        const float *segments = fr_crack_segments(rt, j, &count);
        for (c = 0; c < 6 * count; c++)
            print_bits((double)segments[c]);
    }
    printf("\n");
}

/* Load a private, exactly sized copy (so a sanitizer sees any read past its end). */
static fr_status load_copy(const unsigned char *h, size_t hn, const unsigned char *b, size_t bn, unsigned flags,
                           fr_runtime **rt)
{
    unsigned char *hc = (unsigned char *)malloc(hn ? hn : 1), *bc = (unsigned char *)malloc(bn ? bn : 1);
    fr_status status = FR_ERR_MEMORY;
    char message[FR_MESSAGE_SIZE];
    if (hc != NULL && bc != NULL) {
        memcpy(hc, h, hn);
        memcpy(bc, b, bn);
        status = fr_load(hc, hn, bn ? bc : NULL, bn, flags, NULL, rt, message, sizeof message);
    }
    free(hc);
    free(bc);
    return status;
}

/* A few projections and hits on whatever loaded, with every optional output, and every bond's crack segments. */
static void poke_projections(const fr_runtime *rt)
{
    static const double POINTS[3][3] = {{0, 0, 0}, {1e6, -1e6, 3}, {0.25, -0.5, 0.125}};
    static const double IMPULSES[3][3] = {{1, 2, 3}, {-1e155, 0, 1e155}, {1e-170, 0, 0}};
    fr_info info = fr_get_info(rt);
    int32_t *groups = (int32_t *)malloc(sizeof(int32_t) * (size_t)info.fragments);
    double *disp = (double *)malloc(sizeof(double) * (size_t)info.fragments * (size_t)info.dim);
    double *health = (double *)malloc(sizeof(double) * (size_t)info.edges + 1);
    uint8_t *cracked = (uint8_t *)malloc((size_t)info.edges + 1), *anchored = (uint8_t *)malloc((size_t)info.fragments);
    volatile float sink = 0;
    int32_t i, count, c;
    fr_new_state(rt, health);
    for (i = 0; i < 6 && groups != NULL && disp != NULL && health != NULL && cracked != NULL && anchored != NULL; i++) {
        fr_impact out;
        memset(&out, 0, sizeof out);
        out.groups = groups;
        out.displacement = disp;
        out.cracked = cracked;
        out.anchored = anchored;
        if (i < 3)
            (void)fr_project(rt, POINTS[i], IMPULSES[i], i == 2 ? 1e-171 : info.default_threshold, NULL, &out);
        else
            (void)fr_hit(rt, health, POINTS[i - 3], IMPULSES[i - 3], i == 5 ? 1e-171 : info.default_threshold, NULL,
                         &out);
    }
    for (i = 0; i < info.edges; i++) {
        const float *segments = fr_crack_segments(rt, i, &count);
        for (c = 0; c < 6 * count; c++)
            sink += segments[c];
    }
    (void)sink;
    free(groups), free(disp), free(health), free(cracked), free(anchored);
}

static unsigned long long rng_state = 0x9E3779B97F4A7C15ull;

static unsigned rng(void)
{
    rng_state = rng_state * 6364136223846793005ull + 1442695040888963407ull;
    return (unsigned)(rng_state >> 33);
}

static int sweep(const unsigned char *h, size_t hn, const unsigned char *b, size_t bn)
{
    static const unsigned char INTERESTING[] = "0123456789-+.eE\"\\{}[],: \xff\x80u";
    unsigned char *copy = (unsigned char *)malloc((hn > bn ? hn : bn) + 1);
    size_t i, loads = 0, ok = 0;
    int round, pass;
    fr_runtime *rt;
    if (copy == NULL)
        return 1;
    for (i = 0; i <= hn; i++, loads++)
        if (load_copy(h, i, b, bn, 0, &rt) == FR_OK) {
            ok++;
            poke_projections(rt);
            fr_free(rt);
        }
    for (i = 0; i <= bn; i += (i < 512 || bn - i < 64) ? 1 : 1 + bn / 512, loads++)
        if (load_copy(h, hn, b, i, 0, &rt) == FR_OK) {
            ok++;
            fr_free(rt);
        }
    for (pass = 0; pass < 2; pass++) /* pass 0: header bytes, pass 1: binary bytes (CRC not checked) */
        for (round = 0; round < 3000; round++, loads++) {
            size_t n = pass == 0 ? hn : bn;
            int edits = 1 + (int)(rng() % 3), e;
            if (n == 0)
                break;
            memcpy(copy, pass == 0 ? h : b, n);
            for (e = 0; e < edits; e++)
                copy[rng() % n] = pass == 0 ? INTERESTING[rng() % (sizeof INTERESTING - 1)] : (unsigned char)rng();
            if (load_copy(pass == 0 ? copy : h, pass == 0 ? hn : hn, pass == 1 ? copy : b, bn,
                          (pass == 1 ? FR_LOAD_SKIP_CRC : 0) | (round % 32 ? FR_LOAD_COMPACT : 0), &rt) == FR_OK) {
                ok++;
                poke_projections(rt);
                fr_free(rt);
            }
        }
    free(copy);
    printf("sweep loads=%lu ok=%lu\n", (unsigned long)loads, (unsigned long)ok);
    return 0;
}

int main(int argc, char **argv)
{
    const char *paths[2] = {NULL, NULL};
    int i, names = 0, do_sweep = 0, count = 0, structure = 0, stateful = 0, do_describe = 0, children = 0;
    double *object;
    unsigned flags = 0;
    unsigned char *h, *b;
    size_t hn = 0, bn = 0;
    fr_runtime *rt;
    double *health;
    static char line[1 << 16]; /* a start line holds e * 17 characters */
    char message[FR_MESSAGE_SIZE];
    for (i = 1; i < argc; i++) {
        if (strcmp(argv[i], "--names") == 0) names = 1;
        else if (strcmp(argv[i], "--skip-crc") == 0) flags |= FR_LOAD_SKIP_CRC;
        else if (strcmp(argv[i], "--sweep") == 0) do_sweep = 1;
        else if (strcmp(argv[i], "--compact") == 0) flags |= FR_LOAD_COMPACT;
        else if (strcmp(argv[i], "--structure") == 0) structure = 1;
        else if (strcmp(argv[i], "--describe") == 0) do_describe = 1;
        else if (strcmp(argv[i], "--children") == 0) children = 1;
        else if (count < 2) paths[count++] = argv[i];
    }
    if (count != 2) {
        fprintf(stderr, "usage: fracture_check [--names] [--describe] [--skip-crc] [--compact] [--structure] [--sweep] "
                        "HEADER BINARY < impacts\n");
        return 64;
    }
    h = read_file(paths[0], &hn);
    b = read_file(paths[1], &bn);
    if (h == NULL || b == NULL || do_sweep || load_copy(h, hn, b, bn, flags, &rt) != FR_OK) {
        int status = 2;
        if (h == NULL || b == NULL) {
            printf("load-error cannot read the files\n");
        } else if (do_sweep) {
            status = sweep(h, hn, b, bn);
        } else {
            (void)fr_load(h, hn, b, bn, flags, NULL, &rt, message, sizeof message);
            printf("load-error %s\n", message);
        }
        free(h);
        free(b);
        return status;
    }
    if (names) {
        printf("names");
        for (i = 0; i < fr_get_info(rt).fragments; i++) {
            print_hex_name(fr_fragment_name(rt, i));
        }
        printf("\n");
    }
    if (children) {
        printf("children");
        for (i = fr_get_info(rt).fragments; i < fr_get_levels_info(rt).all_fragments; i++) {
            print_hex_name(fr_any_fragment_name(rt, i));
        }
        printf("\n");
    }
    if (do_describe)
        describe(rt);
    object = (double *)malloc(sizeof(double) * (size_t)fr_get_levels_info(rt).state_size + 8);
    fr_new_object_state(rt, object);
    health = (double *)malloc(sizeof(double) * (size_t)fr_get_info(rt).edges + 1);
    fr_new_state(rt, health); /* until a "start" line loads another */
    while (health != NULL && fgets(line, sizeof line, stdin) != NULL) {
        if (strncmp(line, "start", 5) == 0) {
            start_state(rt, line, health);
            stateful = 1;
        } else if (strncmp(line, "object", 6) == 0 && object != NULL) {
            object_state(rt, line, object);
        } else if (strncmp(line, "hit ", 4) == 0 && object != NULL) {
            if (hit_piece(rt, line, object) < 0) {
                fprintf(stderr, "bad hit line\n");
                return 64;
            }
        } else if (strncmp(line, "body ", 5) == 0) {
            char *rest = line + 5;
            const fr_runtime *body = fr_body(rt, (int32_t)strtol(rest, &rest, 10));
            if (body == NULL || answer(body, rest, NULL, structure) < 0) {
                fprintf(stderr, "bad body line\n");
                return 64;
            }
        } else if (answer(rt, line, stateful ? health : NULL, structure) < 0) {
            fprintf(stderr, "bad impact line\n");
            return 64;
        }
    }
    free(health);
    free(object);
    fr_free(rt);
    free(h);
    free(b);
    return 0;
}
