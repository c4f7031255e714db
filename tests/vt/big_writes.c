/* A controller that writes far more to the port than the shared block's ring holds without
 * waiting once: 1.5 MiB of zeros in one write (larger than the ring: through the pty), then
 * 2 MiB in writes of 64 KiB (through the ring, which fills: the writer waits for climbsim to
 * take it), then a ping of servo 1, whose status must still come: the stream stays in order
 * and nothing hangs. Prints what it wrote and the ping's result. Built by tests/virtual_time.rs. */
#include <fcntl.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <termios.h>
#include <unistd.h>

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
    const char *path = getenv("DXL_PORT");
    if (!path) return 2;
    int fd = open(path, O_RDWR | O_NOCTTY);
    if (fd < 0) { perror("open"); return 1; }
    struct termios tio;
    tcgetattr(fd, &tio);
    cfmakeraw(&tio);
    cfsetspeed(&tio, B1000000);
    tio.c_cc[VMIN] = 0;
    tio.c_cc[VTIME] = 5;
    tcsetattr(fd, TCSANOW, &tio);
    static uint8_t zeros[3 << 19];
    size_t total = write_all(fd, zeros, sizeof zeros);
    for (int i = 0; i < 32; i++) total += write_all(fd, zeros, 64 << 10);
    uint8_t packet[10] = {0xFF, 0xFF, 0xFD, 0x00, 1, 0x03, 0x00, 0x01, 0, 0};
    uint16_t crc = crc16(packet, 8);
    packet[8] = crc & 0xFF;
    packet[9] = crc >> 8;
    total += write_all(fd, packet, sizeof packet);
    uint8_t reply[64];
    size_t got = 0;
    while (got < 14) {
        ssize_t n = read(fd, reply + got, sizeof reply - got);
        if (n <= 0) break;
        got += (size_t)n;
    }
    printf("wrote %zu bytes; ping: %zu bytes\n", total, got);
    return 0;
}
