// N threads at once (argv[1], default 200), each sleeping its own number of milliseconds
// (thread i: i + 1 ms) on CLOCK_MONOTONIC; the main thread joins them all. On virtual time
// every one wakes exactly at its instant, however many there are; past the number virtual time
// follows, the run fails naming it.
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>

static struct timespec start;
static double *woke_ms;

static double since_start_ms(void) {
    struct timespec now;
    clock_gettime(CLOCK_MONOTONIC, &now);
    return (now.tv_sec - start.tv_sec) * 1e3 + (now.tv_nsec - start.tv_nsec) / 1e6;
}

static void *sleeper(void *arg) {
    long i = (long)arg;
    // Past 999 ms in whole seconds: a tv_nsec of a second or more is EINVAL, as in Linux.
    struct timespec nap = {(i + 1) / 1000, ((i + 1) % 1000) * 1000000L};
    nanosleep(&nap, NULL);
    woke_ms[i] = since_start_ms();
    return NULL;
}

int main(int argc, char **argv) {
    long n = argc > 1 ? atol(argv[1]) : 200;
    pthread_t *threads = calloc(n, sizeof *threads);
    woke_ms = calloc(n, sizeof *woke_ms);
    pthread_attr_t attr;
    pthread_attr_init(&attr);
    pthread_attr_setstacksize(&attr, 64 * 1024);
    clock_gettime(CLOCK_MONOTONIC, &start);
    for (long i = 0; i < n; i++) {
        if (pthread_create(&threads[i], &attr, sleeper, (void *)i) != 0) {
            fprintf(stderr, "pthread_create %ld failed\n", i);
            return 1;
        }
    }
    for (long i = 0; i < n; i++) pthread_join(threads[i], NULL);
    double worst = 0;
    for (long i = 0; i < n; i++) {
        double late = woke_ms[i] - (i + 1);
        if (late < 0) late = -late;
        if (late > worst) worst = late;
    }
    printf("%ld threads: each woke within %.3f ms of its instant; all joined after %.3f ms\n", n, worst, since_start_ms());
    return 0;
}
