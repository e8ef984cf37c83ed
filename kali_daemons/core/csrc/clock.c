/* A clocked process's cycle: its statistics and its wait for the wall clock (daemon.py).
 * Part of a library's one translation unit (controller.c), after common.h. */

/* ---------------------------------------------------------------- a cycle's statistics
 *
 * daemon.py's _CycleStats.record_reference, field for field: one cycle of a process-table
 * slot accounted (lateness and execution time, their maxima, the lateness histogram's bin
 * as layout.lateness_bin gives it, the heartbeat), then its acknowledgement, last: the
 * store the clock reads. */

int64_t kali_cycle_stats(StatsArgs *a) {
    int64_t late = a->woke - a->release, exe = a->done - a->woke;
    *a->late = late;
    if (late > *a->late_max) *a->late_max = late;
    *a->exec = exe;
    if (exe > *a->exec_max) *a->exec_max = exe;
    a->hist[lateness_bin(late, a->linear_us, a->log_bins)] += 1u;
    *a->heart = a->done;
    *a->acks += 1u;
    __atomic_store_n(a->ack, a->tick, __ATOMIC_RELEASE); /* last */
    return 0;
}

/* ---------------------------------------------------------------- a clocked process's wait
 *
 * daemon.ClockWait.wait_reference, step for step: the base loop's wait for the wall clock's
 * signal (thesis 3.6.2).  Polling (an SV on another CPU than SIO's, real time), while the
 * clock keeps signalling: sleep on this CPU's timer to the next due tick (the clock's own
 * within a period, else this period's next: daemon.next_wake) plus *after, poll the
 * semaphore's value there for poll_ns, then take the post.  WAIT_IDLE when no signal came within idle_ns,
 * WAIT_INTR when a signal handler interrupted the wait (Python runs it and
 * calls again), WAIT_SHUTDOWN when the post came with the arena's shutdown flag.  Each call
 * first accounts and acknowledges the cycle the last signal ran (kali_clock_settle). */

enum { WAIT_SIGNAL, WAIT_IDLE, WAIT_INTR, WAIT_SHUTDOWN };

/* The cycle of the last signal has run: account it and acknowledge (kali_cycle_stats), then,
 * in lockstep, post the clock's acknowledgement. */
int64_t kali_clock_settle(WaitArgs *a) {
    if (!a->cycled) return 0;
    StatsArgs *st = a->stats;
    st->tick = a->tick;
    st->release = a->since;
    st->woke = a->woke;
    st->done = now_ns();
    kali_cycle_stats(st);
    if (a->ack_sem) sem_post(a->ack_sem);
    a->cycled = 0;
    return 0;
}

int64_t kali_clock_wait(WaitArgs *a) {
    kali_clock_settle(a);
    int64_t after = 0;
    if (a->poll_ns && a->signalled) {
        after = LOAD(*a->after);
        int64_t next = LOAD(*a->next_due); /* daemon.next_wake */
        if (next <= a->tick || next > a->tick + a->period_ticks)
            next = (a->tick / a->period_ticks + 1) * a->period_ticks;
        int64_t due = LOAD(*a->release) + (next - a->tick) * a->base_ns + after, t = now_ns();
        if (t < due) {
            struct timespec at = {(time_t)(due / 1000000000), (long)(due % 1000000000)};
            while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &at, NULL) == EINTR)
                ;
            t = due;
        }
        poll_posted(a->sem, t + a->poll_ns);
    }
    int got = sem_wait_until(a->sem, now_ns() + a->idle_ns);
    if (got != 0) {
        if (got == EINTR) return WAIT_INTR;
        a->signalled = 0;
        return WAIT_IDLE;
    }
    a->woke = now_ns();
    a->signalled = 1;
    if (LOAD(*a->shutdown)) return WAIT_SHUTDOWN;
    a->tick = __atomic_load_n(a->signal_tick, __ATOMIC_ACQUIRE);
    a->since = LOAD(*a->release) + after; /* lateness from when it meant to wake */
    a->cycled = 1; /* the caller runs the cycle; the next call (or settle) accounts it */
    return WAIT_SIGNAL;
}
