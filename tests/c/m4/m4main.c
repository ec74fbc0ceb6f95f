/* Runs the per-tick functions and the table schedule of the single-precision baked C on the
   emulated Cortex-M4F (tests/test_firmware.py) and prints every output as the hex of its float
   bits, one per line, through semihosting: the test compares them with the host double build.
   The inputs are those the test gives the host build (X, K, C, A_REF, SPEEDS). */
#include "maglev.h"
#include "maglev_gain_table.h"

void semihost_write0(const char* s);

static void put_hex(const float* v, int n) {
    static const char digits[] = "0123456789abcdef";
    char line[10];
    int i, k;
    for (i = 0; i < n; ++i) {
        union { float f; unsigned u; } b;
        b.f = v[i];
        for (k = 0; k < 8; ++k) line[k] = digits[(b.u >> (28 - 4 * k)) & 0xFu];
        line[8] = '\n';
        line[9] = 0;
        semihost_write0(line);
    }
}

static void put_rc(int rc) {
    char line[4] = {'r', (char)('0' + rc), '\n', 0};
    semihost_write0(line);
}

int main(void) {
    const float* arg[MAGLEV_LQR_CONTROL_SZ_ARG + MAGLEV_ALLOCATE_SZ_ARG + 8];
    float* res[MAGLEV_LQR_CONTROL_SZ_RES + MAGLEV_ALLOCATE_SZ_RES + 8];
    maglev_int iw[4];
    float w[MAGLEV_LQR_CONTROL_SZ_W + MAGLEV_ALLOCATE_SZ_W + MAGLEV_DAMPING_CONTROL_SZ_W + 1];
    static const float speeds[] = {SPEEDS};
    float x[12] = {X};
    float K[10] = {K_GAINS};
    float c[5] = {C_DAMPING}, a_ref[5] = {A_REF};
    float u_gen[5], F[MAGLEV_NU], out[MAGLEV_SCHEDULE_NOUT];
    unsigned i;
    arg[0] = x;
    arg[1] = K;
    arg[2] = a_ref;
    res[0] = u_gen;
    put_rc(maglev_lqr_control(arg, res, iw, w, 0));
    put_hex(u_gen, 5);
    arg[0] = u_gen;
    res[0] = F;
    put_rc(maglev_allocate(arg, res, iw, w, 0));
    put_hex(F, MAGLEV_NU - 1);
    arg[0] = x;
    arg[1] = c;
    res[0] = u_gen;
    put_rc(maglev_damping_control(arg, res, iw, w, 0));
    put_hex(u_gen, 5);
    for (i = 0; i < sizeof speeds / sizeof speeds[0]; ++i) {
        put_rc(maglev_schedule(speeds[i], out));
        put_hex(out, MAGLEV_SCHEDULE_NOUT);
    }
    return 0;
}
