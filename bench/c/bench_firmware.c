/* x86 time per call of the firmware functions (single precision, baked, --int int32; bench/firmware.py):
   the ticks, the table schedule maglev_schedule and the Newton schedule (maglev_trim then
   maglev_lqr_gains) at the same speeds, in the same run. Prints JSON: ns per call, per round. */
#include "bench_util.h"
#include "maglev.h"
#include "maglev_gain_table.h"

#define ROUNDS 5
#define SZ 2048

static const float* arg[64];
static float* res[64];
static maglev_int iw[SZ];
static float w[SZ];
static volatile float sink;

int main(int argc, char** argv) {
    float x[12] = {0.0f, 1e-3f, -5e-3f, 2e-3f, -1e-3f, 3e-3f, 20.0f, 1e-2f, -2e-2f, 1e-2f, 2e-2f,
                   -1e-2f};
    float K[10] = {1, 2, 0.5f, 1.5f, 0.2f, 1.1f, 1.2f, 0.9f, 1.4f, 0.8f};
    float Kp[25], Kr[25], a_ref[5] = {0}, u_gen[5], F[32], out[MAGLEV_SCHEDULE_NOUT], v;
    float xt[12], fp, Kg[10], c[5];
    double lo, hi, t0, tick_lqr[ROUNDS], tick_coupled[ROUNDS], alloc[ROUNDS], table[ROUNDS],
        newton[ROUNDS];
    long i, n_tick = 200000, n_sched = 2000;
    int r;
    (void)argc;
    (void)argv;
    for (i = 0; i < 25; ++i) {
        Kp[i] = (float)(i % 7) * 0.1f;
        Kr[i] = (float)(i % 5) * 0.05f;
    }
    lo = MAGLEV_SCHEDULE_V_MIN;
    hi = MAGLEV_SCHEDULE_V_MAX;
    for (r = 0; r < ROUNDS; ++r) {
        t0 = now_ns();
        for (i = 0; i < n_tick; ++i) {
            x[1] = (float)(i & 7) * 1e-4f;
            arg[0] = x; arg[1] = K; arg[2] = a_ref; res[0] = u_gen;
            maglev_lqr_control(arg, res, iw, w, 0);
            sink = u_gen[0];
        }
        tick_lqr[r] = (now_ns() - t0) / (double)n_tick;
        t0 = now_ns();
        for (i = 0; i < n_tick; ++i) {
            x[1] = (float)(i & 7) * 1e-4f;
            arg[0] = x; arg[1] = Kp; arg[2] = Kr; arg[3] = a_ref; res[0] = u_gen;
            maglev_coupled_control(arg, res, iw, w, 0);
            sink = u_gen[0];
        }
        tick_coupled[r] = (now_ns() - t0) / (double)n_tick;
        t0 = now_ns();
        for (i = 0; i < n_tick; ++i) {
            u_gen[0] = (float)(i & 7);
            arg[0] = u_gen; res[0] = F;
            maglev_allocate(arg, res, iw, w, 0);
            sink = F[0];
        }
        alloc[r] = (now_ns() - t0) / (double)n_tick;
        t0 = now_ns();
        for (i = 0; i < n_tick; ++i) {
            v = (float)(lo + (hi - lo) * (double)(i % 1000) / 1000.0);
            maglev_schedule(v, out);
            sink = out[0];
        }
        table[r] = (now_ns() - t0) / (double)n_tick;
        t0 = now_ns();
        for (i = 0; i < n_sched; ++i) {
            v = (float)(lo + (hi - lo) * (double)(i % 1000) / 1000.0);
            arg[0] = &v; res[0] = xt; res[1] = &fp;
            maglev_trim(arg, res, iw, w, 0);
            res[0] = Kg; res[1] = c;
            maglev_lqr_gains(arg, res, iw, w, 0);
            sink = Kg[0] + xt[1];
        }
        newton[r] = (now_ns() - t0) / (double)n_sched;
    }
    printf("{\n");
    print_list("lqr_control_ns", tick_lqr, ROUNDS, 0);
    print_list("coupled_control_ns", tick_coupled, ROUNDS, 0);
    print_list("allocate_ns", alloc, ROUNDS, 0);
    print_list("schedule_table_ns", table, ROUNDS, 0);
    print_list("schedule_newton_ns", newton, ROUNDS, 1);
    printf("}\n");
    return 0;
}
