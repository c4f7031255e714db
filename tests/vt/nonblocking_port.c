/* A controller in plain C that reads the port as ROBOTIS's C++ SDK does (PortHandlerLinux):
 * opened O_NONBLOCK with VMIN = VTIME = 0, read(2) in a loop whose result is added to a count
 * unchecked. On such a terminal the kernel returns 0, not EAGAIN, when nothing is there (VMIN
 * and VTIME come first); the shim must too, also while a Sync Read's later replies are written
 * but not due yet. Prints when each status arrives and what the empty reads returned. Built by
 * tests/virtual_time.rs with the system's cc. */
#include <errno.h>
#include <fcntl.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include "protocol2.h"

int main(void) {
    const char *path = getenv("DXL_PORT");
    if (!path) return 2;
    int fd = open(path, O_RDWR | O_NOCTTY | O_NONBLOCK);
    if (fd < 0) { perror("open"); return 1; }
    struct termios tio = {0};
    tio.c_cflag = B1000000 | CS8 | CLOCAL | CREAD;
    tio.c_iflag = IGNPAR;
    tio.c_cc[VTIME] = 0;
    tio.c_cc[VMIN] = 0;
    tcflush(fd, TCIFLUSH);
    tcsetattr(fd, TCSANOW, &tio);
    /* Sync Read of Present Position (132, 4 bytes) from IDs 1-8. */
    uint8_t packet[22] = {0xFF, 0xFF, 0xFD, 0x00, 0xFE, 15, 0, 0x82, 132, 0, 4, 0, 1, 2, 3, 4, 5, 6, 7, 8, 0, 0};
    uint16_t crc = crc16(packet, 20);
    packet[20] = crc & 0xFF;
    packet[21] = crc >> 8;
    if (write(fd, packet, sizeof packet) != (ssize_t)sizeof packet) { perror("write"); return 1; }
    double started = now_us(CLOCK_REALTIME);
    uint8_t reply[256];
    uint16_t got = 0; /* as the SDK counts: a -1 would wrap it */
    long empty_zero = 0, empty_negative = 0;
    while (got < 120 && now_us(CLOCK_REALTIME) - started < 50000) {
        int n = (int)read(fd, reply + got, 120 - got);
        if (n == 0) { empty_zero++; continue; }
        if (n < 0) { empty_negative++; if (errno != EAGAIN) { perror("read"); return 1; } continue; }
        got += (uint16_t)n;
        printf("arrival %u bytes at %.0f us\n", got, now_us(CLOCK_REALTIME) - started);
    }
    printf("empty reads: %ld returned 0, %ld returned -1\n", empty_zero, empty_negative);
    fflush(stdout);
    return got == 120 ? 0 : 1;
}
