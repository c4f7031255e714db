/* System calls made with the program's own `syscall` instruction, as a runtime that bypasses
 * libc makes them (Rust's rustix, Go): followed as libc's are. A parent reads a pipe its forked
 * child writes after 100 ms; poll, ppoll and epoll_wait time out; a raw read of a pipe's write
 * end is EBADF at once. Each instant is simulated time on virtual time. */
#define _GNU_SOURCE
#include <errno.h>
#include <poll.h>
#include <stdio.h>
#include <string.h>
#include <sys/epoll.h>
#include <sys/syscall.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

/* The program's own system call (not libc's `syscall`, whose instruction is libc's). */
static long raw(long number, long a, long b, long c, long d, long e) {
    long result;
    register long r10 __asm__("r10") = d;
    register long r8 __asm__("r8") = e;
    __asm__ volatile("syscall" : "=a"(result) : "a"(number), "D"(a), "S"(b), "d"(c), "r"(r10), "r"(r8) : "rcx", "r11", "memory");
    return result;
}

static double now_ms(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return ts.tv_sec * 1e3 + ts.tv_nsec / 1e6;
}

static void say(const char *what, long result, double since) {
    if (result < 0)
        printf("%s: -%s after %.3f ms\n", what, strerrorname_np((int)-result), now_ms() - since);
    else
        printf("%s: %ld after %.3f ms\n", what, result, now_ms() - since);
    fflush(stdout);
}

int main(void) {
    int pipe_ends[2];
    if (pipe(pipe_ends) != 0)
        return 1;
    pid_t child = fork();
    if (child == 0) {
        usleep(100000);
        if (write(pipe_ends[1], "x", 1) != 1)
            _exit(1);
        _exit(0);
    }
    double start = now_ms();
    char byte = 0;
    say("raw read of a pipe the child writes at 100 ms", raw(SYS_read, pipe_ends[0], (long)&byte, 1, 0, 0), start);
    waitpid(child, NULL, 0);

    start = now_ms();
    say("raw poll(NULL, 0, 50)", raw(SYS_poll, 0, 0, 50, 0, 0), start);

    struct timespec twenty = {0, 20000000};
    start = now_ms();
    say("raw ppoll(NULL, 0, 20 ms)", raw(SYS_ppoll, 0, 0, (long)&twenty, 0, 8), start);

    int epoll = epoll_create1(0);
    struct epoll_event event;
    memset(&event, 0, sizeof event);
    event.events = EPOLLIN;
    raw(SYS_epoll_ctl, epoll, EPOLL_CTL_ADD, pipe_ends[0], (long)&event, 0);
    start = now_ms();
    say("raw epoll_wait of an empty pipe, 30 ms", raw(SYS_epoll_wait, epoll, (long)&event, 1, 30, 0), start);

    start = now_ms();
    say("raw read of a pipe's write end", raw(SYS_read, pipe_ends[1], (long)&byte, 1, 0, 0), start);
    start = now_ms();
    say("raw write to the pipe", raw(SYS_write, pipe_ends[1], (long)"y", 1, 0, 0), start);
    start = now_ms();
    say("raw read of it", raw(SYS_read, pipe_ends[0], (long)&byte, 1, 0, 0), start);
    return 0;
}
