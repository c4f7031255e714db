// posix_spawn, as Rust's std::process::Command and C programs start children: glibc's child
// makes its exec inside libc (only the seccomp trap sees it), while the parent has reserved a
// slot for it. A child that sleeps 200 ms, waited for; then a pipe read from a child (the
// parent blocked in a real read while the child sleeps).
#include <spawn.h>
#include <stdio.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#include "protocol2.h"

extern char **environ;

int main(void) {
    setvbuf(stdout, NULL, _IOLBF, 0);
    double started = now_us(CLOCK_MONOTONIC);
    pid_t child;
    char *argv[] = {"sleep", "0.2", NULL};
    if (posix_spawnp(&child, "sleep", NULL, NULL, argv, environ) != 0) return 1;
    int status = 0;
    waitpid(child, &status, 0);
    printf("spawned sleep 0.2 ended after %.3f ms, status %d\n", (now_us(CLOCK_MONOTONIC) - started) / 1e3, WEXITSTATUS(status));
    return 0;
}
