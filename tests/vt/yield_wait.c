/* A thread waits for a flag another sets after a 300 ms sleep, calling sched_yield in between:
 * each yield costs simulated time and lets ready threads run first, so the flag is seen at
 * 300 ms, and the loop moves the clock there by itself. */
#include <pthread.h>
#include <sched.h>
#include <stdatomic.h>
#include <stdio.h>
#include <time.h>

static atomic_int flag;

static void *setter(void *unused) {
    (void)unused;
    struct timespec delay = {0, 300000000};
    nanosleep(&delay, NULL);
    atomic_store(&flag, 1);
    return NULL;
}

int main(void) {
    pthread_t thread;
    pthread_create(&thread, NULL, setter, NULL);
    struct timespec start, seen;
    clock_gettime(CLOCK_MONOTONIC, &start);
    long yields = 0;
    while (!atomic_load(&flag)) {
        sched_yield();
        yields++;
    }
    clock_gettime(CLOCK_MONOTONIC, &seen);
    printf("flag seen after %ld yields, %.6f s after the start\n", yields, (seen.tv_sec - start.tv_sec) + (seen.tv_nsec - start.tv_nsec) / 1e9);
    pthread_join(thread, NULL);
    return 0;
}
