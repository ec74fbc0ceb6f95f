/* The firmware folder's tick in closed loop with its float32 plant on the emulated Cortex-M4F
   (tests/test_firmware.py): N_TICKS ticks at MAGLEV_TICK_RATE, one RK4 step of maglev_dynamics
   per tick with the command held, the command of MAGLEV_TICK_DELAY ticks ago applied (the
   safe command until then, as the host loop does). Prints every sample's state as the hex
   of its float bits, one line per sample, then a NaN-measurement tick's return code and
   command, through semihosting. X0 and V_REF come from the test. */
#include <math.h>

#include "maglev_tick.h"

#define DEPTH (MAGLEV_TICK_DELAY + 1)

void semihost_write0(const char* s);

static void put_hex(const char* tag, const float* v, int n) {
    static const char digits[] = "0123456789abcdef";
    char line[4 + 9 * MAGLEV_NX + 2];
    int i, k, pos = 0;
    line[pos++] = tag[0];
    for (i = 0; i < n; ++i) {
        union { float f; unsigned u; } b;
        b.f = v[i];
        line[pos++] = ' ';
        for (k = 0; k < 8; ++k) line[pos++] = digits[(b.u >> (28 - 4 * k)) & 0xFu];
    }
    line[pos++] = '\n';
    line[pos] = 0;
    semihost_write0(line);
}

static int rhs(const float* x, const float* u, float* xdot) {
    const float* arg[MAGLEV_DYNAMICS_SZ_ARG + 1];
    float* res[MAGLEV_DYNAMICS_SZ_RES + 1];
    maglev_int iw[MAGLEV_DYNAMICS_SZ_IW + 1];
    float w[MAGLEV_DYNAMICS_SZ_W + 1];
    arg[0] = x;
    arg[1] = u;
    res[0] = xdot;
    return maglev_dynamics(arg, res, iw, w, 0);
}

int main(void) {
    static const float x0[MAGLEV_NX] = {X0};
    float x[MAGLEV_NX], xt[MAGLEV_NX], k1[MAGLEV_NX], k2[MAGLEV_NX], k3[MAGLEV_NX],
        k4[MAGLEV_NX];
    float ring[DEPTH][MAGLEV_NU];
    maglev_tick_state state;
    const float dt = 1.0f / MAGLEV_TICK_RATE, half = dt / 2.0f, sixth = dt / 6.0f;
    float rc_f;
    int i, d, k, rc = 0;
    for (i = 0; i < MAGLEV_NX; ++i) x[i] = x0[i];
    if (maglev_tick_init(&state) != MAGLEV_OK) return 1;
    for (k = 0;; ++k) {
        const float* a;
        put_hex("x", x, MAGLEV_NX);
        if (k == N_TICKS) break;
        if (k == 0) {
            /* the commands before the first computed one: the safe command, no array force
               and the trim propulsion of the measured speed */
            float g[MAGLEV_SCHEDULE_NOUT];
            (void)maglev_schedule(sqrtf(x[MAGLEV_X_U] * x[MAGLEV_X_U] + x[MAGLEV_X_V]
                                        * x[MAGLEV_X_V] + x[MAGLEV_X_W] * x[MAGLEV_X_W]), g);
            for (d = 0; d < DEPTH; ++d) {
                ring[d][0] = g[MAGLEV_SCHEDULE_OUT_F_PROP];
                for (i = 1; i < MAGLEV_NU; ++i) ring[d][i] = 0.0f;
            }
        }
        rc = maglev_tick(&state, x, V_REF, ring[k % DEPTH]);
        if (rc != MAGLEV_OK) break;
        a = ring[(k + 1) % DEPTH];  /* the command of MAGLEV_TICK_DELAY ticks ago */
        rc |= rhs(x, a, k1);
        for (i = 0; i < MAGLEV_NX; ++i) xt[i] = x[i] + half * k1[i];
        rc |= rhs(xt, a, k2);
        for (i = 0; i < MAGLEV_NX; ++i) xt[i] = x[i] + half * k2[i];
        rc |= rhs(xt, a, k3);
        for (i = 0; i < MAGLEV_NX; ++i) xt[i] = x[i] + dt * k3[i];
        rc |= rhs(xt, a, k4);
        if (rc != 0) break;
        for (i = 0; i < MAGLEV_NX; ++i)
            x[i] = x[i] + sixth * (k1[i] + 2.0f * k2[i] + 2.0f * k3[i] + k4[i]);
    }
    rc_f = (float)rc;
    put_hex("r", &rc_f, 1);
    /* a NaN in the measured heave: the tick's code and its command (set to 7 before) */
    x[MAGLEV_X_Z] = NAN;
    for (i = 0; i < MAGLEV_NU; ++i) ring[0][i] = 7.0f;
    rc_f = (float)maglev_tick(&state, x, V_REF, ring[0]);
    put_hex("n", &rc_f, 1);
    put_hex("u", ring[0], MAGLEV_NU);
    return 0;
}
