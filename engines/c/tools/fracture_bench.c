/*
 * fracture_bench - time fr_project (or fr_hit) on a list of hits (used by bench/bench_runtime.py).
 *
 *   fracture_bench HEADER BINARY ROUNDS [--compact] [--all] [--state] < hits
 *   fracture_bench HEADER BINARY ROUNDS --pieces [--compact] < piece hits
 *
 * Hits use fracture_check's line protocol (7 hex doubles, "-" for the default
 * threshold). Every hit is timed on its own with CLOCK_MONOTONIC, ROUNDS times
 * over the whole list; the clock's own cost (measured around an empty call) is
 * subtracted. --compact loads with FR_LOAD_COMPACT (no jump table); --all also asks
 * for the broken edges, alpha and the displacements (by default only the groups);
 * --state times fr_hit on a damage state instead of fr_project, also asking for the
 * cracked bonds and the anchored fragments (what a game draws and keeps static). Each
 * hit gets a fresh state (a copy outside the timed call, inside cpu_mean_ns), so every
 * hit tests and unites every bond that holds, as on an undamaged object.
 * --pieces times fr_hit_piece (docs/FORMAT.md section 14.5) on a file with levels: each line is
 * "<struck> <7 hit tokens> <object state health bits...>", the state copied outside the timed call
 * (e.g. a state where struck's parent has split, so a level-2 piece is hit).
 * Prints one line:
 *   median_ns <x> p99_ns <x> cpu_mean_ns <x> clock_ns <x> calls <n> groups_median <x> load_ms <x> memory_kib <x>
 * where cpu_mean_ns is the thread CPU time of all calls divided by their number, load_ms
 * the thread CPU time of fr_load and memory_kib fr_memory_size.
 *
 * MIT licence, Copyright (c) fracture developers.
 */
#define _POSIX_C_SOURCE 199309L
#include "../fracture_runtime.h"
#include "tool_common.h"

#include <inttypes.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#define MAX_HITS 100000
static double now_ns(clockid_t clock)
{
    struct timespec t;
    clock_gettime(clock, &t);
    return (double)t.tv_sec * 1e9 + (double)t.tv_nsec;
}

