/* CasADi functions of a library opened with dlopen (bench_laws.c, bench_prepared.c): a
 * function's handle with its argument, result and work arrays, and the thread's CPU clock. */
#ifndef MAGLEV_BENCH_DL_H
#define MAGLEV_BENCH_DL_H

#include "bench_util.h"

#include <dlfcn.h>

typedef long long cint;
typedef int (*casadi_fn)(const double **, double **, cint *, double *, int);
typedef int (*work_fn)(cint *, cint *, cint *, cint *);

typedef struct {
    casadi_fn f;
    const double **arg;
    double **res;
    cint *iw;
    double *w;
} fun;

/* NAME of the library h with arrays of its NAME_work sizes; exits when it is missing. */
static fun load_fun(void *h, const char *name) {
    char buf[128];
    fun out;
    cint sz[4];
    work_fn work;
    snprintf(buf, sizeof buf, "%s_work", name);
    out.f = (casadi_fn)dlsym(h, name);
    work = (work_fn)dlsym(h, buf);
    if (!out.f || !work || work(&sz[0], &sz[1], &sz[2], &sz[3])) {
        fprintf(stderr, "bench: %s missing\n", name);
        exit(2);
    }
    out.arg = xmalloc(sizeof(double *) * (size_t)(sz[0] + 1));
    out.res = xmalloc(sizeof(double *) * (size_t)(sz[1] + 1));
    out.iw = xmalloc(sizeof(cint) * (size_t)(sz[2] + 1));
    out.w = xmalloc(sizeof(double) * (size_t)(sz[3] + 1));
    return out;
}

/* The calling thread's CPU time: time the thread spent descheduled stays out. */
static double thread_ns(void) {
    struct timespec ts;
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
    return (double)ts.tv_sec * 1e9 + (double)ts.tv_nsec;
}

#endif
