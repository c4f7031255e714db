// A thread made with a raw clone and no thread pointer of its own (no CLONE_SETTLS): it shares
// its creator's thread-local storage. It sleeps 100 ms, sets a flag and wakes the main thread,
// which waits on the flag with futex. Natively it prints "flag after 100.x ms".
#define _GNU_SOURCE
#include <linux/futex.h>
#include <sched.h>
#include <stdio.h>
#include <stdlib.h>
#include <sys/syscall.h>
#include <time.h>
#include <unistd.h>

static volatile int flag = 0;

static int sleep_then_set_the_flag(void *unused) {
    (void)unused;
    struct timespec pause = {0, 100000000};
    syscall(SYS_nanosleep, &pause, NULL);
    __atomic_store_n(&flag, 1, __ATOMIC_SEQ_CST);
    syscall(SYS_futex, &flag, FUTEX_WAKE, 1, NULL, NULL, 0);
    syscall(SYS_exit, 0);
    return 0;
}

int main(void) {
    size_t size = 1 << 16;
    char *stack = malloc(size);
    struct timespec start, end;
    clock_gettime(CLOCK_MONOTONIC, &start);
    int flags = CLONE_VM | CLONE_FS | CLONE_FILES | CLONE_SIGHAND | CLONE_THREAD | CLONE_SYSVSEM;
    if (clone(sleep_then_set_the_flag, stack + size, flags, NULL) < 0) {
        perror("clone");
        return 1;
    }
    while (!__atomic_load_n(&flag, __ATOMIC_SEQ_CST)) {
        syscall(SYS_futex, &flag, FUTEX_WAIT, 0, NULL, NULL, 0);
    }
    clock_gettime(CLOCK_MONOTONIC, &end);
    printf("flag after %.3f ms\n", ((end.tv_sec - start.tv_sec) * 1e9 + (end.tv_nsec - start.tv_nsec)) / 1e6);
    return 0;
}
