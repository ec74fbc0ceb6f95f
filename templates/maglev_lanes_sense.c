/* maglev_lanes_sense.c: the lane driver's part for runs on the sensors (issue 53), included
   by maglev_lanes.c after its types (batch, lane, stage_arrays, kernel_set) and helpers; not
   compiled on its own. Not generated: the same for every carriage. */

/* the readings of the lanes on the sensors at a tick (`sensed`), from the kernels at their
   states S->x and rates S->k1, with the checks the library's functions make: each gap sensor
   of the lanes that have it, then the IMU */
static void lanes_read(const batch* b, stage_arrays* S, lane* lanes, const int* sensed, int W,
                       const kernel_set* K) {
    const double* in[4];
    double* out[4];
    int l, i, j, n_gap = 0, imu = 0, x_ok[LANES_MAX];
    for (l = 0; l < W; ++l) {
        if (!sensed[l]) continue;
        if (lanes[l].readings.sense->n_gap > n_gap) n_gap = lanes[l].readings.sense->n_gap;
        imu |= lanes[l].readings.sense->imu_point != 0;
        x_ok[l] = all_finite(lane_x(&lanes[l], b), NX); /* every reading's check of x */
    }
    in[0] = S->x;
    for (j = 0; j < n_gap; ++j) {
        for (l = 0; l < W; ++l) {
            const maglev_sensing* s = lanes[l].readings.sense;
            if (!sensed[l] || j >= s->n_gap) continue;
            for (i = 0; i < 3; ++i) {
                S->s_point[i * W + l] = s->gap_point[3 * j + i];
                S->s_normal[i * W + l] = s->gap_normal[3 * j + i];
            }
            S->s_nominal[l] = s->gap_nominal[j];
        }
        in[1] = S->s_point;
        in[2] = S->s_normal;
        in[3] = S->s_nominal;
        out[0] = S->s_gap;
        out[1] = S->s_H;
        (void)K->gap_reading(in, out);
        for (l = 0; l < W; ++l) {
            lane_readings* R = &lanes[l].readings;
            const maglev_sensing* s = R->sense;
            if (!sensed[l] || j >= s->n_gap) continue;
            R->gap[j] = S->s_gap[l];
            R->gap_ok[j] = x_ok[l] && all_finite(s->gap_point + 3 * j, 3)
                           && all_finite(s->gap_normal + 3 * j, 3)
                           && isfinite(s->gap_nominal[j]) && isfinite(S->s_gap[l]);
        }
    }
    if (!imu) return;
    for (l = 0; l < W; ++l) {
        const maglev_sensing* s = lanes[l].readings.sense;
        if (!sensed[l] || s->imu_point == 0) continue;
        for (i = 0; i < 3; ++i) S->s_point[i * W + l] = s->imu_point[i];
    }
    in[1] = S->k1;
    in[2] = S->s_point;
    in[3] = S->p; /* a run-time-parameter library's reading takes p */
    out[0] = S->s_gyro;
    out[1] = S->s_force;
    out[2] = S->s_Hx;
    out[3] = S->s_Hxdot;
    (void)K->imu_reading(in, out);
    for (l = 0; l < W; ++l) {
        lane_readings* R = &lanes[l].readings;
        if (!sensed[l] || R->sense->imu_point == 0) continue;
        for (i = 0; i < 3; ++i) {
            R->gyro[i] = S->s_gyro[i * W + l];
            R->specific_force[i] = S->s_force[i * W + l];
        }
        R->imu_ok = x_ok[l] && all_finite(lanes[l].xdot, NX)
                    && all_finite(R->sense->imu_point, 3) && all_finite(R->gyro, 3)
                    && all_finite(R->specific_force, 3);
    }
}

/* column l of a [entry][W] array holds v[0 .. n - 1], bit for bit */
static int same_column(const double* a, const maglev_real* v, int n, int l, int W) {
    int i;
    for (i = 0; i < n; ++i) {
        if (memcmp(a + i * W + l, v + i, sizeof(double)) != 0) return 0;
    }
    return 1;
}

/* the sense tick of lane l's run at this step's tick, in the sense lanes: its readings
   (sensed_readings) into the group, its state (at its first tick made by the sense init
   here, then loaded into the lanes); 2: waiting for the group's tick; else sensed_command's
   return (an error of the readings, or of the init: then no tick, as sensed_command) */
static int lane_sense_defer(lane* L, work* ws, sense_group* G, int l, int W,
                            const maglev_real* x, maglev_real t, maglev_real* slot) {
    const maglev_sensing* s = L->r.loop->sense;
    const long long n = L->k / L->tick;
    const maglev_real* next = L->ring + ((L->w + 1) % L->depth) * NU;
    int j, rc;
    if (sensed_readings(ws, &L->r, x, n, t, next, L->act, L->lagged, L->y, G->v_ref + l,
                        G->a_ref + l, G->valid + l)) {
        return -1;
    }
    if (n == 0) {
        rc = s->init(s->state, L->y, G->valid[l], G->v_ref[l]);
        if (rc != 0) return sensed_after(&L->r, n, L->y, rc, slot);
        G->fns->move(G->lanes, W, l, s->state, 1);
    }
    for (j = 0; j < s->ny; ++j) G->y[j * W + l] = L->y[j];
    G->states[l] = s->state;
    G->active[l] = 1;
    G->any = 1;
    return 2;
}

/* lane l's step after the group's sense tick: its command into the delay ring
   (sensed_after), then lane_resume */
static int lane_sense_resume(lane* L, stage_arrays* S, int l, int W, const batch* b,
                             const sense_group* G) {
    maglev_real* slot = L->ring + L->w * NU;
    int i;
    for (i = 0; i < NU; ++i) slot[i] = G->u[i * W + l];
    return lane_resume(L, S, l, W, b, 1, sensed_after(&L->r, L->k / L->tick, L->y, G->rc[l], slot));
}
