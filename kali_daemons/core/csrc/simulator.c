/* The simulator's kernels (the plant process): a library of their own, which no controller
 * process loads. */

#include "common.h"

#include "core.c"
#include "plant.c"
