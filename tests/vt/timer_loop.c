/* A control loop on a timerfd, as embedded Linux code often is, for the virtual-time tests: a
 * 20 ms periodic timer read with blocking reads, then a one-shot timer waited for with poll(2).
 * Prints what its monotonic clock saw. Built by tests/virtual_time.rs with the system's cc. */
#include <poll.h>
#include <stdint.h>
#include <stdio.h>
#include <sys/timerfd.h>
#include <time.h>
#include <unistd.h>

static double now_ms(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return ts.tv_sec * 1e3 + ts.tv_nsec / 1e6;
}

int main(void) {
    int tfd = timerfd_create(CLOCK_MONOTONIC, 0);
    if (tfd < 0) { perror("timerfd_create"); return 1; }
    struct itimerspec period = {{0, 20000000}, {0, 20000000}};
    double start = now_ms();
    if (timerfd_settime(tfd, 0, &period, NULL) != 0) { perror("timerfd_settime"); return 1; }
    uint64_t total = 0;
    for (int i = 0; i < 10; i++) {
        uint64_t expirations;
        if (read(tfd, &expirations, sizeof expirations) != 8) { perror("read"); return 1; }
        total += expirations;
    }
    printf("periodic: %llu expirations in %.3f ms\n", (unsigned long long)total, now_ms() - start);
    struct itimerspec once = {{0, 0}, {0, 50000000}};
    start = now_ms();
    timerfd_settime(tfd, 0, &once, NULL);
    struct pollfd fds = {tfd, POLLIN, 0};
    int ready = poll(&fds, 1, 1000);
    uint64_t expirations = 0;
    if (read(tfd, &expirations, sizeof expirations) != 8) { perror("read"); return 1; }
    printf("one-shot: poll %d after %.3f ms, %llu expiration\n", ready, now_ms() - start, (unsigned long long)expirations);
    return 0;
}
