/* maglev_host_sense.c: the firmware's sense tick for the host's runs on the sensors
   (maglevgen/runtime/sense.py). Not generated: the same glue serves every carriage. Compiled
   in the firmware folder (double precision) beside maglev_tick.c, it gives maglev_simulate's
   maglev_sense_init_fn / maglev_sense_tick_fn (the state untyped) and the state's size, so the
   run-time-parameter library reaches the firmware's own code through pointers. */
#include <stddef.h>

#include "maglev_tick.h"

size_t maglev_host_sense_state_size(void);
int maglev_host_sense_init(void* s, const maglev_real* y, unsigned long valid, maglev_real v0);
int maglev_host_sense_tick(void* s, const maglev_real* y, unsigned long valid,
                           maglev_real v_ref, maglev_real a_ref, maglev_real* u);

size_t maglev_host_sense_state_size(void) {
    return sizeof(maglev_sense_state);
}

int maglev_host_sense_init(void* s, const maglev_real* y, unsigned long valid, maglev_real v0) {
    return maglev_sense_init((maglev_sense_state*)s, y, valid, v0);
}

int maglev_host_sense_tick(void* s, const maglev_real* y, unsigned long valid,
                           maglev_real v_ref, maglev_real a_ref, maglev_real* u) {
    return maglev_sense_tick((maglev_sense_state*)s, y, valid, v_ref, a_ref, u);
}
