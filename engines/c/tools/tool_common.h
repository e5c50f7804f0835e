/*
 * tool_common.h - file reading and hex doubles shared by the C reader's test and bench drivers.
 *
 * MIT licence, Copyright (c) fracture developers.
 */
#ifndef FRACTURE_TOOL_COMMON_H
#define FRACTURE_TOOL_COMMON_H

#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* The whole file in a malloc'd buffer of exactly its size (NULL if unreadable). */
static unsigned char *read_file(const char *path, size_t *size)
{
    FILE *f = fopen(path, "rb");
    unsigned char *data = NULL;
    long n;
    if (f != NULL && fseek(f, 0, SEEK_END) == 0 && (n = ftell(f)) >= 0 && fseek(f, 0, SEEK_SET) == 0) {
        data = (unsigned char *)malloc(n > 0 ? (size_t)n : 1);
        if (data != NULL && fread(data, 1, (size_t)n, f) != (size_t)n) {
            free(data);
            data = NULL;
        }
        *size = (size_t)n;
    }
    if (f != NULL)
        fclose(f);
    return data;
}

/* A double from the 16 hex digits of its IEEE-754 bits (the drivers' line protocol). */
static double from_bits(const char *hex)
{
    uint64_t u = (uint64_t)strtoull(hex, NULL, 16);
    double v;
    memcpy(&v, &u, sizeof v);
    return v;
}

#endif
