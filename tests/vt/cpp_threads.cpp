// A wheel controller as C++ programs on the official C++ SDK's pattern are written: the port
// opened O_NONBLOCK with VMIN = VTIME = 0 and read in a loop until a status is whole or the
// packet timeout passes; a 50 Hz std::thread loop (Sync Read of the wheels' Present Velocity,
// Sync Write of their Goal Velocity) that hands each cycle to a statistics thread through a
// std::condition_variable, whose wait_until reads steady_clock::now() while it holds the mutex.
// Built by tests/virtual_time.rs with the system's c++.
#include <fcntl.h>
#include <signal.h>
#include <termios.h>
#include <unistd.h>

#include <chrono>
#include <atomic>
#include <condition_variable>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <deque>
#include <mutex>
#include <thread>
#include <vector>

extern "C" {
#include "protocol2.h"
}

using Clock = std::chrono::steady_clock;

static int port = -1;

static void send(std::vector<uint8_t> packet) {
    uint16_t crc = crc16(packet.data(), packet.size());
    packet.push_back(crc & 0xFF);
    packet.push_back(crc >> 8);
    if (write(port, packet.data(), packet.size()) != (ssize_t)packet.size()) std::exit(1);
}

// Read `want` bytes as the SDK does (a spin of non-blocking reads), or give up after `timeout`.
static size_t receive(size_t want, std::chrono::microseconds timeout) {
    uint8_t buffer[256];
    size_t got = 0;
    auto started = Clock::now();
    while (got < want && Clock::now() - started < timeout) {
        ssize_t n = read(port, buffer + got, want - got);
        if (n > 0) got += (size_t)n;
    }
    return got;
}

static std::vector<uint8_t> header(uint8_t id, uint16_t length, uint8_t instruction) {
    return {0xFF, 0xFF, 0xFD, 0x00, id, (uint8_t)(length & 0xFF), (uint8_t)(length >> 8), instruction};
}

struct Cycle {
    double at_ms;
    size_t replies;
};

// With --until-stopped it runs until SIGTERM, as services do, and reports then.
static std::atomic<bool> stopping{false};

int main(int argc, char **argv) {
    setvbuf(stdout, nullptr, _IOLBF, 0);
    const bool until_stopped = argc > 1 && std::strcmp(argv[1], "--until-stopped") == 0;
    if (until_stopped) {
        struct sigaction on_term {};
        on_term.sa_handler = [](int) { stopping = true; };
        sigaction(SIGTERM, &on_term, nullptr);
    }
    const char *path = std::getenv("DXL_PORT");
    if (!path) return 2;
    port = open(path, O_RDWR | O_NOCTTY | O_NONBLOCK);
    if (port < 0) return 1;
    termios tio{};
    tio.c_cflag = B1000000 | CS8 | CLOCAL | CREAD;
    tio.c_iflag = IGNPAR;
    tcflush(port, TCIFLUSH);
    tcsetattr(port, TCSANOW, &tio);

    int found = 0;
    for (uint8_t id = 1; id <= 8; id++) {
        tcflush(port, TCIFLUSH);
        send(header(id, 3, 0x01));
        found += receive(14, std::chrono::milliseconds(10)) == 14;
    }
    std::printf("ping 1-8: %d found\n", found);

    std::mutex lock;
    std::condition_variable changed;
    std::deque<Cycle> queue;
    bool done = false;
    std::thread stats([&] {
        size_t cycles = 0, replies = 0, timeouts = 0;
        double last_ms = 0;
        std::unique_lock<std::mutex> held(lock);
        while (true) {
            if (!changed.wait_until(held, Clock::now() + std::chrono::milliseconds(7), [&] { return !queue.empty() || done; })) {
                timeouts++;
                continue;
            }
            if (queue.empty() && done) break;
            while (!queue.empty()) {
                cycles++;
                replies += queue.front().replies;
                last_ms = queue.front().at_ms;
                queue.pop_front();
            }
        }
        std::printf("stats: %zu cycles, %zu replies, %zu timeouts, last at %.3f ms\n", cycles, replies, timeouts, last_ms);
    });

    auto start = Clock::now();
    auto next = start;
    auto previous = start;
    Clock::duration longest{};
    int cycle = 0;
    for (; until_stopped ? !stopping : cycle < 100; cycle++) {
        next += std::chrono::milliseconds(20);
        // Sync Read of Present Velocity (128, 4 bytes) from the wheels 1-4: four 15-byte statuses.
        tcflush(port, TCIFLUSH);
        send({0xFF, 0xFF, 0xFD, 0x00, 0xFE, 11, 0, 0x82, 128, 0, 4, 0, 1, 2, 3, 4});
        size_t replies = receive(60, std::chrono::milliseconds(10)) / 15;
        // Sync Write of Goal Velocity (104, 4 bytes) to the wheels.
        std::vector<uint8_t> write_goals = {0xFF, 0xFF, 0xFD, 0x00, 0xFE, 27, 0, 0x83, 104, 0, 4, 0};
        uint32_t goal = (cycle % 50) * 2;
        for (uint8_t id = 1; id <= 4; id++) {
            write_goals.push_back(id);
            for (int b = 0; b < 4; b++) write_goals.push_back((goal >> (8 * b)) & 0xFF);
        }
        send(write_goals);
        {
            std::lock_guard<std::mutex> held(lock);
            queue.push_back({std::chrono::duration<double, std::milli>(Clock::now() - start).count(), replies});
        }
        changed.notify_one();
        std::this_thread::sleep_until(next);
        auto now = Clock::now();
        longest = std::max(longest, now - previous);
        previous = now;
    }
    {
        std::lock_guard<std::mutex> held(lock);
        done = true;
    }
    changed.notify_one();
    stats.join();
    if (until_stopped) {
        // Stopped, the report comes after the run's end, on the wall clock: no time of it is told.
        std::printf("loop: %d cycles, longest period %.3f ms\n", cycle, std::chrono::duration<double, std::milli>(longest).count());
    } else {
        std::printf("loop: %d cycles in %.3f ms, longest period %.3f ms\n", cycle, std::chrono::duration<double, std::milli>(Clock::now() - start).count(),
                    std::chrono::duration<double, std::milli>(longest).count());
    }
    return 0;
}
