/* The wall clock's witness of one other CPU (runtime/stalls.py's CpuWitness; decision 0004):
 * a thread bound to the CPU at the top real-time priority, above every Kali process there,
 * wakes every period to an absolute deadline.  A wake-up more than stall_ns late was time the
 * machine did not run that CPU, nor anything on it: the lateness is summed in lost, and each
 * wake-up's time and the sum after it go into a ring, so the clock can tell how much time a
 * process bound there lost since it was signalled.  The thread writes, the clock reads: seq
 * is odd while a wake-up's fields change.  One witness also guards the clock's bottom half
 * (WallClock._below): the clock drops below the serious processes of its own CPU after a
 * tick's signals, and a witness that finds it still there guard_after_ns later puts it back
 * at its priority, so a process spinning above the bottom half cannot stop the clock.  It
 * runs in the clock's process, in no cycle, and never touches Python; kali_witness_stop ends
 * it. */

#include <pthread.h>
#include <sched.h>

static void *witness_main(void *p) {
    WitnessArgs *a = p;
    int64_t due = now_ns() + a->period_ns;
    __atomic_store_n(&a->due, due, __ATOMIC_RELEASE);
    while (!LOAD(a->stop)) {
        struct timespec until = {(time_t)(due / 1000000000), (long)(due % 1000000000)};
        while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &until, NULL) == EINTR)
            ;
        int64_t t = now_ns(), late = t - due, w = a->wakes;
        __atomic_store_n(&a->seq, a->seq + 1, __ATOMIC_RELAXED); /* odd: changing */
        __atomic_thread_fence(__ATOMIC_RELEASE); /* the odd seq before the fields */
        if (late > a->stall_ns) a->lost += late;
        a->ring_ns[w % a->ring] = t;
        a->ring_lost[w % a->ring] = a->lost;
        a->wakes = w + 1;
        due += a->period_ns;
        if (t >= due) due += ((t - due) / a->period_ns + 1) * a->period_ns; /* skip ahead */
        a->due = due;
        __atomic_store_n(&a->seq, a->seq + 1, __ATOMIC_RELEASE); /* even: whole */
        int64_t below = __atomic_load_n(&a->bottom_since, __ATOMIC_ACQUIRE);
        if (a->guard_tid && below && t - below > a->guard_after_ns) {
            struct sched_param up = {.sched_priority = (int)a->guard_priority};
            sched_setparam((pid_t)a->guard_tid, &up);
            __atomic_store_n(&a->bottom_since, 0, __ATOMIC_RELEASE);
        }
    }
    return NULL;
}

/* Start the thread, bound to cpu at SCHED_FIFO priority (both or nothing): 0, or the
 * error pthread_create gave (EPERM without the privilege). */
int64_t kali_witness_start(WitnessArgs *a) {
    pthread_attr_t attr;
    cpu_set_t cpus;
    struct sched_param param = {.sched_priority = (int)a->priority};
    CPU_ZERO(&cpus);
    CPU_SET((int)a->cpu, &cpus);
    pthread_attr_init(&attr);
    pthread_attr_setstacksize(&attr, 1 << 16);
    pthread_attr_setaffinity_np(&attr, sizeof cpus, &cpus);
    pthread_attr_setinheritsched(&attr, PTHREAD_EXPLICIT_SCHED);
    pthread_attr_setschedpolicy(&attr, SCHED_FIFO);
    pthread_attr_setschedparam(&attr, &param);
    a->stop = 0;
    pthread_t thread;
    int err = pthread_create(&thread, &attr, witness_main, a);
    pthread_attr_destroy(&attr);
    if (err) return err;
    a->thread = (int64_t)thread;
    a->running = 1;
    return 0;
}

/* End the thread (it sees stop within a period) and wait for it. */
int64_t kali_witness_stop(WitnessArgs *a) {
    if (!a->running) return 0;
    __atomic_store_n(&a->stop, 1, __ATOMIC_RELEASE);
    pthread_join((pthread_t)a->thread, NULL);
    a->running = 0;
    return 0;
}
