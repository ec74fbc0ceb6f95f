/*
 * Bench driver: the run-time-parameter double libraries of two force laws (or two builds of
 * one) timed side by side in one process, each function through its CasADi API (dlopen), so
 * that no foreign-function overhead enters the figures and both libraries see the same moment
 * of a shared machine.
 *
 *   bench_laws REPS LIB_1 INPUT_1 [LIB_2 INPUT_2 ...]   (up to MAX_LIBS libraries)
 *
 * Times are the thread's CPU time (CLOCK_THREAD_CPUTIME_ID). Each repeat times every function of every library once, in an order that rotates between
 * repeats; bench/laws.py takes medians and the ratios per repeat. Prints JSON, one list of ns
 * per call per library and function.
 * INPUT (written by bench/laws.py): n_p; p[n_p]; x[12] u[11] (a state near trim); v (a trim
 * speed); x0[12] F_prop K_pos[25] K_rate[25] a_ref[5] dt n_steps gap_min (a closed-loop run).
 */
#include "bench_dl.h"

#include <string.h>

#define NX 12
#define NU 11
#define NG 6
#define NP_MAX 256
#define MAX_LIBS 6

typedef long long (*simulate_fn)(const double *, double, long long, double, const double *,
                                 const double *, const double *, const void *, const double *,
                                 double, double *, double *, double *, long long *, int *);

typedef struct {
    void *h;
    fun dynamics, jacobians, trim, stiffness;
    simulate_fn simulate;
    cint n_p;
    double p[NP_MAX], x[NX], u[NU], v, x0[NX], F_prop, K_pos[25], K_rate[25], a_ref[5], dt,
        gap_min;
    long long n_steps;
    double xdot[NX], A[NX * NX], B[NX * NU], x_trim[NX], f_trim, K_mag[25], K_oth[25];
    double *x_traj, *u_traj, *g_traj;
} lib;

static void load(lib *L, const char *path, const char *input) {
    double v[3];
    FILE *f = fopen(input, "r");
    L->h = dlopen(path, RTLD_NOW | RTLD_LOCAL);
    if (!L->h || !f) {
        fprintf(stderr, "bench: cannot open %s or %s\n", path, input);
        exit(2);
    }
    L->dynamics = load_fun(L->h, "maglev_dynamics");
    L->jacobians = load_fun(L->h, "maglev_jacobians");
    L->trim = load_fun(L->h, "maglev_trim");
    L->stiffness = load_fun(L->h, "maglev_stiffness");
    L->simulate = (simulate_fn)dlsym(L->h, "maglev_simulate");
    read_doubles(f, v, 1, "n_p");
    L->n_p = (cint)v[0];
    if (L->n_p < 1 || L->n_p > NP_MAX) exit(2);
    read_doubles(f, L->p, L->n_p, "p");
    read_doubles(f, L->x, NX, "x");
    read_doubles(f, L->u, NU, "u");
    read_doubles(f, &L->v, 1, "v");
    read_doubles(f, L->x0, NX, "x0");
    read_doubles(f, &L->F_prop, 1, "F_prop");
    read_doubles(f, L->K_pos, 25, "K_pos");
    read_doubles(f, L->K_rate, 25, "K_rate");
    read_doubles(f, L->a_ref, 5, "a_ref");
    read_doubles(f, v, 3, "dt n_steps gap_min");
    fclose(f);
    L->dt = v[0];
    L->n_steps = (long long)v[1];
    L->gap_min = v[2];
    L->x_traj = xmalloc(sizeof(double) * (size_t)(L->n_steps + 1) * NX);
    L->u_traj = xmalloc(sizeof(double) * (size_t)(L->n_steps + 1) * NU);
    L->g_traj = xmalloc(sizeof(double) * (size_t)(L->n_steps + 1) * NG);
}

