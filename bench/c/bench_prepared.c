/*
 * Bench driver: maglev_dynamics_prepared of several builds timed side by side in one process
 * (bench/law_instructions.py --time), each through its CasADi API (dlopen).
 *
 *   bench_prepared REPS CALLS INPUT LIB_1 [LIB_2 ...]   (up to MAX_LIBS libraries)
 *
 * Each library exports maglev_dynamics_prepare (p -> d) and maglev_dynamics_prepared
 * (x, u, d -> xdot) with their _work functions. INPUT is bench/laws.py's (n_p; p; x; u; ...;
 * only the first three are read). Each repeat times CALLS evaluations of every library, in an
 * order that rotates between repeats, on the thread's CPU clock; the state's heave moves by
 * 1e-12 m per call so that no call repeats the last one. Prints JSON: per library, a list of
 * ns per call, one per repeat.
 */
#include "bench_dl.h"

#include <string.h>

#define NX 12
#define NU 11
#define NP_MAX 256
#define ND_MAX 4096
#define MAX_LIBS 8

int main(int argc, char **argv) {
    int reps, n_lib, r, k, i;
    long calls, c;
    double p[NP_MAX], x[NX], u[NU], xdot[NX];
    static double d[MAX_LIBS][ND_MAX];
    fun dyn[MAX_LIBS];
    static double ns[MAX_LIBS][1000];
    cint n_p;
    FILE *f;
    if (argc < 5 || argc - 4 > MAX_LIBS) {
        fprintf(stderr, "usage: bench_prepared REPS CALLS INPUT LIB_1 [LIB_2 ...]\n");
        return 2;
    }
    reps = atoi(argv[1]);
    calls = atol(argv[2]);
    n_lib = argc - 4;
    if (reps < 1 || reps > 1000 || calls < 1) return 2;
    f = fopen(argv[3], "r");
    if (!f || fscanf(f, "%lld", &n_p) != 1 || n_p > NP_MAX) {
        fprintf(stderr, "bench: cannot read %s\n", argv[3]);
        return 2;
    }
    read_doubles(f, p, (long)n_p, "p");
    read_doubles(f, x, NX, "x");
    read_doubles(f, u, NU, "u");
    fclose(f);
    for (k = 0; k < n_lib; ++k) {
        void *h = dlopen(argv[4 + k], RTLD_NOW | RTLD_LOCAL);
        fun prep;
        if (!h) {
            fprintf(stderr, "bench: cannot open %s\n", argv[4 + k]);
            return 2;
        }
        prep = load_fun(h, "maglev_dynamics_prepare");
        dyn[k] = load_fun(h, "maglev_dynamics_prepared");
        prep.arg[0] = p;
        prep.res[0] = d[k];
        if (prep.f(prep.arg, prep.res, prep.iw, prep.w, 0)) return 1;
    }
    for (r = 0; r < reps; ++r) {
        for (i = 0; i < n_lib; ++i) {
            const int j = (i + r) % n_lib;
            fun *g = &dyn[j];
            double t0, z = x[2];
            g->arg[0] = x;
            g->arg[1] = u;
            g->arg[2] = d[j];
            g->res[0] = xdot;
            t0 = thread_ns();
            for (c = 0; c < calls; ++c) {
                x[2] += 1e-12;
                if (g->f(g->arg, g->res, g->iw, g->w, 0)) return 1;
                bench_sink += xdot[8];
            }
            ns[j][r] = (thread_ns() - t0) / (double)calls;
            x[2] = z;
        }
    }
    printf("[\n");
    for (k = 0; k < n_lib; ++k) {
        int q;
        printf(" [");
        for (q = 0; q < reps; ++q) printf("%s%.6g", q ? ", " : "", ns[k][q]);
        printf("]%s\n", k + 1 < n_lib ? "," : "");
    }
    printf("]\n");
    return 0;
}
