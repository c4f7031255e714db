/* A controller in plain C on a blocking port (termios VMIN/VTIME, read(2)), for the
 * virtual-time tests: pings servo 1 and an absent ID with the terminal's own timeouts and
 * prints what its monotonic clock saw. Built by tests/virtual_time.rs with the system's cc. */
#include "protocol2.h"

/* Ping `id`, then read up to 14 bytes with blocking reads until one returns 0 (VTIME ran out)
 * or the status is whole. */
static void ping(int fd, uint8_t id, const char *what) {
    uint8_t packet[10], reply[64];
    ping_packet(id, packet);
    double started = now_us(CLOCK_MONOTONIC);
    if (write(fd, packet, sizeof packet) != (ssize_t)sizeof packet) { perror("write"); exit(1); }
    size_t got = read_status(fd, reply, 14);
    printf("%s: %.1f us, %zu bytes\n", what, now_us(CLOCK_MONOTONIC) - started, got);
    fflush(stdout);
}

int main(void) {
    int fd = open_port_raw(0, 2); /* VTIME 200 ms */
    ping(fd, 1, "vtime ping 1");
    ping(fd, 42, "vtime ping 42");
    struct termios tio;
    tcgetattr(fd, &tio);
    tio.c_cc[VMIN] = 1;
    tio.c_cc[VTIME] = 0;
    tcsetattr(fd, TCSANOW, &tio);
    uint8_t packet[10];
    ping_packet(1, packet);
    double started = now_us(CLOCK_MONOTONIC);
    if (write(fd, packet, sizeof packet) != (ssize_t)sizeof packet) return 1;
    uint8_t reply[14];
    size_t got = 0;
    while (got < sizeof reply) {
        ssize_t n = read(fd, reply + got, sizeof reply - got);
        if (n <= 0) return 1;
        got += (size_t)n;
    }
    printf("vmin ping 1: %.1f us, %zu bytes\n", now_us(CLOCK_MONOTONIC) - started, got);
    return 0;
}
