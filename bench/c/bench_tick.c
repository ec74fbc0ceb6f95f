/* bench/firmware_tick.py: maglev_tick called N_TICKS times on the emulated Cortex-M4F, from a
   state 1 mm / 1 mrad off the table's trim at the middle speed (each tick the same work). */
#include "maglev_tick.h"

volatile int bench_sink;

int main(void) {
    maglev_real x[MAGLEV_NX];
    maglev_real u[MAGLEV_NU];
    maglev_real g[MAGLEV_SCHEDULE_NOUT];
    maglev_tick_state state;
    const maglev_real v = (maglev_real)(0.5 * (MAGLEV_SCHEDULE_V_MIN + MAGLEV_SCHEDULE_V_MAX));
    int i;
    int k;
    int rc = maglev_schedule(v, g) | maglev_tick_init(&state);
    for (i = 0; i < MAGLEV_NX; ++i) {
        x[i] = (maglev_real)0;
    }
    for (i = 0; i < MAGLEV_NAXES; ++i) {
        x[MAGLEV_X_Y + i] = g[MAGLEV_SCHEDULE_OUT_A_REF + i] + (maglev_real)1e-3;
    }
    x[MAGLEV_X_U] = v;
    x[MAGLEV_X_W] = (maglev_real)1e-3;
    for (k = 0; k < N_TICKS; ++k) {
        rc |= maglev_tick(&state, x, v, u);
    }
    bench_sink = rc;
    return 0;
}
