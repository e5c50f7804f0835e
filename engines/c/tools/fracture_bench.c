/*
 * fracture_bench - time fr_project on a list of hits (used by bench/bench_runtime.py).
 *
 *   fracture_bench HEADER BINARY ROUNDS < hits
 *
 * Hits use fracture_check's line protocol (7 hex doubles, "-" for the default
 * threshold). Every hit is timed on its own with CLOCK_MONOTONIC, ROUNDS times
 * over the whole list; the clock's own cost (measured around an empty call) is
 * subtracted. Prints one line:
 *   median_ns <x> p99_ns <x> cpu_mean_ns <x> clock_ns <x> calls <n> groups_median <x>
 * where cpu_mean_ns is the thread CPU time of all calls divided by their number.
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

int main(int argc, char **argv)
{
    static double hits[MAX_HITS][7];
    size_t hn = 0, bn = 0;
    unsigned char *h, *b;
    fr_runtime *rt;
    fr_info info;
    fr_impact out;
    char line[4096], message[FR_MESSAGE_SIZE];
    int n = 0, rounds, r, i, calls = 0;
    double *times, *groups_count, clock_cost = 0, cpu0, cpu1;
    void *workspace;
    if (argc != 4 || (rounds = atoi(argv[3])) < 1) {
        fprintf(stderr, "usage: fracture_bench HEADER BINARY ROUNDS < hits\n");
        return 64;
    }
    h = read_file(argv[1], &hn);
    b = read_file(argv[2], &bn);
    if (h == NULL || b == NULL || fr_load(h, hn, b, bn, 0, NULL, &rt, message, sizeof message) != FR_OK) {
        fprintf(stderr, "cannot load: %s\n", h && b ? message : "cannot read the files");
        return 2;
    }
    info = fr_get_info(rt);
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
    for (i = 0; i < 1000; i++) { /* the clock's own cost */
        double t0 = now_ns(CLOCK_MONOTONIC), t1 = now_ns(CLOCK_MONOTONIC);
        clock_cost += (t1 - t0) / 1000.0;
    }
    cpu0 = now_ns(CLOCK_THREAD_CPUTIME_ID);
    for (r = 0; r < rounds; r++)
        for (i = 0; i < n; i++) {
            double t0 = now_ns(CLOCK_MONOTONIC), t1;
            (void)fr_project(rt, hits[i], hits[i] + 3, hits[i][6], workspace, &out);
            t1 = now_ns(CLOCK_MONOTONIC);
            times[calls++] = t1 - t0 - clock_cost;
            groups_count[i] = out.num_groups;
        }
    cpu1 = now_ns(CLOCK_THREAD_CPUTIME_ID);
    qsort(times, (size_t)calls, sizeof(double), by_value);
    qsort(groups_count, (size_t)n, sizeof(double), by_value);
    printf("median_ns %.1f p99_ns %.1f cpu_mean_ns %.1f clock_ns %.1f calls %d groups_median %.0f\n",
           times[calls / 2], times[(size_t)(0.99 * (calls - 1))], (cpu1 - cpu0) / calls - clock_cost, clock_cost,
           calls, n > 0 ? groups_count[n / 2] : 0.0);
    fr_free(rt);
    free(h), free(b), free(times), free(groups_count), free(workspace), free(out.groups);
    return 0;
}
