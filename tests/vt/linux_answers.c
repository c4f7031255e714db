/* Linux's answers to calls with wrong arguments, and the corner cases of the calls virtual time
 * follows, for tests/virtual_time_linux.rs: each line says what a call returned and its errno,
 * and whether it came back at once. Run natively and on virtual time, the lines must be the
 * same. Built with the system's cc. */
#define _GNU_SOURCE
#include <errno.h>
#include <fcntl.h>
#include <poll.h>
#include <signal.h>
#include <stdio.h>
#include <string.h>
#include <sys/epoll.h>
#include <sys/mman.h>
#include <sys/select.h>
#include <sys/syscall.h>
#include <sys/time.h>
#include <time.h>
#include <unistd.h>

static double now_ms(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return ts.tv_sec * 1e3 + ts.tv_nsec / 1e6;
}

/* "-1 EBADF at once", "0", "4 after 10 ms" ... */
static void say(const char *what, long rc, int error, double started) {
    double took = now_ms() - started;
    const char *when = took < 1.0 ? "at once" : took < 100.0 ? "after a while" : "late";
    if (rc < 0)
        printf("%s: %ld %s %s\n", what, rc, strerrorname_np(error), when);
    else
        printf("%s: %ld %s\n", what, rc, when);
    fflush(stdout);
}

static volatile sig_atomic_t alarms, sigsys_seen;
static void on_alarm(int sig) { (void)sig; alarms++; }
static void on_sigsys(int sig) { (void)sig; sigsys_seen++; }

