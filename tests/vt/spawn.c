// posix_spawn, as Rust's std::process::Command and C programs start children: glibc's child
// makes its exec inside libc (only the seccomp trap sees it), while the parent has reserved a
// slot for it. A child that sleeps 200 ms, waited for; then children that print while their
// parent prints before it waits.
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
    // A spawned child starts in its turn, once its parent parks (here in waitpid): the two
    // print in the same order in every run.
    setvbuf(stdout, NULL, _IONBF, 0);
    for (int i = 0; i < 3; i++) {
        char *echo[] = {"echo", "child", NULL};
        if (posix_spawnp(&child, "echo", NULL, NULL, echo, environ) != 0) return 1;
        printf("parent %d\n", i);
        waitpid(child, NULL, 0);
    }
    return 0;
}
