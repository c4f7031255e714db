/* Waits with a timeout or a signal mask of their own, for tests/virtual_time_linux.rs: each line
 * says what a call returned (and its errno), and when, in simulated time on virtual time.
 * Natively the lines read the same within a millisecond or so, but for the last: futex_waitv is
 * not followed on virtual time and answers as a kernel without it does (ENOSYS). Another thread
 * acts at a set instant in each case (a write, a signal, its own end, a semaphore's post, a
 * message, a timer's expiry). Built with the system's cc. */
#define _GNU_SOURCE
#include <errno.h>
#include <fcntl.h>
#include <linux/futex.h>
#include <mqueue.h>
#include <poll.h>
#include <pthread.h>
#include <signal.h>
#include <stdint.h>
#include <stdio.h>
#include <string.h>
#include <sys/epoll.h>
#include <sys/ipc.h>
#include <sys/select.h>
#include <sys/sem.h>
#include <sys/socket.h>
#include <sys/syscall.h>
#include <sys/time.h>
#include <sys/timerfd.h>
#include <time.h>
#include <unistd.h>

static double now_ms(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return ts.tv_sec * 1e3 + ts.tv_nsec / 1e6;
}

static void say(const char *what, long rc, int error, double since) {
    if (rc < 0)
        printf("%s: %ld %s after %.3f ms\n", what, rc, strerrorname_np(error), now_ms() - since);
    else
        printf("%s: %ld after %.3f ms\n", what, rc, now_ms() - since);
    fflush(stdout);
}

static void sleep_ms(long ms) {
    struct timespec ts = {ms / 1000, (ms % 1000) * 1000000};
    nanosleep(&ts, NULL);
}

/* What the helper thread does, after `after_ms`. */
enum act { WRITE_BYTE, SIGNAL_MAIN, JUST_END, POST_SEMAPHORE, SEND_MESSAGE };
struct helper {
    enum act act;
    long after_ms;
    int fd;
    pthread_t main;
    mqd_t queue;
};

static void *helper_main(void *arg) {
    struct helper *h = arg;
    sleep_ms(h->after_ms);
    switch (h->act) {
    case WRITE_BYTE:
        if (write(h->fd, "x", 1) != 1)
            perror("write");
        break;
    case SIGNAL_MAIN:
        pthread_kill(h->main, SIGUSR1);
        break;
    case JUST_END:
        break;
    case POST_SEMAPHORE: {
        struct sembuf post = {0, 1, 0};
        if (semop(h->fd, &post, 1) != 0)
            perror("semop");
        break;
    }
    case SEND_MESSAGE:
        if (mq_send(h->queue, "hello", 5, 0) != 0)
            perror("mq_send");
        break;
    }
    return NULL;
}

static pthread_t start(struct helper *h) {
    pthread_t thread;
    if (pthread_create(&thread, NULL, helper_main, h) != 0)
        perror("pthread_create");
    return thread;
}

static volatile sig_atomic_t usr1_handled;
static void on_usr1(int sig) { (void)sig; usr1_handled++; }

static double ms_of_timeval(struct timeval tv) { return tv.tv_sec * 1e3 + tv.tv_usec / 1e3; }

/* `clock` read now, plus `ms`: an absolute deadline. */
static struct timespec in_ms(clockid_t clock, long ms) {
    struct timespec at;
    clock_gettime(clock, &at);
    at.tv_sec += ms / 1000;
    at.tv_nsec += (ms % 1000) * 1000000;
    if (at.tv_nsec >= 1000000000) {
        at.tv_sec++;
        at.tv_nsec -= 1000000000;
    }
    return at;
}

