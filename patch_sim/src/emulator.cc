#include "skinbus/patch_sim/emulator.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <string>

#include "skinbus/mlx90393/measurement.h"
#include "skinbus/mlx90393/protocol.h"
#include "skinbus/patch_fw/tca9546a.h"

namespace skinbus::patch_sim {

namespace mlx = mlx90393;
using patch_fw::format_hex_byte;
using patch_fw::I2cMessage;

namespace {

constexpr int kMuxChannels = 4;

unsigned field(uint16_t reg, int shift, unsigned bits) {
  return (static_cast<unsigned>(reg) >> shift) & ((1u << bits) - 1);
}

std::array<uint16_t, mlx::kRegCount> default_registers() {
  std::array<uint16_t, mlx::kRegCount> r{};
  r[mlx::kRegConf1] = mlx::kDefaultConf1;
  r[mlx::kRegConf2] = mlx::kDefaultConf2;
  r[mlx::kRegConf3] = mlx::kDefaultConf3;
  return r;
}

// What a conversion takes from the registers when it starts.
struct Setup {
  std::array<double, 3> sensitivity_ut{};  // X, Y, Z
  std::array<uint8_t, 3> res{};            // X, Y, Z
  uint64_t conversion_us = 0;
};

Setup setup_from(const std::array<uint16_t, mlx::kRegCount>& regs, uint8_t axes) {
  const uint16_t c1 = regs[mlx::kRegConf1], c3 = regs[mlx::kRegConf3];
  mlx::Config c;
  c.gain_sel = static_cast<uint8_t>(field(c1, mlx::kGainSelShift, 3));
  c.res_xy = static_cast<uint8_t>(field(c3, mlx::kResXShift, 2));
  c.res_z = static_cast<uint8_t>(field(c3, mlx::kResZShift, 2));
  c.osr = static_cast<uint8_t>(field(c3, mlx::kOsrShift, 2));
  c.dig_filt = static_cast<uint8_t>(field(c3, mlx::kDigFiltShift, 3));
  c.temperature = (axes & mlx::kAxisT) != 0;
  mlx::Config cy = c;  // RES_Y kept apart from RES_X
  cy.res_xy = static_cast<uint8_t>(field(c3, mlx::kResYShift, 2));
  Setup s;
  s.sensitivity_ut = {mlx::sensitivity_xy_ut(c), mlx::sensitivity_xy_ut(cy),
                      mlx::sensitivity_z_ut(c)};
  s.res = {c.res_xy, cy.res_xy, c.res_z};
  s.conversion_us = static_cast<uint64_t>(std::ceil(mlx::conversion_time_us(c)));
  return s;
}

// Output codes T, X, Y, Z as 16-bit words.
std::array<uint16_t, 4> convert(const Setup& s, const sim::Vec3<double>& field_ut,
                                double temperature_c) {
  std::array<uint16_t, 4> codes{};
  codes[0] = mlx::temperature_code(temperature_c);
  const double f[3] = {field_ut.x, field_ut.y, field_ut.z};
  for (int i = 0; i < 3; ++i) {
    bool saturated = false;
    const int32_t code = mlx::output_code(f[i], s.sensitivity_ut[static_cast<size_t>(i)],
                                          s.res[static_cast<size_t>(i)], &saturated);
    codes[static_cast<size_t>(i) + 1] = mlx::code_word(code);
  }
  return codes;
}

}  // namespace

// One MLX90393: registers, mode, the measurement in flight and the pending answer.
struct EmulatedI2cBus::Chip {
  enum class Mode { kIdle, kSingle, kBurst };

  int channel = -1;
  uint8_t address = 0;
  int sensor = 0;
  std::array<uint16_t, mlx::kRegCount> regs = default_registers();
  Mlx90393Faults faults;
  Mlx90393Counters counters;

  Mode mode = Mode::kIdle;
  bool rs_pending = true;          // RS in the next answer (power-on)
  uint64_t busy_until_us = 0;      // NAKs before this (after RT)
  bool rt_in_transaction = false;  // RT's own answer may still be read until the STOP
  std::vector<uint8_t> answer;     // pending answer; empty: none
  // The measurement: single (one conversion) or burst (conversion k at start + k * period).
  uint8_t axes = 0;
  Setup setup;
  uint64_t start_us = 0;
  uint64_t period_us = 0;           // burst only
  uint64_t started_counted = 0;     // burst conversions already counted in `measurements`
  int64_t sampled_index = -1;       // burst conversion whose codes are in `codes`
  std::array<uint16_t, 4> codes{};  // T, X, Y, Z of the measurement (single: sampled at SM)
  std::array<std::optional<uint16_t>, 4> last_codes;  // last RM answer per axis (stuck fault)

