/* Timing helpers shared by the bench drivers: a monotonic clock, input files and JSON lists. */
#ifndef MAGLEV_BENCH_UTIL_H
#define MAGLEV_BENCH_UTIL_H

#define _POSIX_C_SOURCE 199309L
#include <stdio.h>
#include <stdlib.h>
#include <time.h>

static double now_ns(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec * 1e9 + (double)ts.tv_nsec;
}

/* Read n doubles from f; exits on a short file. */
static void read_doubles(FILE *f, double *out, long n, const char *what) {
    long i;
    for (i = 0; i < n; ++i) {
        if (fscanf(f, "%lf", &out[i]) != 1) {
            fprintf(stderr, "bench: input file ends in %s (item %ld of %ld)\n", what, i, n);
            exit(2);
        }
    }
}

static void *xmalloc(size_t n) {
    void *p = malloc(n ? n : 1);
    if (!p) {
        fprintf(stderr, "bench: out of memory\n");
        exit(2);
    }
    return p;
}

static void print_list(const char *name, const double *v, int n, int last) {
    int i;
    printf("\"%s\": [", name);
    for (i = 0; i < n; ++i) printf("%s%.6g", i ? ", " : "", v[i]);
    printf("]%s\n", last ? "" : ",");
}

/* Keeps results alive so the compiler cannot drop the timed calls. */
static volatile double bench_sink;

#endif
