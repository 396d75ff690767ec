#include "skinbus/patch_fw/config.h"

#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <set>
#include <sstream>

#include "skinbus/common/yaml_reader.h"
#include "skinbus/mlx90393/protocol.h"

namespace skinbus::patch_fw {

namespace {

// A GPIO line offset, or "none".
void get_line(YamlReader& r, const YAML::Node& map, const char* key, const std::string& path,
              std::optional<unsigned>* out) {
  const YAML::Node n = map[key];
  if (r.error || !n) return;
  if (n.IsScalar() && n.Scalar() == "none") {
    out->reset();
    return;
  }
  long long v;
  if (r.integer(n, path + key, 0, 1023, &v)) *out = static_cast<unsigned>(v);
}

Status parse(const YAML::Node& root, PatchNodeSettings* s) {
  YamlReader r;
  if (!root || root.IsNull()) return Status::Ok();  // an empty file keeps the defaults
  r.only(root, "",
         {"node", "mode", "rate_hz", "sync", "event_tail_ms", "heartbeat_ms", "hardware_uid",
          "send_tared", "can", "i2c", "sensor", "health", "gpio", "gate", "sim"});
  r.get_int(root, "node", "", bus::kNodeMin, bus::kNodeMax, &s->node.node_id);
  if (const YAML::Node m = root["mode"]; m && !r.error) {
    const std::string v = m.IsScalar() ? m.Scalar() : "";
    if (v == "stream") {
      s->node.mode = bus::PatchMode::kStream;
    } else if (v == "event") {
      s->node.mode = bus::PatchMode::kEvent;
    } else if (v == "off") {
      s->node.mode = bus::PatchMode::kOff;
    } else {
      r.fail("mode", m, "'" + v + "' is not stream, event or off");
    }
  }
  r.get_double(root, "rate_hz", "", 1.0, 100.0, &s->rate_hz);
  r.get_bool(root, "sync", "", &s->node.sync_mode);
  r.get_int(root, "event_tail_ms", "", 0, 60000, &s->node.event_tail_ms);
  r.get_int(root, "heartbeat_ms", "", 100, 60000, &s->node.heartbeat_period_ms);
  unsigned long long uid = s->node.hardware_uid;
  r.get_uint64(root, "hardware_uid", "", &uid);
  s->node.hardware_uid = uid;
  r.get_bool(root, "send_tared", "", &s->node.send_tared);

  if (const YAML::Node c = root["can"]; c && !r.error) {
    r.only(c, "can", {"interface", "fd", "candump_out"});
    r.get_string(c, "interface", "can.", &s->can_interface);
    r.get_bool(c, "fd", "can.", &s->can_fd);
    r.get_string(c, "candump_out", "can.", &s->candump_out);
  }
  if (const YAML::Node i = root["i2c"]; i && !r.error) {
    r.only(i, "i2c", {"device", "mux_address", "clock_hz", "transaction_overhead_us", "channels"});
    r.get_string(i, "device", "i2c.", &s->i2c_device);
    if (const YAML::Node m = i["mux_address"]; m && !r.error) {
      long long v;
      if (m.IsScalar() && m.Scalar() == "none") {
        s->mux_address.reset();
      } else if (r.integer(m, "i2c.mux_address", 0, 127, &v)) {
        s->mux_address = static_cast<uint8_t>(v);
      }
    }
    r.get_int(i, "clock_hz", "i2c.", 10000, 3400000, &s->array.i2c_clock_hz);
    r.get_int(i, "transaction_overhead_us", "i2c.", 0, 100000, &s->array.transaction_overhead_us);
    if (const YAML::Node ch = i["channels"]; ch && !r.error) {
      if (!ch.IsSequence()) {
        r.fail("i2c.channels", ch, "expected a list of {channel, addresses}");
      } else {
        s->array.slots.clear();
        std::set<int> seen_channels;
        for (std::size_t k = 0; k < ch.size() && !r.error; ++k) {
          const std::string path = "i2c.channels[" + std::to_string(k) + "]";
          const YAML::Node e = ch[k];
          r.only(e, path, {"channel", "addresses"});
          int channel = -1;
          r.get_int(e, "channel", path + ".", -1, 3, &channel);
          if (r.error) break;
          if (!e["channel"]) {
            r.fail(path + ".channel", e, "missing (0..3, or -1 for the trunk)");
            break;
          }
          if (!seen_channels.insert(channel).second) {
            r.fail(path + ".channel", e["channel"],
                   "channel " + std::to_string(channel) + " is listed twice");
            r.error->code = ErrorCode::kInvalidArgument;
            break;
          }
          const YAML::Node a = e["addresses"];
          if (!a || !a.IsSequence()) {
            r.fail(path + ".addresses", e, "expected a list of 7-bit addresses");
            break;
          }
          for (std::size_t j = 0; j < a.size() && !r.error; ++j) {
            long long v;
            const std::string apath = path + ".addresses[" + std::to_string(j) + "]";
            if (!r.integer(a[j], apath, 0, 127, &v)) break;
            s->array.slots.push_back({channel, static_cast<uint8_t>(v)});
          }
        }
      }
    }
  }
  if (const YAML::Node c = root["sensor"]; c && !r.error) {
    r.only(c, "sensor",
           {"gain_sel", "resolution_xy", "resolution_z", "oversampling", "digital_filter",
            "temperature_compensation", "drdy_interrupt"});
    mlx90393::Config& chip = s->array.settings.chip;
    r.get_int(c, "gain_sel", "sensor.", 0, 7, &chip.gain_sel);
    r.get_int(c, "resolution_xy", "sensor.", 0, 3, &chip.res_xy);
    r.get_int(c, "resolution_z", "sensor.", 0, 3, &chip.res_z);
    r.get_int(c, "oversampling", "sensor.", 0, 3, &chip.osr);
    r.get_int(c, "digital_filter", "sensor.", 0, 7, &chip.dig_filt);
    r.get_bool(c, "temperature_compensation", "sensor.",
               &s->array.settings.temperature_compensation);
    r.get_bool(c, "drdy_interrupt", "sensor.", &s->array.settings.drdy_interrupt);
  }
  if (const YAML::Node h = root["health"]; h && !r.error) {
    r.only(h, "health", {"dead_after_failures", "retry_interval_samples", "stuck_after_samples"});
    r.get_int(h, "dead_after_failures", "health.", 1, 1000, &s->array.dead_after_failures);
    r.get_int(h, "retry_interval_samples", "health.", 1, 100000, &s->array.retry_interval_samples);
    r.get_int(h, "stuck_after_samples", "health.", 2, 100000, &s->array.stuck_after_samples);
  }
  if (const YAML::Node g = root["gpio"]; g && !r.error) {
    r.only(g, "gpio", {"chip", "drdy", "mux_reset", "identify_led", "sync_in"});
    r.get_string(g, "chip", "gpio.", &s->gpio.chip);
    if (const YAML::Node d = g["drdy"]; d && !r.error) {
      s->gpio.drdy_lines.clear();
      if (!d.IsSequence()) r.fail("gpio.drdy", d, "expected a list of line offsets");
      for (std::size_t j = 0; d.IsSequence() && j < d.size() && !r.error; ++j) {
        long long v;
        if (r.integer(d[j], "gpio.drdy[" + std::to_string(j) + "]", 0, 1023, &v))
          s->gpio.drdy_lines.push_back(static_cast<unsigned>(v));
      }
    }
    get_line(r, g, "mux_reset", "gpio.", &s->gpio.mux_reset);
    get_line(r, g, "identify_led", "gpio.", &s->gpio.identify_led);
    get_line(r, g, "sync_in", "gpio.", &s->gpio.sync_in);
  }
  if (const YAML::Node g = root["gate"]; g && !r.error) {
    r.only(g, "gate",
           {"on_threshold_ut", "off_threshold_ut", "rms_on_threshold_ut", "rms_off_threshold_ut",
            "rms_smoothing_samples", "off_samples", "tare_samples", "drift_tau_s",
            "drift_max_ut_per_s", "drift_holdoff_s"});
    r.get_double(g, "on_threshold_ut", "gate.", 0.1, 10000, &s->gate.on_threshold_ut);
    r.get_double(g, "off_threshold_ut", "gate.", 0.1, 10000, &s->gate.off_threshold_ut);
    r.get_double(g, "rms_on_threshold_ut", "gate.", 0.01, 10000, &s->gate.rms_on_threshold_ut);
    r.get_double(g, "rms_off_threshold_ut", "gate.", 0.01, 10000, &s->gate.rms_off_threshold_ut);
    r.get_int(g, "rms_smoothing_samples", "gate.", 1, 1000, &s->gate.rms_smoothing_samples);
    r.get_int(g, "off_samples", "gate.", 1, 1000, &s->gate.off_samples);
    r.get_int(g, "tare_samples", "gate.", 1, 10000, &s->gate.tare_samples);
    r.get_double(g, "drift_tau_s", "gate.", 0.0, 1e6, &s->gate.drift_tau_s);
    r.get_double(g, "drift_max_ut_per_s", "gate.", 0.0, 1e4, &s->gate.drift_max_ut_per_s);
    r.get_double(g, "drift_holdoff_s", "gate.", 0.0, 1e4, &s->gate.drift_holdoff_s);
  }
  if (const YAML::Node m = root["sim"]; m && !r.error) {
    r.only(m, "sim",
           {"enabled", "contacts", "random_presses_per_min", "seed", "limb_swing_deg",
            "limb_period_s"});
    r.get_bool(m, "enabled", "sim.", &s->sim.enabled);
    r.get_string(m, "contacts", "sim.", &s->sim.contacts_file);
    r.get_double(m, "random_presses_per_min", "sim.", 0, 600, &s->sim.random_presses_per_min);
    r.get_int(m, "seed", "sim.", 0, INT64_MAX, &s->sim.seed);
    r.get_double(m, "limb_swing_deg", "sim.", 0, 180, &s->sim.limb_swing_deg);
    r.get_double(m, "limb_period_s", "sim.", 0.1, 3600, &s->sim.limb_period_s);
  }
  if (r.error) return *r.error;
  return Status::Ok();
}

}  // namespace

PatchNodeSettings default_settings() {
  PatchNodeSettings s;
  for (int c = 0; c < 4; ++c)
    for (int k = 0; k < 4; ++k)
      s.array.slots.push_back({c, static_cast<uint8_t>(mlx90393::kAddressMin + k)});
  return s;
}

Status load_settings_text(const std::string& yaml, PatchNodeSettings* settings) {
  try {
    return parse(YAML::Load(yaml), settings);
  } catch (const YAML::Exception& e) {
    return make_error(ErrorCode::kParse, "line " + std::to_string(e.mark.line + 1) + ", column " +
                                             std::to_string(e.mark.column + 1) + ": " + e.msg);
  }
}

Status load_settings_file(const std::string& path, PatchNodeSettings* settings) {
  Result<std::string> text = read_text_file(path, "config file");
  if (!text.ok()) return text.error();
  Status st = load_settings_text(text.value(), settings);
  if (!st.ok()) return make_error(st.error().code, path + ": " + st.error().message);
  return st;
}

Status validate_settings(PatchNodeSettings* s) {
  auto bad = [](ErrorCode code, const std::string& msg) { return Status(make_error(code, msg)); };
  if (!bus::is_patch_node(s->node.node_id)) {
    return bad(ErrorCode::kOutOfRange,
               "node " + std::to_string(s->node.node_id) + ": patch node IDs are 1..125");
  }
  {
    const std::string& n = s->can_interface;
    bool ok = !n.empty() && n.size() <= 15;
    for (char c : n) ok = ok && c > ' ' && c < 0x7F && c != '/' && c != ':';
    if (!ok) {
      return bad(ErrorCode::kInvalidArgument,
                 "can.interface '" + n +
                     "': an interface name is 1..15 printable characters without '/' or ':'");
    }
  }
  if (s->mux_address &&
      (*s->mux_address < kTca9546aAddressMin || *s->mux_address > kTca9546aAddressMax)) {
    return bad(ErrorCode::kOutOfRange, "i2c.mux_address " + format_hex_byte(*s->mux_address) +
                                           ": a TCA9546A answers at 0x70..0x77");
  }
  if (s->array.slots.size() != static_cast<std::size_t>(bus::kSensorCount)) {
    return bad(ErrorCode::kInvalidArgument,
               "i2c.channels: " + std::to_string(s->array.slots.size()) +
                   " sensor addresses listed; a patch has " + std::to_string(bus::kSensorCount) +
                   " (in grid order, row-major)");
  }
  std::set<std::pair<int, int>> seen;
  for (std::size_t i = 0; i < s->array.slots.size(); ++i) {
    const SensorSlot& slot = s->array.slots[i];
    const std::string name = "i2c.channels (sensor " + std::to_string(i) + ", channel " +
                             std::to_string(slot.channel) + ")";
    if (slot.address < mlx90393::kAddressMin || slot.address > mlx90393::kAddressMax) {
      return bad(ErrorCode::kOutOfRange, name + ": address " + format_hex_byte(slot.address) +
                                             " is not an MLX90393 address (0x0C..0x1B)");
    }
    if (slot.channel >= 0 && !s->mux_address) {
      return bad(ErrorCode::kInvalidArgument,
                 name + ": a multiplexer channel is used but i2c.mux_address is none");
    }
    if (slot.channel < 0 && s->mux_address && slot.address == *s->mux_address) {
      return bad(ErrorCode::kInvalidArgument, name + ": collides with the multiplexer address");
    }
    if (!seen.insert({slot.channel, slot.address}).second) {
      return bad(ErrorCode::kInvalidArgument, name + ": address " + format_hex_byte(slot.address) +
                                                  " is listed twice on that channel");
    }
  }
  // Lines used once.
  std::set<unsigned> lines;
  auto use = [&](unsigned line, const std::string& what) -> Status {
    if (!lines.insert(line).second) {
      return bad(ErrorCode::kInvalidArgument,
                 what + ": line " + std::to_string(line) + " is already used by another setting");
    }
    return Status::Ok();
  };
  for (std::size_t j = 0; j < s->gpio.drdy_lines.size(); ++j)
    if (Status st = use(s->gpio.drdy_lines[j], "gpio.drdy[" + std::to_string(j) + "]"); !st.ok())
      return st;
  for (auto [line, what] : {std::pair{s->gpio.mux_reset, "gpio.mux_reset"},
                            std::pair{s->gpio.identify_led, "gpio.identify_led"},
                            std::pair{s->gpio.sync_in, "gpio.sync_in"}}) {
    if (line)
      if (Status st = use(*line, what); !st.ok()) return st;
  }
  if (s->gate.off_threshold_ut > s->gate.on_threshold_ut) {
    return bad(ErrorCode::kInvalidArgument,
               "gate.off_threshold_ut must not exceed gate.on_threshold_ut (hysteresis)");
  }
  if (s->gate.rms_off_threshold_ut > s->gate.rms_on_threshold_ut) {
    return bad(ErrorCode::kInvalidArgument,
               "gate.rms_off_threshold_ut must not exceed gate.rms_on_threshold_ut (hysteresis)");
  }
  // Rate against the chip's conversion time and the bus.
  const double max_hz = SensorArray::max_rate_hz(s->array);
  if (!(s->rate_hz >= 1.0) || s->rate_hz > max_hz) {
    mlx90393::Config chip = s->array.settings.chip;
    char msg[320];
    std::snprintf(msg, sizeof msg,
                  "rate_hz %.2f: the sensors allow at most %.2f Hz (one sample takes %u us: "
                  "%.0f us conversion at oversampling %d, digital_filter %d, plus the I2C "
                  "transfers); lower rate_hz or sensor.oversampling / sensor.digital_filter",
                  s->rate_hz, max_hz, SensorArray::cycle_time_us(s->array),
                  mlx90393::conversion_time_us(chip), chip.osr, chip.dig_filt);
    return bad(ErrorCode::kOutOfRange, msg);
  }
  s->node.rate_chz = static_cast<uint16_t>(std::lround(s->rate_hz * 100));
  s->node.max_rate_chz = static_cast<uint16_t>(std::min(65535.0, std::floor(max_hz * 100)));
  s->node.kind = s->can_fd ? bus::FrameKind::kFd : bus::FrameKind::kClassic;
  s->node.simulated = s->sim.enabled;
  return Status::Ok();
}

std::string settings_to_yaml(const PatchNodeSettings& s) {
  std::ostringstream o;
  const char* mode = s.node.mode == bus::PatchMode::kStream  ? "stream"
                     : s.node.mode == bus::PatchMode::kEvent ? "event"
                                                             : "off";
  char uid[24];
  std::snprintf(uid, sizeof uid, "0x%016llx", static_cast<unsigned long long>(s.node.hardware_uid));
  o << "node: " << int{s.node.node_id} << "\nmode: " << mode << "\nrate_hz: " << s.rate_hz
    << "\nsync: " << (s.node.sync_mode ? "true" : "false")
    << "\nevent_tail_ms: " << s.node.event_tail_ms
    << "\nheartbeat_ms: " << s.node.heartbeat_period_ms << "\nhardware_uid: " << uid
    << "\nsend_tared: " << (s.node.send_tared ? "true" : "false")
    << "\ncan:\n  interface: " << yaml_string(s.can_interface)
    << "\n  fd: " << (s.can_fd ? "true" : "false") << "\n";
  if (!s.candump_out.empty()) o << "  candump_out: " << yaml_string(s.candump_out) << "\n";
  o << "i2c:\n  device: " << yaml_string(s.i2c_device) << "\n  mux_address: "
    << (s.mux_address ? format_hex_byte(*s.mux_address) : std::string("none"))
    << "\n  clock_hz: " << s.array.i2c_clock_hz
    << "\n  transaction_overhead_us: " << s.array.transaction_overhead_us << "\n  channels:\n";
  for (std::size_t i = 0; i < s.array.slots.size();) {
    const int c = s.array.slots[i].channel;
    o << "    - channel: " << c << "\n      addresses: [";
    bool first = true;
    for (; i < s.array.slots.size() && s.array.slots[i].channel == c; ++i) {
      o << (first ? "" : ", ") << format_hex_byte(s.array.slots[i].address);
      first = false;
    }
    o << "]\n";
  }
  const mlx90393::Config& c = s.array.settings.chip;
  o << "sensor:\n  gain_sel: " << int{c.gain_sel} << "\n  resolution_xy: " << int{c.res_xy}
    << "\n  resolution_z: " << int{c.res_z} << "\n  oversampling: " << int{c.osr}
    << "\n  digital_filter: " << int{c.dig_filt} << "\n  temperature_compensation: "
    << (s.array.settings.temperature_compensation ? "true" : "false")
    << "\n  drdy_interrupt: " << (s.array.settings.drdy_interrupt ? "true" : "false")
    << "\nhealth:\n  dead_after_failures: " << s.array.dead_after_failures
    << "\n  retry_interval_samples: " << s.array.retry_interval_samples
    << "\n  stuck_after_samples: " << s.array.stuck_after_samples
    << "\ngpio:\n  chip: " << yaml_string(s.gpio.chip) << "\n  drdy: [";
  for (std::size_t j = 0; j < s.gpio.drdy_lines.size(); ++j)
    o << (j ? ", " : "") << s.gpio.drdy_lines[j];
  auto line = [](const std::optional<unsigned>& l) {
    return l ? std::to_string(*l) : std::string("none");
  };
  o << "]\n  mux_reset: " << line(s.gpio.mux_reset)
    << "\n  identify_led: " << line(s.gpio.identify_led) << "\n  sync_in: " << line(s.gpio.sync_in)
    << "\ngate:\n  on_threshold_ut: " << s.gate.on_threshold_ut
    << "\n  off_threshold_ut: " << s.gate.off_threshold_ut
    << "\n  rms_on_threshold_ut: " << s.gate.rms_on_threshold_ut
    << "\n  rms_off_threshold_ut: " << s.gate.rms_off_threshold_ut
    << "\n  rms_smoothing_samples: " << s.gate.rms_smoothing_samples
    << "\n  off_samples: " << s.gate.off_samples << "\n  tare_samples: " << s.gate.tare_samples
    << "\n  drift_tau_s: " << s.gate.drift_tau_s
    << "\n  drift_max_ut_per_s: " << s.gate.drift_max_ut_per_s
    << "\n  drift_holdoff_s: " << s.gate.drift_holdoff_s
    << "\nsim:\n  enabled: " << (s.sim.enabled ? "true" : "false") << "\n";
  if (!s.sim.contacts_file.empty()) o << "  contacts: " << yaml_string(s.sim.contacts_file) << "\n";
  o << "  random_presses_per_min: " << s.sim.random_presses_per_min << "\n  seed: " << s.sim.seed
    << "\n  limb_swing_deg: " << s.sim.limb_swing_deg
    << "\n  limb_period_s: " << s.sim.limb_period_s << "\n";
  return o.str();
}

}  // namespace skinbus::patch_fw
