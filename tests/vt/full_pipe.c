/* A blocking write larger than a pipe holds, to a reader that takes its time: a child that
 * starts reading after 100 ms and reads 64 KiB every 50 ms. The writer waits in the write until
 * the reader has made room, as on Linux; on virtual time it waits on simulated time, so the
 * reader's sleeps move the clock (blocked in the kernel, the writer held time still, and the run
 * failed after 2 s of wall time). Then the same through the program's own `syscall`
 * instruction, through a FIFO, and a thread writing a full socket that another thread of the
 * process reads. */
#define _GNU_SOURCE
#include <fcntl.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/syscall.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#define CHUNK 65536
#define TOTAL (16 * CHUNK)

static double now_ms(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return ts.tv_sec * 1e3 + ts.tv_nsec / 1e6;
}

static void sleep_ms(long ms) {
    struct timespec ts = {ms / 1000, (ms % 1000) * 1000000};
    nanosleep(&ts, NULL);
}

/* Read everything from `fd`, a chunk every 50 ms after 100 ms; how many bytes. */
static long read_slowly(int fd) {
    static char buffer[CHUNK];
    long total = 0;
    sleep_ms(100);
    for (;;) {
        long got = 0;
        while (got < CHUNK) {
            ssize_t n = read(fd, buffer + got, CHUNK - got);
            if (n <= 0)
                return total + got;
            got += n;
        }
        total += got;
        sleep_ms(50);
    }
}

/* The program's own system call (not libc's `syscall`, whose instruction is libc's). */
static long raw_write(long fd, const void *buffer, long count) {
    long result;
    __asm__ volatile("syscall" : "=a"(result) : "a"(SYS_write), "D"(fd), "S"(buffer), "d"(count) : "rcx", "r11", "memory");
    return result;
}

/* `how` 0: a pipe; 1: the same, written with a raw call; 2: a FIFO opened by name (which
 * takes no RWF_NOWAIT). */
static void through_a_pipe(const char *how, int raw) {
    int ends[2];
    char fifo[64];
    if (raw == 2) {
        snprintf(fifo, sizeof fifo, "/tmp/climbsim-full-pipe-%d", (int)getpid());
        unlink(fifo);
        if (mkfifo(fifo, 0600) != 0 || (ends[0] = open(fifo, O_RDONLY | O_NONBLOCK)) < 0 || (ends[1] = open(fifo, O_WRONLY)) < 0)
            exit(1);
        unlink(fifo);
        fcntl(ends[0], F_SETFL, 0);
    } else if (pipe(ends) != 0)
        exit(1);
    pid_t child = fork();
    if (child == 0) {
        close(ends[1]);
        long total = read_slowly(ends[0]);
        printf("  the child read %ld bytes\n", total);
        fflush(stdout);
        _exit(0);
    }
    close(ends[0]);
    char *data = calloc(1, TOTAL);
    double start = now_ms();
    long written = raw == 1 ? raw_write(ends[1], data, TOTAL) : write(ends[1], data, TOTAL);
    printf("%s of %d bytes: %ld after %.3f ms\n", how, TOTAL, written, now_ms() - start);
    fflush(stdout);
    close(ends[1]);
    waitpid(child, NULL, 0);
    free(data);
}

static int pair[2];

static void *reader(void *unused) {
    (void)unused;
    long total = read_slowly(pair[1]);
    printf("  the thread read %ld bytes\n", total);
    fflush(stdout);
    return NULL;
}

int main(void) {
    through_a_pipe("write to a pipe", 0);
    through_a_pipe("raw write to a pipe", 1);
    through_a_pipe("write to a FIFO", 2);
    if (socketpair(AF_UNIX, SOCK_STREAM, 0, pair) != 0)
        return 1;
    pthread_t thread;
    pthread_create(&thread, NULL, reader, NULL);
    char *data = calloc(1, TOTAL);
    double start = now_ms();
    long written = send(pair[0], data, TOTAL, 0);
    printf("send of %d bytes to a socket: %ld after %.3f ms\n", TOTAL, written, now_ms() - start);
    fflush(stdout);
    shutdown(pair[0], SHUT_WR);
    pthread_join(thread, NULL);
    free(data);
    return 0;
}
