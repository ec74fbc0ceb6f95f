/* maglev_lanes.c: many closed-loop runs of a run-time-parameter library's maglev_simulate in
   lock step, W runs at once in SIMD lanes (issue 53), on every core (OpenMP; compiled without
   it, on one).

   Not generated: the same driver serves every carriage. It includes the library's own
   maglev_simulate.c (-I the library's derivation folder) for the loop's pieces (the tick's
   command, the delay ring, the saturation, the speed loop, the actuator lag, the gaps and their
   status) and is linked against the library for the generated functions those pieces call.
   The generated functions a step spends its time in run in lanes, through the kernels
   maglevgen.codegen.lanes translates from the library's C, each lane bit for bit the scalar
   function: the RK4 stages' right-hand side (maglev_dynamics_prepared), the gaps
   (maglev_gaps) and the tick's coupled control (maglev_coupled_control, which the command's
   own code takes through lanes_coupled_control); on the sensors, the plant's rates at a tick
   and the readings (maglev_dynamics_prepared, maglev_gap_reading, maglev_imu_reading, which
   sensed_command takes through lanes_dynamics_prepared, lanes_gap_reading and
   lanes_imu_reading); each with the checks the scalar loop's call makes (of p once per run,
   by one scalar call; of x and the output per lane and call).
   Everything else is the scalar code of maglev_simulate's run_loop, lane by lane, in its
   order, so a lane's run is the run maglev_simulate makes (the tests compare every state,
   input, gap, status and count).

   A lane holds one run; when the run ends (its last step, a contact, a non-finite state, an
   error) the lane takes the next run of the batch at once, so no lane idles while runs are
   left and a finished run never touches the others (the lanes share no arithmetic). A run on
   the sensors (loop->sense) flies its plant and its readings in the lanes and, at each tick,
   its own sense tick (run_loop's sensed_command: the run's noise and rounding lane by lane,
   then the firmware's estimator and law, through the run's pointers and state): for all the
   lanes at once in the firmware's sense lanes where the run's firmware has them
   (maglev_sensing.lanes: each lane bit for bit maglev_sense_tick; the lanes hold the runs'
   sense states, lane_sense_defer), else per lane; where the
   rates its readings took are k1's, bit for bit (the inputs the same in every live lane:
   with the loop's delay), k1 is not computed again (lanes_fly). Runs the lanes do not fly go
   to maglev_simulate whole: a loop without a tick (the continuous loop), or with an argument
   maglev_simulate refuses. The part for runs on the sensors (lanes_read, same_column) is in
   maglev_lanes_sense.c, included below. */
/* its maglev_simulate, maglev_launch, ... stay this driver's own (the library exports them) */
#include "maglev_simulate.h" /* first: the library's functions it declares stay external */
#include <math.h>
#pragma GCC visibility push(hidden)
/* maglev_simulate.c's tick law calls maglev_coupled_control through lanes_coupled_control
   (below): the lane's u_gen from the lanes' kernel where it has one, else the library's */
static int lanes_coupled_control(const maglev_real** arg, maglev_real** res, maglev_int* iw,
                                 maglev_real* w, int mem);
/* and the sense tick's readings take the plant's rates at the tick (held_rhs's
   maglev_dynamics_prepared) through lanes_dynamics_prepared: from the lanes' kernel where it
   computed them, else the library's */
static int lanes_dynamics_prepared(const maglev_real** arg, maglev_real** res, maglev_int* iw,
                                   maglev_real* w, int mem);
/* and the readings themselves (sensor_readings' maglev_gap_reading and maglev_imu_reading)
   likewise, through lanes_gap_reading and lanes_imu_reading */
static int lanes_gap_reading(const maglev_real** arg, maglev_real** res, maglev_int* iw,
                             maglev_real* w, int mem);
static int lanes_imu_reading(const maglev_real** arg, maglev_real** res, maglev_int* iw,
                             maglev_real* w, int mem);
#define maglev_coupled_control lanes_coupled_control
#define maglev_dynamics_prepared lanes_dynamics_prepared
#define maglev_gap_reading lanes_gap_reading
#define maglev_imu_reading lanes_imu_reading
#include "maglev_simulate.c"
#undef maglev_coupled_control
#undef maglev_dynamics_prepared
#undef maglev_gap_reading
#undef maglev_imu_reading
#pragma GCC visibility pop

#include <string.h>

#ifdef _OPENMP
#include <omp.h>
#endif

#define LANES_MAX 8
#define NOISE_AHEAD 16 /* ticks (lane_begin) */
#define ROWS_AHEAD 16 /* steps (lane_begin) */
#define ALIGN __attribute__((aligned(8 * LANES_MAX)))

/* the kernels (maglevgen.codegen.lanes, in double: a double library only): in[i] the
   function's input i, out[j] its output j, each [entry][W] */
