/*
 * Hand-written reference implementation of the maglev carriage model, for benchmarks only.
 *
 * The same model as the generated maglev_dynamics (eqs 1-4, 8-12; derive/model.py), written
 * by hand for speed and kept readable: it is the "practical limit" the generated C is
 * compared against in bench/run.py. tests/test_bench_reference.py checks that it computes the
 * same derivative as the generated C and as the symbolic model, so the comparison is fair.
 *
 * It takes the run-time parameter vector p in the order of the manifest's parameter_vector
 * (REF_PARAM_NAMES below) and is written for the structure of the default carriage: six
 * arrays; arrays 1, 2, 4, 5 with y and z control components, arrays 3 and 6 with z only.
 */
#ifndef MAGLEV_REFERENCE_MODEL_H
#define MAGLEV_REFERENCE_MODEL_H

#define REF_NX 12
#define REF_NU 11
#define REF_NP 76
#define REF_NARRAYS 6
#define REF_NAXES 5

/* Parameter names in p order (the test compares them with the manifest). */
extern const char *const REF_PARAM_NAMES[REF_NP];

/* A 3-vector and a 3x3 matrix by rows, passed by value (kept in registers at -O2). */
typedef struct {
    double x, y, z;
} ref_v3;
typedef struct {
    ref_v3 r0, r1, r2;
} ref_m3;

/* Everything of the model that depends on p alone (it keeps a pointer into p for the array
   geometry: p must outlive it). */
typedef struct {
    double m, inv_m, mg;
    ref_m3 IGinv;         /* inverse of the inertia about the CG */
    ref_m3 IO;            /* inertia about O (parallel axis theorem) */
    ref_v3 rG;            /* CG offset */
    ref_v3 ap;            /* propulsion point */
    double C0;            /* N-free eq 3 factor B0^2 w^2 / (2 k L) */
    double kL, Rc, Rc2, m2k; /* k L, R, R^2, -2 k */
    const double *arrays; /* p's array block: per array position, normal, nominal gap, circuits */
} ref_model;

/* The model's constants and the minimum-norm allocation T = E^T (E E^T)^-1, from p. */
typedef struct {
    ref_model model;
    double T[10][REF_NAXES];
} ref_consts;

void ref_prepare(const double *p, ref_consts *c);

/* xdot = f(x, u, p): same inputs and output as the generated maglev_dynamics. */
void ref_dynamics(const double x[REF_NX], const double u[REF_NU], const double *p,
                  double xdot[REF_NX]);

/* The same with the parameter constants prepared beforehand; gaps may be NULL. */
void ref_dynamics_c(const double x[REF_NX], const double u[REF_NU], const ref_consts *c,
                    double xdot[REF_NX], double gaps[REF_NARRAYS]);

/* Array forces of minimum norm that produce u_gen (as maglev_allocate). */
void ref_allocate(const double u_gen[REF_NAXES], const double *p, double F[10]);

/*
 * Closed loop, as maglev_simulate: u_gen = -(k_pos .* (a - a_ref) + k_rate .* adot),
 * a = (y, z, phi, theta, psi), at every RK4 stage; array forces by minimum-norm allocation;
 * constant F_prop. Row-major outputs x_traj (n_steps+1) x 12, u_traj (n_steps+1) x 11,
 * gap_traj (n_steps+1) x 6. Returns the steps completed; *status 0 ok, 1 contact (a gap
 * below gap_min), 2 non-finite state.
 */
long long ref_simulate(const double x0[REF_NX], double dt, long long n_steps, double F_prop,
                       const double k_pos[REF_NAXES], const double k_rate[REF_NAXES],
                       const double a_ref[REF_NAXES], const double *p, double gap_min,
                       double *x_traj, double *u_traj, double *gap_traj, int *status);

#endif
