/* The machine's peak double-precision add and multiply rate on one core (issue 53's limits;
   bench/casadi_peer.py builds and runs it).

   Each kernel runs 6 independent multiply chains and 6 independent add chains (x *= m,
   y += a; 14 registers with the constants, none spilled: no chain waits on another, so the
   rate is the units' throughput, not their latency), no fused multiply-add (built with -ffp-contract=off; the project's C and its
   peers count a multiply and an add as two operations), on scalars and on GCC vectors of
   2 (SSE2), 4 (AVX) and 8 (AVX-512F) doubles, each in a function built for its extension
   (target attribute) and run only where the CPU has it (__builtin_cpu_supports). The clock
   is the thread's CPU time; the best of REPEATS. Prints one line per kernel:
   "<name> <lanes> <Gflop/s>". Build: gcc -O2 -ffp-contract=off -fno-tree-vectorize
   -fno-tree-slp-vectorize (the scalar kernel stays scalar). */

#define _POSIX_C_SOURCE 199309L
#include <stdio.h>
#include <stdlib.h>
#include <time.h>

#define CHAINS 6
#define REPEATS 5

static double cpu_s(void) {
    struct timespec ts;
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

/* the kernel over type T: 2 * CHAINS operations of its lanes per iteration; the sum of the
   chains is returned so that nothing is dead (without -ffast-math no chain folds) */
#define KERNEL(NAME, T, ATTR)                                                        \
    ATTR static double NAME(long n, double seed) {                                   \
        T m = (T){0} + (1.0 + 0x1p-40), a = (T){0} + 0x1p-30;                        \
        T x0 = (T){0} + seed, x1 = x0 + 1, x2 = x0 + 2, x3 = x0 + 3, x4 = x0 + 4,    \
          x5 = x0 + 5, y0 = x0 - 1, y1 = x0 - 2, y2 = x0 - 3, y3 = x0 - 4,           \
          y4 = x0 - 5, y5 = x0 - 6, s;                                               \
        long i;                                                                      \
        for (i = 0; i < n; ++i) {                                                    \
            x0 = x0 * m; x1 = x1 * m; x2 = x2 * m; x3 = x3 * m; x4 = x4 * m;         \
            x5 = x5 * m;                                                             \
            y0 = y0 + a; y1 = y1 + a; y2 = y2 + a; y3 = y3 + a; y4 = y4 + a;         \
            y5 = y5 + a;                                                             \
        }                                                                            \
        s = x0 + x1 + x2 + x3 + x4 + x5 + y0 + y1 + y2 + y3 + y4 + y5;              \
        return ((double *)&s)[0];                                                    \
    }

typedef double v2d __attribute__((vector_size(16)));
typedef double v4d __attribute__((vector_size(32)));
typedef double v8d __attribute__((vector_size(64)));

KERNEL(k_scalar, double, )
KERNEL(k_sse2, v2d, __attribute__((target("sse2"))))
KERNEL(k_avx, v4d, __attribute__((target("avx"))))
KERNEL(k_avx512, v8d, __attribute__((target("avx512f"))))

static void measure(const char *name, int lanes, double (*k)(long, double), long n) {
    double best = 1e300, sink = 0;
    int r;
    for (r = 0; r < REPEATS; ++r) {
        double t0 = cpu_s(), t;
        sink += k(n, 1.0 + r);
        t = cpu_s() - t0;
        if (t < best) best = t;
    }
    printf("%s %d %.4f\n", name, lanes, 2.0 * CHAINS * lanes * (double)n / best * 1e-9);
    if (sink == 0.5) printf("#\n"); /* never: keeps the results live */
}

int main(int argc, char **argv) {
    long n = argc > 1 ? atol(argv[1]) : 20000000L;
    __builtin_cpu_init();
    measure("scalar", 1, k_scalar, n);
    measure("sse2", 2, k_sse2, n);
    if (__builtin_cpu_supports("avx")) measure("avx", 4, k_avx, n);
    if (__builtin_cpu_supports("avx512f")) measure("avx512f", 8, k_avx512, n);
    return 0;
}
