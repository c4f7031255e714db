// A controller on ROBOTIS's official C++ DynamixelSDK, for the virtual-time test that is gated on
// the SDK's sources (DYNAMIXEL_SDK_CPP: a checkout of ROBOTIS-GIT/DynamixelSDK; no package
// registry carries them). The same steps as tests/vt/sdk_ping.py, timed with the SDK's own clock
// source (clock_gettime): pings, a Sync Read of the eight servos, a few periods of a control
// loop (Sync Read, Sync Write of goal velocities, a 20 ms sleep), pings of an absent ID.
//
// Build (as the test does): g++ -O2 -I"$DYNAMIXEL_SDK_CPP/c++/include/dynamixel_sdk"
//   tests/vt/sdk_cpp_controller.cpp "$DYNAMIXEL_SDK_CPP"/c++/src/dynamixel_sdk/*.cpp -o ctl
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <unistd.h>

#include "dynamixel_sdk.h"

static double now_us() {
  timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return ts.tv_sec * 1e6 + ts.tv_nsec / 1e3;
}

int main() {
  const char *path = std::getenv("DXL_PORT");
  const char *baud = std::getenv("DXL_BAUD");
  if (path == nullptr) return 2;
  dynamixel::PortHandler *port = dynamixel::PortHandler::getPortHandler(path);
  dynamixel::PacketHandler *packet = dynamixel::PacketHandler::getPacketHandler(2.0);
  if (!port->openPort() || !port->setBaudRate(baud ? std::atoi(baud) : 57600)) {
    std::fprintf(stderr, "cannot open the port\n");
    return 1;
  }
  // Pings `id` `attempts` times, printing each one's wall time; false at the first result that
  // is not `expected`.
  auto pings = [&](uint8_t id, int attempts, int expected) {
    for (int attempt = 0; attempt < attempts; attempt++) {
      uint8_t error = 0;
      double started = now_us();
      int result = packet->ping(port, id, &error);
      std::printf("ping %d #%d: %.1f us -> %d\n", id, attempt, now_us() - started, result);
      if (result != expected) return false;
    }
    return true;
  };
  if (!pings(1, 3, COMM_SUCCESS)) return 1;
  dynamixel::GroupSyncRead reader(port, packet, 132, 4);
  dynamixel::GroupSyncWrite writer(port, packet, 104, 4);
  for (uint8_t id = 1; id <= 8; id++) reader.addParam(id);
  for (int attempt = 0; attempt < 2; attempt++) {
    double started = now_us();
    int result = reader.txRxPacket();
    int answered = 0;
    for (uint8_t id = 1; id <= 8; id++) answered += reader.isAvailable(id, 132, 4) ? 1 : 0;
    std::printf("sync read 8 #%d: %.1f us -> %d (%d answered)\n", attempt, now_us() - started, result, answered);
    if (result != COMM_SUCCESS || answered != 8) return 1;
  }
  // A control loop's periods: read, write, sleep to the next 20 ms.
  double period_start = now_us();
  for (int period = 0; period < 5; period++) {
    if (reader.txRxPacket() != COMM_SUCCESS) return 1;
    writer.clearParam();
    for (uint8_t id = 1; id <= 4; id++) {
      uint8_t goal[4] = {0, 0, 0, 0};
      writer.addParam(id, goal);
    }
    if (writer.txPacket() != COMM_SUCCESS) return 1;
    period_start += 20000.0;
    double left = period_start - now_us();
    if (left > 0) usleep(static_cast<useconds_t>(left));
    std::printf("period %d ends at +%.1f us\n", period, now_us() - period_start);
  }
  if (!pings(42, 2, COMM_RX_TIMEOUT)) return 1;
  std::fflush(stdout);
  port->closePort();
  return 0;
}
