/* As many connections to the sensor server as a controller opens (climbsim followed 64 at once
 * before, and the 65th failed the run). First 100 at once, each asking for the line: one poll
 * over all of them gathers the answers. Then 70 open at once, and a thread waits on the 70th
 * alone while the main thread asks on the 6th and takes its answer (70 and 6 are 64 apart: a
 * table of 64 bits would mix them up), sleeps 100 ms and only then asks on the 70th: the thread
 * wakes with its own answer, 100 ms after it began to wait. */
#include <arpa/inet.h>
#include <poll.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

#define FIRST 100
#define SECOND 70

static struct sockaddr_in server;

static double now_ms(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return ts.tv_sec * 1e3 + ts.tv_nsec / 1e6;
}

static int connected(void) {
    int fd = socket(AF_INET, SOCK_STREAM, 0);
    if (fd < 0 || connect(fd, (struct sockaddr *)&server, sizeof server) != 0) {
        perror("connect");
        exit(1);
    }
    return fd;
}

static void ask(int fd) {
    const char request[] = "GET /line HTTP/1.1\r\nHost: climbsim\r\n\r\n";
    if (write(fd, request, sizeof request - 1) != (ssize_t)(sizeof request - 1)) {
        perror("write");
        exit(1);
    }
}

/* Read what there is (an answer's first part counted in `answers`); 1 at the end of the stream
 * (the server closes after its answer). */
static int take(int fd, int *answers) {
    char buffer[4096];
    ssize_t got = read(fd, buffer, sizeof buffer);
    if (got < 0) {
        perror("read");
        exit(1);
    }
    if (got >= 9 && memcmp(buffer, "HTTP/1.1 ", 9) == 0)
        (*answers)++;
    return got == 0;
}

static int waited_on;
static double woke_after;
static int woke_ready;

static void *wait_for_its_own(void *unused) {
    (void)unused;
    struct pollfd entry = {.fd = waited_on, .events = POLLIN};
    double start = now_ms();
    woke_ready = poll(&entry, 1, 1000);
    woke_after = now_ms() - start;
    return NULL;
}

int main(void) {
    const char *url = getenv("CLIMBSIM_SENSORS");
    unsigned port = 0;
    if (!url || sscanf(url, "http://127.0.0.1:%u", &port) != 1) {
        printf("no sensor server (CLIMBSIM_SENSORS=%s)\n", url ? url : "");
        return 1;
    }
    server.sin_family = AF_INET;
    server.sin_port = htons((unsigned short)port);
    server.sin_addr.s_addr = htonl(INADDR_LOOPBACK);

    int fds[FIRST];
    struct pollfd watched[FIRST];
    for (int i = 0; i < FIRST; i++) {
        fds[i] = connected();
        ask(fds[i]);
        watched[i].fd = fds[i];
        watched[i].events = POLLIN;
    }
    int open = FIRST, answers = 0;
    double start = now_ms();
    while (open > 0) {
        if (poll(watched, FIRST, 2000) <= 0) {
            printf("a poll of %d connections found nothing with %d still open\n", FIRST, open);
            return 1;
        }
        for (int i = 0; i < FIRST; i++)
            if (watched[i].fd >= 0 && (watched[i].revents & (POLLIN | POLLHUP)) && take(watched[i].fd, &answers)) {
                close(watched[i].fd);
                watched[i].fd = -1;
                open--;
            }
    }
    printf("%d connections at once: %d answered, all within %.3f ms\n", FIRST, answers, now_ms() - start);

    int more[SECOND];
    for (int i = 0; i < SECOND; i++)
        more[i] = connected();
    waited_on = more[SECOND - 1];
    pthread_t waiter;
    pthread_create(&waiter, NULL, wait_for_its_own, NULL);
    usleep(1000); /* the thread is waiting by now */
    answers = 0;
    ask(more[5]);
    while (!take(more[5], &answers))
        ;
    usleep(100000);
    ask(more[SECOND - 1]);
    pthread_join(waiter, NULL);
    printf("connection %d answered (%d answer); the thread on connection %d woke after %.3f ms with %d ready\n", 6, answers, SECOND, woke_after, woke_ready);
    return 0;
}
