/* A controller whose child is a statically linked program (this file built with -static, run
 * with --child) that sleeps: the child inherits the run's seccomp filter but cannot load the
 * shim that answers it, so its sleep kills it (SIGSYS). The parent reports how its child ended
 * and exits 0 either way: the run must not pass. */
#include <signal.h>
#include <stdio.h>
#include <string.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

int main(int argc, char **argv) {
    if (argc > 1 && strcmp(argv[1], "--child") == 0) {
        struct timespec pause = {0, 10000000};
        nanosleep(&pause, NULL);
        puts("the static child slept");
        return 0;
    }
    if (argc < 2) {
        fprintf(stderr, "usage: %s STATIC_CHILD\n", argv[0]);
        return 2;
    }
    pid_t child = fork();
    if (child == 0) {
        execl(argv[1], argv[1], "--child", (char *)NULL);
        _exit(127);
    }
    int status = 0;
    waitpid(child, &status, 0);
    if (WIFSIGNALED(status))
        printf("the child was killed by signal %d\n", WTERMSIG(status));
    else
        printf("the child exited with %d\n", WEXITSTATUS(status));
    return 0;
}
