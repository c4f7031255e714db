/* A main thread that ends with pthread_exit while another thread works on, for
 * tests/virtual_time_linux.rs: the process ends with its last thread, at 0.1 s, in every run
 * (its end was seen at 0.100 or 0.101 s as the host raced). */
#include <pthread.h>
#include <stdio.h>
#include <time.h>
#include <unistd.h>

static double start;

static double now_ms(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return ts.tv_sec * 1e3 + ts.tv_nsec / 1e6;
}

static void *worker(void *arg) {
    (void)arg;
    usleep(100000);
    printf("worker done at %.3f ms\n", now_ms() - start);
    fflush(stdout);
    return NULL;
}

int main(void) {
    start = now_ms();
    pthread_t thread;
    pthread_create(&thread, NULL, worker, NULL);
    printf("main ends its thread\n");
    fflush(stdout);
    pthread_exit(NULL);
}
