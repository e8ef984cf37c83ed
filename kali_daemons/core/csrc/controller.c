/* The controller's kernels (SIO, the SVs, every clocked process): one translation unit, so
 * the compiler sees every kernel SIO's and an SV's tick call. */

#include "common.h"

#include "core.c"
#include "chain.c"
#include "clock.c"
#include "witness.c"
#include "flightrec.c"
#include "fifo.c"
#include "sio.c"
#include "franka.c"
#include "servo.c"
