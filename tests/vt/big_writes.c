/* A controller that writes far more to the port than the shared block's ring holds without
 * waiting once: 1.5 MiB of zeros in one blocking write (larger than the ring: it waits for room), then
 * 2 MiB in writes of 64 KiB (through the ring, which fills: the writer waits for climbsim to
 * take it), then a ping of servo 1, whose status must still come: the stream stays in order
 * and nothing hangs. Prints what it wrote and the ping's result. Built by tests/virtual_time.rs. */
#include <string.h>

#include "protocol2.h"

/* Write all of `len` bytes, as many writes as it takes; the bytes written. */
static size_t write_all(int fd, const uint8_t *bytes, size_t len) {
    size_t done = 0;
    while (done < len) {
        ssize_t n = write(fd, bytes + done, len - done);
        if (n <= 0) { perror("write"); exit(1); }
        done += (size_t)n;
    }
    return done;
}

int main(void) {
    int fd = open_port_raw(0, 5);
    static uint8_t zeros[3 << 19];
    size_t total = write_all(fd, zeros, sizeof zeros);
    for (int i = 0; i < 32; i++) total += write_all(fd, zeros, 64 << 10);
    uint8_t packet[10], reply[64];
    ping_packet(1, packet);
    total += write_all(fd, packet, sizeof packet);
    size_t got = read_status(fd, reply, 14);
    printf("wrote %zu bytes; ping: %zu bytes\n", total, got);
    return 0;
}
