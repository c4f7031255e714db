// A futex shared between processes: a named POSIX semaphore (a file in /dev/shm, mapped by
// both) that a forked child posts after a 30 ms sleep while its parent waits on it. The two
// processes map the word at their own addresses; the shim must meet them on the same futex.
#include <fcntl.h>
#include <semaphore.h>
#include <stdio.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#include "protocol2.h"

int main(void) {
    setvbuf(stdout, NULL, _IOLBF, 0);
    char name[64];
    snprintf(name, sizeof name, "/climbsim-vt-test-%d", (int)getpid());
    sem_t *posted = sem_open(name, O_CREAT | O_EXCL, 0600, 0);
    if (posted == SEM_FAILED) return 1;
    sem_unlink(name);
    double started = now_us(CLOCK_MONOTONIC);
    pid_t child = fork();
    if (child == 0) {
        struct timespec thirty = {0, 30000000L};
        nanosleep(&thirty, NULL);
        sem_post(posted);
        _exit(0);
    }
    sem_wait(posted);
    printf("posted by the child after %.3f ms\n", (now_us(CLOCK_MONOTONIC) - started) / 1e3);
    int status = 0;
    waitpid(child, &status, 0);
    return WIFEXITED(status) && WEXITSTATUS(status) == 0 ? 0 : 1;
}
