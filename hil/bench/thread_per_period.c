/* A controller that starts a worker thread every period and joins it before the next: the
 * pattern of a program that hands each cycle's work to a fresh thread. Runs for SECONDS of
 * (simulated) time at one thread every PERIOD_US, or, with a third argument 0, only sleeps
 * through the periods (the same run without the threads). Prints what it did. */
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>

static void *work(void *unused) { return unused; }

int main(int argc, char **argv) {
    long period_us = argc > 1 ? atol(argv[1]) : 1000;
    double seconds = argc > 2 ? atof(argv[2]) : 1.0;
    int threads = argc > 3 ? atoi(argv[3]) : 1;
    struct timespec next, start;
    clock_gettime(CLOCK_MONOTONIC, &start);
    next = start;
    long periods = (long)(seconds * 1e6 / period_us);
    for (long i = 0; i < periods; i++) {
        next.tv_nsec += period_us * 1000;
        while (next.tv_nsec >= 1000000000) { next.tv_nsec -= 1000000000; next.tv_sec++; }
        clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &next, NULL);
        if (threads) {
            pthread_t thread;
            if (pthread_create(&thread, NULL, work, NULL) != 0) return 1;
            pthread_join(thread, NULL);
        }
    }
    printf("%ld periods of %ld us, %s\n", periods, period_us, threads ? "a thread created and joined in each" : "no thread");
    return 0;
}
