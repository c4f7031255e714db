// tests/vt/exec_from_thread.c in a forked child, whose parent (followed) waits for it: the new
// program's main thread starts in its turn there, and the earlier image's threads must be
// gone before it waits for it.
#include <pthread.h>
#include <stdio.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

static void *exec_after_50_ms(void *unused) {
    (void)unused;
    struct timespec pause = {0, 50000000};
    nanosleep(&pause, NULL);
    execl("/bin/sh", "sh", "-c", "sleep 0.1; echo exec-done", (char *)NULL);
    perror("execl");
    return NULL;
}

int main(void) {
    pid_t child = fork();
    if (child == 0) {
        pthread_t thread;
        pthread_create(&thread, NULL, exec_after_50_ms, NULL);
        pthread_join(thread, NULL);
        puts("never");
        return 1;
    }
    int status;
    waitpid(child, &status, 0);
    printf("child status %d\n", WEXITSTATUS(status));
    return 0;
}
