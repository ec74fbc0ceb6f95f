/*
 * Hand-written reference implementation of the maglev carriage model (see maglev_model.h).
 *
 * Written from derive/rigid_body.py, derive/inductrack.py, derive/geometry.py and
 * derive/model.py; the hand optimisations are the ones an engineer would make:
 *   - each sine and cosine once, the rotation matrix R built once; 3-vectors as small structs
 *     passed by value, so that -O2 keeps them in registers (no loops over 3 components);
 *   - R a_i computed once per array and used for its gap, its speed and its moment:
 *     the along-track speed of the face centre is (R v)_x + ((R w) x (R a_i))_x;
 *   - forces and moments summed in the inertial frame, rotated to body axes once;
 *   - eq 3's lift and drag share one exponential and one division:
 *     c = N C0 exp(-2 k gap) / ((k s L)^2 + R^2), lift = c (k s L)^2, drag = c (k s L) R;
 *   - the inverse of I_G and everything else that depends on p alone in ref_prepare.
 */
#include "maglev_model.h"

#include <math.h>
#include <stddef.h>

#define PI 3.14159265358979323846

/* Offsets in p (the manifest's parameter_vector for the default carriage). */
enum {
    P_MASS = 0, P_IXX = 2, P_IYY, P_IZZ, P_IXY, P_IXZ, P_IYZ, P_CG = 8, P_GRAVITY = 11,
    P_BR = 12, P_THICKNESS, P_M, P_WAVELENGTH, P_WIDTH, P_RES, P_IND, P_PITCH,
    P_ARRAYS = 20, P_ARRAY_STRIDE = 8, /* position xyz, normal xyz, nominal_gap, circuits */
    P_PROP = 69
};

const char *const REF_PARAM_NAMES[REF_NP] = {
    "vehicle.mass", "vehicle.length", "vehicle.inertia_cg.xx", "vehicle.inertia_cg.yy",
    "vehicle.inertia_cg.zz", "vehicle.inertia_cg.xy", "vehicle.inertia_cg.xz",
    "vehicle.inertia_cg.yz", "vehicle.cg_offset.x", "vehicle.cg_offset.y", "vehicle.cg_offset.z",
    "vehicle.gravity", "halbach.remanence", "halbach.thickness", "halbach.magnets_per_wavelength",
    "halbach.wavelength", "halbach.width", "circuit.resistance", "circuit.inductance",
    "circuit.pitch", /* read by the distributed force law only: this is the paper's point law */
#define ARRAY_NAMES(i)                                                                     \
    "arrays." #i ".position.x", "arrays." #i ".position.y", "arrays." #i ".position.z",    \
    "arrays." #i ".normal.x", "arrays." #i ".normal.y", "arrays." #i ".normal.z",          \
    "arrays." #i ".nominal_gap", "arrays." #i ".circuits"
    ARRAY_NAMES(1), ARRAY_NAMES(2), ARRAY_NAMES(3), ARRAY_NAMES(4), ARRAY_NAMES(5),
    ARRAY_NAMES(6),
#undef ARRAY_NAMES
    "operation.speed", "operation.propulsion_point.x", "operation.propulsion_point.y",
    "operation.propulsion_point.z", "control.state_weights.0", "control.state_weights.1",
    "control.input_weight", "track.min_gap"};

/* Control components: which arrays have a y component (all have z); u[1..10] in this order. */
static const int HAS_Y[REF_NARRAYS] = {1, 1, 0, 1, 1, 0};

/* ------------------------------------------------------------------------------ constants */

/* Column j of E: generalized force (F_y, F_z, M_x, M_y, M_z) of unit array force j. */
static void effectiveness(double a[REF_NARRAYS][3], double E[REF_NAXES][10]) {
    int i, j = 0;
    for (i = 0; i < REF_NARRAYS; ++i) {
        if (HAS_Y[i]) { /* a x e_y = (-a_z, 0, a_x) */
            E[0][j] = 1.0; E[1][j] = 0.0; E[2][j] = -a[i][2]; E[3][j] = 0.0; E[4][j] = a[i][0];
            ++j;
        }
        /* a x e_z = (a_y, -a_x, 0) */
        E[0][j] = 0.0; E[1][j] = 1.0; E[2][j] = a[i][1]; E[3][j] = -a[i][0]; E[4][j] = 0.0;
        ++j;
    }
}

