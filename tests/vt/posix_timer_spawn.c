/* POSIX timers and new programs, for the virtual-time tests. A 10 ms periodic timer survives
 * the process starting a child (glibc's posix_spawn execs from a clone that shares this
 * process's memory: the child's exec must not delete its parent's timers); then the process
 * execs itself, and its new image has no timer (the kernel deletes them at an exec). Prints
 * how many ticks came. Built by tests/virtual_time_signals.rs with the system's cc. */
#include <signal.h>
#include <spawn.h>
#include <stdio.h>
#include <string.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

extern char **environ;
static volatile sig_atomic_t ticks;
static void on_tick(int signo) { (void)signo; ticks++; }

/* Sleep until `ms` after `*from` (advanced to that instant), through the signals' interruptions. */
static void sleep_for(struct timespec *from, long ms) {
    from->tv_nsec += ms * 1000000;
    while (from->tv_nsec >= 1000000000) { from->tv_sec++; from->tv_nsec -= 1000000000; }
    while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, from, NULL) != 0) {}
}

int main(int argc, char **argv) {
    signal(SIGUSR1, on_tick);
    struct timespec at;
    clock_gettime(CLOCK_MONOTONIC, &at);
    if (argc > 1 && strcmp(argv[1], "exec'd") == 0) {
        sleep_for(&at, 100);
        printf("after the exec: %d ticks in 100 ms\n", ticks);
        return 0;
    }
    struct sigevent event = {0};
    event.sigev_notify = SIGEV_SIGNAL;
    event.sigev_signo = SIGUSR1;
    timer_t timer;
    if (timer_create(CLOCK_MONOTONIC, &event, &timer) != 0) { perror("timer_create"); return 1; }
    struct itimerspec every = {{0, 10000000}, {0, 10000000}};
    if (timer_settime(timer, 0, &every, NULL) != 0) { perror("timer_settime"); return 1; }
    sleep_for(&at, 55);
    int before = ticks;
    char *child_argv[] = {"/bin/true", NULL};
    pid_t child;
    if (posix_spawn(&child, "/bin/true", NULL, NULL, child_argv, environ) != 0) { perror("posix_spawn"); return 1; }
    waitpid(child, NULL, 0);
    int at_spawn = ticks;
    sleep_for(&at, 100);
    printf("ticks before the spawn %d, in the 100 ms after it %d\n", before, ticks - at_spawn);
    fflush(stdout);
    execl("/proc/self/exe", argv[0], "exec'd", (char *)NULL);
    perror("execl");
    return 1;
}
