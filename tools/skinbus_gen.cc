// skinbus-gen: put synthetic skinbus traffic on a bus or into a candump log.
//
// A traffic source for testing the bus, the decoder and the host without patch hardware.
// The field values are a synthetic test pattern (noise plus a smooth bump that visits the
// patches in turn), not the patch physics: that is the simulator's job (sim/).
//
//   skinbus-gen --nodes 1-4 --duration 2 | skinbus-decode
//   skinbus-gen -i vcan0 --nodes 1-8 --expect sent.txt
#include <CLI/CLI.hpp>

#include <algorithm>
#include <cerrno>
#include <cinttypes>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <memory>
#include <random>
#include <string>
#include <thread>
#include <vector>

#include "skinbus/bus/candump.h"
#include "skinbus/bus/codec.h"
#include "skinbus/bus/format.h"
#include "skinbus/bus/socketcan.h"
#include "tool_util.h"

namespace {

using namespace skinbus;
using namespace skinbus::bus;

struct Pattern {
  double noise_ut = 0.5;
  double bump_ut = 300.0;
  double press_s = 0.5;  // each patch pressed in turn for this long
};

// Synthetic field for `node_index` of `node_count` at time t (tared values, uT -> LSB).
Sample make_sample(const Pattern& p, int node_index, int node_count, double t_s,
                   std::mt19937_64& rng) {
  Sample s;
  s.timestamp_us = static_cast<uint32_t>(static_cast<uint64_t>(t_s * 1e6 + node_index * 997.0));
  s.flags = sample_flags::kTared;
  std::normal_distribution<double> noise(0.0, p.noise_ut);
  const double cycle = p.press_s * node_count;
  const double phase = std::fmod(t_s, cycle);
  const bool pressed = static_cast<int>(phase / p.press_s) == node_index;
  const double local = std::fmod(phase, p.press_s) / p.press_s;  // 0..1 within the press
  const double amp = pressed ? p.bump_ut * std::sin(M_PI * local) : 0.0;
  // The bump centre walks across the patch diagonal during a press (mm, patch frame).
  const double cx = -30.0 + 60.0 * local, cy = 20.0 - 40.0 * local;
  for (int sensor = 0; sensor < kSensorCount; ++sensor) {
    const double sx = -45.0 + 30.0 * (sensor % 4), sy = -45.0 + 30.0 * (sensor / 4);
    const double dx = sx - cx, dy = sy - cy;
    const double g = amp * std::exp(-(dx * dx + dy * dy) / (2 * 25.0 * 25.0));
    const double f[3] = {g * dx / 40.0, g * dy / 40.0, -g};
    for (int a = 0; a < kAxisCount; ++a) {
      bool clipped = false;
      s.field_lsb[sensor * 3 + a] = field_ut_to_lsb(f[a] + noise(rng), &clipped);
      // At or beyond the wire's range: clipped, and flagged as the protocol requires.
      if (clipped) {
        s.saturation_mask = static_cast<uint16_t>(s.saturation_mask | (1u << sensor));
        s.flags |= sample_flags::kSaturated;
      }
    }
  }
  if (amp > 20.0) s.flags |= sample_flags::kContact;
  return s;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{
      "skinbus-gen: synthetic skinbus traffic (samples and heartbeats of several patches) as a\n"
      "candump log on standard output, into a file, or sent on a SocketCAN interface.\n\n"
      "The field values are a synthetic test pattern (noise plus a smooth bump that visits the\n"
      "patches in turn); they exercise the bus, not the skin physics (see sim/).\n\n"
      "Examples:\n"
      "  skinbus-gen --nodes 1-4 --duration 2 | skinbus-decode --stats\n"
      "  skinbus-gen -i vcan0 --nodes 1-8 --duration 5 --expect sent.txt\n"};
  std::string nodes = "1-4";
  double rate_hz = 41.7, duration_s = 2.0, heartbeat_hz = 1.0;
  bool classic = false, fast = false, realtime = false;
  uint64_t seed = 1;
  std::string out_path, iface, expect_path, log_iface = "can0";
  Pattern pattern;
  app.add_option("--nodes", nodes, "patch node IDs, e.g. 1-4,9")->capture_default_str();
  app.add_option("--rate", rate_hz, "sample rate per patch, Hz")
      ->capture_default_str()
      ->check(CLI::Range(0.1, 655.35));  // heartbeats carry it in 0.01 Hz, 16 bits
  app.add_option("--duration", duration_s, "seconds of traffic")
      ->capture_default_str()
      ->check(CLI::Range(0.0, 86400.0));
  app.add_option("--heartbeat-hz", heartbeat_hz, "heartbeat rate per patch, Hz (0: none)")
      ->capture_default_str()
      ->check(CLI::Range(0.0, 100.0));
  app.add_flag("--classic", classic, "classic CAN frames (8 bytes) instead of CAN FD");
  app.add_option("--seed", seed, "random seed of the noise")->capture_default_str();
  app.add_option("--noise-ut", pattern.noise_ut, "noise standard deviation, uT")
      ->capture_default_str();
  app.add_option("-o,--output", out_path, "write the candump log here instead of standard output");
  app.add_option("-i,--interface", iface,
                 "send on this SocketCAN interface instead of writing a log");
  app.add_flag("--fast", fast, "with -i: send as fast as the bus takes it instead of in real time");
  app.add_flag("--realtime", realtime, "log output: pace lines in real time (for live pipes)");
  app.add_option("--log-interface", log_iface, "interface name written in log lines")
      ->capture_default_str();
  app.add_option("--expect", expect_path,
                 "also write each message as skinbus-decode prints it, in send order");
  CLI11_PARSE(app, argc, argv);

  try {
    tools::install_stop_handler();
    const std::vector<int> node_ids = tools::parse_id_list(nodes, kNodeMin, kNodeMax);
    std::unique_ptr<SocketCanPort> port;
    if (!iface.empty()) {
      SocketCanOptions opts;
      opts.fd = !classic;
      opts.error_frames = false;
      opts.filters = {CanIdFilter{0x7FF, 0x7FF}};  // receive nothing we do not need
      auto p = SocketCanPort::open(iface, opts);
      if (!p.ok()) throw std::runtime_error(p.error().message);
      port = std::move(p).value();
      if (!classic && !port->fd_enabled()) {
        throw std::runtime_error("'" + iface +
                                 "' is a classic CAN interface: use --classic or `ip link set " +
                                 iface + " mtu 72`");
      }
    }
    std::FILE* out = stdout;
    if (!out_path.empty() && !port) {
      out = std::fopen(out_path.c_str(), "w");
      if (!out)
        throw std::runtime_error("cannot write '" + out_path + "': " + std::strerror(errno));
    }
    std::FILE* expect = nullptr;
    if (!expect_path.empty()) {
      expect = std::fopen(expect_path.c_str(), "w");
      if (!expect)
        throw std::runtime_error("cannot write '" + expect_path + "': " + std::strerror(errno));
    }

    std::mt19937_64 rng(seed);
    const FrameKind kind = classic ? FrameKind::kClassic : FrameKind::kFd;
    const uint64_t t0_wall_us = realtime_now_us();
    const uint64_t t0_mono_us = monotonic_now_us();
    const double sample_dt = 1.0 / rate_hz;
    const double hb_dt = heartbeat_hz > 0 ? 1.0 / heartbeat_hz : 1e300;
    std::vector<uint8_t> sample_seq(node_ids.size(), 0), hb_seq(node_ids.size(), 0);
    double next_sample = 0, next_hb = heartbeat_hz > 0 ? 0 : 1e300;
    uint64_t frames_sent = 0, messages = 0;
    CanFrame frames[kMaxParts];
    char line[kCandumpLineMax];

    auto emit = [&](const Message& m, double t_s) {
      const EncodeResult r = encode(m, frames);
      if (r.error != EncodeError::kNone) throw std::runtime_error("encode failed");
      const uint64_t t_us = t0_wall_us + static_cast<uint64_t>(t_s * 1e6);
      if (port || realtime) {
        if (!fast) {  // pace to the traffic's own clock
          const uint64_t due = t0_mono_us + static_cast<uint64_t>(t_s * 1e6);
          const uint64_t now = monotonic_now_us();
          if (due > now) std::this_thread::sleep_for(std::chrono::microseconds(due - now));
        }
      }
      for (std::size_t i = 0; i < r.frames; ++i) {
        if (port) {
          Status s = port->send_blocking(frames[i], 1000);
          if (!s.ok()) throw std::runtime_error(s.error().message);
        } else {
          if (format_candump_line(frames[i], t_us, log_iface, line) == 0) {
            throw std::invalid_argument("--log-interface '" + log_iface +
                                        "' is too long (32 characters at most)");
          }
          std::fprintf(out, "%s\n", line);
        }
      }
      if (!port && realtime) std::fflush(out);
      frames_sent += r.frames;
      ++messages;
      if (expect) std::fprintf(expect, "%s\n", format_message(m).c_str());
    };

    while (!tools::stop_requested()) {
      const double t = std::min(next_sample, next_hb);
      if (t >= duration_s) break;
      if (next_hb <= next_sample) {
        for (std::size_t i = 0; i < node_ids.size(); ++i) {
          Heartbeat hb;
          hb.state = PatchState::kRunning;
          hb.mode = PatchMode::kStream;
          hb.rate_chz = static_cast<uint16_t>(std::lround(rate_hz * 100));
          hb.uptime_s = static_cast<uint32_t>(t);
          hb.hardware_uid = 0x5B00000000000000ull | static_cast<uint64_t>(node_ids[i]);
          hb.fw_major = 0;
          hb.fw_minor = 1;
          hb.status = heartbeat_status::kSimulated | heartbeat_status::kTared;
          hb.temperature_cdeg = 3000;
          emit(Message{static_cast<uint8_t>(node_ids[i]), hb_seq[i]++, kind, hb}, t);
        }
        next_hb += hb_dt;
      } else {
        for (std::size_t i = 0; i < node_ids.size(); ++i) {
          const Sample s =
              make_sample(pattern, static_cast<int>(i), static_cast<int>(node_ids.size()), t, rng);
          emit(Message{static_cast<uint8_t>(node_ids[i]), sample_seq[i]++, kind, s}, t);
        }
        next_sample += sample_dt;
      }
    }
    // A log that could not be written whole is an error, not a success.
    const bool out_failed = std::fflush(out) != 0 || std::ferror(out);
    if (out != stdout && std::fclose(out) != 0)
      throw std::runtime_error("writing '" + out_path + "' failed");
    if (out_failed)
      throw std::runtime_error(std::string("writing the log failed: ") + std::strerror(errno));
    if (expect && (std::fflush(expect) != 0 || std::ferror(expect) || std::fclose(expect) != 0)) {
      throw std::runtime_error("writing '" + expect_path + "' failed");
    }
    std::fprintf(
        stderr, "skinbus-gen: %" PRIu64 " messages in %" PRIu64 " %s frames from %zu patches%s\n",
        messages, frames_sent, classic ? "classic" : "FD", node_ids.size(),
        port ? (" on " + iface + (port->stats().tx_queued ? " (some sends waited for room)" : ""))
                   .c_str()
             : "");
  } catch (const std::exception& e) {
    return skinbus::tools::fail("skinbus-gen", e.what(), 1);
  }
  return 0;
}