enum { DYNAMICS, JACOBIANS, TRIM, STIFFNESS, SIMULATE, N_WHAT };
static const char *WHAT[N_WHAT] = {"dynamics", "jacobians", "trim", "stiffness", "closed_loop"};
static const long CALLS[N_WHAT] = {20000, 2000, 1000, 2000, 1};

/* CPU ns per call of one function */
static double time_one(lib *L, int what) {
    long i, n = CALLS[what];
    double t0 = thread_ns(), acc = 0;
    for (i = 0; i < n; ++i) {
        if (what == DYNAMICS) {
            fun *F = &L->dynamics;
            F->arg[0] = L->x;
            F->arg[1] = L->u;
            F->arg[2] = L->p;
            F->res[0] = L->xdot;
            F->f(F->arg, F->res, F->iw, F->w, 0);
            acc += L->xdot[i % NX];
        } else if (what == JACOBIANS) {
            fun *F = &L->jacobians;
            F->arg[0] = L->x;
            F->arg[1] = L->u;
            F->arg[2] = L->p;
            F->res[0] = L->A;
            F->res[1] = L->B;
            F->f(F->arg, F->res, F->iw, F->w, 0);
            acc += L->A[i % (NX * NX)];
        } else if (what == TRIM) {
            fun *F = &L->trim;
            F->arg[0] = &L->v;
            F->arg[1] = L->p;
            F->res[0] = L->x_trim;
            F->res[1] = &L->f_trim;
            F->f(F->arg, F->res, F->iw, F->w, 0);
            acc += L->f_trim;
        } else if (what == STIFFNESS) {
            fun *F = &L->stiffness;
            F->arg[0] = L->x;
            F->arg[1] = L->u;
            F->arg[2] = L->p;
            F->res[0] = L->K_mag;
            F->res[1] = L->K_oth;
            F->f(F->arg, F->res, F->iw, F->w, 0);
            acc += L->K_mag[i % 25];
        } else {
            long long sat;
            int status;
            L->simulate(L->x0, L->dt, L->n_steps, L->F_prop, L->K_pos, L->K_rate, L->a_ref, 0,
                        L->p, L->gap_min, L->x_traj, L->u_traj, L->g_traj, &sat, &status);
            acc += L->x_traj[L->n_steps * NX + 2] + status;
        }
    }
    bench_sink = acc;
    return (thread_ns() - t0) / (double)n;
}

int main(int argc, char **argv) {
    lib L[MAX_LIBS];
    int reps, k, w, j, n;
    double *t;
    if (argc < 4 || argc % 2 != 0 || (argc - 2) / 2 > MAX_LIBS) {
        fprintf(stderr, "usage: bench_laws REPS LIB_1 INPUT_1 [LIB_2 INPUT_2 ...]\n");
        return 2;
    }
    reps = atoi(argv[1]);
    n = (argc - 2) / 2;
    if (reps < 1) return 2;
    for (j = 0; j < n; ++j) load(&L[j], argv[2 + 2 * j], argv[3 + 2 * j]);
    t = xmalloc(sizeof(double) * (size_t)(n * N_WHAT * reps));
    for (w = 0; w < N_WHAT; ++w) { /* warm up */
        for (j = 0; j < n; ++j) time_one(&L[j], w);
    }
    for (k = 0; k < reps; ++k) {
        for (w = 0; w < N_WHAT; ++w) {
            for (j = 0; j < n; ++j) {
                int which = (j + k) % n;
                t[(which * N_WHAT + w) * reps + k] = time_one(&L[which], w);
            }
        }
    }
    printf("[\n");
    for (j = 0; j < n; ++j) {
        printf("{\n");
        for (w = 0; w < N_WHAT; ++w) {
            char name[64];
            snprintf(name, sizeof name, "%s_ns", WHAT[w]);
            print_list(name, t + (j * N_WHAT + w) * reps, reps, w == N_WHAT - 1);
        }
        printf("}%s\n", j == n - 1 ? "" : ",");
    }
    printf("]\n");
    free(t);
    return 0;
}
