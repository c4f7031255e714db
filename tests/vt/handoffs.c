/* Two threads hand a mutex and a condition variable back and forth N times and nothing else:
 * no clock read, no sleep. Each hand-over must cost simulated time (a woken futex waiter pays
 * a call), or the clock never moves and the world stands still. */
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>

static pthread_mutex_t lock = PTHREAD_MUTEX_INITIALIZER;
static pthread_cond_t changed = PTHREAD_COND_INITIALIZER;
static int whose_turn = 0;

static void *other(void *unused) {
    (void)unused;
    for (;;) {
        pthread_mutex_lock(&lock);
        while (whose_turn != 1) pthread_cond_wait(&changed, &lock);
        whose_turn = 0;
        pthread_cond_signal(&changed);
        pthread_mutex_unlock(&lock);
    }
    return NULL;
}

static double seconds(void) {
    struct timespec now;
    clock_gettime(CLOCK_MONOTONIC, &now);
    return now.tv_sec + now.tv_nsec / 1e9;
}

int main(int argc, char **argv) {
    long round_trips = argc > 1 ? atol(argv[1]) : 1000;
    pthread_t thread;
    pthread_create(&thread, NULL, other, NULL);
    double start = seconds();
    for (long i = 0; i < round_trips; i++) {
        pthread_mutex_lock(&lock);
        while (whose_turn != 0) pthread_cond_wait(&changed, &lock);
        whose_turn = 1;
        pthread_cond_signal(&changed);
        pthread_mutex_unlock(&lock);
    }
    printf("%ld round trips in %.6f s simulated\n", round_trips, seconds() - start);
    return 0;
}