static int by_value(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

#define MAX_STATE 4096

/* --pieces: fr_hit_piece on the states of the hit lines; prints the line main prints. */
static int bench_pieces(fr_runtime *rt, int rounds, double load_ms)
{
    static char line[1 << 17];
    const fr_levels_info lv = fr_get_levels_info(rt);
    double *hits = (double *)malloc(sizeof(double) * 8 * MAX_HITS);
    double *states = NULL, *health = (double *)malloc(sizeof(double) * (size_t)lv.state_size + 1);
    double *times, clock_cost = 0, cpu0, cpu1, *groups_count;
    void *workspace = malloc(fr_piece_workspace_size(rt) + 16);
    fr_piece_hit out;
    int n = 0, i, r, calls = 0;
    if (lv.state_size > MAX_STATE || hits == NULL || health == NULL || workspace == NULL)
        return 2;
    states = (double *)malloc(sizeof(double) * (size_t)lv.state_size * MAX_HITS + 1);
    memset(&out, 0, sizeof out);
    out.body.groups = (int32_t *)malloc(sizeof(int32_t) * (size_t)lv.max_children);
    out.child.groups = (int32_t *)malloc(sizeof(int32_t) * (size_t)lv.max_children);
    out.pieces.fragments = (int32_t *)malloc(sizeof(int32_t) * (size_t)lv.all_fragments);
    out.pieces.offsets = (int32_t *)malloc(sizeof(int32_t) * ((size_t)lv.all_fragments + 1));
    while (states != NULL && n < MAX_HITS && fgets(line, sizeof line, stdin) != NULL) {
        char *token = strtok(line, " \t\r\n");
        for (i = 0; i < 8 + lv.state_size && token != NULL; i++, token = strtok(NULL, " \t\r\n")) {
            if (i == 0)
                hits[8 * n] = atof(token);
            else if (i < 8)
                hits[8 * n + i] = strcmp(token, "-") == 0 ? -1.0 : from_bits(token);
            else
                states[(size_t)n * (size_t)lv.state_size + (size_t)(i - 8)] = from_bits(token);
        }
        n += i == 8 + lv.state_size;
    }
    times = (double *)malloc(sizeof(double) * (size_t)n * (size_t)rounds + 1);
    groups_count = (double *)malloc(sizeof(double) * (size_t)n + 1);
    for (i = 0; i < 1000; i++) {
        double t0 = now_ns(CLOCK_MONOTONIC), t1 = now_ns(CLOCK_MONOTONIC);
        clock_cost += (t1 - t0) / 1000.0;
    }
    cpu0 = now_ns(CLOCK_THREAD_CPUTIME_ID);
    for (r = 0; r < rounds; r++)
        for (i = 0; i < n; i++) {
            const double *hit = hits + 8 * i;
            double t0, t1;
            memcpy(health, states + (size_t)i * (size_t)lv.state_size, sizeof(double) * (size_t)lv.state_size);
            t0 = now_ns(CLOCK_MONOTONIC);
            (void)fr_hit_piece(rt, health, (int32_t)hit[0], hit + 1, hit + 4, hit[7] < 0 ? NULL : hit + 7, workspace,
                               &out);
            t1 = now_ns(CLOCK_MONOTONIC);
            times[calls++] = t1 - t0 - clock_cost;
            groups_count[i] = out.pieces.count;
        }
    cpu1 = now_ns(CLOCK_THREAD_CPUTIME_ID);
    qsort(times, (size_t)calls, sizeof(double), by_value);
    qsort(groups_count, (size_t)n, sizeof(double), by_value);
    printf("median_ns %.1f p99_ns %.1f cpu_mean_ns %.1f clock_ns %.1f calls %d groups_median %.0f load_ms %.2f "
           "memory_kib %.0f\n",
           calls ? times[calls / 2] : 0.0, calls ? times[(size_t)(0.99 * (calls - 1))] : 0.0,
           calls ? (cpu1 - cpu0) / calls - clock_cost : 0.0, clock_cost, calls, n > 0 ? groups_count[n / 2] : 0.0,
           load_ms, (double)fr_memory_size(rt) / 1024.0);
    free(hits), free(states), free(health), free(times), free(groups_count), free(workspace);
    free(out.body.groups), free(out.child.groups), free(out.pieces.fragments), free(out.pieces.offsets);
    return 0;
}

int main(int argc, char **argv)
{
    static double hits[MAX_HITS][7];
    size_t hn = 0, bn = 0;
    unsigned char *h, *b;
    fr_runtime *rt;
    fr_info info;
    fr_impact out;
    char line[4096], message[FR_MESSAGE_SIZE];
    int n = 0, rounds, r, i, calls = 0, all = 0, stateful = 0, pieces = 0;
    unsigned flags = 0;
    double *times, *groups_count, clock_cost = 0, cpu0, cpu1, load0, load_ms;
    double *health, *fresh;
    void *workspace;
    for (i = 4; i < argc; i++) {
        if (strcmp(argv[i], "--compact") == 0) flags |= FR_LOAD_COMPACT;
        else if (strcmp(argv[i], "--all") == 0) all = 1;
        else if (strcmp(argv[i], "--state") == 0) stateful = 1;
        else if (strcmp(argv[i], "--pieces") == 0) pieces = 1;
        else argc = 0;
    }
    if (argc < 4 || (rounds = atoi(argv[3])) < 1) {
        fprintf(stderr, "usage: fracture_bench HEADER BINARY ROUNDS [--compact] [--all] [--state] < hits\n");
        return 64;
    }
    h = read_file(argv[1], &hn);
    b = read_file(argv[2], &bn);
    load0 = now_ns(CLOCK_THREAD_CPUTIME_ID);
    if (h == NULL || b == NULL || fr_load(h, hn, b, bn, flags, NULL, &rt, message, sizeof message) != FR_OK) {
        fprintf(stderr, "cannot load: %s\n", h && b ? message : "cannot read the files");
        return 2;
    }
    load_ms = (now_ns(CLOCK_THREAD_CPUTIME_ID) - load0) / 1e6;
    info = fr_get_info(rt);
    if (pieces) {
        int status = bench_pieces(rt, rounds, load_ms);
        fr_free(rt);
        free(h), free(b);
        return status;
    }
    while (n < MAX_HITS && fgets(line, sizeof line, stdin) != NULL) {
        char *token = strtok(line, " \t\r\n");
        for (i = 0; i < 7 && token != NULL; i++, token = strtok(NULL, " \t\r\n"))
            hits[n][i] = strcmp(token, "-") == 0 ? info.default_threshold : from_bits(token);
        n += i == 7;
    }
    times = (double *)malloc(sizeof(double) * (size_t)n * (size_t)rounds + 1);
    groups_count = (double *)malloc(sizeof(double) * (size_t)n + 1);
    workspace = malloc(fr_workspace_size(rt) + 16);
    memset(&out, 0, sizeof out);
    out.groups = (int32_t *)malloc(sizeof(int32_t) * (size_t)info.fragments);
    health = (double *)malloc(sizeof(double) * (size_t)info.edges + 1);
    fresh = (double *)malloc(sizeof(double) * (size_t)info.edges + 1);
    fr_new_state(rt, fresh);
    if (stateful) {
        out.cracked = (uint8_t *)malloc((size_t)info.edges + 1);
        out.anchored = (uint8_t *)malloc((size_t)info.fragments);
    }
    if (all) {
        out.broken = (uint8_t *)malloc((size_t)info.edges + 1);
        out.alpha = (double *)malloc(sizeof(double) * (size_t)info.modes);
        out.displacement = (double *)malloc(sizeof(double) * (size_t)info.fragments * (size_t)info.dim);
    }
    for (i = 0; i < 1000; i++) { /* the clock's own cost */
        double t0 = now_ns(CLOCK_MONOTONIC), t1 = now_ns(CLOCK_MONOTONIC);
        clock_cost += (t1 - t0) / 1000.0;
    }
    cpu0 = now_ns(CLOCK_THREAD_CPUTIME_ID);
    for (r = 0; r < rounds; r++)
        for (i = 0; i < n; i++) {
            double t0, t1;
            if (stateful)
                memcpy(health, fresh, sizeof(double) * (size_t)info.edges);
            t0 = now_ns(CLOCK_MONOTONIC);
            if (stateful)
                (void)fr_hit(rt, health, hits[i], hits[i] + 3, hits[i][6], workspace, &out);
            else
                (void)fr_project(rt, hits[i], hits[i] + 3, hits[i][6], workspace, &out);
            t1 = now_ns(CLOCK_MONOTONIC);
            times[calls++] = t1 - t0 - clock_cost;
            groups_count[i] = out.num_groups;
        }
    cpu1 = now_ns(CLOCK_THREAD_CPUTIME_ID);
    qsort(times, (size_t)calls, sizeof(double), by_value);
    qsort(groups_count, (size_t)n, sizeof(double), by_value);
    printf("median_ns %.1f p99_ns %.1f cpu_mean_ns %.1f clock_ns %.1f calls %d groups_median %.0f load_ms %.2f "
           "memory_kib %.0f\n",
           times[calls / 2], times[(size_t)(0.99 * (calls - 1))], (cpu1 - cpu0) / calls - clock_cost, clock_cost,
           calls, n > 0 ? groups_count[n / 2] : 0.0, load_ms, (double)fr_memory_size(rt) / 1024.0);
    fr_free(rt);
    free(h), free(b), free(times), free(groups_count), free(workspace), free(out.groups);
    free(out.broken), free(out.alpha), free(out.displacement), free(out.cracked), free(out.anchored);
    free(health), free(fresh);
    return 0;
}
