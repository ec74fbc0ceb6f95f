/*
 * Bench driver (bench/simd_lanes.py): maglev_dynamics_prepared of the scalar library against
 * its W-lane translation (GCC vector extensions: W states per call), one process.
 *
 *   bench_lanes REPS CALLS SCALAR_LIB INPUT     (W, the lane count, fixed at compile time)
 *
 * INPUT is bench/laws.py's (n_p; p; x; u; ...). Lane l evaluates x with its heave moved by
 * l * 1e-4 m and every entry scaled by 1 + 1e-3 l; each lane's output is compared bit for bit
 * with the scalar library's at the same state. Prints JSON: ns per state of each, per repeat.
 */
#include "bench_dl.h"

#include <string.h>

#define NX 12
#define NU 11
#define NP_MAX 256
#define ND_MAX 4096

typedef double V __attribute__((vector_size(8 * W)));
int lanes_prepared(const V **arg, V **res);

int main(int argc, char **argv) {
    static double p[NP_MAX], d[ND_MAX], x[NX], u[NU], xs[W][NX], out[W][NX], w[100000];
    static V vx[NX], vu[NU], vd[ND_MAX], vr[NX];
    static double t_scalar[1000], t_lanes[1000];
    cint n_p, iw[1000];
    const double *arg[8];
    double *res[8];
    const V *varg[3] = {vx, vu, vd};
    V *vres[1] = {vr};
    casadi_fn prep, dyn;
    int reps, r, l, i, same = 1;
    long calls, c;
    void *h;
    FILE *f;
    if (argc != 5) return 2;
    reps = atoi(argv[1]);
    calls = atol(argv[2]);
    if (reps < 1 || reps > 1000 || calls < 1) return 2;
    h = dlopen(argv[3], RTLD_NOW | RTLD_LOCAL);
    f = fopen(argv[4], "r");
    if (!h || !f || fscanf(f, "%lld", &n_p) != 1 || n_p > NP_MAX) return 2;
    read_doubles(f, p, (long)n_p, "p");
    read_doubles(f, x, NX, "x");
    read_doubles(f, u, NU, "u");
    fclose(f);
    prep = (casadi_fn)dlsym(h, "maglev_dynamics_prepare");
    dyn = (casadi_fn)dlsym(h, "maglev_dynamics_prepared");
    if (!prep || !dyn) return 2;
    arg[0] = p;
    res[0] = d;
    if (prep(arg, res, iw, w, 0)) return 1;
    for (l = 0; l < W; ++l)
        for (i = 0; i < NX; ++i) xs[l][i] = x[i] * (1 + 1e-3 * l) + (i == 2 ? 1e-4 * l : 0);
    for (i = 0; i < NU; ++i)
        for (l = 0; l < W; ++l) vu[i][l] = u[i];
    for (i = 0; i < ND_MAX; ++i)
        for (l = 0; l < W; ++l) vd[i][l] = d[i];
    for (r = 0; r < reps; ++r) {
        double t0 = thread_ns();
        for (c = 0; c < calls; ++c) {
            l = (int)(c % W);
            arg[0] = xs[l];
            arg[1] = u;
            arg[2] = d;
            res[0] = out[l];
            if (dyn(arg, res, iw, w, 0)) return 1;
            bench_sink += out[l][8];
        }
        t_scalar[r] = (thread_ns() - t0) / (double)calls;
        for (i = 0; i < NX; ++i)
            for (l = 0; l < W; ++l) vx[i][l] = xs[l][i];
        t0 = thread_ns();
        for (c = 0; c < calls / W; ++c) {
            if (lanes_prepared(varg, vres)) return 1;
            bench_sink += vr[8][0];
        }
        t_lanes[r] = (thread_ns() - t0) / (double)(calls / W * W);
    }
    for (l = 0; l < W; ++l) {
        arg[0] = xs[l];
        res[0] = out[l];
        if (dyn(arg, res, iw, w, 0)) return 1;
        for (i = 0; i < NX; ++i) same &= memcmp(&out[l][i], &vr[i][l], sizeof(double)) == 0;
    }
    printf("{\"lanes\": %d, \"bitwise_same\": %s,\n", W, same ? "true" : "false");
    print_list("scalar_ns", t_scalar, reps, 0);
    print_list("lanes_ns_per_state", t_lanes, reps, 1);
    printf("}\n");
    return 0;
}