int main(void) {
    int pipefd[2];
    if (pipe(pipefd) != 0) { perror("pipe"); return 1; }
    char byte;
    double t;

    /* A read of a pipe's write end: EBADF at once (the descriptor is not open for reading). */
    t = now_ms(); errno = 0;
    long rc = read(pipefd[1], &byte, 1);
    say("read of a pipe's write end", rc, errno, t);
    t = now_ms(); errno = 0;
    rc = syscall(SYS_read, pipefd[1], &byte, 1);
    say("raw read of a pipe's write end", rc, errno, t);
    /* A write to a pipe's read end: EBADF. */
    t = now_ms(); errno = 0;
    rc = write(pipefd[0], "x", 1);
    say("write to a pipe's read end", rc, errno, t);
    /* A read of a closed descriptor. */
    t = now_ms(); errno = 0;
    rc = read(1000, &byte, 1);
    say("read of a closed descriptor", rc, errno, t);

    /* poll and ppoll on an array that is not there: EFAULT. */
    t = now_ms(); errno = 0;
    rc = poll(NULL, 1, 0);
    say("poll(NULL, 1, 0)", rc, errno, t);
    t = now_ms(); errno = 0;
    rc = poll((struct pollfd *)16, 1, 10);
    say("poll(16, 1, 10)", rc, errno, t);
    struct timespec zero = {0, 0};
    t = now_ms(); errno = 0;
    rc = ppoll(NULL, 1, &zero, NULL);
    say("ppoll(NULL, 1, 0)", rc, errno, t);
    /* An array whose second entry lies past the end of its mapping: EFAULT; the same array
     * moved back into the mapping: polled. */
    long page = sysconf(_SC_PAGESIZE);
    char *pages = mmap(NULL, 2 * page, PROT_READ | PROT_WRITE, MAP_PRIVATE | MAP_ANONYMOUS, -1, 0);
    munmap(pages + page, page);
    struct pollfd *straddling = (struct pollfd *)(pages + page - sizeof(struct pollfd));
    straddling[0] = (struct pollfd){pipefd[0], POLLIN, 0};
    t = now_ms(); errno = 0;
    rc = poll(straddling, 2, 0);
    say("poll of an array past its mapping's end", rc, errno, t);
    struct pollfd *inside = straddling - 1;
    inside[0] = inside[1] = (struct pollfd){pipefd[0], POLLIN, 0};
    t = now_ms(); errno = 0;
    rc = poll(inside, 2, 0);
    say("poll of the same array inside it", rc, errno, t);
    fd_set *unmapped_set = (fd_set *)(pages + page);
    t = now_ms(); errno = 0;
    rc = select(pipefd[0] + 1, unmapped_set, NULL, NULL, &(struct timeval){0, 0});
    say("select of an unmapped set", rc, errno, t);
    /* poll of nothing with no array: a sleep. */
    t = now_ms(); errno = 0;
    rc = poll(NULL, 0, 10);
    say("poll(NULL, 0, 10)", rc, errno, t);
    /* More descriptors than a process may have: EINVAL. */
    struct pollfd one = {pipefd[0], POLLIN, 0};
    t = now_ms(); errno = 0;
    rc = poll(&one, 1u << 30, 0);
    say("poll of 2^30 descriptors", rc, errno, t);
    /* select with a negative count: EINVAL; with a bad timeout: EINVAL. */
    fd_set set;
    FD_ZERO(&set);
    FD_SET(pipefd[0], &set);
    t = now_ms(); errno = 0;
    rc = select(-1, &set, NULL, NULL, NULL);
    say("select(-1)", rc, errno, t);
    struct timeval bad_tv = {0, -1};
    t = now_ms(); errno = 0;
    rc = select(pipefd[0] + 1, &set, NULL, NULL, &bad_tv);
    say("select with tv_usec -1", rc, errno, t);

    /* Sleeps with wrong times: EINVAL. */
    struct timespec bad_ns = {0, 1000000000L}, negative = {-1, 0}, ten_ms = {0, 10000000L};
    t = now_ms(); errno = 0;
    rc = nanosleep(&bad_ns, NULL);
    say("nanosleep of 1e9 ns", rc, errno, t);
    t = now_ms(); errno = 0;
    rc = nanosleep(&negative, NULL);
    say("nanosleep of -1 s", rc, errno, t);
    t = now_ms(); errno = 0;
    rc = nanosleep(NULL, NULL);
    say("nanosleep(NULL)", rc, errno, t);

    /* epoll_pwait2's timeout is checked as ppoll's: EFAULT for an unmapped one, EINVAL for a bad one. */
    int epoll = epoll_create1(0);
    struct epoll_event event;
    t = now_ms(); errno = 0;
    rc = epoll_pwait2(epoll, &event, 1, (const struct timespec *)16, NULL);
    say("epoll_pwait2 with an unmapped timeout", rc, errno, t);
    t = now_ms(); errno = 0;
    rc = epoll_pwait2(epoll, &event, 1, &bad_ns, NULL);
    say("epoll_pwait2 with a timeout of 1e9 ns", rc, errno, t);
    close(epoll);

    /* clock_nanosleep returns the error itself. Clocks that cannot sleep: EOPNOTSUPP; a clock
     * that does not exist or a thread's CPU clock: EINVAL. */
    static const struct { clockid_t id; const char *name; } clocks[] = {
        {CLOCK_MONOTONIC_RAW, "CLOCK_MONOTONIC_RAW"}, {CLOCK_MONOTONIC_COARSE, "CLOCK_MONOTONIC_COARSE"},
        {CLOCK_REALTIME_COARSE, "CLOCK_REALTIME_COARSE"}, {CLOCK_THREAD_CPUTIME_ID, "CLOCK_THREAD_CPUTIME_ID"},
        {99, "clock 99"}, {CLOCK_BOOTTIME, "CLOCK_BOOTTIME"},
    };
    for (unsigned i = 0; i < sizeof clocks / sizeof clocks[0]; i++) {
        char what[80];
        snprintf(what, sizeof what, "clock_nanosleep(%s, 10 ms)", clocks[i].name);
        t = now_ms();
        int error = clock_nanosleep(clocks[i].id, 0, &ten_ms, NULL);
        say(what, error ? -1 : 0, error, t);
    }
    t = now_ms();
    int error = clock_nanosleep(CLOCK_MONOTONIC, 0, &bad_ns, NULL);
    say("clock_nanosleep(CLOCK_MONOTONIC, 1e9 ns)", error ? -1 : 0, error, t);
    struct timespec res;
    t = now_ms(); errno = 0;
    rc = clock_gettime(99, &res);
    say("clock_gettime(clock 99)", rc, errno, t);
    t = now_ms(); errno = 0;
    rc = clock_getres(99, &res);
    say("clock_getres(clock 99)", rc, errno, t);

    /* setitimer with a zero value disarms the timer whatever its interval. */
    signal(SIGALRM, on_alarm);
    struct itimerval armed = {{0, 5000}, {0, 5000}}, disarm = {{0, 10000}, {0, 0}}, now;
    setitimer(ITIMER_REAL, &armed, NULL);
    setitimer(ITIMER_REAL, &disarm, NULL);
    getitimer(ITIMER_REAL, &now);
    struct timespec fifty_ms = {0, 50000000L};
    while (nanosleep(&fifty_ms, &fifty_ms) != 0 && errno == EINTR) {}
    printf("setitimer with a zero value and a 10 ms interval: %d alarms in 50 ms; getitimer says value %ld.%06ld interval %ld.%06ld\n", (int)alarms,
           (long)now.it_value.tv_sec, (long)now.it_value.tv_usec, (long)now.it_interval.tv_sec, (long)now.it_interval.tv_usec);
    struct itimerval bad_timer = {{0, 0}, {0, 1000000}};
    t = now_ms(); errno = 0;
    rc = setitimer(ITIMER_REAL, &bad_timer, NULL);
    say("setitimer with tv_usec 1e6", rc, errno, t);
    t = now_ms(); errno = 0;
    rc = setitimer(99, &armed, NULL);
    say("setitimer(99)", rc, errno, t);

    /* A SIGSYS the program raises itself reaches its own handler. */
    signal(SIGSYS, on_sigsys);
    raise(SIGSYS);
    printf("raise(SIGSYS): the handler ran %d time(s)\n", (int)sigsys_seen);
    kill(getpid(), SIGSYS);
    printf("kill(self, SIGSYS): the handler ran %d time(s)\n", (int)sigsys_seen);
    return 0;
}
