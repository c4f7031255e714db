// The reference line follower (hil/controllers/line_follower.py, the built-in controller's
// algorithm) in C++, on the official C++ SDK's port pattern without the SDK: the port opened
// O_NONBLOCK with VMIN = VTIME = 0, flushed before each transaction (the SDK's clearPort), and
// read in a spin until a packet is whole or its timeout passes (the SDK's isPacketTimeout on
// the monotonic clock). The line comes from the sensor server over plain HTTP (GET /line), on one
// kept connection.
// Like the Python one it knows nothing of climbsim but DXL_PORT, DXL_BAUD and CLIMBSIM_SENSORS.
//
//   c++ -O2 -std=c++17 -o line_follower hil/controllers/line_follower.cpp
//   line_follower [--zeta Z] [--omega-n W] [--max-yaw-rate R]
//
// It runs until SIGTERM/SIGINT, then stops the wheels and turns their torque off.
#include <arpa/inet.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <termios.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <csignal>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <ctime>
#include <deque>
#include <optional>
#include <string>
#include <utility>
#include <vector>

namespace {

constexpr uint16_t kTorqueEnable = 64, kOperatingMode = 11, kGoalVelocity = 104, kPresentPosition = 132;
constexpr double kRpmPerUnit = 0.229, kPulsesPerRev = 4096, kMagnetDownPulses = 2048, kVelocityLimit = 128;
constexpr double kPeriod = 0.02, kSpeedWindow = 0.5, kRadius = 0.05, kTrack = 0.26;
constexpr uint8_t kWheels[4] = {1, 2, 3, 4};  // front-left, front-right, rear-left, rear-right
constexpr uint8_t kMagnets[4] = {5, 6, 7, 8};
constexpr bool kLeft[4] = {true, false, true, false};

volatile std::sig_atomic_t running = 1;
int port = -1;
double byte_us = 10.0;  // one byte on the wire at the port's baud (µs)

double now_s() {
    timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return ts.tv_sec + ts.tv_nsec / 1e9;
}

uint16_t crc16(const uint8_t *data, size_t len) {
    uint16_t crc = 0;
    for (size_t i = 0; i < len; i++) {
        crc ^= uint16_t(data[i]) << 8;
        for (int bit = 0; bit < 8; bit++) crc = (crc & 0x8000) ? uint16_t((crc << 1) ^ 0x8005) : uint16_t(crc << 1);
    }
    return crc;
}

// One instruction packet (no byte stuffing is needed for what this controller sends).
void send(uint8_t id, uint8_t instruction, const std::vector<uint8_t> &params) {
    uint16_t length = uint16_t(params.size() + 3);
    std::vector<uint8_t> packet = {0xFF, 0xFF, 0xFD, 0x00, id, uint8_t(length & 0xFF), uint8_t(length >> 8), instruction};
    packet.insert(packet.end(), params.begin(), params.end());
    uint16_t crc = crc16(packet.data(), packet.size());
    packet.push_back(crc & 0xFF);
    packet.push_back(crc >> 8);
    tcflush(port, TCIFLUSH);  // the SDK's clearPort
    if (write(port, packet.data(), packet.size()) != ssize_t(packet.size())) std::perror("write");
}

// `want` bytes in a spin of non-blocking reads, or fewer once `timeout_s` has passed.
std::vector<uint8_t> receive(size_t want, double timeout_s) {
    std::vector<uint8_t> got(want);
    size_t have = 0;
    double started = now_s();
    while (have < want && now_s() - started < timeout_s) {
        ssize_t n = read(port, got.data() + have, want - have);
        if (n > 0) have += size_t(n);
    }
    got.resize(have);
    return got;
}

// The SDK's packet timeout: its 16 ms latency timer twice, plus the bytes on the wire.
double packet_timeout_s(size_t bytes) { return (2 * 16.0 + 2.0 + bytes * byte_us / 1000.0) / 1000.0; }

bool write1(uint8_t id, uint16_t address, uint8_t value) {
    send(id, 0x03, {uint8_t(address & 0xFF), uint8_t(address >> 8), value});
    return receive(11, packet_timeout_s(11)).size() == 11;
}

// Sync Read of Present Position (4 bytes) of `ids`: each one's value, or nothing.
std::optional<std::vector<int32_t>> sync_read_positions(const std::vector<uint8_t> &ids) {
    std::vector<uint8_t> params = {uint8_t(kPresentPosition & 0xFF), uint8_t(kPresentPosition >> 8), 4, 0};
    params.insert(params.end(), ids.begin(), ids.end());
    send(0xFE, 0x82, params);
    std::vector<int32_t> values;
    for (uint8_t id : ids) {
        std::vector<uint8_t> status = receive(15, packet_timeout_s(15));
        if (status.size() != 15 || status[4] != id || crc16(status.data(), 13) != (status[13] | status[14] << 8)) return std::nullopt;
        values.push_back(int32_t(uint32_t(status[9]) | uint32_t(status[10]) << 8 | uint32_t(status[11]) << 16 | uint32_t(status[12]) << 24));
    }
    return values;
}

void sync_write_velocities(const int32_t goals[4]) {
    std::vector<uint8_t> params = {uint8_t(kGoalVelocity & 0xFF), uint8_t(kGoalVelocity >> 8), 4, 0};
    for (int i = 0; i < 4; i++) {
        params.push_back(kWheels[i]);
        for (int b = 0; b < 4; b++) params.push_back(uint8_t(uint32_t(goals[i]) >> (8 * b)));
    }
    send(0xFE, 0x83, params);
}

struct Line {
    double d, psi;
};

// The number after `"key":` in `json`, if there is one.
std::optional<double> json_number(const std::string &json, const char *key) {
    std::string quoted = std::string("\"") + key + "\":";
    size_t at = json.find(quoted);
    if (at == std::string::npos) return std::nullopt;
    char *end = nullptr;
    const char *start = json.c_str() + at + quoted.size();
    double value = std::strtod(start, &end);
    return end == start ? std::nullopt : std::optional<double>(value);
}

// The sensor server over one kept connection (`Connection: keep-alive`), as an HTTP client
// library would keep it: no new TCP connection each period. Opened again after any failure.
class SensorClient {
  public:
    struct Answer {
        int status;
        std::string body;
    };
    SensorClient(std::string host, uint16_t port) : host_(std::move(host)), port_(port) {}
    SensorClient(const SensorClient &) = delete;
    SensorClient &operator=(const SensorClient &) = delete;
    ~SensorClient() { drop(); }

