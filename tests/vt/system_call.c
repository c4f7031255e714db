/* system(3) on virtual time, for tests/virtual_time_linux.rs: glibc waits for the shell with a
 * wait4 made inside libc, which the shim must follow (before, the parent counted as running
 * and its child's sleep could never end: the run failed after 2 s "blocked in wait4"). */
#include <stdio.h>
#include <stdlib.h>
#include <time.h>

static double now_ms(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return ts.tv_sec * 1e3 + ts.tv_nsec / 1e6;
}

int main(void) {
    double start = now_ms();
    int rc = system("sleep 0.2; echo from the shell");
    printf("system returned %d after %.0f ms\n", rc, now_ms() - start);
    return 0;
}
