/* What the C test controllers in tests/vt/ share: Protocol 2.0's CRC and a clock in µs. */
#ifndef CLIMBSIM_VT_PROTOCOL2_H
#define CLIMBSIM_VT_PROTOCOL2_H

#include <fcntl.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

/* Protocol 2.0's CRC-16 (polynomial 0x8005, no reflection, initial 0). */
static inline uint16_t crc16(const uint8_t *data, size_t len) {
    uint16_t crc = 0;
    for (size_t i = 0; i < len; i++) {
        crc ^= (uint16_t)data[i] << 8;
        for (int bit = 0; bit < 8; bit++) crc = (crc & 0x8000) ? (uint16_t)((crc << 1) ^ 0x8005) : (uint16_t)(crc << 1);
    }
    return crc;
}

/* `clock` now, in µs. */
static inline double now_us(clockid_t clock) {
    struct timespec ts;
    clock_gettime(clock, &ts);
    return ts.tv_sec * 1e6 + ts.tv_nsec / 1e3;
}

/* The servo port (DXL_PORT) opened raw at 1 Mbps, its blocking reads as `vmin` and `vtime`
 * say; the process exits if it cannot. */
static inline int open_port_raw(cc_t vmin, cc_t vtime) {
    const char *path = getenv("DXL_PORT");
    if (!path) exit(2);
    int fd = open(path, O_RDWR | O_NOCTTY);
    if (fd < 0) { perror("open"); exit(1); }
    struct termios tio;
    tcgetattr(fd, &tio);
    cfmakeraw(&tio);
    cfsetspeed(&tio, B1000000);
    tio.c_cc[VMIN] = vmin;
    tio.c_cc[VTIME] = vtime;
    tcsetattr(fd, TCSANOW, &tio);
    return fd;
}

/* A ping of servo `id`: 10 bytes into `packet`. */
static inline void ping_packet(uint8_t id, uint8_t packet[10]) {
    const uint8_t head[8] = {0xFF, 0xFF, 0xFD, 0x00, id, 0x03, 0x00, 0x01};
    for (int i = 0; i < 8; i++) packet[i] = head[i];
    uint16_t crc = crc16(packet, 8);
    packet[8] = crc & 0xFF;
    packet[9] = crc >> 8;
}

/* Read up to `want` bytes into `buf` until a read returns nothing (the terminal's timeout); how
 * many came. A failed read ends the process. */
static inline size_t read_status(int fd, uint8_t *buf, size_t want) {
    size_t got = 0;
    while (got < want) {
        ssize_t n = read(fd, buf + got, want - got);
        if (n < 0) { perror("read"); exit(1); }
        if (n == 0) break;
        got += (size_t)n;
    }
    return got;
}

#endif
