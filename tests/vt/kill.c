// Signals one controller process or thread sends another: a parent's kill to its child, which
// sleeps in 10 ms steps, and a pthread_kill to a thread waiting in pause(). On virtual time
// each handler runs at the sender's instant, in the receiver's turn, in every run alike.
#include <pthread.h>
#include <signal.h>
#include <stdio.h>
#include <string.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

static struct timespec start;
static volatile sig_atomic_t got;
static double handled_at_ms;

static double since_start_ms(void) {
    struct timespec now;
    clock_gettime(CLOCK_MONOTONIC, &now);
    return (now.tv_sec - start.tv_sec) * 1e3 + (now.tv_nsec - start.tv_nsec) / 1e6;
}

static void on_signal(int signo) {
    (void)signo;
    got++;
    handled_at_ms = since_start_ms();
}

static void *pauser(void *unused) {
    pause();
    printf("thread: pause ended at %.3f ms, the handler ran at %.3f ms\n", since_start_ms(), handled_at_ms);
    return unused;
}

int main(void) {
    setvbuf(stdout, NULL, _IONBF, 0);
    struct sigaction action;
    memset(&action, 0, sizeof action);
    action.sa_handler = on_signal;
    sigaction(SIGUSR1, &action, NULL);
    clock_gettime(CLOCK_MONOTONIC, &start);
    pid_t child = fork();
    if (child == 0) {
        int naps = 0;
        struct timespec nap = {0, 10000000};
        while (!got) {
            nanosleep(&nap, NULL);
            naps++;
        }
        printf("child: SIGUSR1 at %.3f ms, after %d naps\n", handled_at_ms, naps);
        return 0;
    }
    struct timespec wait = {0, 35000000};
    nanosleep(&wait, NULL);
    kill(child, SIGUSR1);
    printf("parent: sent SIGUSR1 at %.3f ms\n", since_start_ms());
    waitpid(child, NULL, 0);

    pthread_t thread;
    pthread_create(&thread, NULL, pauser, NULL);
    nanosleep(&wait, NULL);
    printf("parent: pthread_kill at %.3f ms\n", since_start_ms());
    pthread_kill(thread, SIGUSR1);
    pthread_join(thread, NULL);
    return 0;
}
