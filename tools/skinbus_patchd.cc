// skinbus-patchd: the patch node daemon. Samples the patch's 16 MLX90393s (over i2c-dev and a
// TCA9546A, or emulated chips fed by the simulator with --sim), gates contacts and publishes
// samples and heartbeats on a CAN (FD) interface; answers the host's commands and SYNC.
//
//   skinbus-patchd --config /etc/skinbus/patch.yaml
//   skinbus-patchd --sim -i vcan0 --node 3 --mode event --contacts presses.csv
#include <poll.h>
#include <unistd.h>

#include <CLI/CLI.hpp>
#include <cerrno>
#include <cinttypes>
#include <cstdio>
#include <cstring>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

#include "skinbus/bus/candump.h"
#include "skinbus/bus/format.h"
#include "skinbus/bus/reassembler.h"
#include "skinbus/bus/socketcan.h"
#include "skinbus/patch_fw/config.h"
#include "skinbus/patch_fw/node.h"
#include "skinbus/patch_sim/sim_source.h"
#include "tool_util.h"

using namespace skinbus;
using namespace skinbus::patch_fw;
using skinbus::patch_sim::SimulatedBoard;

namespace {

constexpr int kExitConfig = 2;  // the settings are wrong (named in the message)
constexpr int kExitDevice = 1;  // a device is missing or failed

struct ConfigError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

// Sends to the CAN port and/or a candump log; optionally prints every complete message it sent
// the way skinbus-decode prints it (--expect), by reassembling its own frames.
class DaemonSink final : public FrameSink {
 public:
  bus::SocketCanPort* port = nullptr;
  std::FILE* log = nullptr;
  std::string log_iface = "can0";
  std::FILE* expect = nullptr;
  // The daemon's own frames, complete and in order: never dropped as stale. A daemon stopped or
  // descheduled between two frames of a message (a SIGSTOP, a loaded machine) would otherwise
  // leave that message out of --expect, while a reader of the log on its own clock
  // (skinbus-host --replay --live) gets the frames together and counts it.
  bus::Reassembler own{bus::Reassembler::Config{.timeout_us = UINT32_MAX}};
  int write_errno = 0;  // a write to the log or the expect file failed (the loop ends on it)

