/* How long the kernel's pty worker takes to hand bytes over while many threads sleep briefly in
 * a loop beside busy cores: the pattern of a virtual-time run's parked threads (each looks at the kernel, then
 * sleeps) on a loaded CI machine. `short_sleepers N PERIOD_US SECONDS`: N threads sleep
 * PERIOD_US in a loop; every 20 ms the main thread writes a status packet to a pty's master, as
 * climbsim writes a reply, and waits until the kernel's pty worker has handed it to the slave:
 * how long that took (median, worst). Run beside busy loops by hil/bench/short-sleepers.sh. */
#define _GNU_SOURCE
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <fcntl.h>
#include <poll.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

static double now_s(void) {
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return t.tv_sec + t.tv_nsec / 1e9;
}

static void *short_sleeper(void *period_us) {
    struct timespec pause = { 0, (long)period_us * 1000 };
    for (;;) nanosleep(&pause, NULL);
    return NULL;
}

static int by_value(const void *a, const void *b) {
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

int main(int argc, char **argv) {
    if (argc != 4) {
        fprintf(stderr, "usage: %s THREADS PERIOD_US SECONDS\n", argv[0]);
        return 2;
    }
    int threads = atoi(argv[1]);
    long period_us = atol(argv[2]);
    double seconds = atof(argv[3]);
    for (int i = 0; i < threads; i++) {
        pthread_t thread;
        if (pthread_create(&thread, NULL, short_sleeper, (void *)period_us) != 0) { perror("pthread_create"); return 1; }
    }
    /* A pseudo-terminal in raw mode, as climbsim's port. */
    int master = posix_openpt(O_RDWR | O_NOCTTY);
    if (master < 0 || grantpt(master) != 0 || unlockpt(master) != 0) { perror("pty"); return 1; }
    int slave = open(ptsname(master), O_RDWR | O_NOCTTY);
    struct termios raw;
    if (slave < 0 || tcgetattr(slave, &raw) != 0) { perror("slave"); return 1; }
    cfmakeraw(&raw);
    tcsetattr(slave, TCSANOW, &raw);
    enum { MAX_WAKES = 100000 };
    static double late[MAX_WAKES];
    int wakes = 0;
    double end = now_s() + seconds;
    struct timespec pause = { 0, 20 * 1000 * 1000 };
    unsigned char reply[14] = { 0xFF, 0xFF, 0xFD, 0x00, 0x01, 0x07, 0x00, 0x55, 0x00, 0x06, 0x04, 0x26, 0x65, 0x5D };
    while (now_s() < end && wakes < MAX_WAKES) {
        nanosleep(&pause, NULL);
        double sent = now_s();
        if (write(master, reply, sizeof reply) != sizeof reply) { perror("write"); return 1; }
        struct pollfd readable = { slave, POLLIN, 0 };
        if (poll(&readable, 1, 120000) != 1) { fprintf(stderr, "no hand-over in 120 s\n"); return 1; }
        late[wakes++] = now_s() - sent;
        unsigned char got[64];
        if (read(slave, got, sizeof got) <= 0) { perror("read"); return 1; }
    }
    qsort(late, wakes, sizeof late[0], by_value);
    printf("%d threads sleeping %ld us: %d pty hand-overs, median %.3f ms, worst %.3f ms\n", threads, period_us, wakes, late[wakes / 2] * 1e3, late[wakes - 1] * 1e3);
    return 0;
}
