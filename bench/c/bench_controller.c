/*
 * Bench driver for the controller path of a baked-parameter build, in the build's precision
 * (casadi_real is float or double): ns per call of maglev_lqr_gains, maglev_lqr_control,
 * maglev_damping_control and maglev_allocate, and of one control tick (lqr_control then
 * allocate), timed from C.
 *
 *   bench_controller INPUT REPS MS
 *
 * Each kind of call is repeated enough times to take about MS milliseconds per timing.
 * INPUT (written by bench/run.py): speed; n_samples; n_samples rows of x[12].
 */
#include "bench_util.h"

#include "maglev_functions.h"

#define NX 12
#define NS_MAX 1024
#define MAX2(a, b) ((a) > (b) ? (a) : (b))
#define SZ_W                                                                               \
    MAX2(MAX2(maglev_lqr_gains_SZ_W, maglev_lqr_control_SZ_W),                             \
         MAX2(maglev_damping_control_SZ_W, maglev_allocate_SZ_W))
#define SZ_IW                                                                              \
    MAX2(MAX2(maglev_lqr_gains_SZ_IW, maglev_lqr_control_SZ_IW),                           \
         MAX2(maglev_damping_control_SZ_IW, maglev_allocate_SZ_IW))

static casadi_real SPEED, XS[NS_MAX][NX];
static long N_SAMPLES;
static casadi_real W[SZ_W + 1];
static casadi_int IW[SZ_IW + 1];

enum { GAINS, LQR, DAMPING, ALLOCATE, TICK, N_KINDS };
static const char *const NAMES[N_KINDS] = {"lqr_gains_ns", "lqr_control_ns",
                                           "damping_control_ns", "allocate_ns", "tick_ns"};

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
    SPEED = (casadi_real)v;
    read_doubles(f, &v, 1, "n_samples");
    N_SAMPLES = (long)v;
    if (N_SAMPLES < 1 || N_SAMPLES > NS_MAX) {
        fprintf(stderr, "bench: n_samples must be 1..%d\n", NS_MAX);
        exit(2);
    }
    for (i = 0; i < N_SAMPLES; ++i) {
        read_doubles(f, x, NX, "x samples");
        for (j = 0; j < NX; ++j) XS[i][j] = (casadi_real)x[j];
    }
    fclose(f);
}

static double time_kind(int kind, long calls) {
    const casadi_real *arg[8];
    casadi_real *res[8];
    casadi_real K[10], c[5], ug[5], F[10];
    double acc = 0.0, t0;
    long i;
    int j;
    for (j = 0; j < 5; ++j) ug[j] = (casadi_real)(j + 1);
    t0 = now_ns();
    for (i = 0; i < calls; ++i) {
        const casadi_real *x = XS[i % N_SAMPLES];
        switch (kind) {
        case GAINS:
            arg[0] = &SPEED;
            res[0] = K;
            res[1] = c;
            maglev_lqr_gains(arg, res, IW, W, 0);
            acc += (double)K[i % 10];
            break;
        case LQR:
        case DAMPING:
            arg[0] = x;
            arg[1] = &SPEED;
            res[0] = ug;
            if (kind == LQR)
                maglev_lqr_control(arg, res, IW, W, 0);
            else
                maglev_damping_control(arg, res, IW, W, 0);
            acc += (double)ug[i % 5];
            break;
        case ALLOCATE:
            ug[i % 5] = x[1 + i % 5];
            arg[0] = ug;
            res[0] = F;
            maglev_allocate(arg, res, IW, W, 0);
            acc += (double)F[i % 10];
            break;
        default: /* TICK: one control period of the LQR path, gains computed before */
            arg[0] = x;
            arg[1] = &SPEED;
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

int main(int argc, char **argv) {
    double *t[N_KINDS], target_ns;
    long calls[N_KINDS];
    int reps, k, kind;
    if (argc != 4) {
        fprintf(stderr, "usage: %s INPUT REPS MS\n", argv[0]);
        return 2;
    }
    read_input(argv[1]);
    reps = atoi(argv[2]);
    target_ns = atof(argv[3]) * 1e6;
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
    printf("{\"real_bytes\": %d,\n", (int)sizeof(casadi_real));
    for (kind = 0; kind < N_KINDS; ++kind) print_list(NAMES[kind], t[kind], reps, 0);
    printf("\"sz_w\": %d, \"sz_iw\": %d}\n", (int)SZ_W, (int)SZ_IW);
    return 0;
}
