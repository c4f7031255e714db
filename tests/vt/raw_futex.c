// System calls made without libc's wrappers (as Rust std, libstdc++, Go and JITs make them),
// and glibc's own futex-based waits, on simulated time. Each line is a simulated instant,
// read with a raw clock_gettime system call.
#define _GNU_SOURCE
#include <errno.h>
#include <linux/futex.h>
#include <pthread.h>
#include <stdint.h>
#include <stdio.h>
#include <sys/syscall.h>
#include <time.h>
#include <unistd.h>

static struct timespec start;

static double raw_ms(void) {
    struct timespec now;
    syscall(SYS_clock_gettime, CLOCK_MONOTONIC, &now);
    return (now.tv_sec - start.tv_sec) * 1e3 + (now.tv_nsec - start.tv_nsec) / 1e6;
}

static void raw_sleep_ms(long ms) {
    struct timespec request = {ms / 1000, (ms % 1000) * 1000000L};
    syscall(SYS_nanosleep, &request, NULL);
}

static uint32_t timeout_word, wake_word;

static void *times_out(void *unused) {
    (void)unused;
    // An absolute CLOCK_MONOTONIC deadline 50 ms after the start, as Rust std and libstdc++ pass.
    struct timespec deadline = start;
    deadline.tv_nsec += 50000000L;
    if (deadline.tv_nsec >= 1000000000L) {
        deadline.tv_sec += 1;
        deadline.tv_nsec -= 1000000000L;
    }
    long rc = syscall(SYS_futex, &timeout_word, FUTEX_WAIT_BITSET | FUTEX_PRIVATE_FLAG, 0, &deadline, NULL, FUTEX_BITSET_MATCH_ANY);
    printf("bitset wait: %s at %.3f ms\n", rc == -1 && errno == ETIMEDOUT ? "timed out" : "woken", raw_ms());
    return NULL;
}

static void *waits_for_wake(void *unused) {
    (void)unused;
    while (__atomic_load_n(&wake_word, __ATOMIC_ACQUIRE) == 0) {
        syscall(SYS_futex, &wake_word, FUTEX_WAIT_PRIVATE, 0, NULL, NULL, 0);
    }
    printf("plain wait: woken at %.3f ms\n", raw_ms());
    return NULL;
}

static uint32_t op_word;

static void *waits_for_wake_op(void *unused) {
    (void)unused;
    while (__atomic_load_n(&op_word, __ATOMIC_ACQUIRE) == 0) {
        syscall(SYS_futex, &op_word, FUTEX_WAIT_PRIVATE, 0, NULL, NULL, 0);
    }
    printf("wake-op wait: woken at %.3f ms\n", raw_ms());
    return NULL;
}

static pthread_mutex_t lock = PTHREAD_MUTEX_INITIALIZER;

static void *holds_the_lock(void *unused) {
    (void)unused;
    pthread_mutex_lock(&lock);
    raw_sleep_ms(10);
    pthread_mutex_unlock(&lock);
    return NULL;
}

int main(void) {
    setvbuf(stdout, NULL, _IOLBF, 0);
    syscall(SYS_clock_gettime, CLOCK_MONOTONIC, &start);
    pthread_t a, b;
    pthread_create(&a, NULL, times_out, NULL);
    pthread_create(&b, NULL, waits_for_wake, NULL);
    struct timespec twenty = {0, 20000000L};
    syscall(SYS_clock_nanosleep, CLOCK_MONOTONIC, 0, &twenty, NULL);
    __atomic_store_n(&wake_word, 1, __ATOMIC_RELEASE);
    syscall(SYS_futex, &wake_word, FUTEX_WAKE_PRIVATE, 1, NULL, NULL, 0);
    pthread_join(b, NULL);
    pthread_join(a, NULL);

    // glibc's condition variable: a timed wait that nobody signals, on CLOCK_MONOTONIC.
    pthread_condattr_t attributes;
    pthread_condattr_init(&attributes);
    pthread_condattr_setclock(&attributes, CLOCK_MONOTONIC);
    pthread_cond_t cond;
    pthread_cond_init(&cond, &attributes);
    double before = raw_ms();
    struct timespec deadline;
    syscall(SYS_clock_gettime, CLOCK_MONOTONIC, &deadline);
    deadline.tv_nsec += 30000000L;
    if (deadline.tv_nsec >= 1000000000L) {
        deadline.tv_sec += 1;
        deadline.tv_nsec -= 1000000000L;
    }
    pthread_mutex_lock(&lock);
    int rc = pthread_cond_timedwait(&cond, &lock, &deadline);
    pthread_mutex_unlock(&lock);
    printf("condvar: %s after %.3f ms\n", rc == ETIMEDOUT ? "timed out" : "woken", raw_ms() - before);

    // FUTEX_WAKE_OP: set the word to 1 and wake its waiter if it held 0; then one on an address
    // that is not mapped, which must fail with EFAULT as the kernel's does (not crash).
    pthread_t d;
    pthread_create(&d, NULL, waits_for_wake_op, NULL);
    raw_sleep_ms(5);
    uint32_t first = 0;
    long woken = syscall(SYS_futex, &first, FUTEX_WAKE_OP_PRIVATE, 0, 1, &op_word, FUTEX_OP(FUTEX_OP_SET, 1, FUTEX_OP_CMP_EQ, 0));
    pthread_join(d, NULL);
    long bad = syscall(SYS_futex, &first, FUTEX_WAKE_OP_PRIVATE, 0, 1, (uint32_t *)4096, FUTEX_OP(FUTEX_OP_SET, 1, FUTEX_OP_CMP_EQ, 0));
    printf("wake-op: %ld woken; on an unmapped word %ld (%s)\n", woken, bad, bad == -1 && errno == EFAULT ? "EFAULT" : "?");

    // A contended mutex: its holder sleeps 10 ms with it.
    pthread_t c;
    pthread_create(&c, NULL, holds_the_lock, NULL);
    raw_sleep_ms(1);
    before = raw_ms();
    pthread_mutex_lock(&lock);
    printf("mutex: taken after %.3f ms\n", raw_ms() - before);
    pthread_mutex_unlock(&lock);
    pthread_join(c, NULL);
    return 0;
}