    // GET `path`; on a kept connection the server has closed meanwhile, once more on a new one.
    std::optional<Answer> get(const char *path) {
        for (int attempt = 0; attempt < 2; attempt++) {
            if (sock_ < 0 && !open()) return std::nullopt;
            if (auto answer = exchange(path)) return answer;
            drop();
        }
        return std::nullopt;
    }

  private:
    bool open() {
        sock_ = socket(AF_INET, SOCK_STREAM, 0);
        if (sock_ < 0) return false;
        sockaddr_in address{};
        address.sin_family = AF_INET;
        address.sin_port = htons(port_);
        inet_pton(AF_INET, host_.c_str(), &address.sin_addr);
        if (connect(sock_, reinterpret_cast<sockaddr *>(&address), sizeof address) != 0) {
            drop();
            return false;
        }
        return true;
    }

    void drop() {
        if (sock_ >= 0) close(sock_);
        sock_ = -1;
        buffer_.clear();
    }

    // More bytes of the answer; false at the end of the stream or on an error.
    bool fill() {
        char chunk[1024];
        ssize_t n = read(sock_, chunk, sizeof chunk);
        if (n <= 0) return false;
        buffer_.append(chunk, size_t(n));
        return true;
    }

    std::optional<Answer> exchange(const char *path) {
        std::string request = std::string("GET ") + path + " HTTP/1.1\r\nHost: " + host_ + "\r\nConnection: keep-alive\r\n\r\n";
        if (write(sock_, request.data(), request.size()) != ssize_t(request.size())) return std::nullopt;
        size_t end;
        while ((end = buffer_.find("\r\n\r\n")) == std::string::npos)
            if (!fill()) return std::nullopt;
        std::string head = buffer_.substr(0, end);
        buffer_.erase(0, end + 4);
        size_t length_at = head.find("Content-Length:");
        if (head.compare(0, 9, "HTTP/1.1 ") != 0 || length_at == std::string::npos) return std::nullopt;
        size_t length = std::strtoul(head.c_str() + length_at + 15, nullptr, 10);
        while (buffer_.size() < length)
            if (!fill()) return std::nullopt;
        Answer answer{std::atoi(head.c_str() + 9), buffer_.substr(0, length)};
        buffer_.erase(0, length);
        if (head.find("Connection: close") != std::string::npos) drop();
        return answer;
    }

