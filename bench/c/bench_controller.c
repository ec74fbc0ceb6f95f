/*
 * Bench driver for the firmware functions of a baked-parameter build, in the build's precision
 * (maglev_real is float or double), timed from C.
 *
 *   bench_controller INPUT time REPS MS     ns per call of each kind (JSON)
 *   bench_controller INPUT schedule V...    the schedule at each speed V (JSON): trim, its
 *                                           residual, Newton iterations, plants and gains
 *
 * The controller path, every control tick: maglev_lqr_control (or maglev_damping_control)
 * then maglev_allocate. The schedule, once per speed set-point: maglev_trim (Newton in C),
 * maglev_axis_plants (trim + per-axis stiffness and inertia), maglev_axis_gains (closed-form
 * LQR and damping gains from those), or maglev_lqr_gains (all three in one call). The ticks
 * are timed with the gains and reference this driver's own schedule computed at the input
 * speed, as firmware would use them.
 *
 * Compiled with -DBENCH_NEWTON_COUNT against a copy of maglev_functions.c whose Newton loop
 * increments bench_newton_iterations (bench/native.py makes it), `schedule` also reports the
 * Newton iterations of each trim; otherwise it reports -1.
 *
 * Each kind of call is repeated enough times to take about MS milliseconds per timing.
 * INPUT (written by bench/run.py): speed; n_samples; n_samples rows of x[12].
 */
#include "bench_util.h"

#include <math.h>
#include <string.h>

#include "maglev_functions.h"

#define NX 12
#define NA 5
#define NU_MAX 64
#define NS_MAX 1024
#define ARGN 32 /* arg/res entries (CasADi uses those past the inputs/outputs as scratch) */
#define MAX2(a, b) ((a) > (b) ? (a) : (b))
#define SZ_W                                                                               \
    MAX2(MAX2(MAX2(maglev_trim_SZ_W, maglev_axis_plants_SZ_W),                             \
              MAX2(maglev_axis_gains_SZ_W, maglev_lqr_gains_SZ_W)),                        \
         MAX2(MAX2(maglev_lqr_control_SZ_W, maglev_damping_control_SZ_W),                  \
              MAX2(maglev_allocate_SZ_W, maglev_dynamics_SZ_W)))
#define SZ_IW                                                                              \
    MAX2(MAX2(MAX2(maglev_trim_SZ_IW, maglev_axis_plants_SZ_IW),                           \
              MAX2(maglev_axis_gains_SZ_IW, maglev_lqr_gains_SZ_IW)),                      \
         MAX2(MAX2(maglev_lqr_control_SZ_IW, maglev_damping_control_SZ_IW),                \
              MAX2(maglev_allocate_SZ_IW, maglev_dynamics_SZ_IW)))

typedef char bench_argn_is_enough[(maglev_trim_SZ_ARG <= ARGN && maglev_trim_SZ_RES <= ARGN &&
                                   maglev_axis_plants_SZ_ARG <= ARGN &&
                                   maglev_axis_plants_SZ_RES <= ARGN &&
                                   maglev_lqr_gains_SZ_ARG <= ARGN &&
                                   maglev_lqr_gains_SZ_RES <= ARGN)
                                      ? 1
                                      : -1];

#ifdef BENCH_NEWTON_COUNT
extern long bench_newton_iterations;
#define NEWTON_ITERATIONS() bench_newton_iterations
#define NEWTON_RESET() (bench_newton_iterations = 0)
#else
#define NEWTON_ITERATIONS() (-1L)
#define NEWTON_RESET() ((void)0)
#endif

static maglev_real SPEED, XS[NS_MAX][NX];
static long N_SAMPLES;
static maglev_real W[SZ_W + 1];
static maglev_int IW[SZ_IW + 1];
/* the schedule at SPEED: what the ticks use */
static maglev_real K_S[2 * NA], C_S[NA], A_REF[NA], K_AX[NA], M_AX[NA];

enum { TRIM, PLANTS, LQR_GAINS, AXIS_GAINS, LQR, DAMPING, ALLOCATE, TICK, N_KINDS };
static const char *const NAMES[N_KINDS] = {
    "trim_ns", "axis_plants_ns", "lqr_gains_ns",     "axis_gains_ns",
    "lqr_control_ns", "damping_control_ns", "allocate_ns", "tick_ns"};

