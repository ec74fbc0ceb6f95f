/*
 * Bench driver for the peers of the generated C (bench/peers.py): the generated
 * maglev_dynamics (CasADi), the hand-written ref_dynamics (bench/reference) and
 * sympy_dynamics (sympy.cse + sympy.ccode) and, built with -DHAVE_SYMFORCE,
 * symforce_dynamics (SymForce's C++ behind a C wrapper), each its own translation unit.
 *
 *   bench_peers INPUT REPS CALLS   ns per call of each, as JSON
 *
 * INPUT: p[75]; n_samples; n_samples rows of x[12] u[11]. Each repeat times every contender
 * once, in an order that rotates between repeats. The largest relative difference of each
 * peer's xdot from the generated one over the samples is printed too.
 */
#include "bench_util.h"

#include <math.h>

#include "maglev_functions.h"
#include "maglev_model.h"

#define NX 12
#define NU 11
#define NS_MAX 1024

void sympy_dynamics(const double *x, const double *u, const double *p, double *xdot);
#ifdef HAVE_SYMFORCE
/* SymForce's C++ (sym::SymforceDynamics, Eigen) behind a C wrapper (bench/peers.py) */
void symforce_dynamics(const double *x, const double *u, const double *p, double *xdot);
#define N_CONTENDERS 4
#else
#define N_CONTENDERS 3
#endif

static double P[REF_NP];
static long N_SAMPLES;
static double XS[NS_MAX][NX], US[NS_MAX][NU];

static void read_input(const char *path) {
    double v;
    long i;
    FILE *f = fopen(path, "r");
    if (!f) {
        fprintf(stderr, "bench: cannot open %s\n", path);
        exit(2);
    }
    read_doubles(f, P, REF_NP, "p");
    read_doubles(f, &v, 1, "n_samples");
    N_SAMPLES = (long)v;
    if (N_SAMPLES < 1 || N_SAMPLES > NS_MAX) {
        fprintf(stderr, "bench: n_samples must be 1..%d\n", NS_MAX);
        exit(2);
    }
    for (i = 0; i < N_SAMPLES; ++i) {
        read_doubles(f, XS[i], NX, "x samples");
        read_doubles(f, US[i], NU, "u samples");
    }
    fclose(f);
}

static void generated(const double *x, const double *u, double *xdot) {
    const maglev_real *arg[maglev_dynamics_SZ_ARG + 1];
    maglev_real *res[maglev_dynamics_SZ_RES + 1];
    maglev_int iw[maglev_dynamics_SZ_IW + 1];
    maglev_real w[maglev_dynamics_SZ_W + 1];
    arg[0] = x;
    arg[1] = u;
    arg[2] = P;
    res[0] = xdot;
    maglev_dynamics(arg, res, iw, w, 0);
}

static double time_one(int which, long calls) {
    double xdot[NX], acc = 0.0, t0;
    long i;
    t0 = now_ns();
    for (i = 0; i < calls; ++i) {
        long k = i % N_SAMPLES;
        if (which == 0) {
            generated(XS[k], US[k], xdot);
        } else if (which == 1) {
            ref_dynamics(XS[k], US[k], P, xdot);
        } else if (which == 2) {
            sympy_dynamics(XS[k], US[k], P, xdot);
        }
#ifdef HAVE_SYMFORCE
        else {
            symforce_dynamics(XS[k], US[k], P, xdot);
        }
#endif
        acc += xdot[i % NX];
    }
    t0 = now_ns() - t0;
    bench_sink = acc;
    return t0 / (double)calls;
}

static double max_rel_diff(int which) {
    double worst = 0.0, a[NX], b[NX];
    long k;
    int i;
    for (k = 0; k < N_SAMPLES; ++k) {
        generated(XS[k], US[k], a);
        if (which == 1) {
            ref_dynamics(XS[k], US[k], P, b);
        } else if (which == 2) {
            sympy_dynamics(XS[k], US[k], P, b);
        }
#ifdef HAVE_SYMFORCE
        else {
            symforce_dynamics(XS[k], US[k], P, b);
        }
#endif
        for (i = 0; i < NX; ++i) {
            double d = fabs(a[i] - b[i]) / (fabs(a[i]) > 1e-12 ? fabs(a[i]) : 1.0);
            if (d > worst) worst = d;
        }
    }
    return worst;
}

int main(int argc, char **argv) {
    double *t[N_CONTENDERS];
    int reps, k, j;
    long calls;
    if (argc != 4) {
        fprintf(stderr, "usage: %s INPUT REPS CALLS\n", argv[0]);
        return 2;
    }
    read_input(argv[1]);
    reps = atoi(argv[2]);
    calls = atol(argv[3]);
    for (j = 0; j < N_CONTENDERS; ++j) {
        t[j] = xmalloc(sizeof(double) * reps);
        time_one(j, calls / 4); /* warm up */
    }
    for (k = 0; k < reps; ++k) {
        for (j = 0; j < N_CONTENDERS; ++j) {
            int which = (j + k) % N_CONTENDERS;
            t[which][k] = time_one(which, calls);
        }
    }
    printf("{\n");
    printf("\"max_rel_diff_ref\": %.3g,\n\"max_rel_diff_sympy\": %.3g,\n", max_rel_diff(1),
           max_rel_diff(2));
    print_list("generated_ns", t[0], reps, 0);
    print_list("reference_ns", t[1], reps, 0);
#ifdef HAVE_SYMFORCE
    printf("\"max_rel_diff_symforce\": %.3g,\n", max_rel_diff(3));
    print_list("symforce_ns", t[3], reps, 0);
#endif
    print_list("sympy_ns", t[2], reps, 1);
    printf("}\n");
    return 0;
}