  bool acknowledges(bool read, uint64_t now_us) const {
    if (faults.nak) return false;
    return now_us >= busy_until_us || (read && rt_in_transaction);
  }

  uint8_t mode_bits() const {
    return mode == Mode::kBurst    ? mlx::kStatusBurstMode
           : mode == Mode::kSingle ? mlx::kStatusSmMode
                                   : 0;
  }

  // The status byte of an answer: consumes RS, counts errors.
  uint8_t status(uint8_t bits) {
    uint8_t s = static_cast<uint8_t>(mode_bits() | bits);
    if (rs_pending) s |= mlx::kStatusReset;
    rs_pending = false;
    if (bits & mlx::kStatusError) ++counters.errors;
    return s;
  }
  void answer_status(uint8_t bits = 0) { answer.assign(1, status(bits)); }
  void answer_error() { answer_status(mlx::kStatusError); }

  // Counts burst conversions started up to `now_us`.
  void count_burst(uint64_t now_us) {
    if (mode != Mode::kBurst) return;
    const uint64_t started = (now_us - start_us) / period_us + 1;
    counters.measurements += started - started_counted;
    started_counted = started;
  }

  void end_measurement(uint64_t now_us) {
    count_burst(now_us);
    mode = Mode::kIdle;
    axes = 0;
  }

  void reset_state(uint64_t now_us) {
    end_measurement(now_us);
    regs = default_registers();
    answer.clear();
    rs_pending = true;
    ++counters.resets;
  }

  bool hallconf_ok() const {
    return field(regs[mlx::kRegConf1], mlx::kHallconfShift, 4) == mlx::kHallconfDefault;
  }

  void start(Mode m, uint8_t sel, uint64_t now_us, FieldSource* source) {
    mode = m;
    axes = sel;
    setup = setup_from(regs, sel);
    start_us = now_us;
    if (m == Mode::kSingle) {
      ++counters.measurements;
      codes =
          convert(setup, source->field_ut(sensor, now_us), source->temperature_c(sensor, now_us));
    } else {
      const uint64_t rate = field(regs[mlx::kRegConf2], mlx::kBurstDataRateShift, 6);
      period_us = std::max<uint64_t>(setup.conversion_us, rate * mlx::kBurstDataRateStepUs);
      if (period_us == 0) period_us = 1;
      started_counted = 0;
      sampled_index = -1;
      count_burst(now_us);
    }
    answer_status();
  }

  void read_measurement(uint8_t sel, uint64_t now_us, FieldSource* source) {
    if (sel == 0 || mode == Mode::kIdle) return answer_error();
    const uint64_t complete = mode == Mode::kSingle
                                  ? (now_us >= start_us + setup.conversion_us ? 1 : 0)
                                  : (now_us - start_us) / period_us;
    if (complete == 0) {
      ++counters.early_reads;
      return answer_error();
    }
    if ((sel & ~axes) != 0) return answer_error();
    if (mode == Mode::kBurst) {
      const int64_t k = static_cast<int64_t>(complete) - 1;
      if (k != sampled_index) {
        const uint64_t t_us = start_us + static_cast<uint64_t>(k) * period_us;
        codes = convert(setup, source->field_ut(sensor, t_us), source->temperature_c(sensor, t_us));
        sampled_index = k;
      }
    } else {
      mode = Mode::kIdle;  // single measurement consumed
    }
    std::vector<uint8_t> data;
    for (size_t i = 0; i < 4; ++i) {
      if (!(sel & (1u << i))) continue;
      uint16_t code = codes[i];
      if (faults.stuck && last_codes[i]) code = *last_codes[i];
      last_codes[i] = code;
      data.push_back(static_cast<uint8_t>(code >> 8));
      data.push_back(static_cast<uint8_t>(code & 0xFF));
    }
    int d = (mlx::measurement_bytes(sel) - 2) / 2;
    if (faults.wrong_data_count > 0) {
      --faults.wrong_data_count;
      d = std::max(d - 1, 0);
      data.resize(data.size() - 2);
    }
    answer.assign(1, status(static_cast<uint8_t>(d)));
    answer.insert(answer.end(), data.begin(), data.end());
  }

