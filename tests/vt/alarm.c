// Signals and signal timers on simulated time: alarm and pause, a periodic ITIMER_REAL, a sleep
// that a signal interrupts, POSIX timers seen by sigtimedwait and by a SIGEV_THREAD callback
// (glibc's helper thread), sigsuspend, a sigtimedwait that times out, and a loop that spins on
// the clock until a handler sets a flag. Every instant is printed in ms from the start; on
// virtual time each is exact and every run prints the same.
#define _GNU_SOURCE
#include <errno.h>
#include <semaphore.h>
#include <signal.h>
#include <stdio.h>
#include <string.h>
#include <sys/time.h>
#include <time.h>
#include <unistd.h>

static struct timespec start;
static volatile sig_atomic_t alarms;
static double handled_at_ms;

static double since_start_ms(void) {
    struct timespec now;
    clock_gettime(CLOCK_MONOTONIC, &now);
    return (now.tv_sec - start.tv_sec) * 1e3 + (now.tv_nsec - start.tv_nsec) / 1e6;
}

static void on_alarm(int signo) {
    (void)signo;
    alarms++;
    handled_at_ms = since_start_ms();
}

static void set_itimer_ms(long value_ms, long interval_ms) {
    struct itimerval it = {{interval_ms / 1000, (interval_ms % 1000) * 1000}, {value_ms / 1000, (value_ms % 1000) * 1000}};
    setitimer(ITIMER_REAL, &it, NULL);
}

static sem_t callback_done;
static double callback_at_ms;
static int callback_value;

static void on_timer_thread(union sigval value) {
    callback_at_ms = since_start_ms();
    callback_value = value.sival_int;
    sem_post(&callback_done);
}

int main(void) {
    setvbuf(stdout, NULL, _IOLBF, 0);
    struct sigaction action;
    memset(&action, 0, sizeof action);
    action.sa_handler = on_alarm;
    sigaction(SIGALRM, &action, NULL);
    clock_gettime(CLOCK_MONOTONIC, &start);

    // 1. alarm + pause.
    alarm(1);
    int rc = pause();
    printf("alarm: pause returned %d (%s) at %.3f ms, handler at %.3f ms\n", rc, strerror(errno), since_start_ms(), handled_at_ms);

    // 2. A periodic ITIMER_REAL, 20 ms, ten expirations.
    double from = since_start_ms();
    alarms = 0;
    set_itimer_ms(20, 20);
    while (alarms < 10) pause();
    set_itimer_ms(0, 0);
    printf("setitimer: 10 expirations of 20 ms in %.3f ms\n", since_start_ms() - from);

    // 3. A 1 s sleep that a 50 ms one-shot interrupts.
    from = since_start_ms();
    set_itimer_ms(50, 0);
    struct timespec nap = {1, 0}, left = {0, 0};
    rc = nanosleep(&nap, &left);
    printf("nanosleep: returned %d (%s) after %.3f ms, %.3f ms left\n", rc, strerror(errno), since_start_ms() - from, left.tv_sec * 1e3 + left.tv_nsec / 1e6);
    struct itimerval now_left;
    getitimer(ITIMER_REAL, &now_left);
    printf("getitimer: %ld.%06ld s left\n", (long)now_left.it_value.tv_sec, (long)now_left.it_value.tv_usec);

    // 4. A POSIX timer (5 ms period) on SIGRTMIN, taken by sigtimedwait with the signal blocked.
    sigset_t rt;
    sigemptyset(&rt);
    sigaddset(&rt, SIGRTMIN);
    sigprocmask(SIG_BLOCK, &rt, NULL);
    struct sigevent event;
    memset(&event, 0, sizeof event);
    event.sigev_notify = SIGEV_SIGNAL;
    event.sigev_signo = SIGRTMIN;
    event.sigev_value.sival_int = 42;
    timer_t timer;
    if (timer_create(CLOCK_MONOTONIC, &event, &timer) != 0) {
        perror("timer_create");
        return 1;
    }
    from = since_start_ms();
    struct itimerspec period = {{0, 5000000}, {0, 5000000}};
    timer_settime(timer, 0, &period, NULL);
    for (int i = 0; i < 4; i++) {
        siginfo_t info;
        int signo = sigtimedwait(&rt, &info, NULL);
        printf("timer_create: signal %s, value %d, code %s, at +%.3f ms\n", signo == SIGRTMIN ? "SIGRTMIN" : "?", info.si_value.sival_int, info.si_code == SI_TIMER ? "SI_TIMER" : "?", since_start_ms() - from);
    }
    timer_delete(timer);

    // 5. SIGEV_THREAD: glibc's helper thread waits for the signal and runs the callback.
    sem_init(&callback_done, 0, 0);
    memset(&event, 0, sizeof event);
    event.sigev_notify = SIGEV_THREAD;
    event.sigev_notify_function = on_timer_thread;
    event.sigev_value.sival_int = 7;
    if (timer_create(CLOCK_REALTIME, &event, &timer) != 0) {
        perror("timer_create SIGEV_THREAD");
        return 1;
    }
    from = since_start_ms();
    struct itimerspec once = {{0, 0}, {0, 12000000}};
    timer_settime(timer, 0, &once, NULL);
    sem_wait(&callback_done);
    printf("SIGEV_THREAD: callback with value %d at +%.3f ms\n", callback_value, callback_at_ms - from);
    timer_delete(timer);

    // 6. sigsuspend: SIGALRM blocked, then waited for with it let through.
    sigset_t alarm_only, none;
    sigemptyset(&alarm_only);
    sigaddset(&alarm_only, SIGALRM);
    sigemptyset(&none);
    sigprocmask(SIG_BLOCK, &alarm_only, NULL);
    from = since_start_ms();
    alarms = 0;
    set_itimer_ms(30, 0);
    rc = sigsuspend(&none);
    printf("sigsuspend: returned %d (%s) after %.3f ms, %d alarm\n", rc, strerror(errno), since_start_ms() - from, (int)alarms);
    sigprocmask(SIG_UNBLOCK, &alarm_only, NULL);

    // 7. sigtimedwait for a signal nobody sends: EAGAIN after 10 ms.
    from = since_start_ms();
    struct timespec ten_ms = {0, 10000000};
    rc = sigtimedwait(&rt, NULL, &ten_ms);
    printf("sigtimedwait: returned %d (%s) after %.3f ms\n", rc, strerror(errno), since_start_ms() - from);

    // 8. A loop that spins on the clock until the handler has run.
    from = since_start_ms();
    alarms = 0;
    set_itimer_ms(7, 0);
    long reads = 0;
    while (!alarms) {
        since_start_ms();
        reads++;
    }
    printf("spin: the handler ran at +%.3f ms, after %s clock reads\n", handled_at_ms - from, reads > 1000 ? "many" : "few");
    printf("done at %.3f ms\n", since_start_ms());
    return 0;
}
