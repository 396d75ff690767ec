#include "skinbus/patch_fw/tca9546a.h"

#include <cstdio>
#include <string>

namespace skinbus::patch_fw {

namespace {
std::string where(uint8_t address, const I2cBus& bus) {
  return "TCA9546A at " + format_hex_byte(address) + " on " + std::string(bus.name());
}
}  // namespace

Tca9546a::Tca9546a(I2cBus* bus, uint8_t address, GpioOutput* reset_line, Clock* clock)
    : bus_(bus), address_(address), reset_line_(reset_line), clock_(clock) {}

Status Tca9546a::write_control(uint8_t value) {
  ++writes_;
  uint8_t b = value;
  Status st = i2c_write(*bus_, address_, {&b, 1});
  if (!st.ok()) {
    ++errors_;
    cached_ = -2;
    return make_error(st.error().code, where(address_, *bus_) + ": " + st.error().message);
  }
  return Status::Ok();
}

Status Tca9546a::select(int channel) {
  if (channel < 0 || channel >= kTca9546aChannels) {
    return make_error(ErrorCode::kInvalidArgument,
                      where(address_, *bus_) + ": channel " + std::to_string(channel) + " (0..3)");
  }
  if (cached_ == channel) return Status::Ok();
  Status st = write_control(static_cast<uint8_t>(1u << channel));
  if (st.ok()) cached_ = channel;
  return st;
}

Status Tca9546a::deselect() {
  if (cached_ == -1) return Status::Ok();
  Status st = write_control(0);
  if (st.ok()) cached_ = -1;
  return st;
}

Result<uint8_t> Tca9546a::read_control() {
  uint8_t b = 0;
  I2cMessage m{address_, true, {&b, 1}};
  Status st = bus_->transfer({&m, 1});
  if (!st.ok()) {
    ++errors_;
    cached_ = -2;
    return make_error(st.error().code, where(address_, *bus_) + ": " + st.error().message);
  }
  const int expect = cached_ >= 0 ? (1 << cached_) : cached_ == -1 ? 0 : -1;
  if (expect >= 0 && (b & 0x0F) != expect) cached_ = -2;  // someone else changed it
  return static_cast<uint8_t>(b & 0x0F);
}

Status Tca9546a::reset() {
  cached_ = -2;
  if (reset_line_ != nullptr) {
    Status st = reset_line_->set(true);
    if (!st.ok()) return st;
    clock_->sleep_until_us(clock_->now_us() + 10);
    st = reset_line_->set(false);
    if (!st.ok()) return st;
    cached_ = -1;
    return Status::Ok();
  }
  return deselect();
}

}  // namespace skinbus::patch_fw