int main(void) {
    double t;
    long rc;
    int pipe_ends[2];
    if (pipe(pipe_ends) != 0)
        return 1;
    char byte;

    /* select reports the time left, as Linux does. */
    struct helper writer = {WRITE_BYTE, 30, pipe_ends[1], 0, 0};
    pthread_t thread = start(&writer);
    fd_set readable;
    FD_ZERO(&readable);
    FD_SET(pipe_ends[0], &readable);
    struct timeval timeout = {0, 100000};
    t = now_ms();
    rc = select(pipe_ends[0] + 1, &readable, NULL, NULL, &timeout);
    printf("select for 100 ms, written at 30 ms: %ld after %.3f ms, %.3f ms left\n", rc, now_ms() - t, ms_of_timeval(timeout));
    pthread_join(thread, NULL);
    if (read(pipe_ends[0], &byte, 1) != 1)
        return 1;

    /* The mask of pselect, ppoll and epoll_pwait lets SIGUSR1 through for the wait only. */
    struct sigaction action = {0};
    action.sa_handler = on_usr1;
    sigaction(SIGUSR1, &action, NULL);
    sigset_t blocked, during;
    sigemptyset(&blocked);
    sigaddset(&blocked, SIGUSR1);
    pthread_sigmask(SIG_BLOCK, &blocked, NULL);
    sigemptyset(&during);
    struct helper signaller = {SIGNAL_MAIN, 20, 0, pthread_self(), 0};

    thread = start(&signaller);
    FD_ZERO(&readable);
    FD_SET(pipe_ends[0], &readable);
    struct timespec long_wait = {0, 300000000};
    t = now_ms();
    errno = 0;
    rc = pselect(pipe_ends[0] + 1, &readable, NULL, NULL, &long_wait, &during);
    say("pselect letting SIGUSR1 through, sent at 20 ms", rc, errno, t);
    pthread_join(thread, NULL);

    thread = start(&signaller);
    struct pollfd entry = {pipe_ends[0], POLLIN, 0};
    t = now_ms();
    errno = 0;
    rc = ppoll(&entry, 1, &long_wait, &during);
    say("ppoll letting SIGUSR1 through, sent at 20 ms", rc, errno, t);
    pthread_join(thread, NULL);

    int epfd = epoll_create1(0);
    struct epoll_event event = {EPOLLIN, {0}};
    epoll_ctl(epfd, EPOLL_CTL_ADD, pipe_ends[0], &event);
    thread = start(&signaller);
    t = now_ms();
    errno = 0;
    rc = epoll_pwait(epfd, &event, 1, 300, &during);
    say("epoll_pwait letting SIGUSR1 through, sent at 20 ms", rc, errno, t);
    pthread_join(thread, NULL);
    sigset_t now_blocked;
    pthread_sigmask(SIG_BLOCK, NULL, &now_blocked);
    printf("SIGUSR1 handled %d times, blocked again after: %s\n", (int)usr1_handled, sigismember(&now_blocked, SIGUSR1) ? "yes" : "no");

    /* A pending signal the mask lets through that is ignored is discarded; the wait goes on. */
    sigset_t pipe_signal;
    sigemptyset(&pipe_signal);
    sigaddset(&pipe_signal, SIGPIPE);
    pthread_sigmask(SIG_BLOCK, &pipe_signal, NULL);
    signal(SIGPIPE, SIG_IGN);
    int broken[2];
    if (pipe(broken) != 0)
        return 1;
    close(broken[0]);
    if (write(broken[1], "x", 1) != -1)
        return 1;
    t = now_ms();
    struct timespec short_wait = {0, 50000000};
    errno = 0;
    rc = ppoll(NULL, 0, &short_wait, &during);
    say("ppoll letting an ignored, pending SIGPIPE through, 50 ms", rc, errno, t);
    close(broken[1]);

    /* A blocking read of a pipe that a timer's signal interrupts: EINTR if its handler was
     * installed without SA_RESTART; with it, the read goes on until the data comes. */
    int quiet[2];
    if (pipe(quiet) != 0)
        return 1;
    struct sigaction on_alarm = {0};
    on_alarm.sa_handler = on_usr1;
    sigaction(SIGALRM, &on_alarm, NULL);
    struct itimerval in_15_ms = {{0, 0}, {0, 15000}};
    setitimer(ITIMER_REAL, &in_15_ms, NULL);
    t = now_ms();
    errno = 0;
    rc = read(quiet[0], &byte, 1);
    say("read of an empty pipe, SIGALRM at 15 ms without SA_RESTART", rc, errno, t);
    on_alarm.sa_flags = SA_RESTART;
    sigaction(SIGALRM, &on_alarm, NULL);
    struct helper late_writer = {WRITE_BYTE, 40, quiet[1], 0, 0};
    thread = start(&late_writer);
    setitimer(ITIMER_REAL, &in_15_ms, NULL);
    t = now_ms();
    errno = 0;
    rc = read(quiet[0], &byte, 1);
    say("read of a pipe written at 40 ms, SIGALRM at 15 ms with SA_RESTART", rc, errno, t);
    pthread_join(thread, NULL);
    close(quiet[0]);
    close(quiet[1]);

    /* sleep() that a signal interrupts: the whole seconds left, as glibc answers. */
    setitimer(ITIMER_REAL, &in_15_ms, NULL);
    t = now_ms();
    errno = 0;
    unsigned int seconds_left = sleep(10);
    printf("sleep(10), SIGALRM at 15 ms: %u seconds left, errno %s, after %.3f ms\n", seconds_left, strerrorname_np(errno), now_ms() - t);

    /* Timed joins. */
    struct helper short_one = {JUST_END, 40, 0, 0, 0};
    thread = start(&short_one);
    struct timespec at = in_ms(CLOCK_REALTIME, 200);
    t = now_ms();
    rc = pthread_timedjoin_np(thread, NULL, &at);
    say("pthread_timedjoin_np of a thread ending at 40 ms, 200 ms allowed", rc ? -1 : 0, (int)rc, t);
    struct helper long_one = {JUST_END, 500, 0, 0, 0};
    thread = start(&long_one);
    at = in_ms(CLOCK_REALTIME, 50);
    t = now_ms();
    rc = pthread_timedjoin_np(thread, NULL, &at);
    say("pthread_timedjoin_np of a thread ending at 500 ms, 50 ms allowed", rc ? -1 : 0, (int)rc, t);
    at = in_ms(CLOCK_MONOTONIC, 1000);
    t = now_ms();
    rc = pthread_clockjoin_np(thread, NULL, CLOCK_MONOTONIC, &at);
    say("pthread_clockjoin_np of it then, 1 s allowed", rc ? -1 : 0, (int)rc, t);
    /* A deadline whose nanoseconds are out of range: glibc joins when the thread ends. */
    struct helper thirty = {JUST_END, 30, 0, 0, 0};
    thread = start(&thirty);
    struct timespec not_a_time = {0, 1000000000};
    t = now_ms();
    rc = pthread_timedjoin_np(thread, NULL, &not_a_time);
    say("pthread_timedjoin_np with tv_nsec 1e9 of a thread ending at 30 ms", rc ? -1 : 0, (int)rc, t);

    /* A System V semaphore's timed wait. */
    int semid = semget(IPC_PRIVATE, 1, IPC_CREAT | 0600);
    struct sembuf take = {0, -1, 0};
    struct timespec sem_wait = {0, 60000000};
    t = now_ms();
    errno = 0;
    rc = semtimedop(semid, &take, 1, &sem_wait);
    say("semtimedop for 60 ms, nothing posted", rc, errno, t);
    struct helper poster = {POST_SEMAPHORE, 25, semid, 0, 0};
    thread = start(&poster);
    t = now_ms();
    errno = 0;
    rc = semtimedop(semid, &take, 1, &sem_wait);
    say("semtimedop for 60 ms, posted at 25 ms", rc, errno, t);
    pthread_join(thread, NULL);
    thread = start(&poster);
    t = now_ms();
    errno = 0;
    rc = semop(semid, &take, 1);
    say("semop, posted at 25 ms", rc, errno, t);
    pthread_join(thread, NULL);
    /* A signal's handler never restarts a System V semaphore's wait, whatever SA_RESTART says
     * (the SIGALRM handler has it now). */
    setitimer(ITIMER_REAL, &in_15_ms, NULL);
    t = now_ms();
    errno = 0;
    rc = semtimedop(semid, &take, 1, &sem_wait);
    say("semtimedop for 60 ms, SIGALRM at 15 ms with SA_RESTART", rc, errno, t);
    semctl(semid, 0, IPC_RMID);

    /* A POSIX message queue's timed receive (its deadline on CLOCK_REALTIME). */
    char name[64];
    snprintf(name, sizeof name, "/climbsim-timed-waits-%d", (int)getpid());
    struct mq_attr attributes = {0, 4, 16, 0};
    mqd_t queue = mq_open(name, O_RDWR | O_CREAT | O_EXCL, 0600, &attributes);
    mq_unlink(name);
    char message[16];
    at = in_ms(CLOCK_REALTIME, 70);
    t = now_ms();
    errno = 0;
    rc = mq_timedreceive(queue, message, sizeof message, NULL, &at);
    say("mq_timedreceive for 70 ms, nothing sent", rc, errno, t);
    struct helper sender = {SEND_MESSAGE, 35, 0, 0, queue};
    thread = start(&sender);
    at = in_ms(CLOCK_REALTIME, 70);
    t = now_ms();
    errno = 0;
    rc = mq_timedreceive(queue, message, sizeof message, NULL, &at);
    say("mq_timedreceive for 70 ms, sent at 35 ms", rc, errno, t);
    pthread_join(thread, NULL);
    /* It restarts a message queue's (the deadline is absolute: the same one). */
    thread = start(&sender);
    setitimer(ITIMER_REAL, &in_15_ms, NULL);
    at = in_ms(CLOCK_REALTIME, 70);
    t = now_ms();
    errno = 0;
    rc = mq_timedreceive(queue, message, sizeof message, NULL, &at);
    say("mq_timedreceive for 70 ms, SIGALRM at 15 ms with SA_RESTART, sent at 35 ms", rc, errno, t);
    pthread_join(thread, NULL);
    mq_close(queue);

    /* A socket's receive timeout (SO_RCVTIMEO). */
    int pair[2];
    socketpair(AF_UNIX, SOCK_STREAM, 0, pair);
    struct timeval receive_timeout = {0, 80000};
    setsockopt(pair[0], SOL_SOCKET, SO_RCVTIMEO, &receive_timeout, sizeof receive_timeout);
    t = now_ms();
    errno = 0;
    rc = recv(pair[0], &byte, 1, 0);
    say("recv with an 80 ms SO_RCVTIMEO, nothing sent", rc, errno, t);
    t = now_ms();
    errno = 0;
    rc = read(pair[0], &byte, 1);
    say("read of it, nothing sent", rc, errno, t);
    /* A socket's send timeout (SO_SNDTIMEO), on a socket nobody reads. */
    int unread[2];
    socketpair(AF_UNIX, SOCK_STREAM, 0, unread);
    struct timeval send_timeout = {0, 40000};
    setsockopt(unread[0], SOL_SOCKET, SO_SNDTIMEO, &send_timeout, sizeof send_timeout);
    static char lots[1 << 20];
    t = now_ms();
    rc = send(unread[0], lots, sizeof lots, 0);
    printf("send of 1 MiB with a 40 ms SO_SNDTIMEO, nobody reading: %s after %.3f ms\n", rc > 0 && rc < (long)sizeof lots ? "part of it" : "not part of it", now_ms() - t);
    t = now_ms();
    errno = 0;
    rc = send(unread[0], lots, sizeof lots, 0);
    say("another, the socket full", rc, errno, t);
    close(unread[0]);
    close(unread[1]);

    struct helper socket_writer = {WRITE_BYTE, 10, pair[1], 0, 0};
    thread = start(&socket_writer);
    t = now_ms();
    errno = 0;
    rc = recv(pair[0], &byte, 1, 0);
    say("recv of it, sent at 10 ms", rc, errno, t);
    pthread_join(thread, NULL);

    /* A timerfd inside an epoll instance that another epoll instance watches. */
    int timer = timerfd_create(CLOCK_MONOTONIC, 0);
    struct itimerspec in_30_ms = {{0, 0}, {0, 30000000}};
    int inner = epoll_create1(0), outer = epoll_create1(0);
    struct epoll_event watch = {EPOLLIN, {0}};
    epoll_ctl(inner, EPOLL_CTL_ADD, timer, &watch);
    epoll_ctl(outer, EPOLL_CTL_ADD, inner, &watch);
    timerfd_settime(timer, 0, &in_30_ms, NULL);
    t = now_ms();
    errno = 0;
    rc = epoll_wait(outer, &event, 1, 500);
    say("epoll_wait of an epoll watching a 30 ms timerfd", rc, errno, t);

    /* A POSIX timer's signal blocked while the timer fires on: one signal stays pending, and
     * the expirations after it count as the timer's overrun. */
    sigset_t usr2;
    sigemptyset(&usr2);
    sigaddset(&usr2, SIGUSR2);
    pthread_sigmask(SIG_BLOCK, &usr2, NULL);
    timer_t every_ms;
    struct sigevent on_expiry = {0};
    on_expiry.sigev_notify = SIGEV_SIGNAL;
    on_expiry.sigev_signo = SIGUSR2;
    timer_create(CLOCK_MONOTONIC, &on_expiry, &every_ms);
    struct itimerspec one_ms = {{0, 1000000}, {0, 1000000}};
    timer_settime(every_ms, 0, &one_ms, NULL);
    struct timespec fifty_ms = {0, 50000000};
    nanosleep(&fifty_ms, NULL);
    int taken;
    sigwait(&usr2, &taken);
    printf("a 1 ms timer's blocked signal taken after 50 ms: overrun %d\n", timer_getoverrun(every_ms));
    timer_delete(every_ms);

    /* futex_waitv (Linux 5.16): not followed on virtual time, where it answers ENOSYS. */
    uint32_t word = 0;
    struct futex_waitv waiter = {0, (uintptr_t)&word, FUTEX_32 | FUTEX_PRIVATE_FLAG, 0};
    struct timespec futex_at = in_ms(CLOCK_MONOTONIC, 10);
    errno = 0;
    rc = syscall(SYS_futex_waitv, &waiter, 1, 0, &futex_at, CLOCK_MONOTONIC);
    printf("futex_waitv for 10 ms: %ld %s\n", rc, rc < 0 ? strerrorname_np(errno) : "");
    return 0;
}