  // Executes one command write (non-empty).
  void command(std::span<const uint8_t> in, uint64_t now_us, FieldSource* source) {
    ++counters.commands;
    count_burst(now_us);
    if (faults.error_bit_commands > 0) {
      --faults.error_bit_commands;
      return answer_error();
    }
    const uint8_t cmd = in[0], hi = cmd & 0xF0, sel = cmd & 0x0F;
    const size_t n = in.size();
    const bool one = n == 1, plain = n == 1 && sel == 0;
    switch (hi) {
      case mlx::kCmdNop:
        return plain ? answer_status() : answer_error();
      case mlx::kCmdStartBurst: {
        const uint8_t burst_sel =
            sel ? sel : static_cast<uint8_t>(field(regs[mlx::kRegConf2], mlx::kBurstSelShift, 4));
        if (!one || mode != Mode::kIdle || !hallconf_ok() || burst_sel == 0) return answer_error();
        return start(Mode::kBurst, burst_sel, now_us, source);
      }
      case mlx::kCmdStartSingle:
        if (!one || mode != Mode::kIdle || !hallconf_ok() || sel == 0) return answer_error();
        return start(Mode::kSingle, sel, now_us, source);
      case mlx::kCmdReadMeasurement:
        return one ? read_measurement(sel, now_us, source) : answer_error();
      case mlx::kCmdReadRegister: {
        const uint8_t reg = n == 2 ? static_cast<uint8_t>(in[1] >> 2) : mlx::kRegCount;
        if (sel != 0 || reg >= mlx::kRegCount) return answer_error();
        uint16_t v = regs[reg];
        if (faults.corrupt_register_reads) v = static_cast<uint16_t>(~v);
        answer.assign({status(0), static_cast<uint8_t>(v >> 8), static_cast<uint8_t>(v & 0xFF)});
        return;
      }
      case mlx::kCmdWriteRegister: {
        const uint8_t reg = n == 4 ? static_cast<uint8_t>(in[3] >> 2) : mlx::kRegCount;
        if (sel != 0 || reg >= mlx::kRegCount) return answer_error();
        regs[reg] = static_cast<uint16_t>(in[1] << 8 | in[2]);
        return answer_status();
      }
      case mlx::kCmdExit:
        if (!plain) return answer_error();
        end_measurement(now_us);
        return answer_status();
      case mlx::kCmdMemoryRecall:
        if (!plain) return answer_error();
        regs = default_registers();
        return answer_status();
      case mlx::kCmdReset: {
        if (!plain) return answer_error();
        end_measurement(now_us);
        const uint8_t s = status(0);  // idle; carries an RS still pending from before
        reset_state(now_us);          // RS pending again: for the first answer after the reset
        answer.assign(1, s);
        busy_until_us = now_us + mlx::kResetTimeUs;
        rt_in_transaction = true;
        return;
      }
      default:  // SW, HS (not emulated) and unknown commands
        return answer_error();
    }
  }

