// An exec made by a second thread while the main thread waits in a join: Linux ends the main
// thread, and the exec'ing thread becomes the process (it takes the main thread's id). The new
// program sleeps 100 ms and says so; the old one never prints "never". With the argument
// `in-a-child`, all that happens in a forked child that the (followed) parent waits for, where
// the new program starts in its turn.
#include <pthread.h>
#include <stdio.h>
#include <string.h>
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

static int exec_from_a_thread(void) {
    pthread_t thread;
    if (pthread_create(&thread, NULL, exec_after_50_ms, NULL) != 0) {
        return 2;
    }
    pthread_join(thread, NULL);
    puts("never");
    return 1;
}

int main(int argc, char **argv) {
    if (argc < 2 || strcmp(argv[1], "in-a-child") != 0) {
        return exec_from_a_thread();
    }
    pid_t child = fork();
    if (child == 0) {
        return exec_from_a_thread();
    }
    int status;
    waitpid(child, &status, 0);
    printf("child status %d\n", WEXITSTATUS(status));
    return 0;
}