static void read_input(const char *path) {
    double v, x[NX];
    long i;
    int j;
    FILE *f = fopen(path, "r");
    if (!f) {
        fprintf(stderr, "bench: cannot open %s\n", path);
        exit(2);
    }
    read_doubles(f, &v, 1, "speed");
    SPEED = (maglev_real)v;
    read_doubles(f, &v, 1, "n_samples");
    N_SAMPLES = (long)v;
    if (N_SAMPLES < 1 || N_SAMPLES > NS_MAX) {
        fprintf(stderr, "bench: n_samples must be 1..%d\n", NS_MAX);
        exit(2);
    }
    for (i = 0; i < N_SAMPLES; ++i) {
        read_doubles(f, x, NX, "x samples");
        for (j = 0; j < NX; ++j) XS[i][j] = (maglev_real)x[j];
    }
    fclose(f);
}

static void trim(const maglev_real *v, maglev_real *x_trim, maglev_real *f_prop) {
    const maglev_real *arg[ARGN];
    maglev_real *res[ARGN];
    arg[0] = v;
    res[0] = x_trim;
    res[1] = f_prop;
    maglev_trim(arg, res, IW, W, 0);
}

static void plants(const maglev_real *v, maglev_real *k, maglev_real *m) {
    const maglev_real *arg[ARGN];
    maglev_real *res[ARGN];
    arg[0] = v;
    res[0] = k;
    res[1] = m;
    maglev_axis_plants(arg, res, IW, W, 0);
}

static void axis_gains(const maglev_real *k, const maglev_real *m, maglev_real *K,
                       maglev_real *c) {
    const maglev_real *arg[ARGN];
    maglev_real *res[ARGN];
    arg[0] = k;
    arg[1] = m;
    res[0] = K;
    res[1] = c;
    maglev_axis_gains(arg, res, IW, W, 0);
}

static void lqr_gains(const maglev_real *v, maglev_real *K, maglev_real *c) {
    const maglev_real *arg[ARGN];
    maglev_real *res[ARGN];
    arg[0] = v;
    res[0] = K;
    res[1] = c;
    maglev_lqr_gains(arg, res, IW, W, 0);
}

/* The largest |acceleration| (xdot[6..11]) of the dynamics at a trim, in the build's precision. */
static double trim_residual(const maglev_real *x_trim, maglev_real f_prop) {
    const maglev_real *arg[ARGN];
    maglev_real *res[ARGN];
    maglev_real u[NU_MAX], xdot[NX];
    const maglev_int *sp = maglev_dynamics_sparsity_in(1);
    double worst = 0.0;
    int j, nu = (int)sp[0];
    if (nu > NU_MAX) {
        fprintf(stderr, "bench: more than %d inputs\n", NU_MAX);
        exit(2);
    }
    for (j = 0; j < nu; ++j) u[j] = 0;
    u[0] = f_prop;
    arg[0] = x_trim;
    arg[1] = u;
    res[0] = xdot;
    maglev_dynamics(arg, res, IW, W, 0);
    for (j = 6; j < NX; ++j) worst = MAX2(worst, fabs((double)xdot[j]));
    return worst;
}

static void schedule_at_speed(void) {
    maglev_real x_trim[NX], f_prop;
    int j;
    trim(&SPEED, x_trim, &f_prop);
    for (j = 0; j < NA; ++j) A_REF[j] = x_trim[1 + j]; /* a = (y, z, phi, theta, psi) */
    plants(&SPEED, K_AX, M_AX);
    axis_gains(K_AX, M_AX, K_S, C_S);
}

