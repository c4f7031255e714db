/* As many timerfds as a program opens: 300 of them (climbsim followed 64 per process before),
 * timer i expiring at i ms. The program reads them one after another, then polls 20 of them at
 * once, and then, in an epoll set of 50, waits for the next to expire; then polls all 300 at
 * once (64 in one wait were followed before) and, in an epoll set of 250, waits again. Every
 * expiry is simulated time. */
#include <poll.h>
#include <stdint.h>
#include <stdio.h>
#include <sys/epoll.h>
#include <sys/timerfd.h>
#include <time.h>
#include <unistd.h>

#define TIMERS 300

static double now_ms(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return ts.tv_sec * 1e3 + ts.tv_nsec / 1e6;
}

static void arm(int fd, long ms) {
    struct itimerspec at = {{0, 0}, {ms / 1000, (ms % 1000) * 1000000L}};
    timerfd_settime(fd, 0, &at, NULL);
}

int main(void) {
    int fds[TIMERS];
    double start = now_ms();
    for (int i = 0; i < TIMERS; i++) {
        fds[i] = timerfd_create(CLOCK_MONOTONIC, 0);
        if (fds[i] < 0) {
            printf("timerfd %d: not created\n", i);
            return 1;
        }
        arm(fds[i], i + 1);
    }
    uint64_t expirations = 0, total = 0;
    for (int i = 0; i < TIMERS; i++) {
        if (read(fds[i], &expirations, sizeof expirations) != 8)
            return 1;
        total += expirations;
    }
    printf("read %d timers, %llu expirations, the last at %.3f ms\n", TIMERS, (unsigned long long)total, now_ms() - start);

    struct pollfd watched[20];
    for (int i = 0; i < 20; i++) {
        arm(fds[280 + i], 50 + 10 * (20 - i));
        watched[i].fd = fds[280 + i];
        watched[i].events = POLLIN;
    }
    start = now_ms();
    int ready = poll(watched, 20, 1000);
    printf("poll of 20: %d ready after %.3f ms (the last one's, %s)\n", ready, now_ms() - start, watched[19].revents & POLLIN ? "readable" : "not readable");

    int epoll = epoll_create1(0);
    for (int i = 0; i < 50; i++) {
        struct epoll_event event = {.events = EPOLLIN, .data.u32 = (uint32_t)i};
        epoll_ctl(epoll, EPOLL_CTL_ADD, fds[100 + i], &event);
        arm(fds[100 + i], 500 - i);
    }
    struct epoll_event got;
    start = now_ms();
    ready = epoll_wait(epoll, &got, 1, 1000);
    printf("epoll of 50: %d ready after %.3f ms (timer %u)\n", ready, now_ms() - start, got.data.u32);

    /* All 300 in one poll: the one due first (timer 5, at 69 ms: among the first few a wait
     * keeps, moved with them as the list grows) is the one ready; then timer 137 (at 70 ms). */
    struct pollfd all[TIMERS];
    for (int i = 0; i < TIMERS; i++) {
        arm(fds[i], i == 5 ? 69 : i == 137 ? 70 : 100 + i);
        all[i].fd = fds[i];
        all[i].events = POLLIN;
    }
    start = now_ms();
    for (int first = 5; first >= 0; first = first == 5 ? 137 : -1) {
        ready = poll(all, TIMERS, 1000);
        printf("poll of %d: %d ready after %.3f ms (timer %d %s)\n", TIMERS, ready, now_ms() - start, first, all[first].revents & POLLIN ? "readable" : "not readable");
        if (read(fds[first], &expirations, sizeof expirations) != 8)
            return 1;
    }

    /* 250 in an epoll set (the 50 above, 200 more): the next due is timer 230's. */
    for (int i = 0; i < 250; i++) {
        struct epoll_event event = {.events = EPOLLIN, .data.u32 = (uint32_t)i};
        if (i < 100 || i >= 150)
            epoll_ctl(epoll, EPOLL_CTL_ADD, fds[i], &event);
    }
    for (int i = 0; i < 250; i++)
        arm(fds[i], i == 230 ? 40 : 600 + i);
    start = now_ms();
    ready = epoll_wait(epoll, &got, 1, 1000);
    printf("epoll of 250: %d ready after %.3f ms (timer %u)\n", ready, now_ms() - start, got.data.u32);
    return 0;
}
