/*
 * Bench driver for the run-time-parameter double build: the generated maglev_dynamics and
 * maglev_simulate against the hand-written reference (bench/reference/maglev_model.c), timed
 * from C so that no foreign-function overhead enters the figures.
 *
 *   bench_runtime INPUT dynamics REPS CALLS   ns per call, generated vs hand-written
 *   bench_runtime INPUT simulate REPS         ns per closed-loop run, generated vs hand-written
 *   bench_runtime INPUT count gen|ref CALLS   only calls one model (for callgrind)
 *   bench_runtime INPUT count simgen|simref 1 only runs one closed loop (for callgrind)
 *
 * Each repeat times every contender once, in an order that alternates between repeats, so
 * that the figures of one repeat are taken at the same moment; bench/run.py takes medians.
 * INPUT (written by bench/run.py): p[75]; x0[12] F_prop k_pos[5] k_rate[5] a_ref[5] dt
 * n_steps gap_min; n_samples; n_samples rows of x[12] u[11].
 */
#include "bench_util.h"

#include <math.h>
#include <string.h>

#include "maglev_functions.h"
#include "maglev_model.h"
#include "maglev_simulate.h"

#define NX 12
#define NU 11
#define NG 6
#define NS_MAX 1024

static double P[REF_NP], X0[NX], F_PROP, K_POS[5], K_RATE[5], A_REF[5], DT, GAP_MIN;
/* the per-axis gains as maglev_simulate takes them: 5 x 5 matrices, diagonal (per-axis LQR) */
static double K_POS_M[25], K_RATE_M[25];
static long long N_STEPS;
static long N_SAMPLES;
static double XS[NS_MAX][NX], US[NS_MAX][NU];

