// N forked children (argv[1], default 100) that end at once with _exit(0), each waited for
// before the next. Every clock the program can read is simulated under virtual time, so the
// wall time each child costs is measured from outside: hil/bench/exit-children.sh times a
// run with N children against one with none.
#include <stdio.h>
#include <stdlib.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

int main(int argc, char **argv) {
    int children = argc > 1 ? atoi(argv[1]) : 100;
    struct timespec start, end;
    clock_gettime(CLOCK_MONOTONIC, &start);
    for (int i = 0; i < children; i++) {
        pid_t child = fork();
        if (child == 0) _exit(0);
        int status;
        waitpid(child, &status, 0);
    }
    clock_gettime(CLOCK_MONOTONIC, &end);
    printf("%d children ended with _exit in %.3f ms of simulated time\n", children, (end.tv_sec - start.tv_sec) * 1e3 + (end.tv_nsec - start.tv_nsec) / 1e6);
    return 0;
}