#define LANES_KERNEL(name) int name(const maglev_real* const* in, maglev_real* const* out)
typedef LANES_KERNEL((*lanes_kernel));
#define LANES_KERNELS(w)                                                                    \
    LANES_KERNEL(maglev_lanes_dynamics_w##w);                                               \
    LANES_KERNEL(maglev_lanes_gaps_w##w);                                                   \
    LANES_KERNEL(maglev_lanes_control_w##w);                                                \
    LANES_KERNEL(maglev_lanes_gap_reading_w##w);                                            \
    LANES_KERNEL(maglev_lanes_imu_reading_w##w)
LANES_KERNELS(2);
#if defined(__x86_64__)
LANES_KERNELS(4);
LANES_KERNELS(8);
#endif

/* the kernels of one lane count */
typedef struct {
    lanes_kernel dynamics, gaps, control, gap_reading, imu_reading;
} kernel_set;
#define KERNEL_SET(w)                                                                       \
    { maglev_lanes_dynamics_w##w, maglev_lanes_gaps_w##w, maglev_lanes_control_w##w,         \
      maglev_lanes_gap_reading_w##w, maglev_lanes_imu_reading_w##w }

/* the u_gen the tick's command takes for the lane it runs (NULL: maglev_coupled_control's,
   computed now); one per thread */
static __thread const maglev_real* lanes_u_gen;

static int lanes_coupled_control(const maglev_real** arg, maglev_real** res, maglev_int* iw,
                                 maglev_real* w, int mem) {
    int i;
    if (lanes_u_gen == 0) return maglev_coupled_control(arg, res, iw, w, mem);
    for (i = 0; i < 5; ++i) res[0][i] = lanes_u_gen[i];
    return 0;
}

/* the xdot the sense tick's readings take for the lane it runs (NULL: maglev_dynamics_prepared's,
   computed now) and whether maglev_dynamics_prepared's checks pass on it (lanes_stage_ok: its x,
   u and xdot finite; else its error, the output zeroed as it zeroes it); one per thread */
static __thread const maglev_real* lanes_xdot;
static __thread int lanes_xdot_ok;

static int lanes_dynamics_prepared(const maglev_real** arg, maglev_real** res, maglev_int* iw,
                                   maglev_real* w, int mem) {
    int i;
    if (lanes_xdot == 0) return maglev_dynamics_prepared(arg, res, iw, w, mem);
    for (i = 0; i < NX; ++i) res[0][i] = lanes_xdot_ok ? lanes_xdot[i] : 0;
    return lanes_xdot_ok ? 0 : 1;
}

/* the readings the sense tick takes for the lane it runs, from the kernels (NULL: the
   library's, computed now): each gap sensor's, in sensor_readings' order (lanes_gap_next: the
   next one's index; a call at another sensor's point is the library's), and the IMU's gyro
   and specific force; with each one's checks (the library's: its inputs and the requested
   outputs finite; sensor_readings requests no Jacobian; the IMU's check of p made once a
   run, lane_start). One per thread. */
typedef struct {
    const maglev_sensing* sense;
    maglev_real gap[MAGLEV_SIM_MAX_READINGS], gyro[3], specific_force[3];
    int gap_ok[MAGLEV_SIM_MAX_READINGS], imu_ok;
} lane_readings;
static __thread const lane_readings* lanes_readings;
static __thread int lanes_gap_next;

static int lanes_gap_reading(const maglev_real** arg, maglev_real** res, maglev_int* iw,
                             maglev_real* w, int mem) {
    const lane_readings* R = lanes_readings;
    const int j = lanes_gap_next;
    if (R == 0 || j >= R->sense->n_gap || arg[1] != R->sense->gap_point + 3 * j || res[1] != 0) {
        return maglev_gap_reading(arg, res, iw, w, mem);
    }
    lanes_gap_next = j + 1;
    res[0][0] = R->gap_ok[j] ? R->gap[j] : 0;
    return R->gap_ok[j] ? 0 : 1;
}

static int lanes_imu_reading(const maglev_real** arg, maglev_real** res, maglev_int* iw,
                             maglev_real* w, int mem) {
    const lane_readings* R = lanes_readings;
    int i;
    if (R == 0 || arg[2] != R->sense->imu_point || res[2] != 0 || res[3] != 0) {
        return maglev_imu_reading(arg, res, iw, w, mem);
    }
    for (i = 0; i < 3; ++i) {
        res[0][i] = R->imu_ok ? R->gyro[i] : 0;
        res[1][i] = R->imu_ok ? R->specific_force[i] : 0;
    }
    return R->imu_ok ? 0 : 1;
}
#define NP_MAX 256 /* the most parameters the lanes' gaps take (else maglev_gaps per lane) */

/* the batch: run i's inputs and outputs as maglev_batch_simulate (maglev_batch.c) takes them */
typedef struct {
    long long n_runs, n_p, n_steps;
    const maglev_real *x0, *F_prop, *K_pos, *K_rate, *a_ref, *p;
    const maglev_control_loop* loops;
    maglev_real dt, gap_min;
    maglev_real *x_traj, *u_traj, *gap_traj;
    long long *last, *saturated;
    int* status;
} batch;

/* one lane: the run it flies and run_loop's state of that run between steps */
typedef struct {
    long long run; /* -1: none */
    long long k, n_sat, tick;
    loop_run r;
    law_state law;
    maglev_real fixed[NY], T[NT], buf[NY];
    maglev_real ring[(MAGLEV_SIM_MAX_DELAY + 1) * NU], applied[NU];
    maglev_real act[NU], act_half[NU], act_end[NU];
    maglev_real e_half, e_full;
    int ring_sat[MAGLEV_SIM_MAX_DELAY + 1];
    int w, sat, depth, lagged;
    int gaps_lanes; /* the gaps in lanes: p passed maglev_gaps's checks (lane_start) */
    int control_lanes; /* the tick's u_gen in lanes: maglev_coupled_control took p */
    int sense_lanes; /* on the sensors: the rates and readings at a tick in lanes (lane_start) */
    maglev_real u_gen[5]; /* the lane's u_gen from the lanes' kernel at this step's tick */
    maglev_real xdot[NX]; /* on the sensors: the plant's rates at this step's tick (kernel) */
    maglev_real u_read[NU]; /* and the inputs they were computed under */
    int xdot_ok;          /* and maglev_dynamics_prepared's checks on them */
    lane_readings readings; /* and the readings there (kernels) */
    int sense_batch; /* on the sensors: its sense tick in the thread's sense lanes (lane_start) */
    maglev_real y[MAGLEV_SIM_MAX_READINGS]; /* a tick's readings, waiting for the sense lanes */
} lane;

/* the thread's sense lanes (maglev_sensing.lanes: the firmware's sense tick over W runs in
   SIMD lanes, one firmware's) and the runs of a step waiting for them (lane_sense_defer):
   each one's readings [NY][W], speed reference and its slope, valid flags and state; their
   commands [NU][W] and codes */
typedef struct {
    const maglev_sense_lanes* fns; /* NULL: none (each run's sense tick per lane) */
    void* lanes;
    int tried; /* fns->create was called (the first run with sense lanes) */
    double y[MAGLEV_SIM_MAX_READINGS * LANES_MAX] ALIGN, u[NU * LANES_MAX] ALIGN;
    maglev_real v_ref[LANES_MAX], a_ref[LANES_MAX];
    unsigned long valid[LANES_MAX];
    void* states[LANES_MAX];
    int active[LANES_MAX], rc[LANES_MAX], any;
} sense_group;

/* the lanes' stage arrays, [entry][W] */
typedef struct {
    double x[NX * LANES_MAX] ALIGN, xt[NX * LANES_MAX] ALIGN;
    double u[NU * LANES_MAX] ALIGN, u_half[NU * LANES_MAX] ALIGN, u_end[NU * LANES_MAX] ALIGN;
    double d[ND * LANES_MAX] ALIGN, p[NP_MAX * LANES_MAX] ALIGN, g[NG * LANES_MAX] ALIGN;
    double K_pos[25 * LANES_MAX] ALIGN, K_rate[25 * LANES_MAX] ALIGN, a_ref[5 * LANES_MAX] ALIGN;
    double u_gen[5 * LANES_MAX] ALIGN;
    /* the readings' kernels: a gap sensor's point, normal and nominal gap, the IMU's point,
       and their outputs (the Jacobians not kept) */
    double s_point[3 * LANES_MAX] ALIGN, s_normal[3 * LANES_MAX] ALIGN, s_nominal[LANES_MAX] ALIGN;
    double s_gap[LANES_MAX] ALIGN, s_H[12 * LANES_MAX] ALIGN;
    double s_gyro[3 * LANES_MAX] ALIGN, s_force[3 * LANES_MAX] ALIGN;
    double s_Hx[72 * LANES_MAX] ALIGN, s_Hxdot[72 * LANES_MAX] ALIGN;
    double k1[NX * LANES_MAX] ALIGN, k2[NX * LANES_MAX] ALIGN, k3[NX * LANES_MAX] ALIGN,
        k4[NX * LANES_MAX] ALIGN;
} stage_arrays;

/* run i as maglev_simulate, whole */
static void scalar_run(const batch* b, long long i) {
    const long long rows = b->n_steps + 1;
    b->last[i] = maglev_simulate(b->x0 + i * NX, b->dt, b->n_steps, b->F_prop[i],
                                 b->K_pos + 25 * i, b->K_rate + 25 * i, b->a_ref + 5 * i,
                                 b->loops + i, b->p + b->n_p * i, b->gap_min,
                                 b->x_traj + i * rows * NX, b->u_traj + i * rows * NU,
                                 b->gap_traj + i * rows * NG, b->saturated + i, b->status + i);
}

/* the lanes fly run i: the tick-held loop (on the state or on the sensors), arguments valid
   (the checks of maglev_simulate) */
static int lane_run_ok(const batch* b, long long i) {
    const maglev_control_loop* loop = b->loops + i;
    return loop->tick_steps > 0
        && run_arguments_ok(b->x0 + i * NX, b->dt, b->n_steps, b->gap_min, b->x_traj,
                            b->u_traj, b->gap_traj)
        && isfinite(b->F_prop[i]) && finite_vector(b->K_pos + 25 * i, 25)
        && finite_vector(b->K_rate + 25 * i, 25) && finite_vector(b->a_ref + 5 * i, 5)
        && loop_valid(loop) && law_gains_ok(loop);
}

/* lane l of width W takes run i: maglev_simulate's and run_loop's set-up, d (the prepared
   constants) into the lane's column. 1: the run is in the lane; 0: it ended already (status
   and last written) */
static int lane_start(lane* L, work* ws, stage_arrays* S, int l, int W, const batch* b,
                      long long i, sense_group* G) {
    const maglev_control_loop* loop = b->loops + i;
    const maglev_real* p = b->p + b->n_p * i;
    const maglev_real half = b->dt / (maglev_real)2;
    maglev_real d[ND];
    int j;
    if (!lane_run_ok(b, i)) {
        scalar_run(b, i);
        return 0;
    }
    b->saturated[i] = 0;
    ws->arg[0] = p;
    ws->res[0] = L->T;
    if (maglev_allocation_matrix(ws->arg, ws->res, ws->iw, ws->w, 0)) {
        b->status[i] = MAGLEV_SIM_ERROR;
        b->last[i] = 0;
        return 0;
    }
    L->fixed[MAGLEV_SCHEDULE_F_DRAG] = b->F_prop[i];
    for (j = 0; j < 5; ++j) L->fixed[MAGLEV_SCHEDULE_A_REF + j] = b->a_ref[5 * i + j];
    for (j = 0; j < 25; ++j) {
        L->fixed[MAGLEV_SCHEDULE_K_POS + j] = b->K_pos[25 * i + j];
        L->fixed[MAGLEV_SCHEDULE_K_RATE + j] = b->K_rate[25 * i + j];
        L->fixed[MAGLEV_SCHEDULE_K_LAG + j] = loop->K_lag != 0 ? loop->K_lag[j] : 0;
    }
    for (j = 0; j < 25 * MAGLEV_SIM_MAX_DELAY; ++j) {
        L->fixed[MAGLEV_SCHEDULE_K_DELAY + j] =
            loop->K_delay != 0 && j < 25 * loop->delay_ticks ? loop->K_delay[j] : 0;
    }
    L->r.schedule = 0;
    L->r.fixed = L->fixed;
    L->r.hold_steps = 0;
    L->r.F_extra = 0;
    L->r.launch = 0;
    L->r.v_end = 0;
    L->r.loop = loop;
    L->r.T = L->T;
    L->r.p = p;
    /* run_loop's */
    L->tick = loop->tick_steps;
    L->depth = loop->delay_ticks + 1;
    L->lagged = loop->tau > 0;
    L->e_half = loop->tau > 0 ? EXP(-half / loop->tau) : 0;
    L->e_full = loop->tau > 0 ? EXP(-b->dt / loop->tau) : 0;
    L->w = 0;
    L->sat = 0;
    L->n_sat = 0;
    for (j = 0; j < NQ + 1; ++j) L->law.in_flight[j] = 0;
    for (j = 0; j < LAW_NAXES; ++j) L->law.w_hat[j] = 0;
    L->law.xi = 0;
    L->law.n_flight = LAW_NAXES * loop->delay_ticks;
    L->law.h = (maglev_real)L->tick * b->dt;
    L->law.pole = loop->law_tau > 0 ? EXP(-L->law.h / loop->law_tau) : 0;
    L->law.gain = (maglev_real)1 - L->law.pole;
    for (j = 0; j < NU; ++j) L->act[j] = 0;
    ws->arg[0] = p;
    ws->res[0] = d;
    if (maglev_dynamics_prepare(ws->arg, ws->res, ws->iw, ws->w, 0)) {
        b->status[i] = MAGLEV_SIM_ERROR;
        b->last[i] = 0;
        return 0;
    }
    for (j = 0; j < ND; ++j) S->d[j * W + l] = d[j];
    /* the gaps in lanes when maglev_gaps takes this p (its checks of p pass for the whole run:
       p does not change; of x only its output's finiteness is left, checked per step), else
       maglev_gaps of the lane at each step */
    L->gaps_lanes = 0;
    if (b->n_p <= NP_MAX && all_finite(b->x0 + i * NX, NX)) {
        maglev_real g[NG];
        L->r.p = p;
        L->gaps_lanes = sample_gaps(ws, &L->r, b->x0 + i * NX, g) == 0;
    }
    for (j = 0; j < b->n_p && j < NP_MAX; ++j) S->p[j * W + l] = p[j];
    /* the tick's coupled control in lanes likewise, when maglev_coupled_control takes this p
       and the gains (the gains and a_ref are the run's: checked finite); on the sensors the
       sense tick computes the command (sensed_command), not maglev_coupled_control */
    L->control_lanes = 0;
    if (loop->sense == 0 && b->n_p <= NP_MAX && all_finite(b->x0 + i * NX, NX)) {
        maglev_real u_gen[5];
        ws->arg[0] = b->x0 + i * NX;
        ws->arg[1] = L->fixed + MAGLEV_SCHEDULE_K_POS;
        ws->arg[2] = L->fixed + MAGLEV_SCHEDULE_K_RATE;
        ws->arg[3] = L->fixed + MAGLEV_SCHEDULE_A_REF;
        ws->arg[4] = p;
        ws->res[0] = u_gen;
        L->control_lanes = maglev_coupled_control(ws->arg, ws->res, ws->iw, ws->w, 0) == 0;
    }
    /* on the sensors, the rates and the readings at a tick in lanes when the IMU's reading
       takes this p (its checks of p, finite and in range, pass for the whole run; of the
       rest, per tick, lanes_read) */
    L->sense_lanes = 0;
    if (loop->sense != 0 && b->n_p <= NP_MAX) {
        const maglev_sensing* s = loop->sense;
        L->sense_lanes = 1;
        if (s->imu_point != 0) {
            maglev_real xdot[NX], gyro[3], force[3];
            for (j = 0; j < NX; ++j) xdot[j] = 0;
            ws->arg[0] = b->x0 + i * NX;
            ws->arg[1] = xdot;
            ws->arg[2] = s->imu_point;
            ws->arg[3] = p;
            ws->res[0] = gyro;
            ws->res[1] = force;
            ws->res[2] = 0;
            ws->res[3] = 0;
            L->sense_lanes = maglev_imu_reading(ws->arg, ws->res, ws->iw, ws->w, 0) == 0;
        }
    }
    /* its sense tick in the thread's sense lanes when the run's firmware has them (the
       first such run makes them: one firmware's a thread) */
    L->sense_batch = 0;
    if (loop->sense != 0 && loop->sense->lanes != 0) {
        if (!G->tried) {
            G->tried = 1;
            G->lanes = loop->sense->lanes->create(W);
            if (G->lanes != 0) G->fns = loop->sense->lanes;
        }
        L->sense_batch = G->fns == loop->sense->lanes;
    }
    for (j = 0; j < 25; ++j) {
        S->K_pos[j * W + l] = L->fixed[MAGLEV_SCHEDULE_K_POS + j];
        S->K_rate[j * W + l] = L->fixed[MAGLEV_SCHEDULE_K_RATE + j];
    }
    for (j = 0; j < 5; ++j) S->a_ref[j * W + l] = L->fixed[MAGLEV_SCHEDULE_A_REF + j];
    for (j = 0; j < NX; ++j) b->x_traj[i * (b->n_steps + 1) * NX + j] = b->x0[i * NX + j];
    L->run = i;
    L->k = 0;
    return 1;
}

static void lane_end(lane* L, const batch* b, int status) {
    b->status[L->run] = status;
    b->last[L->run] = L->k;
    b->saturated[L->run] = L->n_sat;
    L->run = -1;
}

static maglev_real* lane_x(const lane* L, const batch* b) {
    return b->x_traj + (L->run * (b->n_steps + 1) + L->k) * NX;
}

static int lane_resume(lane* L, stage_arrays* S, int l, int W, const batch* b, int ticked,
                       int s);
static int lane_sense_defer(lane* L, work* ws, sense_group* G, int l, int W,
                            const maglev_real* x, maglev_real t, maglev_real* slot);

/* run_loop's step k up to the tick's command (the tick, the delay, the lag), then
   lane_resume. 1: the step goes on; 0: the run ended; 2 (`defer` and the run's sense tick
   in the sense lanes): the step waits for them (lane_sense_resume) */
static int lane_begin(lane* L, work* ws, stage_arrays* S, int l, int W, const batch* b,
                      int ready, sense_group* G, int defer) {
    const maglev_real* x = lane_x(L, b);
    const maglev_real t = (maglev_real)L->k * b->dt;
    int i, d;
    if (!all_finite(x, NX)) {
        lane_end(L, b, MAGLEV_SIM_NONFINITE);
        return 0;
    }
    /* the run's rows ROWS_AHEAD steps on, fetched for writing: each lane writes three rows
       a step (x, u, gaps), W lanes' interleaved, into memory the cache does not hold (a
       chunk's rows are tens of MB); without it the stores wait on each line's fetch */
    if (L->k + ROWS_AHEAD <= b->n_steps) {
        const long long row = L->run * (b->n_steps + 1) + L->k + ROWS_AHEAD;
        __builtin_prefetch(b->x_traj + row * NX, 1, 3);
        __builtin_prefetch(b->x_traj + row * NX + NX - 1, 1, 3);
        __builtin_prefetch(b->u_traj + row * NU, 1, 3);
        __builtin_prefetch(b->u_traj + row * NU + NU - 1, 1, 3);
        __builtin_prefetch(b->gap_traj + row * NG, 1, 3);
        __builtin_prefetch(b->gap_traj + row * NG + NG - 1, 1, 3);
    }
    if (L->k % L->tick == 0) {
        const maglev_real* g;
        maglev_real* slot = L->ring + L->w * NU;
        int s;
        if (gains_at(&L->r, x, L->buf, &g)) {
            lane_end(L, b, MAGLEV_SIM_NONFINITE);
            return 0;
        }
        if (L->k == 0) {
            for (d = 0; d < L->depth; ++d) {
                safe_command(&L->r, g, L->ring + d * NU);
                L->ring_sat[d] = 0;
            }
        }
        if (L->r.loop->sense != 0) {
            /* on the sensors: run_loop's sensed_command, the lane's own sense tick; its
               readings' rates from the dynamics kernel when it computed them at this x
               (`ready`), else by maglev_dynamics_prepared from the lane's d (ws->d: run_loop
               prepares it per run, the lanes keep it in their column) */
            /* the noise NOISE_AHEAD ticks on, fetched ahead (a run's noise, n_noise x ny, is
               read once, a row a tick, W runs' rows in turn: else a cache miss a tick);
               here, not in a function of its own: GCC finds a function of prefetches
               alone free of side effects and drops its calls */
            const maglev_sensing* sense = L->r.loop->sense;
            const long long ahead = L->k / L->tick + NOISE_AHEAD;
            if (ahead < sense->n_noise) { /* n_noise: 0 without noise */
                __builtin_prefetch(sense->noise + ahead * sense->ny, 0, 0);
                __builtin_prefetch(sense->noise + (ahead * sense->ny + sense->ny - 1), 0, 0);
            }
            if (ready) {
                lanes_xdot = L->xdot;
                lanes_xdot_ok = L->xdot_ok;
                lanes_readings = &L->readings;
                lanes_gap_next = 0;
            } else {
                for (i = 0; i < ND; ++i) ws->d[i] = S->d[i * W + l];
            }
            if (defer && L->sense_batch) {
                s = lane_sense_defer(L, ws, G, l, W, x, t, slot);
            } else {
                /* the sense tick per lane on the run's own state: the lanes' column stored
                   there first and loaded back after (at the first tick, sensed_command's init
                   makes the state) */
                void* state = L->r.loop->sense->state;
                if (L->sense_batch && L->k > 0) G->fns->move(G->lanes, W, l, state, 0);
                s = sensed_command(ws, &L->r, x, L->k / L->tick, t,
                                   L->ring + ((L->w + 1) % L->depth) * NU, L->act, L->lagged,
                                   slot);
                if (L->sense_batch) G->fns->move(G->lanes, W, l, state, 1);
            }
            lanes_xdot = 0;
            lanes_readings = 0;
            if (s == 2) return 2;
        } else {
            /* u_gen from the lanes' kernel when it was computed at this x (`ready`) */
            lanes_u_gen = ready ? L->u_gen : 0;
            s = command(ws, &L->r, x, t, g, &L->law, slot);
            lanes_u_gen = 0;
        }
        return lane_resume(L, S, l, W, b, 1, s);
    }
    return lane_resume(L, S, l, W, b, 0, 0);
}

/* the rest of run_loop's step k up to k1 after the tick's command (`ticked`; s its return):
   the delay ring, the lag; the lane's x and inputs into its columns. 1: the step goes on;
   0: the run ended */
static int lane_resume(lane* L, stage_arrays* S, int l, int W, const batch* b, int ticked,
                       int s) {
    const maglev_real* x = lane_x(L, b);
    maglev_real* u = b->u_traj + (L->run * (b->n_steps + 1) + L->k) * NU;
    int i;
    if (ticked) {
        if (s < 0) {
            lane_end(L, b, MAGLEV_SIM_ERROR);
            return 0;
        }
        L->ring_sat[L->w] = s;
        L->w = (L->w + 1) % L->depth;
        for (i = 0; i < NU; ++i) L->applied[i] = L->ring[L->w * NU + i];
        L->sat = L->ring_sat[L->w];
        L->act[0] = L->applied[0];
    }
    if (!L->lagged) {
        for (i = 0; i < NU; ++i) L->act[i] = L->applied[i];
    }
    /* from the ring's entry, which applied copies (and holds until the next tick): not from
       applied itself, whose values the copy above has only just stored */
    plant_lag_inputs(L->ring + L->w * NU, L->act, NU, L->lagged, L->e_half, L->e_full,
                     L->act_half, L->act_end);
    for (i = 0; i < NU; ++i) {
        u[i] = L->act[i];
        S->u[i * W + l] = L->act[i];
        S->u_half[i * W + l] = L->act_half[i];
        S->u_end[i * W + l] = L->act_end[i];
    }
    for (i = 0; i < NX; ++i) S->x[i * W + l] = x[i];
    return 1;
}

/* after k1: the gaps (from the lanes' gaps kernel, S->g, or maglev_gaps of the lane) and
   their status, the last step. 1: the step goes on; 0: the run ended */
static int lane_check(lane* L, work* ws, const stage_arrays* S, int l, int W, const batch* b) {
    const maglev_real* x = lane_x(L, b);
    maglev_real* gaps = b->gap_traj + (L->run * (b->n_steps + 1) + L->k) * NG;
    int i, s;
    if (L->gaps_lanes) {
        for (i = 0; i < NG; ++i) gaps[i] = S->g[i * W + l];
        if (!all_finite(gaps, NG)) { /* maglev_gaps: an error, its output zeroed */
            for (i = 0; i < NG; ++i) gaps[i] = 0;
            lane_end(L, b, MAGLEV_SIM_ERROR);
            return 0;
        }
    } else if (sample_gaps(ws, &L->r, x, gaps)) {
        lane_end(L, b, MAGLEV_SIM_ERROR);
        return 0;
    }
    if ((s = gap_status(gaps, b->gap_min)) != MAGLEV_SIM_OK || L->k == b->n_steps) {
        lane_end(L, b, s);
        return 0;
    }
    return 1;
}

/* the lanes' next states into xn: rk4_combine over every lane at once (its operation per
   entry, so each lane's bits; [entry][W] taken as W blocks of NX entries) */
static void lanes_rk4(const stage_arrays* S, maglev_real sixth, double* xn, int W) {
    int c;
    for (c = 0; c < W; ++c) {
        rk4_combine(S->x + c * NX, S->k1 + c * NX, S->k2 + c * NX, S->k3 + c * NX,
                    S->k4 + c * NX, sixth, xn + c * NX);
    }
}

/* a live lane's next state (xn's column, lanes_rk4), then its next step */
static void lane_finish_step(lane* L, const double* xn, int l, int W, const batch* b) {
    maglev_real* x_next = lane_x(L, b) + NX;
    int i;
    for (i = 0; i < NX; ++i) x_next[i] = xn[i * W + l];
    for (i = 0; i < NU; ++i) L->act[i] = L->act_end[i];
    L->n_sat += L->sat;
    L->k += 1;
}

/* xt = x + h k over every lane (the same operation per lane as run_loop's) */
static void lanes_axpy(double* xt, const double* x, maglev_real h, const double* k, int W) {
    int i;
    for (i = 0; i < NX * W; ++i) xt[i] = x[i] + h * k[i];
}

/* the lanes' stage as maglev_dynamics_prepared checks it (the scalar loop calls it through
   that check): ok[l] cleared for each live lane l whose x, u or xdot holds a non-finite
   value (where the check returns an error); over [entry][W] at once, the lanes' columns
   side by side (vectorised) */
static void lanes_stage_ok(const double* x, const double* u, const double* xdot,
                           const int* live, int* ok, int W) {
    int bad[LANES_MAX] = {0};
    int i, l;
    for (i = 0; i < NX; ++i) {
        for (l = 0; l < W; ++l) bad[l] |= !isfinite(x[i * W + l]) | !isfinite(xdot[i * W + l]);
    }
    for (i = 0; i < NU; ++i) {
        for (l = 0; l < W; ++l) bad[l] |= !isfinite(u[i * W + l]);
    }
    for (l = 0; l < W; ++l) {
        if (live[l] && bad[l]) ok[l] = 0;
    }
}

/* the stage kernel on every lane (unless `done`: xdot holds its result at these inputs
   already), then each live lane's check (ok[l] cleared on a failure) */
static void lanes_stage(lanes_kernel kernel, const double* x, const double* u,
                        const stage_arrays* S, double* xdot, const int* live, int* ok, int W,
                        int done) {
    const double* in[3];
    double* out[1];
    in[0] = x;
    in[1] = u;
    in[2] = S->d;
    out[0] = xdot;
    if (!done) (void)kernel(in, out);
    lanes_stage_ok(x, u, xdot, live, ok, W);
}

/* the lanes on the sensors at a tick: their readings (lanes_read), k1 reused
   (same_column) */
#include "maglev_lanes_sense.c"

/* lane l's step begun (lane_begin), taking the next runs *next hands out while its run ends
   before k1 (none left: *more 0). 1: the step goes on; 2: it waits for the sense lanes; 0: no
   run left */
static int lane_fill(lane* L, work* ws, stage_arrays* S, int l, int W, const batch* b,
                     long long* next, int* more, int ready, sense_group* G, int defer) {
    int r;
    for (;;) {
        if (L->run < 0) {
            long long i;
            if (!*more) return 0;
#ifdef _OPENMP
#pragma omp atomic capture
#endif
            i = (*next)++;
            if (i >= b->n_runs) {
                *more = 0;
                return 0;
            }
            if (!lane_start(L, ws, S, l, W, b, i, G)) continue;
            ready = 0;
        }
        r = lane_begin(L, ws, S, l, W, b, ready, G, defer);
        if (r) return r;
    }
}

/* the runs *next hands out, W at a time in lock step, until none is left */
static void lanes_fly(const batch* b, int W, const kernel_set* K, long long* next) {
    lane lanes[LANES_MAX];
    int live[LANES_MAX], ok[LANES_MAX], ready[LANES_MAX], sensed[LANES_MAX], any_gaps;
    int any_tick, any_sense, k1_done;
    stage_arrays arrays, *S = &arrays;
    sense_group group, *G = &group;
    work ws;
    const maglev_real half = b->dt / (maglev_real)2;
    int l, any = 1, more = 1;
    memset(S, 0, sizeof(stage_arrays));
    memset(G, 0, sizeof(sense_group));
    for (l = 0; l < W; ++l) lanes[l].run = -1;
    while (any) {
        /* the tick's coupled control of the running lanes at a tick, in lanes (a lane that
           takes a new run below computes its own); on the sensors, the plant's rates under
           the inputs acting at the tick, which the sense tick's readings take (sensed_command:
           the command applied over this tick, the array forces through the lag), in lanes
           after the run's first tick (whose inputs the safe command sets) */
        any_tick = any_sense = 0;
        for (l = 0; l < W; ++l) {
            lane* L = lanes + l;
            ready[l] = sensed[l] = 0;
            if (L->run >= 0 && L->k % L->tick == 0
                && (L->control_lanes || (L->sense_lanes && L->k > 0))) {
                const maglev_real* x = lane_x(L, b);
                int i;
                for (i = 0; i < NX; ++i) S->x[i * W + l] = x[i];
                ready[l] = 1;
                if (L->control_lanes) {
                    any_tick = 1;
                } else {
                    const maglev_real* next = L->ring + ((L->w + 1) % L->depth) * NU;
                    S->u[l] = next[0];
                    for (i = 1; i < NU; ++i) S->u[i * W + l] = L->lagged ? L->act[i] : next[i];
                    for (i = 0; i < NU; ++i) L->u_read[i] = S->u[i * W + l];
                    any_sense = 1;
                }
            }
        }
        if (any_sense) {
            const double* in[3];
            double* out[1];
            in[0] = S->x;
            in[1] = S->u;
            in[2] = S->d;
            out[0] = S->k1;
            (void)K->dynamics(in, out);
            for (l = 0; l < W; ++l) ok[l] = 1;
            lanes_stage_ok(S->x, S->u, S->k1, ready, ok, W);
            for (l = 0; l < W; ++l) {
                int i;
                sensed[l] = ready[l] && !lanes[l].control_lanes;
                if (!sensed[l]) continue;
                for (i = 0; i < NX; ++i) lanes[l].xdot[i] = S->k1[i * W + l];
                lanes[l].xdot_ok = ok[l];
                lanes[l].readings.sense = lanes[l].r.loop->sense;
            }
            lanes_read(b, S, lanes, sensed, W, K);
        }
        if (any_tick) {
            const double* in[5];
            double* out[1];
            in[0] = S->x;
            in[1] = S->K_pos;
            in[2] = S->K_rate;
            in[3] = S->a_ref;
            in[4] = S->p;
            out[0] = S->u_gen;
            (void)K->control(in, out);
            for (l = 0; l < W; ++l) {
                int i;
                if (!ready[l] || !lanes[l].control_lanes) continue;
                for (i = 0; i < 5; ++i) lanes[l].u_gen[i] = S->u_gen[i * W + l];
                /* a non-finite u_gen (or x): maglev_coupled_control's own answer */
                ready[l] = all_finite(lanes[l].u_gen, 5) && all_finite(lane_x(&lanes[l], b), NX);
            }
        }
        /* each lane's step up to k1; the sense ticks of the lanes on the sense lanes wait
           for them (lane_sense_defer), all at once below, then those lanes' steps go on (a
           run that ends there hands its lane on, the next run's sense tick per lane) */
        any = 0;
        for (l = 0; l < W; ++l) {
            live[l] = lane_fill(&lanes[l], &ws, S, l, W, b, next, &more, ready[l], G, 1) != 0;
            any |= live[l];
        }
        if (G->any) {
            (void)G->fns->tick(G->lanes, W, G->active, G->states, G->y, G->valid, G->v_ref, G->a_ref,
                         G->u, G->rc);
            for (l = 0; l < W; ++l) {
                if (!G->active[l]) continue;
                G->active[l] = 0;
                live[l] = lane_sense_resume(&lanes[l], S, l, W, b, G)
                          || lane_fill(&lanes[l], &ws, S, l, W, b, next, &more, 0, G, 0);
            }
            G->any = 0;
            any = 0;
            for (l = 0; l < W; ++l) any |= live[l];
        }
        if (!any) break;
        for (l = 0; l < W; ++l) ok[l] = 1;
        /* k1: on the sensors, the rates the readings took where every live lane's step is
           the tick's (the run the lanes' kernel read, its x) and its inputs, bit for bit,
           those they were computed under (with delay: the command applied over this tick,
           set before the tick; the arrays through the lag): the same kernel at the same
           inputs, so the same k1, not computed twice */
        k1_done = any_sense;
        for (l = 0; l < W && k1_done; ++l) {
            if (live[l]) {
                k1_done = sensed[l] && ready[l] && same_column(S->u, lanes[l].u_read, NU, l, W);
            }
        }
        lanes_stage(K->dynamics, S->x, S->u, S, S->k1, live, ok, W, k1_done);
        any_gaps = 0;
        for (l = 0; l < W; ++l) {
            if (live[l] && !ok[l]) {
                lane_end(&lanes[l], b, MAGLEV_SIM_ERROR); /* run_loop: k1's error */
                live[l] = 0;
            }
            any_gaps |= live[l] && lanes[l].gaps_lanes;
        }
        if (any_gaps) {
            const double* in[2];
            double* out[1];
            in[0] = S->x;
            in[1] = S->p;
            out[0] = S->g;
            (void)K->gaps(in, out);
        }
        for (l = 0; l < W; ++l) {
            if (live[l]) live[l] = lane_check(&lanes[l], &ws, S, l, W, b);
        }
        lanes_axpy(S->xt, S->x, half, S->k1, W);
        lanes_stage(K->dynamics, S->xt, S->u_half, S, S->k2, live, ok, W, 0);
        lanes_axpy(S->xt, S->x, half, S->k2, W);
        lanes_stage(K->dynamics, S->xt, S->u_half, S, S->k3, live, ok, W, 0);
        lanes_axpy(S->xt, S->x, b->dt, S->k3, W);
        lanes_stage(K->dynamics, S->xt, S->u_end, S, S->k4, live, ok, W, 0);
        lanes_rk4(S, b->dt / (maglev_real)6, S->xt, W);
        for (l = 0; l < W; ++l) {
            if (!live[l]) continue;
            if (ok[l]) {
                lane_finish_step(&lanes[l], S->xt, l, W, b);
            } else {
                lane_end(&lanes[l], b, MAGLEV_SIM_ERROR); /* run_loop: a stage's error */
            }
        }
    }
    if (G->lanes != 0) G->fns->destroy(G->lanes);
}

/* the widest lanes this CPU runs (8: AVX-512F, 4: AVX2, else 2), or `width` when it is one
   of those and the CPU has it; 0 for any other width */
int maglev_lanes_width(int width) {
    int best = 2;
#if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__))
    __builtin_cpu_init();
    if (__builtin_cpu_supports("avx2")) best = 4;
    if (__builtin_cpu_supports("avx512f")) best = 8;
#endif
    if (width == 0) return best;
    return (width == 2 || width == 4 || width == 8) && width <= best ? width : 0;
}

/* maglev_batch_simulate's runs (maglev_batch.c, without the function pointer: this driver
   has maglev_simulate) in lanes of `width` (0: maglev_lanes_width's widest) on `threads`
   threads (<= 0: OpenMP's default). Returns 0, or -1 when a pointer, a count or the width is
   invalid (nothing run). */
int maglev_lanes_simulate(long long n_runs, int width, int threads, int nx, int nu, int ng,
                          long long n_p, const maglev_real* x0, maglev_real dt,
                          long long n_steps, const maglev_real* F_prop,
                          const maglev_real* K_pos, const maglev_real* K_rate,
                          const maglev_real* a_ref, const maglev_control_loop* loops,
                          const maglev_real* p, maglev_real gap_min, maglev_real* x_traj,
                          maglev_real* u_traj, maglev_real* gap_traj, long long* last,
                          long long* saturated, int* status) {
    batch b;
    static const kernel_set K2 = KERNEL_SET(2);
#if defined(__x86_64__)
    static const kernel_set K4 = KERNEL_SET(4), K8 = KERNEL_SET(8);
#endif
    const kernel_set* K = &K2;
    long long next = 0;
    const int W = maglev_lanes_width(width);
    if (W == 0 || n_runs < 0 || nx != NX || nu != NU || ng != NG || n_p < 1 || n_steps < 0
        || x0 == 0 || F_prop == 0 || K_pos == 0 || K_rate == 0 || a_ref == 0 || loops == 0
        || p == 0 || x_traj == 0 || u_traj == 0 || gap_traj == 0 || last == 0
        || saturated == 0 || status == 0) {
        return -1;
    }
#if defined(__x86_64__)
    if (W == 4) K = &K4;
    if (W == 8) K = &K8;
#endif
    b.n_runs = n_runs;
    b.n_p = n_p;
    b.n_steps = n_steps;
    b.x0 = x0;
    b.F_prop = F_prop;
    b.K_pos = K_pos;
    b.K_rate = K_rate;
    b.a_ref = a_ref;
    b.p = p;
    b.loops = loops;
    b.dt = dt;
    b.gap_min = gap_min;
    b.x_traj = x_traj;
    b.u_traj = u_traj;
    b.gap_traj = gap_traj;
    b.last = last;
    b.saturated = saturated;
    b.status = status;
#ifdef _OPENMP
#pragma omp parallel num_threads(threads > 0 ? threads : omp_get_max_threads())
#else
    (void)threads;
#endif
    lanes_fly(&b, W, K, &next);
    return 0;
}
