/* The servo path's per-tick arithmetic, compiled (issue 26 item 2): see kernels.py.  This is
 * what every owner's kernels share; a library is one translation unit (controller.c,
 * simulator.c) including it and its owners' files.
 *
 * Every kernel takes one pointer to its argument block, laid out once at configure time
 * (the arrays never move: arena views and preallocated arrays), so a call costs ~0.3 us.
 * The blocks' structs are generated from their one declaration (kernel_args.py) into
 * kernel_args.h, as are their ctypes classes; kali_layout() lists each one's fields, and
 * kernels.load() refuses a library whose layout is not the ctypes classes'.
 * A per-joint array is a View: its first element and its stride in bytes, so arena record
 * fields (strided) and private arrays (contiguous) are read alike.  The arithmetic is the
 * reference numpy implementation's, operation for operation, built with -ffp-contract=off
 * so no multiply-add is fused: the results are bit for bit numpy's. */

#define _GNU_SOURCE /* clock_gettime; a thread bound to a CPU (witness.c) */

#include <errno.h>
#include <math.h>
#include <semaphore.h>
#include <stddef.h>
#include <stdint.h>
#include <string.h>
#include <time.h>

#include "kernel_args.h" /* every block's and record's struct: kernel_args.py */

#define AT(type, v, i) (*(type *)((v).p + (int64_t)(i) * (v).stride))

/* What a client writes while the SV looks: read from memory each time, never cached. */
#define LOAD(x) __atomic_load_n(&(x), __ATOMIC_RELAXED)

#define WRENCH 6 /* layout.WRENCH: force and torque, a weld's constraint rows too */

static inline int64_t now_ns(void) {
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (int64_t)t.tv_sec * 1000000000 + t.tv_nsec;
}

/* Take a post of sem, waiting until deadline (CLOCK_MONOTONIC ns): 0, else errno (ETIMEDOUT,
 * EINTR).  Measured on the monotonic clock like every deadline here: a step of the wall-time
 * clock (sem_timedwait's) neither cuts a wait short nor stretches it. */
static int sem_wait_until(sem_t *sem, int64_t deadline) {
    struct timespec at = {(time_t)(deadline / 1000000000), (long)(deadline % 1000000000)};
    return sem_clockwait(sem, CLOCK_MONOTONIC, &at) == 0 ? 0 : errno;
}

/* rt.poll_semaphore: read (never take) sem's value until it is posted or deadline passes */
static void poll_posted(sem_t *sem, int64_t deadline) {
    int v = 0;
    while (sem_getvalue(sem, &v) == 0 && v == 0 && now_ns() < deadline)
        ;
}

/* layout.lateness_bin: a lateness's histogram bin */
static int64_t lateness_bin(int64_t ns, int64_t linear_us, int64_t log_bins) {
    int64_t us = ns >= 0 ? ns / 1000 : -((-ns + 999) / 1000); /* Python's floor // */
    if (us < linear_us) return us > 0 ? us : 0;
    int64_t b = (int64_t)(log2((double)us / (double)linear_us) * 8.0);
    return linear_us + (b < log_bins - 1 ? b : log_bins - 1);
}