static void read_input(const char *path) {
    double v[3];
    long i;
    FILE *f = fopen(path, "r");
    if (!f) {
        fprintf(stderr, "bench: cannot open %s\n", path);
        exit(2);
    }
    read_doubles(f, P, REF_NP, "p");
    read_doubles(f, X0, NX, "x0");
    read_doubles(f, &F_PROP, 1, "F_prop");
    read_doubles(f, K_POS, 5, "k_pos");
    read_doubles(f, K_RATE, 5, "k_rate");
    read_doubles(f, A_REF, 5, "a_ref");
    read_doubles(f, v, 3, "dt n_steps gap_min");
    DT = v[0];
    N_STEPS = (long long)v[1];
    GAP_MIN = v[2];
    for (i = 0; i < 5; ++i) {
        K_POS_M[i * 6] = K_POS[i];
        K_RATE_M[i * 6] = K_RATE[i];
    }
    read_doubles(f, v, 1, "n_samples");
    N_SAMPLES = (long)v[0];
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

/* ---------------------------------------------------------------------- ns per call */

static double time_generated(long calls) {
    const maglev_real *arg[maglev_dynamics_SZ_ARG + 1];
    maglev_real *res[maglev_dynamics_SZ_RES + 1];
    maglev_int iw[maglev_dynamics_SZ_IW + 1];
    maglev_real w[maglev_dynamics_SZ_W + 1];
    double xdot[NX], acc = 0.0, t0;
    long i;
    t0 = now_ns();
    for (i = 0; i < calls; ++i) {
        long k = i % N_SAMPLES;
        arg[0] = XS[k];
        arg[1] = US[k];
        arg[2] = P;
        res[0] = xdot;
        maglev_dynamics(arg, res, iw, w, 0);
        acc += xdot[i % NX];
    }
    t0 = now_ns() - t0;
    bench_sink = acc;
    return t0 / (double)calls;
}

static double time_reference(long calls) {
    double xdot[NX], acc = 0.0, t0;
    long i;
    t0 = now_ns();
    for (i = 0; i < calls; ++i) {
        long k = i % N_SAMPLES;
        ref_dynamics(XS[k], US[k], P, xdot);
        acc += xdot[i % NX];
    }
    t0 = now_ns() - t0;
    bench_sink = acc;
    return t0 / (double)calls;
}

static double time_reference_prepared(long calls) {
    double xdot[NX], acc = 0.0, t0;
    ref_consts c;
    long i;
    ref_prepare(P, &c);
    t0 = now_ns();
    for (i = 0; i < calls; ++i) {
        long k = i % N_SAMPLES;
        ref_dynamics_c(XS[k], US[k], &c, xdot, NULL);
        acc += xdot[i % NX];
    }
    t0 = now_ns() - t0;
    bench_sink = acc;
    return t0 / (double)calls;
}

static void bench_dynamics(int reps, long calls) {
    double *g = xmalloc(sizeof(double) * reps), *r = xmalloc(sizeof(double) * reps);
    double *rc = xmalloc(sizeof(double) * reps);
    int k;
    time_generated(calls / 4); /* warm up caches and the clock */
    time_reference(calls / 4);
    for (k = 0; k < reps; ++k) {
        if (k % 2) {
            r[k] = time_reference(calls);
            rc[k] = time_reference_prepared(calls);
            g[k] = time_generated(calls);
        } else {
            g[k] = time_generated(calls);
            rc[k] = time_reference_prepared(calls);
            r[k] = time_reference(calls);
        }
    }
    printf("{\"calls\": %ld,\n", calls);
    print_list("generated_ns", g, reps, 0);
    print_list("reference_ns", r, reps, 0);
    print_list("reference_prepared_ns", rc, reps, 1);
    printf("}\n");
    free(g);
    free(r);
    free(rc);
}

/* ------------------------------------------------------------------------ closed loop */

typedef struct {
    double *x, *u, *g;
    long long last;
    int status;
} traj;

static void traj_alloc(traj *t) {
    size_t n = (size_t)(N_STEPS + 1);
    t->x = xmalloc(sizeof(double) * n * NX);
    t->u = xmalloc(sizeof(double) * n * NU);
    t->g = xmalloc(sizeof(double) * n * NG);
}

static double run_generated(traj *t) {
    double t0 = now_ns();
    t->last = maglev_simulate(X0, DT, N_STEPS, F_PROP, K_POS_M, K_RATE_M, A_REF, 0, P, GAP_MIN,
                              t->x, t->u, t->g, 0, &t->status);
    return now_ns() - t0;
}

static double run_reference(traj *t) {
    double t0 = now_ns();
    t->last = ref_simulate(X0, DT, N_STEPS, F_PROP, K_POS, K_RATE, A_REF, P, GAP_MIN, t->x, t->u, t->g,
                 &t->status);
    return now_ns() - t0;
}

/* Largest |a - b| relative to the largest |b| of each column, over the rows both hold. */
static double max_rel_diff(const double *a, const double *b, long long rows, int cols) {
    double worst = 0.0;
    int j;
    for (j = 0; j < cols; ++j) {
        double scale = 0.0, diff = 0.0;
        long long i;
        for (i = 0; i < rows; ++i) {
            double d = fabs(a[i * cols + j] - b[i * cols + j]), s = fabs(b[i * cols + j]);
            if (d > diff) diff = d;
            if (s > scale) scale = s;
        }
        if (scale > 0.0 && diff / scale > worst) worst = diff / scale;
    }
    return worst;
}

static void bench_simulate(int reps) {
    traj tg, tr;
    double *g = xmalloc(sizeof(double) * reps), *r = xmalloc(sizeof(double) * reps);
    long long rows;
    int k;
    traj_alloc(&tg);
    traj_alloc(&tr);
    run_generated(&tg); /* warm up: touches every page of the outputs */
    run_reference(&tr);
    for (k = 0; k < reps; ++k) {
        if (k % 2) {
            r[k] = run_reference(&tr);
            g[k] = run_generated(&tg);
        } else {
            g[k] = run_generated(&tg);
            r[k] = run_reference(&tr);
        }
    }
    rows = (tg.last < tr.last ? tg.last : tr.last) + 1;
    printf("{\"n_steps\": %lld, \"dt\": %.17g,\n", N_STEPS, DT);
    printf("\"generated\": {\"last\": %lld, \"status\": %d},\n", tg.last, tg.status);
    printf("\"reference\": {\"last\": %lld, \"status\": %d},\n", tr.last, tr.status);
    printf("\"max_rel_diff\": {\"x\": %.3g, \"u\": %.3g, \"gaps\": %.3g},\n",
           max_rel_diff(tg.x, tr.x, rows, NX), max_rel_diff(tg.u, tr.u, rows, NU),
           max_rel_diff(tg.g, tr.g, rows, NG));
    printf("\"x_final\": [");
    for (k = 0; k < NX; ++k) printf("%s%.17g", k ? ", " : "", tg.x[(rows - 1) * NX + k]);
    printf("],\n");
    print_list("generated_ns", g, reps, 0);
    print_list("reference_ns", r, reps, 1);
    printf("}\n");
}

int main(int argc, char **argv) {
    if (argc < 4) {
        fprintf(stderr, "usage: %s INPUT dynamics REPS CALLS | simulate REPS | "
                        "count gen|ref CALLS\n", argv[0]);
        return 2;
    }
    read_input(argv[1]);
    if (!strcmp(argv[2], "dynamics") && argc == 5) {
        bench_dynamics(atoi(argv[3]), atol(argv[4]));
    } else if (!strcmp(argv[2], "simulate")) {
        bench_simulate(atoi(argv[3]));
    } else if (!strcmp(argv[2], "count") && argc == 5) {
        long calls = atol(argv[4]);
        if (!strcmp(argv[3], "gen") || !strcmp(argv[3], "ref")) {
            bench_sink = !strcmp(argv[3], "gen") ? time_generated(calls) : time_reference(calls);
        } else {
            traj t;
            traj_alloc(&t);
            bench_sink = !strcmp(argv[3], "simgen") ? run_generated(&t) : run_reference(&t);
        }
    } else {
        fprintf(stderr, "bench: unknown mode %s\n", argv[2]);
        return 2;
    }
    return 0;
}