static double time_kind(int kind, long calls) {
    const maglev_real *arg[ARGN];
    maglev_real *res[ARGN];
    maglev_real K[2 * NA], c[NA], ug[NA], F[16], xt[NX], fp, k[NA], m[NA];
    double acc = 0.0, t0;
    long i;
    int j;
    for (j = 0; j < NA; ++j) ug[j] = (maglev_real)(j + 1);
    t0 = now_ns();
    for (i = 0; i < calls; ++i) {
        const maglev_real *x = XS[i % N_SAMPLES];
        switch (kind) {
        case TRIM:
            trim(&SPEED, xt, &fp);
            acc += (double)xt[2];
            break;
        case PLANTS:
            plants(&SPEED, k, m);
            acc += (double)k[i % NA];
            break;
        case LQR_GAINS:
            lqr_gains(&SPEED, K, c);
            acc += (double)K[i % 10];
            break;
        case AXIS_GAINS: /* the plants of a sample's heave and attitude, perturbed per call */
            for (j = 0; j < NA; ++j) {
                k[j] = K_AX[j] * (maglev_real)(1.0 + 0.01 * x[1 + j]);
                m[j] = M_AX[j];
            }
            axis_gains(k, m, K, c);
            acc += (double)K[i % 10];
            break;
        case LQR:
        case DAMPING:
            arg[0] = x;
            res[0] = ug;
            if (kind == LQR) {
                arg[1] = K_S;
                arg[2] = A_REF;
                maglev_lqr_control(arg, res, IW, W, 0);
            } else {
                arg[1] = C_S;
                maglev_damping_control(arg, res, IW, W, 0);
            }
            acc += (double)ug[i % NA];
            break;
        case ALLOCATE:
            ug[i % NA] = x[1 + i % NA];
            arg[0] = ug;
            res[0] = F;
            maglev_allocate(arg, res, IW, W, 0);
            acc += (double)F[i % 10];
            break;
        default: /* TICK: one control period of the LQR path, the schedule computed before */
            arg[0] = x;
            arg[1] = K_S;
            arg[2] = A_REF;
            res[0] = ug;
            maglev_lqr_control(arg, res, IW, W, 0);
            arg[0] = ug;
            res[0] = F;
            maglev_allocate(arg, res, IW, W, 0);
            acc += (double)F[i % 10];
            break;
        }
    }
    t0 = now_ns() - t0;
    bench_sink = acc;
    return t0 / (double)calls;
}

static void print_reals(const char *name, const maglev_real *v, int n, const char *end) {
    int i;
    printf("\"%s\": [", name);
    for (i = 0; i < n; ++i) printf("%s%.17g", i ? ", " : "", (double)v[i]);
    printf("]%s", end);
}

static int run_schedule(int n, char **speeds) {
    int s;
    printf("{\"real_bytes\": %d, \"speeds\": [\n", (int)sizeof(maglev_real));
    for (s = 0; s < n; ++s) {
        maglev_real v = (maglev_real)atof(speeds[s]), xt[NX], fp, k[NA], m[NA], K[2 * NA],
                    c[NA], K2[2 * NA], c2[NA];
        long iters;
        NEWTON_RESET();
        trim(&v, xt, &fp);
        iters = NEWTON_ITERATIONS();
        plants(&v, k, m);
        axis_gains(k, m, K, c);
        lqr_gains(&v, K2, c2);
        printf("{\"speed\": %.17g, \"newton_iterations\": %ld, \"residual\": %.6g, ", (double)v,
               iters, trim_residual(xt, fp));
        print_reals("x_trim", xt, NX, ", ");
        printf("\"F_prop\": %.17g, ", (double)fp);
        print_reals("k", k, NA, ", ");
        print_reals("m", m, NA, ", ");
        print_reals("K", K, 2 * NA, ", ");
        print_reals("c_damping", c, NA, ", ");
        print_reals("K_lqr_gains", K2, 2 * NA, ", ");
        print_reals("c_lqr_gains", c2, NA, "}");
        printf("%s\n", s + 1 < n ? "," : "");
    }
    printf("]}\n");
    return 0;
}

int main(int argc, char **argv) {
    double *t[N_KINDS], target_ns;
    long calls[N_KINDS];
    int reps, k, kind;
    if (argc >= 3 && !strcmp(argv[2], "schedule")) {
        read_input(argv[1]);
        return run_schedule(argc - 3, argv + 3);
    }
    if (argc != 5 || strcmp(argv[2], "time")) {
        fprintf(stderr, "usage: %s INPUT time REPS MS | %s INPUT schedule V...\n", argv[0],
                argv[0]);
        return 2;
    }
    read_input(argv[1]);
    schedule_at_speed();
    reps = atoi(argv[3]);
    target_ns = atof(argv[4]) * 1e6;
    for (kind = 0; kind < N_KINDS; ++kind) { /* calibrate: double until a timing is long enough */
        t[kind] = xmalloc(sizeof(double) * (size_t)reps);
        calls[kind] = 1;
        while (time_kind(kind, calls[kind]) * (double)calls[kind] < target_ns) calls[kind] *= 2;
    }
    for (k = 0; k < reps; ++k)
        for (kind = 0; kind < N_KINDS; ++kind) {
            int which = (k % 2) ? N_KINDS - 1 - kind : kind;
            t[which][k] = time_kind(which, calls[which]);
        }
    printf("{\"real_bytes\": %d,\n", (int)sizeof(maglev_real));
    for (kind = 0; kind < N_KINDS; ++kind) print_list(NAMES[kind], t[kind], reps, 0);
    printf("\"sz_w\": %d, \"sz_iw\": %d}\n", (int)SZ_W, (int)SZ_IW);
    return 0;
}
