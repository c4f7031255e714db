/* A process that ends through a raw exit_group while another thread sleeps for 10 s, as Go
 * ends: for tests/virtual_time_linux.rs, whose run must see it end at 0.1 s. */
#define _GNU_SOURCE
#include <pthread.h>
#include <stdio.h>
#include <sys/syscall.h>
#include <time.h>
#include <unistd.h>
static void *sleeper(void *arg) { (void)arg; sleep(10); return NULL; }
int main(void) {
    pthread_t thread;
    pthread_create(&thread, NULL, sleeper, NULL);
    usleep(100000);
    struct timespec ts; clock_gettime(CLOCK_MONOTONIC, &ts);
    printf("done at %.3f\n", ts.tv_sec + ts.tv_nsec / 1e9); fflush(stdout);
    syscall(SYS_exit_group, 0);
    return 1;
}