/* Cholesky factor (lower) of the 5x5 Gram matrix E E^T. */
static void gram_cholesky(double E[REF_NAXES][10], double Lc[REF_NAXES][REF_NAXES]) {
    int i, j, k;
    for (i = 0; i < REF_NAXES; ++i) {
        for (j = 0; j <= i; ++j) {
            double s = 0.0;
            for (k = 0; k < 10; ++k) s += E[i][k] * E[j][k];
            for (k = 0; k < j; ++k) s -= Lc[i][k] * Lc[j][k];
            Lc[i][j] = (i == j) ? sqrt(s) : s / Lc[j][j];
        }
    }
}

/* y = (L L^T)^-1 b */
static void cholesky_solve(double Lc[REF_NAXES][REF_NAXES], const double b[REF_NAXES],
                           double y[REF_NAXES]) {
    int i, k;
    for (i = 0; i < REF_NAXES; ++i) {
        double s = b[i];
        for (k = 0; k < i; ++k) s -= Lc[i][k] * y[k];
        y[i] = s / Lc[i][i];
    }
    for (i = REF_NAXES - 1; i >= 0; --i) {
        double s = y[i];
        for (k = i + 1; k < REF_NAXES; ++k) s -= Lc[k][i] * y[k];
        y[i] = s / Lc[i][i];
    }
}

static void read_arrays(const double *p, double a[REF_NARRAYS][3], double n[REF_NARRAYS][3],
                        double g0[REF_NARRAYS], double N[REF_NARRAYS]) {
    int i, k;
    for (i = 0; i < REF_NARRAYS; ++i) {
        const double *q = p + P_ARRAYS + P_ARRAY_STRIDE * i;
        for (k = 0; k < 3; ++k) {
            a[i][k] = q[k];
            n[i][k] = q[3 + k];
        }
        g0[i] = q[6];
        N[i] = q[7];
    }
}

/* ----------------------------------------------------------------------- 3-vectors */

