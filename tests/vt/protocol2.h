/* What the C test controllers in tests/vt/ share: Protocol 2.0's CRC and a clock in µs. */
#ifndef CLIMBSIM_VT_PROTOCOL2_H
#define CLIMBSIM_VT_PROTOCOL2_H

#include <stddef.h>
#include <stdint.h>
#include <time.h>

/* Protocol 2.0's CRC-16 (polynomial 0x8005, no reflection, initial 0). */
static uint16_t crc16(const uint8_t *data, size_t len) {
    uint16_t crc = 0;
    for (size_t i = 0; i < len; i++) {
        crc ^= (uint16_t)data[i] << 8;
        for (int bit = 0; bit < 8; bit++) crc = (crc & 0x8000) ? (uint16_t)((crc << 1) ^ 0x8005) : (uint16_t)(crc << 1);
    }
    return crc;
}

/* `clock` now, in µs. */
static double now_us(clockid_t clock) {
    struct timespec ts;
    clock_gettime(clock, &ts);
    return ts.tv_sec * 1e6 + ts.tv_nsec / 1e3;
}

#endif
