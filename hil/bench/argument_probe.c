/* What it costs the shim to ask the kernel whether a call's argument is readable before it
 * reads it (shim/src/sys.rs, copy_from_program): an rt_sigprocmask with an invalid `how` (one
 * 8-byte window) against a process_vm_readv of 64 bytes, and a bare system call for scale.
 * Natively, no climbsim: cc -O2 hil/bench/argument_probe.c -o /tmp/probe && /tmp/probe */
#define _GNU_SOURCE
#include <stdio.h>
#include <sys/syscall.h>
#include <sys/uio.h>
#include <time.h>
#include <unistd.h>

static double now_ns(void) {
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return t.tv_sec * 1e9 + t.tv_nsec;
}

int main(void) {
    char buf[64] = {0}, out[64];
    const int n = 200000;
    pid_t pid = getpid();
    double t = now_ns();
    for (int i = 0; i < n; i++) syscall(SYS_rt_sigprocmask, -1, buf, 0, 8);
    double probe = (now_ns() - t) / n;
    struct iovec local = {out, sizeof out}, remote = {buf, sizeof buf};
    t = now_ns();
    for (int i = 0; i < n; i++) syscall(SYS_process_vm_readv, pid, &local, 1, &remote, 1, 0);
    double copy = (now_ns() - t) / n;
    t = now_ns();
    for (int i = 0; i < n; i++) syscall(SYS_getppid);
    double bare = (now_ns() - t) / n;
    printf("rt_sigprocmask probe %.0f ns, process_vm_readv of 64 bytes %.0f ns, getppid %.0f ns\n", probe, copy, bare);
    return 0;
}
