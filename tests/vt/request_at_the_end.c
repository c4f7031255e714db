/* A controller that sends a request at the run's very last instant and waits for its status
 * while the run ends: it sleeps to the instant the run ends (argv[1] seconds; climbsim's
 * CLOCK_MONOTONIC starts at 1000 s), pings servo 1 there, and waits for the status with the
 * terminal's timeout (500 ms). The world has ticked its last and never reads the request
 * within the run; the servos still answer after it, on the wall clock, at once. Prints how
 * many bytes came and how long the wait took. Built by tests/virtual_time.rs. */
#include <fcntl.h>
#include <signal.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include "protocol2.h"

/* SIGTERM (the run's end) changes nothing: the wait for the status goes on. */
static void on_term(int signo) { (void)signo; }

int main(int argc, char **argv) {
    struct sigaction term = {0};
    term.sa_handler = on_term;
    term.sa_flags = SA_RESTART;
    sigaction(SIGTERM, &term, NULL);
    const char *path = getenv("DXL_PORT");
    if (!path || argc < 2) return 2;
    int fd = open(path, O_RDWR | O_NOCTTY);
    if (fd < 0) { perror("open"); return 1; }
    struct termios tio;
    tcgetattr(fd, &tio);
    cfmakeraw(&tio);
    cfsetspeed(&tio, B1000000);
    tio.c_cc[VMIN] = 0;
    tio.c_cc[VTIME] = 5;
    tcsetattr(fd, TCSANOW, &tio);
    double end_s = 1000.0 + atof(argv[1]);
    struct timespec end = {(time_t)end_s, (long)((end_s - (double)(time_t)end_s) * 1e9 + 0.5)};
    while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &end, NULL) != 0) {}
    uint8_t packet[10] = {0xFF, 0xFF, 0xFD, 0x00, 1, 0x03, 0x00, 0x01, 0, 0};
    uint16_t crc = crc16(packet, 8);
    packet[8] = crc & 0xFF;
    packet[9] = crc >> 8;
    if (write(fd, packet, sizeof packet) != (ssize_t)sizeof packet) { perror("write"); return 1; }
    double started = now_us(CLOCK_MONOTONIC);
    uint8_t reply[64];
    size_t got = 0;
    while (got < 14) {
        ssize_t n = read(fd, reply + got, sizeof reply - got);
        if (n <= 0) break;
        got += (size_t)n;
    }
    printf("ping at the end: %zu bytes in %.1f ms\n", got, (now_us(CLOCK_MONOTONIC) - started) / 1e3);
    return 0;
}
