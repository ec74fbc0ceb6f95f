/* bench/firmware_tick.py: maglev_sense_tick called N_TICKS times on the emulated Cortex-M4F from
   the readings at the table's trim at the middle speed, each gap 0.1 mm off (the same work each tick);
   with -DBENCH_INIT, maglev_sense_init N_TICKS times on them instead: the start, and what a tick whose
   state is corrupted adds (maglev_sense_tick then starts again from its readings, the whole
   estimator's table evaluated at once). */
#include "maglev_tick.h"

volatile int bench_sink;

int main(void) {
    maglev_real y[MAGLEV_SENSE_NY];
    maglev_real u[MAGLEV_NU];
    maglev_real g[MAGLEV_SENSE_SCHEDULE_NOUT];
    maglev_sense_state state;
    const maglev_real v = (maglev_real)(0.5 * (MAGLEV_SENSE_SCHEDULE_V_MIN + MAGLEV_SENSE_SCHEDULE_V_MAX));
    int i;
    int k;
    int rc = maglev_sense_schedule(v, g);
    for (i = 0; i < MAGLEV_SENSE_NY; ++i) {
        y[i] = g[MAGLEV_SENSE_SCHEDULE_OUT_Y_TRIM + i];
    }
    for (i = 0; i < MAGLEV_SENSE_NGAP; ++i) {
        y[i] += (maglev_real)1e-4;
    }
#ifdef BENCH_INIT
    (void)u;
    for (k = 0; k < N_TICKS; ++k) {
        rc |= maglev_sense_init(&state, y, MAGLEV_SENSE_ALL_VALID, v);
    }
#else
    rc |= maglev_sense_init(&state, y, MAGLEV_SENSE_ALL_VALID, v);
    for (k = 0; k < N_TICKS; ++k) {
        rc |= maglev_sense_tick(&state, y, MAGLEV_SENSE_ALL_VALID, v, 0.0, u);
    }
#endif
    bench_sink = rc;
    return 0;
}
