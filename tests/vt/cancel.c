// A thread canceled (pthread_cancel) while it waits in a cancellation point: it ends at the
// instant of the cancel, its cleanup handlers run, and its join reads PTHREAD_CANCELED. In a
// sleep, a condition wait, and the poll family's waits; and one canceled before it sleeps.
#include <poll.h>
#include <pthread.h>
#include <stdio.h>
#include <sys/epoll.h>
#include <sys/select.h>
#include <time.h>
#include <unistd.h>

static double now_ms(void) {
    struct timespec now;
    clock_gettime(CLOCK_MONOTONIC, &now);
    return now.tv_sec * 1e3 + now.tv_nsec / 1e6;
}

static pthread_mutex_t mutex = PTHREAD_MUTEX_INITIALIZER;
static pthread_cond_t never_signalled = PTHREAD_COND_INITIALIZER;
static int quiet[2];
static int cleanups;

static void cleaned_up(void *unused) {
    (void)unused;
    cleanups++;
}

static void unlock(void *locked) {
    pthread_mutex_unlock(locked);
    cleanups++;
}

static void *in_sleep(void *unused) {
    (void)unused;
    pthread_cleanup_push(cleaned_up, NULL);
    sleep(10);
    pthread_cleanup_pop(0);
    return NULL;
}

static void *in_nanosleep(void *unused) {
    (void)unused;
    pthread_cleanup_push(cleaned_up, NULL);
    struct timespec ten_s = {10, 0};
    nanosleep(&ten_s, NULL);
    pthread_cleanup_pop(0);
    return NULL;
}

static void *in_condition_wait(void *unused) {
    (void)unused;
    pthread_mutex_lock(&mutex);
    pthread_cleanup_push(unlock, &mutex);
    pthread_cond_wait(&never_signalled, &mutex);
    pthread_cleanup_pop(1);
    return NULL;
}

static void *in_poll(void *unused) {
    (void)unused;
    pthread_cleanup_push(cleaned_up, NULL);
    struct pollfd entry = {quiet[0], POLLIN, 0};
    poll(&entry, 1, 10000);
    pthread_cleanup_pop(0);
    return NULL;
}

static void *in_select(void *unused) {
    (void)unused;
    pthread_cleanup_push(cleaned_up, NULL);
    fd_set read;
    FD_ZERO(&read);
    FD_SET(quiet[0], &read);
    struct timeval ten_s = {10, 0};
    select(quiet[0] + 1, &read, NULL, NULL, &ten_s);
    pthread_cleanup_pop(0);
    return NULL;
}

static void *in_epoll_wait(void *unused) {
    (void)unused;
    pthread_cleanup_push(cleaned_up, NULL);
    int epfd = epoll_create1(0);
    struct epoll_event event = {EPOLLIN, {0}};
    epoll_ctl(epfd, EPOLL_CTL_ADD, quiet[0], &event);
    epoll_wait(epfd, &event, 1, 10000);
    pthread_cleanup_pop(0);
    return NULL;
}

static void *canceled_first(void *unused) {
    (void)unused;
    pthread_cleanup_push(cleaned_up, NULL);
    struct timespec pause = {0, 30000000};
    /* Cancellation is off while the cancel comes; the sleep acts on it at once. */
    int old;
    pthread_setcancelstate(PTHREAD_CANCEL_DISABLE, &old);
    clock_nanosleep(CLOCK_MONOTONIC, 0, &pause, NULL);
    pthread_setcancelstate(old, NULL);
    usleep(10000000);
    pthread_cleanup_pop(0);
    return NULL;
}

int main(void) {
    if (pipe(quiet) != 0) {
        return 1;
    }
    struct { const char *name; void *(*run)(void *); } cases[] = {
        {"sleep", in_sleep},
        {"nanosleep", in_nanosleep},
        {"pthread_cond_wait", in_condition_wait},
        {"poll", in_poll},
        {"select", in_select},
        {"epoll_wait", in_epoll_wait},
    };
    for (unsigned i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        pthread_t thread;
        double start = now_ms();
        int before = cleanups;
        pthread_create(&thread, NULL, cases[i].run, NULL);
        struct timespec pause = {0, 20000000};
        nanosleep(&pause, NULL);
        pthread_cancel(thread);
        void *result;
        pthread_join(thread, &result);
        printf("canceled in %s at 20 ms: %s, %d cleanup, joined after %.3f ms\n", cases[i].name, result == PTHREAD_CANCELED ? "canceled" : "not canceled", cleanups - before, now_ms() - start);
        fflush(stdout);
    }
    pthread_t thread;
    double start = now_ms();
    pthread_create(&thread, NULL, canceled_first, NULL);
    struct timespec pause = {0, 20000000};
    nanosleep(&pause, NULL);
    pthread_cancel(thread);
    void *result;
    pthread_join(thread, &result);
    printf("canceled at 20 ms with cancellation off until 30 ms, then usleep: %s after %.3f ms\n", result == PTHREAD_CANCELED ? "canceled" : "not canceled", now_ms() - start);
    return 0;
}