  Status send(const bus::CanFrame& frame) override {
    Status st;
    if (port != nullptr) st = port->send(frame);
    const uint64_t t_us = bus::realtime_now_us();
    if (log != nullptr) {
      const std::string line = bus::format_candump_line(frame, t_us, log_iface);
      errno = 0;
      if (std::fprintf(log, "%s\n", line.c_str()) < 0 && write_errno == 0) {
        write_errno = errno != 0 ? errno : EIO;
      }
    }
    if (expect != nullptr && st.ok()) {
      const bus::FeedResult r = own.feed(frame, bus::monotonic_now_us());
      if (r.status == bus::FeedStatus::kMessage) {
        errno = 0;
        if (std::fprintf(expect, "%s\n", bus::format_message(*r.message).c_str()) < 0 &&
            write_errno == 0) {
          write_errno = errno != 0 ? errno : EIO;
        }
      }
    }
    return st;
  }
};

// Set across the re-execution that serves the reboot command, so outputs are appended to.
constexpr const char* kRestartedEnv = "SKINBUS_PATCHD_RESTARTED";

// Opens an output ("-": stdout). Line-buffered, so every line reaches a pipe in one write: several
// daemons can share one pipe (`{ patchd ... & patchd ... & } | skinbus-host --replay -`) without
// their lines tearing.
std::FILE* open_out(const std::string& path, const char* what) {
  std::FILE* f =
      path == "-" ? stdout : std::fopen(path.c_str(), std::getenv(kRestartedEnv) ? "a" : "w");
  if (f == nullptr) {
    throw ConfigError(std::string(what) + " " + path + ": " + std::strerror(errno));
  }
  std::setvbuf(f, nullptr, _IOLBF, 1024);
  return f;
}

template <typename T>
T need(Result<T> r, const std::string& what) {
  if (!r.ok()) throw std::runtime_error(what + ": " + r.error().message);
  return std::move(r).value();
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{
      "skinbus-patchd: the patch node daemon. Reads the 16 MLX90393 Hall sensors of one skin\n"
      "patch (i2c-dev + TCA9546A multiplexer, libgpiod lines), tracks the untouched baseline,\n"
      "gates contacts and publishes samples and heartbeats on CAN (FD) with the skinbus\n"
      "protocol (docs/protocol.md); answers the host's commands (tare, mode, rate, sync,\n"
      "identify, reboot, info) and SYNC frames.\n\n"
      "Settings come from a YAML file (--config; format in docs/patch_node.md), and the flags\n"
      "below override it. With --sim the chips are emulated at the I2C transaction level and\n"
      "the field comes from the simulator: a fabricated patch (variation and noise seeded by\n"
      "--uid) pressed by a contact script and/or random presses.\n\n"
      "Modes: stream sends every sample; event sends samples only while touched (plus a short\n"
      "tail) and a 1 Hz heartbeat otherwise; off sends only heartbeats.\n\n"
      "Examples:\n"
      "  skinbus-patchd --config /etc/skinbus/patch.yaml\n"
      "  skinbus-patchd --sim -i vcan0 --node 3 --contacts presses.csv\n"
      "  skinbus-patchd --sim -i none --candump-out - --duration 5 | skinbus-decode\n"
      "  skinbus-patchd --config patch.yaml --check      # validate, print, exit\n\n"
      "Exit status: 0 done, 1 a device is missing or failed, 2 bad settings."};
  std::string config_path, iface, mode, candump_out, expect_path, i2c_device, mux, contacts,
      gpio_chip;
  int node = 0;
  double rate_hz = 0, duration_s = 0, presses_per_min = -1;
  uint64_t uid = 0;
  bool sim = false, classic = false, check = false, print_config = false, quiet = false,
       sync = false;
  app.add_option("-c,--config", config_path, "YAML settings file");
  app.add_option("-i,--interface", iface,
                 "SocketCAN interface (default can0; 'none': no CAN, use --candump-out)");
  app.add_option("-n,--node", node, "node ID on the bus, 1..125")->check(CLI::Range(1, 125));
  app.add_option("--mode", mode, "stream, event or off (default event)")
      ->check(CLI::IsMember({"stream", "event", "off"}));
  app.add_option("--rate", rate_hz, "sample rate, Hz (default 41.7)");
  app.add_flag("--sync", sync, "sample only on host SYNC (CAN SYNC frames or the SYNC line)");
  app.add_flag("--classic", classic, "classic CAN frames (8 bytes) instead of CAN FD");
  app.add_option("--uid", uid, "hardware UID (64 bit; --sim: seeds the patch's variation)");
  app.add_option("--i2c", i2c_device, "i2c-dev device (default /dev/i2c-1)");
  app.add_option("--mux", mux, "TCA9546A address, 0x70..0x77, or 'none'");
  app.add_option("--gpio-chip", gpio_chip, "GPIO chip for the lines in the settings");
  app.add_flag("--sim", sim, "emulated chips and simulated physics instead of hardware");
  app.add_option("--contacts", contacts, "--sim: contact script (CSV, docs/patch_node.md)");
  app.add_option("--presses-per-min", presses_per_min, "--sim: random presses a minute");
  app.add_option("--candump-out", candump_out,
                 "also write every frame sent as a candump -L log here ('-': stdout)");
  app.add_option("--expect", expect_path,
                 "write every message sent as skinbus-decode prints it (for tests)");
  app.add_option("--duration", duration_s, "stop after this many seconds (0: run until killed)")
      ->check(CLI::Range(0.0, 1e7));
  app.add_flag("--check", check, "validate the settings, print them and exit");
  app.add_flag("--print-config", print_config, "print the effective settings before starting");
  app.add_flag("-q,--quiet", quiet, "log only errors");
  CLI11_PARSE(app, argc, argv);

  tools::install_stop_handler();
  PatchNodeSettings settings = default_settings();
  std::unique_ptr<bus::SocketCanPort> port;
  std::FILE* log = nullptr;
  std::FILE* expect = nullptr;
  try {
    // ---- Settings: file, then flags, then the whole checked.
    if (!config_path.empty()) {
      if (Status st = load_settings_file(config_path, &settings); !st.ok())
        throw ConfigError(st.error().message);
    }
    if (!iface.empty()) settings.can_interface = iface;
    if (node != 0) settings.node.node_id = static_cast<uint8_t>(node);
    if (!mode.empty()) {
      settings.node.mode = mode == "stream"  ? bus::PatchMode::kStream
                           : mode == "event" ? bus::PatchMode::kEvent
                                             : bus::PatchMode::kOff;
    }
    if (rate_hz != 0) settings.rate_hz = rate_hz;
    if (sync) settings.node.sync_mode = true;
    if (classic) settings.can_fd = false;
    if (app.count("--uid")) settings.node.hardware_uid = uid;
    if (!i2c_device.empty()) settings.i2c_device = i2c_device;
    if (!mux.empty()) {
      if (mux == "none") {
        settings.mux_address.reset();
        for (SensorSlot& s : settings.array.slots) s.channel = -1;
      } else {
        char* end = nullptr;
        const long v = std::strtol(mux.c_str(), &end, 0);
        if (*end != '\0' || v < 0 || v > 127)
          throw ConfigError("--mux '" + mux + "': not an address");
        settings.mux_address = static_cast<uint8_t>(v);
      }
    }
    if (!gpio_chip.empty()) settings.gpio.chip = gpio_chip;
    if (sim) settings.sim.enabled = true;
    if (!contacts.empty()) settings.sim.contacts_file = contacts;
    if (presses_per_min >= 0) settings.sim.random_presses_per_min = presses_per_min;
    if (!candump_out.empty()) settings.candump_out = candump_out;
    if (settings.sim.enabled && settings.node.hardware_uid == 0) {
      settings.node.hardware_uid = 0x5EED000000000000ull | settings.node.node_id;
    }
    if (Status st = validate_settings(&settings); !st.ok()) throw ConfigError(st.error().message);
    if (check || print_config)
      std::fputs(settings_to_yaml(settings).c_str(), check ? stdout : stderr);
    if (check) return 0;

    const std::string tag = "skinbus-patchd[node " + std::to_string(settings.node.node_id) + "]";
    auto info = [&](const std::string& msg) {
      if (!quiet) std::fprintf(stderr, "%s: %s\n", tag.c_str(), msg.c_str());
    };

    // ---- Devices.
    MonotonicClock clock;
    std::unique_ptr<SimulatedBoard> board;
    std::unique_ptr<LinuxI2cBus> linux_bus;
    std::unique_ptr<GpioChip> gpio_owned;
    I2cBus* i2c = nullptr;
    GpioChip* gpio = nullptr;
    const bool any_line = !settings.gpio.drdy_lines.empty() || settings.gpio.mux_reset ||
                          settings.gpio.identify_led || settings.gpio.sync_in;
    if (settings.sim.enabled) {
      auto b = SimulatedBoard::create(settings, &clock);
      if (!b.ok()) throw ConfigError(b.error().message);
      board = std::move(b).value();
      i2c = board->bus.get();
      gpio = board->gpio.get();
    } else {
      auto b = LinuxI2cBus::open(settings.i2c_device);
      if (!b.ok()) throw std::runtime_error("i2c.device: " + b.error().message);
      linux_bus = std::move(b).value();
      i2c = linux_bus.get();
      if (any_line) {
        gpio_owned = need(open_gpiod_chip(settings.gpio.chip), "gpio.chip " + settings.gpio.chip);
        gpio = gpio_owned.get();
      }
    }
    std::unique_ptr<GpioOutput> mux_reset, led;
    std::unique_ptr<GpioInput> sync_in;
    std::vector<std::unique_ptr<GpioInput>> drdy_owned;
    std::vector<GpioInput*> drdy;
    if (gpio != nullptr) {
      if (settings.gpio.mux_reset) {
        mux_reset =
            need(gpio->request_output({*settings.gpio.mux_reset, true, false}, "skinbus-mux-reset"),
                 "gpio.mux_reset");
      }
      if (settings.gpio.identify_led) {
        led = need(
            gpio->request_output({*settings.gpio.identify_led, false, false}, "skinbus-identify"),
            "gpio.identify_led");
      }
      if (settings.gpio.sync_in) {
        sync_in =
            need(gpio->request_input({*settings.gpio.sync_in, false, true, false}, "skinbus-sync"),
                 "gpio.sync_in");
      }
      for (std::size_t j = 0; j < settings.gpio.drdy_lines.size(); ++j) {
        drdy_owned.push_back(need(
            gpio->request_input({settings.gpio.drdy_lines[j], false, true, false}, "skinbus-drdy"),
            "gpio.drdy[" + std::to_string(j) + "]"));
        drdy.push_back(drdy_owned.back().get());
      }
    }
    std::unique_ptr<Tca9546a> tca;
    if (settings.mux_address)
      tca = std::make_unique<Tca9546a>(i2c, *settings.mux_address, mux_reset.get(), &clock);
    SensorArray array(i2c, tca.get(), &clock, settings.array, drdy);
    if (Status st = array.init(); !st.ok()) throw std::runtime_error(st.error().message);
    if (array.fault_mask() != 0) {
      for (int i = 0; i < bus::kSensorCount; ++i)
        if (array.health(i).faulty)
          info("sensor " + std::to_string(i) + " faulty at start: " + array.health(i).last_error);
    }

    // ---- Bus and outputs.
    DaemonSink sink;
    if (settings.can_interface != "none") {
      bus::SocketCanOptions opts;
      opts.fd = settings.can_fd;
      opts.error_frames = true;
      // Commands and SYNC to us or to everyone, and anything else sent with our node ID (a
      // second node configured with the same ID).
      opts.filters = {bus::filter_for_node(settings.node.node_id),
                      bus::filter_for_node(bus::kNodeBroadcast)};
      auto p = bus::SocketCanPort::open(settings.can_interface, opts);
      if (!p.ok()) throw std::runtime_error("can.interface: " + p.error().message);
      port = std::move(p).value();
      if (settings.can_fd && !port->fd_enabled()) {
        throw ConfigError("can.interface " + settings.can_interface +
                          " is a classic CAN interface: set can.fd: false (--classic) or `ip "
                          "link set " +
                          settings.can_interface + " mtu 72`");
      }
      sink.port = port.get();
      sink.log_iface = settings.can_interface;
    } else if (settings.candump_out.empty() && expect_path.empty()) {
      throw ConfigError("can.interface none: nothing would be sent; give --candump-out");
    }
    if (!settings.candump_out.empty())
      sink.log = log = open_out(settings.candump_out, "--candump-out");
    if (!expect_path.empty()) sink.expect = expect = open_out(expect_path, "--expect");

    PatchNode patch(settings.node, settings.gate, &array, &clock, &sink, led.get());
    char start[200];
    std::snprintf(
        start, sizeof start, "%s, %s mode, %.2f Hz (max %.2f), %s on %s, uid %016" PRIx64,
        settings.sim.enabled ? "simulated patch" : std::string(settings.i2c_device).c_str(),
        std::string(bus::patch_mode_name(settings.node.mode)).c_str(), settings.rate_hz,
        settings.node.max_rate_chz / 100.0, settings.can_fd ? "CAN FD" : "classic CAN",
        settings.can_interface.c_str(), settings.node.hardware_uid);
    info(start);
    // A baseline capture that a changing field stopped or restarted: said once a capture.
    bool capture_change_said = false;
    patch.on_sample = [&](const bus::Sample&, const patch_fw::GateOutput& g, bool) {
      if (g.tare_changed_ut > 0 && !capture_change_said) {
        char msg[200];
        std::snprintf(msg, sizeof msg,
                      "tare: the field changed by %.1f uT during the baseline capture (a touch?): "
                      "%s",
                      g.tare_changed_ut,
                      g.tare_active ? "capturing again" : "the baseline is the field before it");
        info(msg);
      }
      capture_change_said = g.tare_active && (capture_change_said || g.tare_changed_ut > 0);
    };

    // ---- Loop: sample on schedule, answer frames and SYNC edges as they come.
    const uint64_t t0 = clock.now_us();
    const uint64_t end_us = duration_s > 0 ? t0 + static_cast<uint64_t>(duration_s * 1e6) : 0;
    uint16_t last_faults = array.fault_mask();
    uint64_t foreign_same_id = 0;
    while (!tools::stop_requested()) {
      uint64_t next = patch.poll();
      if (sink.write_errno != 0) {  // the log's reader went away (EPIPE) or its disk is full
        tools::exit_on_write_error("skinbus-patchd", "the candump log or --expect file",
                                   sink.write_errno);
      }
      if (patch.reboot_requested()) {
        info("reboot requested: restarting");
        if (log) std::fflush(log);
        if (expect) std::fflush(expect);
        port.reset();
        setenv(kRestartedEnv, "1", 1);
        execv("/proc/self/exe", argv);
        throw std::runtime_error(std::string("reboot: execv failed: ") + std::strerror(errno));
      }
      const uint16_t faults = array.fault_mask();
      if (faults != last_faults) {
        char msg[96];
        std::snprintf(msg, sizeof msg, "sensor fault mask %04x -> %04x (i2c errors %u)",
                      last_faults, faults, array.i2c_errors());
        info(msg);
        last_faults = faults;
      }
      uint64_t now = clock.now_us();
      if (end_us != 0) {
        if (now >= end_us) break;
        next = std::min(next, end_us);
      }
      if (port) port->flush();
      pollfd fds[2];
      nfds_t nfds = 0;
      if (port) fds[nfds++] = {port->fd(), POLLIN, 0};
      if (sync_in && sync_in->event_fd() >= 0) fds[nfds++] = {sync_in->event_fd(), POLLIN, 0};
      const uint64_t wait_us = next > now ? next - now : 0;
      timespec ts{static_cast<time_t>(wait_us / 1000000),
                  static_cast<long>(wait_us % 1000000) * 1000};
      const int n = ppoll(fds, nfds, &ts, nullptr);
      if (n < 0 && errno != EINTR)
        throw std::runtime_error(std::string("ppoll: ") + std::strerror(errno));
      if (n <= 0) continue;
      if (port) {
        bus::CanFrame f;
        bus::RxMeta meta;
        while (true) {
          const auto rs = port->receive(&f, &meta);
          if (rs == bus::SocketCanPort::RecvStatus::kNoFrame) break;
          if (rs == bus::SocketCanPort::RecvStatus::kError) {
            info("CAN receive: " + port->error().message);
            break;
          }
          if (f.error) {
            info("CAN controller: " + bus::describe_bus_error(bus::decode_error_frame(f)));
            continue;
          }
          const uint8_t cls = bus::can_id_class(f.id);
          if (!f.extended && bus::can_id_node(f.id) == settings.node.node_id &&
              cls >= static_cast<uint8_t>(bus::MessageClass::kAck)) {
            if (foreign_same_id++ % 1000 == 0) {  // a warning: shown even with --quiet
              std::fprintf(stderr,
                           "%s: warning: another node sends with node ID %d (duplicate node ID on "
                           "the bus?)\n",
                           tag.c_str(), settings.node.node_id);
            }
            continue;
          }
          patch.on_frame(f);
        }
      }
      if (sync_in) {
        GpioEvent ev;
        while (true) {
          Result<bool> got = sync_in->wait_event(0, &ev);
          if (!got.ok() || !*got) break;
          patch.on_sync_edge();
        }
      }
    }
    errno = 0;
    if ((log && (std::fflush(log) != 0 || std::ferror(log))) ||
        (expect && (std::fflush(expect) != 0 || std::ferror(expect)))) {
      tools::exit_on_write_error("skinbus-patchd", "the candump log or --expect file",
                                 errno != 0 ? errno : EIO);
    }
    const NodeStats& s = patch.stats();
    char done[256];
    std::snprintf(done, sizeof done,
                  "stopped: %" PRIu64 " samples taken, %" PRIu64 " sent, %" PRIu64
                  " heartbeats, %" PRIu64 " acks, %" PRIu64 " frames, %" PRIu64
                  " send errors, %" PRIu64 " overruns, i2c errors %u, fault mask %04x",
                  s.samples_taken, s.samples_sent, s.heartbeats_sent, s.acks_sent, s.frames_sent,
                  s.send_errors, s.overruns, array.i2c_errors(), array.fault_mask());
    info(done);
    if (log && log != stdout) std::fclose(log);
    if (expect && expect != stdout) std::fclose(expect);
    return 0;
  } catch (const ConfigError& e) {
    return skinbus::tools::fail("skinbus-patchd", std::string("bad settings: ") + e.what(),
                                kExitConfig);
  } catch (const std::exception& e) {
    return skinbus::tools::fail("skinbus-patchd", e.what(), kExitDevice);
  }
}
