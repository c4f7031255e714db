/* Threads that wait by spinning on memory, with no system call in the loop (a spin lock, a
 * lock-free queue polled): the kernel would preempt them so that the thread they wait for
 * runs. `sleeper`: a thread sets the flag after a 300 ms sleep. `ready`: a new thread sets it
 * at once (the spinner keeps the CPU it started on). `alarm`: the only thread's SIGALRM
 * handler sets it, 50 ms on (setitimer). `pingpong N`: two threads hand a token back and forth
 * N times, each spinning for its turn. `winch`: the program's own SIGWINCH (the signal climbsim
 * asks with), raised once ignored by default and once with a handler of its own, then
 * `sleeper`. Prints when each wait ended, in simulated time. */
#include <pthread.h>
#include <signal.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/time.h>
#include <time.h>

static atomic_int flag;
static atomic_long token;
static long rounds;
static struct timespec start;

static double since_start(void) {
    struct timespec now;
    clock_gettime(CLOCK_MONOTONIC, &now);
    return (now.tv_sec - start.tv_sec) + (now.tv_nsec - start.tv_nsec) / 1e9;
}

static void *set_after_sleep(void *unused) {
    (void)unused;
    struct timespec delay = {0, 300000000};
    nanosleep(&delay, NULL);
    atomic_store(&flag, 1);
    return NULL;
}

static void *set_at_once(void *unused) {
    (void)unused;
    atomic_store(&flag, 1);
    return NULL;
}

static void on_alarm(int signal) {
    (void)signal;
    atomic_store(&flag, 1);
}

static atomic_int winches;

static void on_winch(int signal) {
    (void)signal;
    atomic_fetch_add(&winches, 1);
}

/* Player `me` (0 or 1) moves when the token is even (0) or odd (1). */
static void *play(void *arg) {
    long me = (long)arg;
    for (long move = me; move < 2 * rounds; move += 2) {
        while (atomic_load(&token) != move) {
        }
        atomic_store(&token, move + 1);
    }
    return NULL;
}

static void spin_for_flag(void) {
    unsigned long turns = 0;
    while (!atomic_load(&flag)) {
        turns++;
    }
    printf("flag seen %.6f s after the start\n", since_start());
}

int main(int argc, char **argv) {
    clock_gettime(CLOCK_MONOTONIC, &start);
    const char *mode = argc > 1 ? argv[1] : "sleeper";
    pthread_t thread;
    if (strcmp(mode, "winch") == 0) {
        raise(SIGWINCH);
        signal(SIGWINCH, on_winch);
        raise(SIGWINCH);
        printf("own SIGWINCH handled %d time(s)\n", atomic_load(&winches));
        mode = "sleeper";
    }
    if (strcmp(mode, "sleeper") == 0) {
        pthread_create(&thread, NULL, set_after_sleep, NULL);
        spin_for_flag();
    } else if (strcmp(mode, "ready") == 0) {
        pthread_create(&thread, NULL, set_at_once, NULL);
        spin_for_flag();
    } else if (strcmp(mode, "alarm") == 0) {
        signal(SIGALRM, on_alarm);
        struct itimerval in_50_ms = {{0, 0}, {0, 50000}};
        setitimer(ITIMER_REAL, &in_50_ms, NULL);
        spin_for_flag();
        return 0;
    } else if (strcmp(mode, "pingpong") == 0) {
        rounds = argc > 2 ? atol(argv[2]) : 10;
        pthread_create(&thread, NULL, play, (void *)1L);
        play((void *)0L);
        printf("%ld rounds played, %.6f s after the start\n", rounds, since_start());
    } else {
        fprintf(stderr, "unknown mode %s\n", mode);
        return 2;
    }
    pthread_join(thread, NULL);
    return 0;
}
