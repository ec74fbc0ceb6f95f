/* maglev_batch.c: many closed-loop runs of a run-time-parameter library's maglev_simulate in
   one call, on every core (OpenMP; compiled without it, the runs go one after another).

   Not generated: the same driver serves every carriage. It is compiled on its own against the
   library's maglev_simulate.h (-I the library's derivation folder, for maglev_real and
   maglev_control_loop) and reaches maglev_simulate through the pointer it is given, so the
   large generated library is neither recompiled nor linked again (maglevgen.runtime.library). Each run
   is exactly the call maglevgen.analyses.simulate.simulate makes for it (maglev_simulate is reentrant:
   its work arrays are on the stack), so a run's trajectory does not depend on the threads. */
#include "maglev_simulate.h"

#ifdef _OPENMP
#include <omp.h>
#endif

typedef long long (*maglev_simulate_fn)(const maglev_real* x0, maglev_real dt,
                                        long long n_steps, maglev_real F_prop,
                                        const maglev_real* K_pos, const maglev_real* K_rate,
                                        const maglev_real* a_ref,
                                        const maglev_control_loop* loop, const maglev_real* p,
                                        maglev_real gap_min, maglev_real* x_traj,
                                        maglev_real* u_traj, maglev_real* gap_traj,
                                        long long* saturated, int* status);

/* Run i (0 <= i < n_runs) is maglev_simulate(x0 + i nx, dt, n_steps, F_prop[i],
   K_pos + 25 i, K_rate + 25 i, a_ref + 5 i, loops + i, p + n_p i, gap_min, ...) with its
   trajectories at x_traj + i (n_steps + 1) nx (u_traj: nu, gap_traj: ng columns); last[i],
   saturated[i] and status[i] are its return value, saturated steps and status. threads <= 0:
   OpenMP's default. Returns 0, or -1 when a pointer or a count is invalid (nothing run). */
int maglev_batch_simulate(maglev_simulate_fn simulate, long long n_runs, int threads, int nx,
                          int nu, int ng, long long n_p, const maglev_real* x0, maglev_real dt,
                          long long n_steps, const maglev_real* F_prop,
                          const maglev_real* K_pos, const maglev_real* K_rate,
                          const maglev_real* a_ref, const maglev_control_loop* loops,
                          const maglev_real* p, maglev_real gap_min, maglev_real* x_traj,
                          maglev_real* u_traj, maglev_real* gap_traj, long long* last,
                          long long* saturated, int* status) {
    long long i;
    if (simulate == 0 || n_runs < 0 || nx < 1 || nu < 1 || ng < 1 || n_p < 1 || n_steps < 0
        || x0 == 0 || F_prop == 0 || K_pos == 0 || K_rate == 0 || a_ref == 0 || loops == 0
        || p == 0 || x_traj == 0 || u_traj == 0 || gap_traj == 0 || last == 0
        || saturated == 0 || status == 0) {
        return -1;
    }
#ifdef _OPENMP
#pragma omp parallel for schedule(dynamic, 1) num_threads(threads > 0 ? threads : omp_get_max_threads())
#else
    (void)threads;
#endif
    for (i = 0; i < n_runs; ++i) {
        const long long rows = n_steps + 1;
        last[i] = simulate(x0 + i * nx, dt, n_steps, F_prop[i], K_pos + 25 * i, K_rate + 25 * i,
                           a_ref + 5 * i, loops + i, p + n_p * i, gap_min,
                           x_traj + i * rows * nx, u_traj + i * rows * nu,
                           gap_traj + i * rows * ng, saturated + i, status + i);
    }
    return 0;
}
