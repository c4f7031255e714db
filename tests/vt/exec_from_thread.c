// An exec made by a second thread while the main thread waits in a join: Linux ends the main
// thread, and the exec'ing thread becomes the process (it takes the main thread's id). The new
// program sleeps 100 ms and says so; the old one never prints "never".
#include <pthread.h>
#include <stdio.h>
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
    pthread_t thread;
    if (pthread_create(&thread, NULL, exec_after_50_ms, NULL) != 0) {
        return 2;
    }
    pthread_join(thread, NULL);
    puts("never");
    return 1;
}
