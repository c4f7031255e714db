/* A controller that sends a request at the run's very last instant and waits for its status
 * while the run ends: it sleeps to the instant the run ends (argv[1] seconds; climbsim's
 * CLOCK_MONOTONIC starts at 1000 s), pings servo 1 there, and waits for the status with the
 * terminal's timeout (500 ms). The world has ticked its last and never reads the request
 * within the run; the servos still answer after it, on the wall clock, at once. Prints how
 * many bytes came and how long the wait took. Built by tests/virtual_time.rs. */
#include <signal.h>

#include "protocol2.h"

/* SIGTERM (the run's end) changes nothing: the wait for the status goes on. */
static void on_term(int signo) { (void)signo; }

int main(int argc, char **argv) {
    struct sigaction term = {0};
    term.sa_handler = on_term;
    term.sa_flags = SA_RESTART;
    sigaction(SIGTERM, &term, NULL);
    if (argc < 2) return 2;
    int fd = open_port_raw(0, 5);
    double end_s = 1000.0 + atof(argv[1]);
    struct timespec end = {(time_t)end_s, (long)((end_s - (double)(time_t)end_s) * 1e9 + 0.5)};
    while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &end, NULL) != 0) {}
    uint8_t packet[10], reply[64];
    ping_packet(1, packet);
    if (write(fd, packet, sizeof packet) != (ssize_t)sizeof packet) { perror("write"); return 1; }
    double started = now_us(CLOCK_MONOTONIC);
    size_t got = read_status(fd, reply, 14);
    printf("ping at the end: %zu bytes in %.1f ms\n", got, (now_us(CLOCK_MONOTONIC) - started) / 1e3);
    return 0;
}
