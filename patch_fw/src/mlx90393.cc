#include "skinbus/patch_fw/mlx90393.h"

#include <array>
#include <cmath>
#include <cstdio>
#include <string>

namespace skinbus::patch_fw {

namespace m = mlx90393;

namespace {

uint16_t set_field(uint16_t reg, int shift, unsigned bits, unsigned value) {
  const unsigned mask = ((1u << bits) - 1u) << shift;
  return static_cast<uint16_t>((reg & ~mask) | ((value << shift) & mask));
}

}  // namespace

Mlx90393::Mlx90393(I2cBus* bus, uint8_t address, Clock* clock)
    : bus_(bus), address_(address), clock_(clock) {}

Status Mlx90393::command(std::span<const uint8_t> cmd, std::span<uint8_t> in, bool expect_reset) {
  std::array<I2cMessage, 2> msgs{
      I2cMessage{address_, false, {const_cast<uint8_t*>(cmd.data()), cmd.size()}},
      I2cMessage{address_, true, in}};
  Status st = bus_->transfer(msgs);
  const std::string where =
      "MLX90393 at " + format_hex_byte(address_) + " on " + std::string(bus_->name());
  if (!st.ok()) {
    if (st.error().code == ErrorCode::kUnavailable) ++stats_.naks;
    return make_error(st.error().code, where + ": " + st.error().message);
  }
  const uint8_t status = in[0];
  if ((status & m::kStatusReset) && !expect_reset) {
    ++stats_.unexpected_resets;
    configured_ = false;
    return make_error(ErrorCode::kUnavailable,
                      where + ": the chip reset itself (RS bit); its configuration is lost");
  }
  if (status & m::kStatusError) {
    ++stats_.error_bits;
    return make_error(ErrorCode::kIo, where + ": error bit set in status " +
                                          format_hex_byte(status) + " answering command " +
                                          format_hex_byte(cmd[0]));
  }
  return Status::Ok();
}

Status Mlx90393::nop() {
  const uint8_t cmd[1] = {m::kCmdNop};
  uint8_t in[1];
  return command(cmd, in, false);
}

Status Mlx90393::exit() {
  const uint8_t cmd[1] = {m::kCmdExit};
  uint8_t in[1];
  return command(cmd, in, false);
}

Status Mlx90393::reset() {
  ++stats_.resets;
  configured_ = false;
  // Leave burst or wake-on-change first (the chip may ignore RT while converting). A chip that
  // just reset itself answers EX with RS: that is expected here.
  {
    const uint8_t cmd[1] = {m::kCmdExit};
    uint8_t in[1];
    Status st = command(cmd, in, true);
    if (!st.ok() && st.error().code == ErrorCode::kUnavailable) return st;  // NAK: not there
  }
  const uint8_t rt[1] = {m::kCmdReset};
  I2cMessage msg{address_, false, {const_cast<uint8_t*>(rt), 1}};
  Status st = bus_->transfer({&msg, 1});
  if (!st.ok()) {
    if (st.error().code == ErrorCode::kUnavailable) ++stats_.naks;
    return make_error(st.error().code, "MLX90393 at " + format_hex_byte(address_) +
                                           ": reset: " + st.error().message);
  }
  clock_->sleep_until_us(clock_->now_us() + m::kResetTimeUs);
  // The first status after RT carries RS; accept it here.
  const uint8_t nop_cmd[1] = {m::kCmdNop};
  uint8_t in[1];
  return command(nop_cmd, in, true);
}

Result<uint16_t> Mlx90393::read_register(uint8_t reg) {
  const uint8_t cmd[2] = {m::kCmdReadRegister, static_cast<uint8_t>(reg << 2)};
  uint8_t in[3];
  Status st = command(cmd, in, false);
  if (!st.ok()) return st.error();
  if (m::status_data_bytes(in[0]) != 2) {
    ++stats_.bad_data_counts;
    return make_error(ErrorCode::kIo,
                      "MLX90393 at " + format_hex_byte(address_) + ": register read " +
                          format_hex_byte(reg) + " announced " +
                          std::to_string(m::status_data_bytes(in[0])) + " data bytes, expected 2");
  }
  return static_cast<uint16_t>(in[1] << 8 | in[2]);
}

Status Mlx90393::write_register(uint8_t reg, uint16_t value) {
  const uint8_t cmd[4] = {m::kCmdWriteRegister, static_cast<uint8_t>(value >> 8),
                          static_cast<uint8_t>(value & 0xFF), static_cast<uint8_t>(reg << 2)};
  uint8_t in[1];
  return command(cmd, in, false);
}

Status Mlx90393::configure(const Mlx90393Settings& settings) {
  configured_ = false;
  const m::Config& c = settings.chip;
  if (!m::config_valid(c)) {
    return make_error(ErrorCode::kInvalidArgument,
                      "MLX90393 configuration out of range (gain_sel 0..7, resolution 0..3, "
                      "oversampling 0..3, digital_filter 0..7)");
  }
  uint16_t want[3];
  for (uint8_t reg = 0; reg < 3; ++reg) {
    Result<uint16_t> r = read_register(reg);
    if (!r.ok()) return r.error();
    want[reg] = *r;
  }
  want[0] = set_field(want[0], m::kHallconfShift, 4, m::kHallconfDefault);
  want[0] = set_field(want[0], m::kGainSelShift, 3, c.gain_sel);
  want[0] = set_field(want[0], m::kZSeriesBit, 1, 0);
  want[0] = set_field(want[0], m::kBistBit, 1, 0);
  want[1] = set_field(want[1], m::kTcmpEnBit, 1, settings.temperature_compensation ? 1 : 0);
  want[1] = set_field(want[1], m::kTrigIntBit, 1, settings.drdy_interrupt ? 1 : 0);
  want[1] = set_field(want[1], m::kExtTrgBit, 1, 0);
  want[1] = set_field(want[1], m::kWocDiffBit, 1, 0);
  want[1] = set_field(want[1], m::kBurstSelShift, 4, 0);
  want[1] = set_field(want[1], m::kBurstDataRateShift, 6, 0);
  want[2] = set_field(want[2], m::kOsrShift, 2, c.osr);
  want[2] = set_field(want[2], m::kDigFiltShift, 3, c.dig_filt);
  want[2] = set_field(want[2], m::kResXShift, 2, c.res_xy);
  want[2] = set_field(want[2], m::kResYShift, 2, c.res_xy);
  want[2] = set_field(want[2], m::kResZShift, 2, c.res_z);
  for (uint8_t reg = 0; reg < 3; ++reg) {
    Status st = write_register(reg, want[reg]);
    if (!st.ok()) return st;
    Result<uint16_t> back = read_register(reg);
    if (!back.ok()) return back.error();
    if (*back != want[reg]) {
      ++stats_.verify_failures;
      char msg[96];
      std::snprintf(msg, sizeof msg, ": register 0x%02X reads back 0x%04X after writing 0x%04X",
                    reg, *back, want[reg]);
      return make_error(ErrorCode::kIo, "MLX90393 at " + format_hex_byte(address_) + msg);
    }
  }
  settings_ = settings;
  settings_.chip.temperature = false;  // the driver converts x, y, z only
  configured_ = true;
  return Status::Ok();
}

Status Mlx90393::start_single(uint8_t axes) {
  const uint8_t cmd[1] = {static_cast<uint8_t>(m::kCmdStartSingle | (axes & 0xF))};
  uint8_t in[1];
  return command(cmd, in, false);
}

Status Mlx90393::read_measurement(Mlx90393Reading* out) {
  const uint8_t cmd[1] = {static_cast<uint8_t>(m::kCmdReadMeasurement | m::kAxesXyz)};
  uint8_t in[7];
  Status st = command(cmd, in, false);
  if (!st.ok()) return st;
  if (m::status_data_bytes(in[0]) != m::measurement_bytes(m::kAxesXyz)) {
    ++stats_.bad_data_counts;
    return make_error(ErrorCode::kIo,
                      "MLX90393 at " + format_hex_byte(address_) + ": measurement announced " +
                          std::to_string(m::status_data_bytes(in[0])) + " data bytes, expected 6");
  }
  const m::Config& c = settings_.chip;
  for (int axis = 0; axis < 3; ++axis) {
    const uint16_t raw = static_cast<uint16_t>(in[1 + 2 * axis] << 8 | in[2 + 2 * axis]);
    const uint8_t res = axis == 2 ? c.res_z : c.res_xy;
    const int32_t code = m::code_from_word(raw, res);
    const double sens = axis == 2 ? m::sensitivity_z_ut(c) : m::sensitivity_xy_ut(c);
    out->code[axis] = code;
    out->field_ut[axis] = m::field_ut(code, sens, res);
    out->saturated[axis] = m::code_at_limit(code, res);
  }
  ++stats_.measurements;
  return Status::Ok();
}

Result<double> Mlx90393::measure_temperature_c() {
  if (Status st = start_single(m::kAxisT); !st.ok()) return st.error();
  clock_->sleep_until_us(clock_->now_us() + temperature_conversion_time_us(settings_.chip));
  const uint8_t cmd[1] = {static_cast<uint8_t>(m::kCmdReadMeasurement | m::kAxisT)};
  uint8_t in[3];
  if (Status st = command(cmd, in, false); !st.ok()) return st.error();
  if (m::status_data_bytes(in[0]) != m::measurement_bytes(m::kAxisT)) {
    ++stats_.bad_data_counts;
    return make_error(ErrorCode::kIo,
                      "MLX90393 at " + format_hex_byte(address_) + ": temperature announced " +
                          std::to_string(m::status_data_bytes(in[0])) + " data bytes, expected 2");
  }
  ++stats_.measurements;
  return m::temperature_c_from_code(static_cast<uint16_t>(in[1] << 8 | in[2]));
}

uint32_t Mlx90393::temperature_conversion_time_us(const m::Config& chip) {
  m::Config with_t = chip;
  with_t.temperature = true;
  return static_cast<uint32_t>(std::ceil(m::conversion_time_us(with_t)));
}

uint32_t Mlx90393::conversion_time_us() const {
  return static_cast<uint32_t>(std::ceil(m::conversion_time_us(settings_.chip)));
}

}  // namespace skinbus::patch_fw