static inline ref_v3 v3(double x, double y, double z) {
    ref_v3 r;
    r.x = x;
    r.y = y;
    r.z = z;
    return r;
}
static inline ref_v3 v3_at(const double *a) { return v3(a[0], a[1], a[2]); }
static inline ref_v3 add(ref_v3 a, ref_v3 b) { return v3(a.x + b.x, a.y + b.y, a.z + b.z); }
static inline ref_v3 sub(ref_v3 a, ref_v3 b) { return v3(a.x - b.x, a.y - b.y, a.z - b.z); }
static inline ref_v3 scale(ref_v3 a, double s) { return v3(a.x * s, a.y * s, a.z * s); }
static inline double dot(ref_v3 a, ref_v3 b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
static inline ref_v3 cross(ref_v3 a, ref_v3 b) {
    return v3(a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x);
}
static inline ref_v3 mul(const ref_m3 *A, ref_v3 b) { /* A b */
    return v3(dot(A->r0, b), dot(A->r1, b), dot(A->r2, b));
}
static inline ref_v3 mul_t(const ref_m3 *A, ref_v3 b) { /* A^T b */
    return add(add(scale(A->r0, b.x), scale(A->r1, b.y)), scale(A->r2, b.z));
}

/* Everything but the allocation matrix (not needed by ref_dynamics). */
static void prepare_model(const double *p, ref_model *c) {
    const double m = p[P_MASS];
    const double k = 2.0 * PI / p[P_WAVELENGTH];
    const double x = PI / p[P_M];
    const double B0 = p[P_BR] * (1.0 - exp(-k * p[P_THICKNESS])) * sin(x) / x; /* eq 4 */
    const double w = p[P_WIDTH], L = p[P_IND];
    const double xx = p[P_IXX], yy = p[P_IYY], zz = p[P_IZZ];
    const double xy = p[P_IXY], xz = p[P_IXZ], yz = p[P_IYZ];
    const ref_v3 r = v3_at(p + P_CG);
    const double rr = dot(r, r);
    /* adjugate of the symmetric I_G, and its determinant */
    const double a00 = yy * zz - yz * yz, a01 = xz * yz - xy * zz, a02 = xy * yz - xz * yy;
    const double a11 = xx * zz - xz * xz, a12 = xz * xy - xx * yz, a22 = xx * yy - xy * xy;
    const double inv_det = 1.0 / (xx * a00 + xy * a01 + xz * a02);

    c->m = m;
    c->inv_m = 1.0 / m;
    c->mg = m * p[P_GRAVITY];
    c->IGinv.r0 = scale(v3(a00, a01, a02), inv_det);
    c->IGinv.r1 = scale(v3(a01, a11, a12), inv_det);
    c->IGinv.r2 = scale(v3(a02, a12, a22), inv_det);
    /* I_O = I_G + m (|r|^2 1 - r r^T) */
    c->IO.r0 = v3(xx + m * (rr - r.x * r.x), xy - m * r.x * r.y, xz - m * r.x * r.z);
    c->IO.r1 = v3(xy - m * r.y * r.x, yy + m * (rr - r.y * r.y), yz - m * r.y * r.z);
    c->IO.r2 = v3(xz - m * r.z * r.x, yz - m * r.z * r.y, zz + m * (rr - r.z * r.z));
    c->rG = r;
    c->ap = v3_at(p + P_PROP);
    c->C0 = B0 * B0 * w * w / (2.0 * k * L);
    c->kL = k * L;
    c->Rc = p[P_RES];
    c->Rc2 = c->Rc * c->Rc;
    c->m2k = -2.0 * k;
    c->arrays = p + P_ARRAYS;
}

void ref_prepare(const double *p, ref_consts *c) {
    double a[REF_NARRAYS][3], n[REF_NARRAYS][3], g0[REF_NARRAYS], N[REF_NARRAYS];
    double E[REF_NAXES][10], Lc[REF_NAXES][REF_NAXES], e[REF_NAXES], col[REF_NAXES];
    int i, j, k;
    prepare_model(p, &c->model);
    read_arrays(p, a, n, g0, N);
    effectiveness(a, E);
    gram_cholesky(E, Lc);
    for (j = 0; j < REF_NAXES; ++j) { /* column j of (E E^T)^-1, then T = E^T (E E^T)^-1 */
        for (k = 0; k < REF_NAXES; ++k) e[k] = (k == j) ? 1.0 : 0.0;
        cholesky_solve(Lc, e, col);
        for (i = 0; i < 10; ++i) {
            double s = 0.0;
            for (k = 0; k < REF_NAXES; ++k) s += E[k][i] * col[k];
            c->T[i][j] = s;
        }
    }
}

void ref_allocate(const double u_gen[REF_NAXES], const double *p, double F[10]) {
    double a[REF_NARRAYS][3], n[REF_NARRAYS][3], g0[REF_NARRAYS], N[REF_NARRAYS];
    double E[REF_NAXES][10], Lc[REF_NAXES][REF_NAXES], y[REF_NAXES];
    int i, k;
    read_arrays(p, a, n, g0, N);
    effectiveness(a, E);
    gram_cholesky(E, Lc);
    cholesky_solve(Lc, u_gen, y);
    for (i = 0; i < 10; ++i) {
        double s = 0.0;
        for (k = 0; k < REF_NAXES; ++k) s += E[k][i] * y[k];
        F[i] = s;
    }
}

/* ---------------------------------------------------------------------------------- model */

/* The pose part: R = Rz(psi) Ry(theta) Rx(phi) (body to inertial). */
typedef struct {
    ref_m3 R;
} pose;

/* R and the kinematics xdot[0..5]: inertial velocity R v and the Z-Y-X Euler rates. */
static void kinematics(const double *restrict x, pose *restrict ps, double *restrict xdot) {
    const double sf = sin(x[3]), cf = cos(x[3]);
    const double st = sin(x[4]), ct = cos(x[4]);
    const double sp = sin(x[5]), cp = cos(x[5]);
    const double inv_ct = 1.0 / ct;
    const double qs = x[10] * sf + x[11] * cf;
    ref_v3 Rv;
    ps->R.r0 = v3(cp * ct, cp * st * sf - sp * cf, cp * st * cf + sp * sf);
    ps->R.r1 = v3(sp * ct, sp * st * sf + cp * cf, sp * st * cf - cp * sf);
    ps->R.r2 = v3(-st, ct * sf, ct * cf);
    Rv = mul(&ps->R, v3_at(x + 6));
    xdot[0] = Rv.x;
    xdot[1] = Rv.y;
    xdot[2] = Rv.z;
    xdot[3] = x[9] + qs * st * inv_ct;
    xdot[4] = x[10] * cf - x[11] * sf;
    xdot[5] = qs * inv_ct;
}

/* The accelerations xdot[6..11] (eqs 1-4, 8-12), given the kinematics; gaps may be NULL.
   The array geometry comes first and the six exponentials after it, so that no call to exp
   sits in the middle of the arithmetic (every floating register is caller-saved). */
static void accelerations(const double *restrict x, const double *restrict u,
                          const ref_model *restrict c, const pose *restrict ps,
                          double *restrict xdot, double *restrict gaps) {
    const ref_m3 *R = &ps->R;
    const ref_v3 X = v3_at(x), v = v3_at(x + 6), w = v3_at(x + 9);
    const ref_v3 Rw = mul(R, w);
    const double vx = xdot[0]; /* (R v)_x */
    ref_v3 Ra[REF_NARRAYS], F, M, Fb, Mb, A, B, wxv, wd;
    double gap[REF_NARRAYS], wl[REF_NARRAYS], e[REF_NARRAYS];
    int i, j;

    /* each array's face centre R a_i, exact gap, and along-track speed times k L:
       (R (v + w x a))_x = (R v)_x + ((R w) x (R a))_x */
    for (i = 0; i < REF_NARRAYS; ++i) {
        const double *q = c->arrays + P_ARRAY_STRIDE * i;
        const ref_v3 a = v3_at(q);
        Ra[i] = mul(R, a);
        gap[i] = q[6] + dot(v3_at(q + 3), add(X, sub(Ra[i], a)));
        wl[i] = c->kL * (vx + Rw.y * Ra[i].z - Rw.z * Ra[i].y);
    }
    if (gaps)
        for (i = 0; i < REF_NARRAYS; ++i) gaps[i] = gap[i];
    for (i = 0; i < REF_NARRAYS; ++i) e[i] = exp(c->m2k * gap[i]);

    /* propulsion along the track at ap and gravity at the CG, inertial frame */
    {
        const ref_v3 RrG = mul(R, c->rG), Rap = mul(R, c->ap);
        F = v3(u[0], 0.0, -c->mg);
        M = v3(-c->mg * RrG.y, c->mg * RrG.x + Rap.z * u[0], -Rap.y * u[0]);
    }
    /* lift along n and drag along -x (eq 3), and their moments about O */
    for (i = 0; i < REF_NARRAYS; ++i) {
        const double *q = c->arrays + P_ARRAY_STRIDE * i;
        const double cc = q[7] * c->C0 * e[i] / (wl[i] * wl[i] + c->Rc2);
        const double FL = cc * wl[i] * wl[i], FD = cc * wl[i] * c->Rc;
        const ref_v3 f = v3(FL * q[3] - FD, FL * q[4], FL * q[5]);
        F = add(F, f);
        M = add(M, cross(Ra[i], f));
    }

    /* to body axes, then the array control forces (body axes, at the face centres) */
    Fb = mul_t(R, F);
    Mb = mul_t(R, M);
    for (i = 0, j = 1; i < REF_NARRAYS; ++i) {
        const double *a = c->arrays + P_ARRAY_STRIDE * i;
        if (HAS_Y[i]) { /* a x (0, f, 0) = (-a_z f, 0, a_x f) */
            const double f = u[j++];
            Fb.y += f;
            Mb.x -= a[2] * f;
            Mb.z += a[0] * f;
        }
        { /* a x (0, 0, f) = (a_y f, -a_x f, 0) */
            const double f = u[j++];
            Fb.z += f;
            Mb.x += a[1] * f;
            Mb.y -= a[0] * f;
        }
    }

    /* eqs 1-2 solved for (vdot, wdot): I_G wdot = b - r_G x a, vdot = a/m - wdot x r_G */
    wxv = cross(w, v);
    A = sub(Fb, scale(add(wxv, cross(w, cross(w, c->rG))), c->m));
    B = sub(sub(Mb, cross(w, mul(&c->IO, w))), scale(cross(c->rG, wxv), c->m));
    wd = mul(&c->IGinv, sub(B, cross(c->rG, A)));
    A = sub(scale(A, c->inv_m), cross(wd, c->rG));
    xdot[6] = A.x;
    xdot[7] = A.y;
    xdot[8] = A.z;
    xdot[9] = wd.x;
    xdot[10] = wd.y;
    xdot[11] = wd.z;
}

void ref_dynamics_c(const double x[REF_NX], const double u[REF_NU], const ref_consts *c,
                    double xdot[REF_NX], double gaps[REF_NARRAYS]) {
    pose ps;
    kinematics(x, &ps, xdot);
    accelerations(x, u, &c->model, &ps, xdot, gaps);
}

void ref_dynamics(const double x[REF_NX], const double u[REF_NU], const double *p,
                  double xdot[REF_NX]) {
    ref_model c;
    pose ps;
    prepare_model(p, &c);
    kinematics(x, &ps, xdot);
    accelerations(x, u, &c, &ps, xdot, NULL);
}

/* ----------------------------------------------------------------------------- closed loop */

typedef struct {
    const ref_consts *c;
    double F_prop;
    const double *k_pos, *k_rate, *a_ref;
} loop;

static const int AXIS_STATE[REF_NAXES] = {1, 2, 3, 4, 5}; /* y, z, phi, theta, psi */

/* One closed-loop stage: feedback on (a, adot), allocation, dynamics. */
static void stage(const loop *lp, const double x[REF_NX], double xdot[REF_NX], double u[REF_NU],
                  double gaps[REF_NARRAYS]) {
    const ref_consts *c = lp->c;
    double ug[REF_NAXES];
    pose ps;
    int i, k;
    kinematics(x, &ps, xdot); /* adot = xdot[1..5] */
    for (k = 0; k < REF_NAXES; ++k)
        ug[k] = -(lp->k_pos[k] * (x[AXIS_STATE[k]] - lp->a_ref[k]) + lp->k_rate[k] * xdot[1 + k]);
    u[0] = lp->F_prop;
    for (i = 0; i < 10; ++i) {
        double s = 0.0;
        for (k = 0; k < REF_NAXES; ++k) s += c->T[i][k] * ug[k];
        u[1 + i] = s;
    }
    accelerations(x, u, &c->model, &ps, xdot, gaps);
}

/* The loop of maglev_simulate: sample k holds x_k, the input applied at x_k and the gaps at
   x_k; the run stops at the first sample that is not finite or in contact. */
static long long run(const loop *lp, const double x0[REF_NX], double dt, long long n_steps,
                     double gap_min, double *x_traj, double *u_traj, double *gap_traj,
                     int *status) {
    double xs[REF_NX], k1[REF_NX], k2[REF_NX], k3[REF_NX], k4[REF_NX], us[REF_NU];
    long long step;
    int i;
    for (i = 0; i < REF_NX; ++i) x_traj[i] = x0[i];
    for (step = 0;; ++step) {
        const double *x = x_traj + REF_NX * step;
        double *gaps = gap_traj + REF_NARRAYS * step;
        int bad = 0;
        for (i = 0; i < REF_NX; ++i) bad |= !isfinite(x[i]);
        if (bad) {
            *status = 2;
            return step;
        }
        stage(lp, x, k1, u_traj + REF_NU * step, gaps);
        if (step < n_steps) {
            double *xn = x_traj + REF_NX * (step + 1);
            for (i = 0; i < REF_NX; ++i) xs[i] = x[i] + 0.5 * dt * k1[i];
            stage(lp, xs, k2, us, NULL);
            for (i = 0; i < REF_NX; ++i) xs[i] = x[i] + 0.5 * dt * k2[i];
            stage(lp, xs, k3, us, NULL);
            for (i = 0; i < REF_NX; ++i) xs[i] = x[i] + dt * k3[i];
            stage(lp, xs, k4, us, NULL);
            for (i = 0; i < REF_NX; ++i)
                xn[i] = x[i] + dt / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]);
        }
        for (i = 0; i < REF_NARRAYS; ++i) bad |= !(gaps[i] >= gap_min);
        if (bad) {
            *status = 1;
            return step;
        }
        if (step == n_steps) {
            *status = 0;
            return step;
        }
    }
}

long long ref_simulate(const double x0[REF_NX], double dt, long long n_steps, double F_prop,
                       const double k_pos[REF_NAXES], const double k_rate[REF_NAXES],
                       const double a_ref[REF_NAXES], const double *p, double gap_min,
                       double *x_traj, double *u_traj, double *gap_traj, int *status) {
    ref_consts c;
    loop lp;
    ref_prepare(p, &c);
    lp.c = &c;
    lp.F_prop = F_prop;
    lp.k_pos = k_pos;
    lp.k_rate = k_rate;
    lp.a_ref = a_ref;
    return run(&lp, x0, dt, n_steps, gap_min, x_traj, u_traj, gap_traj, status);
}
