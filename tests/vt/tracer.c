// A controller that traces its own child, as strace does when it is the scenario's command: the
// child stops at every system call until the tracer lets it go on. On virtual time the stopped
// child holds the turn the tracer waits for, so the run fails naming the tracer (rather than
// wait for it for ever, as for a person's debugger).
#include <signal.h>
#include <stdio.h>
#include <sys/ptrace.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

int main(void) {
    pid_t child = fork();
    if (child == 0) {
        ptrace(PTRACE_TRACEME, 0, NULL, NULL);
        raise(SIGSTOP);
        struct timespec nap = {0, 1000000};
        for (int i = 0; i < 100; i++) nanosleep(&nap, NULL);
        return 0;
    }
    int status;
    long stops = 0;
    while (waitpid(child, &status, 0) == child && !WIFEXITED(status) && !WIFSIGNALED(status)) {
        stops++;
        ptrace(PTRACE_SYSCALL, child, NULL, NULL);
    }
    printf("traced child done after %ld stops\n", stops);
    return 0;
}