    std::string host_;
    uint16_t port_;
    int sock_ = -1;
    std::string buffer_;  // received and not yet taken
};

// GET /line: the robot relative to the line, if valid.
std::optional<Line> read_line(SensorClient &sensors) {
    auto answer = sensors.get("/line");
    if (!answer || answer->status != 200 || answer->body.find("\"valid\":true") == std::string::npos) return std::nullopt;
    auto d = json_number(answer->body, "d"), psi = json_number(answer->body, "psi");
    if (!d || !psi) return std::nullopt;
    return Line{*d, *psi};
}

double arg_value(int argc, char **argv, const char *name, double fallback) {
    for (int i = 1; i + 1 < argc; i++)
        if (std::strcmp(argv[i], name) == 0) return std::atof(argv[i + 1]);
    return fallback;
}

speed_t termios_speed(int baud) {
    switch (baud) {
        case 57600: return B57600;
        case 115200: return B115200;
        case 1000000: return B1000000;
        case 2000000: return B2000000;
        case 3000000: return B3000000;
        case 4000000: return B4000000;
        default: return B57600;
    }
}

}  // namespace

int main(int argc, char **argv) {
    setvbuf(stdout, nullptr, _IOLBF, 0);
    const double zeta = arg_value(argc, argv, "--zeta", 0.7), omega_n = arg_value(argc, argv, "--omega-n", 0.3);
    const double max_yaw_rate = arg_value(argc, argv, "--max-yaw-rate", 0.2);
    std::signal(SIGTERM, [](int) { running = 0; });
    std::signal(SIGINT, [](int) { running = 0; });
    const char *path = std::getenv("DXL_PORT");
    if (!path) {
        std::fprintf(stderr, "DXL_PORT is not set\n");
        return 2;
    }
    const int baud = std::atoi(std::getenv("DXL_BAUD") ? std::getenv("DXL_BAUD") : "57600");
    byte_us = 10e6 / baud;
    const double target = std::atof(std::getenv("CLIMBSIM_TARGET_SPEED_MM_MIN") ? std::getenv("CLIMBSIM_TARGET_SPEED_MM_MIN") : "250") / 60000.0;
    // CLIMBSIM_SENSORS = http://HOST:PORT
    std::string sensors = std::getenv("CLIMBSIM_SENSORS") ? std::getenv("CLIMBSIM_SENSORS") : "";
    std::string host;
    uint16_t sensor_port = 0;
    if (sensors.rfind("http://", 0) == 0) {
        std::string rest = sensors.substr(7);
        size_t colon = rest.find(':');
        host = rest.substr(0, colon);
        sensor_port = uint16_t(std::atoi(rest.c_str() + colon + 1));
    }
    SensorClient sensor_client(host, sensor_port);

    port = open(path, O_RDWR | O_NOCTTY | O_NONBLOCK);
    if (port < 0) {
        std::perror(path);
        return 1;
    }
    termios tio{};
    tio.c_cflag = termios_speed(baud) | CS8 | CLOCAL | CREAD;
    tio.c_iflag = IGNPAR;
    tcsetattr(port, TCSANOW, &tio);
    for (uint8_t id : kWheels) {
        if (!write1(id, kTorqueEnable, 0) || !write1(id, kOperatingMode, 1) || !write1(id, kTorqueEnable, 1)) {
            std::fprintf(stderr, "wheel %d does not answer\n", id);
            return 1;
        }
    }
    for (uint8_t id : kMagnets) write1(id, kTorqueEnable, 0);  // passive magnets

    const std::vector<uint8_t> all = {1, 2, 3, 4, 5, 6, 7, 8};
    const double rad_per_pulse = 2 * M_PI / kPulsesPerRev;
    std::deque<std::pair<double, std::vector<int32_t>>> history;
    double residual[4] = {0, 0, 0, 0};
    double next_tick = now_s();
    long ticks = 0, blind = 0;
    while (running) {
        double now = now_s();
        auto positions = sync_read_positions(all);
        if (!running) break;  // stopped during the transaction (the run ended): not a period of the run
        if (!positions) {
            std::fprintf(stderr, "sync read failed\n");
        } else {
            std::vector<int32_t> wheels(positions->begin(), positions->begin() + 4);
            history.emplace_back(now, wheels);
            while (history.size() > 2 && now - history[1].first >= kSpeedWindow) history.pop_front();
            double speed = 0;
            if (history.size() > 1 && now > history.front().first) {
                for (int i = 0; i < 4; i++) {
                    double alpha = ((*positions)[4 + i] - kMagnetDownPulses) * rad_per_pulse;
                    double rate = (wheels[i] - history.front().second[i]) * rad_per_pulse / (now - history.front().first);
                    speed += rate * kRadius / std::max(std::cos(alpha), 0.5) / 4.0;
                }
            }
            double command = target + (target - speed);  // feedforward + kp = 1, as the reference
            double yaw_rate = 0;
            auto line = sensor_port ? read_line(sensor_client) : std::nullopt;
            blind += !line;
            if (line && target > 0) {
                double damping = 2 * zeta * omega_n;
                double k_d = -(omega_n * omega_n) / target, k_psi = -damping;
                yaw_rate = std::clamp(k_d * line->d + k_psi * line->psi, -max_yaw_rate, max_yaw_rate);
            }
            int32_t goals[4];
            for (int i = 0; i < 4; i++) {
                double side = kLeft[i] ? -1.0 : 1.0;
                double wheel = (command + side * yaw_rate * kTrack / 2) / kRadius;
                double units = wheel * 60 / (2 * M_PI) / kRpmPerUnit + residual[i];
                double rounded = std::clamp(std::copysign(std::floor(std::fabs(units) + 0.5), units), -kVelocityLimit, kVelocityLimit);
                residual[i] = std::clamp(units - rounded, -1.0, 1.0);
                goals[i] = int32_t(rounded);
            }
            sync_write_velocities(goals);
            ticks++;
        }
        next_tick += kPeriod;
        double delay = next_tick - now_s();
        if (delay > 0) {
            timespec sleep{time_t(delay), long((delay - std::floor(delay)) * 1e9)};
            nanosleep(&sleep, nullptr);
        } else {
            next_tick = now_s();
        }
    }
    const int32_t stopped[4] = {0, 0, 0, 0};
    sync_write_velocities(stopped);
    for (uint8_t id : kWheels) write1(id, kTorqueEnable, 0);
    close(port);
    std::printf("line_follower: %ld control periods, %ld without a line measurement\n", ticks, blind);
    return 0;
}
