/* What a trapped system call costs a controller under --clock virtual (hil/bench/trap-cost.sh
 * runs it): the same clock read made through libc's symbol (which the shim's preload answers
 * with no system call) and with syscall(2) (which the seccomp filter traps into the shim's
 * SIGSYS handler), a futex wake nobody waits for (trapped and emulated), and getppid (not
 * trapped: the kernel's own cost). Each is timed on this thread's CPU clock, which the shim
 * leaves to the kernel, as the median of 21 rounds, in ns per call. */
#define _GNU_SOURCE
#include <linux/futex.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <sys/syscall.h>
#include <time.h>
#include <unistd.h>

#define CALLS 20000
#define ROUNDS 21

static double cpu_ns(void) {
    struct timespec ts;
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
    return ts.tv_sec * 1e9 + ts.tv_nsec;
}

static int compare(const void *a, const void *b) {
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

static uint32_t word;

static void libc_clock(void) { struct timespec ts; clock_gettime(CLOCK_MONOTONIC, &ts); }
static void raw_clock(void) { struct timespec ts; syscall(SYS_clock_gettime, CLOCK_MONOTONIC, &ts); }
static void raw_futex_wake(void) { syscall(SYS_futex, &word, FUTEX_WAKE_PRIVATE, 1, NULL, NULL, 0); }
static void raw_getppid(void) { syscall(SYS_getppid); }

static double per_call(void (*call)(void)) {
    double rounds[ROUNDS];
    for (int r = 0; r < ROUNDS; r++) {
        double started = cpu_ns();
        for (int i = 0; i < CALLS; i++) call();
        rounds[r] = (cpu_ns() - started) / CALLS;
    }
    qsort(rounds, ROUNDS, sizeof rounds[0], compare);
    return rounds[ROUNDS / 2];
}

int main(void) {
    printf("clock_gettime through libc (preload): %.0f ns\n", per_call(libc_clock));
    printf("clock_gettime with syscall(2) (trapped): %.0f ns\n", per_call(raw_clock));
    printf("futex wake, nobody waiting (trapped, emulated): %.0f ns\n", per_call(raw_futex_wake));
    printf("getppid (not trapped): %.0f ns\n", per_call(raw_getppid));
    fflush(stdout);
    return 0;
}