  void read(std::span<uint8_t> out) {
    if (out.empty()) return;
    std::fill(out.begin(), out.end(), uint8_t{0xFF});
    if (answer.empty()) {
      out[0] = static_cast<uint8_t>(mode_bits() | (rs_pending ? mlx::kStatusReset : 0));
      return;
    }
    std::copy_n(answer.begin(), std::min(answer.size(), out.size()), out.begin());
    answer.clear();
  }
};

EmulatedI2cBus::EmulatedI2cBus(patch_fw::Clock* clock, FieldSource* source)
    : clock_(clock), source_(source) {}
EmulatedI2cBus::~EmulatedI2cBus() = default;

Status EmulatedI2cBus::add_mux(uint8_t address) {
  if (mux_address_) return make_error(ErrorCode::kInvalidArgument, "emulator: mux already added");
  if (address < patch_fw::kTca9546aAddressMin || address > patch_fw::kTca9546aAddressMax) {
    return make_error(ErrorCode::kInvalidArgument,
                      "emulator: mux address " + format_hex_byte(address) + " outside 0x70..0x77");
  }
  mux_address_ = address;
  return Status::Ok();
}

Status EmulatedI2cBus::add_mlx90393(int channel, uint8_t address, int sensor) {
  const std::string what = "emulator: MLX90393 at " + format_hex_byte(address) + " channel " +
                           std::to_string(channel) + " sensor " + std::to_string(sensor) + ": ";
  if (channel < -1 || channel >= kMuxChannels) {
    return make_error(ErrorCode::kInvalidArgument, what + "channel outside -1..3");
  }
  if (channel >= 0 && !mux_address_) {
    return make_error(ErrorCode::kInvalidArgument, what + "no multiplexer on the bus");
  }
  if (address < mlx::kAddressMin || address > mlx::kAddressMax) {
    return make_error(ErrorCode::kInvalidArgument, what + "address outside 0x0C..0x1B");
  }
  if (sensor < 0) return make_error(ErrorCode::kInvalidArgument, what + "negative sensor index");
  for (const auto& c : chips_) {
    if (c->sensor == sensor) {
      return make_error(ErrorCode::kInvalidArgument, what + "sensor index already used");
    }
    if (c->channel == channel && c->address == address) {
      return make_error(ErrorCode::kInvalidArgument, what + "address taken on that segment");
    }
  }
  auto chip = std::make_unique<Chip>();
  chip->channel = channel;
  chip->address = address;
  chip->sensor = sensor;
  chips_.push_back(std::move(chip));
  return Status::Ok();
}

Status EmulatedI2cBus::transfer(std::span<I2cMessage> messages) {
  ++transactions_;
  if (messages.empty()) return make_error(ErrorCode::kInvalidArgument, "emulator: no messages");
  const uint64_t now_us = clock_->now_us();
  Status result;
  for (size_t i = 0; i < messages.size() && result.ok(); ++i) {
    I2cMessage& m = messages[i];
    const auto fail = [&](ErrorCode code, const std::string& what) {
      result = make_error(code, "emulator: " + what + " at " + format_hex_byte(m.address) +
                                    " (message " + std::to_string(i + 1) + " of " +
                                    std::to_string(messages.size()) + ")");
    };
    if (mux_address_ && m.address == *mux_address_) {
      if (mux_nak_) {
        fail(ErrorCode::kUnavailable, "NAK");
      } else if (m.read) {
        std::fill(m.data.begin(), m.data.end(), mux_control_);
      } else if (!m.data.empty()) {
        mux_control_ = m.data.back() & 0x0F;
      }
      continue;
    }
    Chip* target = nullptr;
    int responders = 0;
    for (const auto& c : chips_) {
      const bool connected = c->channel < 0 || (mux_active_ >> c->channel) & 1;
      if (c->address == m.address && connected && c->acknowledges(m.read, now_us)) {
        target = c.get();
        ++responders;
      }
    }
    if (responders == 0) {
      fail(ErrorCode::kUnavailable, "NAK");
    } else if (responders > 1) {
      fail(ErrorCode::kIo, "bus conflict, " + std::to_string(responders) + " chips answer");
    } else if (m.read) {
      target->read(m.data);
    } else if (!m.data.empty()) {
      target->command(m.data, now_us, source_);
    }
  }
  // STOP: the mux connects the channels selected, RT's grace for its answer ends.
  mux_active_ = mux_control_;
  for (const auto& c : chips_) c->rt_in_transaction = false;
  return result;
}

namespace {
template <typename Chips>
auto& chip_of(Chips& chips, int sensor) {
  for (auto& c : chips) {
    if (c->sensor == sensor) return *c;
  }
  std::fprintf(stderr, "EmulatedI2cBus: no MLX90393 with sensor index %d\n", sensor);
  std::abort();
}
}  // namespace

Mlx90393Faults& EmulatedI2cBus::faults(int sensor) {
  return chip_of(chips_, sensor).faults;
}
const Mlx90393Counters& EmulatedI2cBus::counters(int sensor) const {
  return chip_of(chips_, sensor).counters;
}
uint16_t EmulatedI2cBus::register_value(int sensor, uint8_t reg) const {
  if (reg >= mlx::kRegCount) {
    std::fprintf(stderr, "EmulatedI2cBus: register 0x%02X out of range\n", reg);
    std::abort();
  }
  return chip_of(chips_, sensor).regs[reg];
}
void EmulatedI2cBus::power_cycle(int sensor) {
  chip_of(chips_, sensor).reset_state(clock_->now_us());
}
uint8_t EmulatedI2cBus::mux_control() const {
  return mux_control_;
}
void EmulatedI2cBus::set_mux_nak(bool nak) {
  mux_nak_ = nak;
}
void EmulatedI2cBus::mux_reset() {
  mux_control_ = 0;
  mux_active_ = 0;
}

}  // namespace skinbus::patch_sim
