// skinbus/patch_fw/tca9546a.h: the TCA9546A 4-channel I2C multiplexer.
//
// A one-register device: writing bit i of its control byte connects downstream channel i to the
// trunk. The driver keeps the selection it last wrote and skips rewriting it; any error forgets
// it (the next select writes again). The active-low RESET line (optional) clears the switch, for
// recovering a bus a downstream device holds.
#pragma once

#include <cstdint>

#include "skinbus/common/result.h"
#include "skinbus/patch_fw/clock.h"
#include "skinbus/patch_fw/gpio.h"
#include "skinbus/patch_fw/i2c.h"

namespace skinbus::patch_fw {

inline constexpr uint8_t kTca9546aAddressMin = 0x70;
inline constexpr uint8_t kTca9546aAddressMax = 0x77;
inline constexpr int kTca9546aChannels = 4;

class Tca9546a {
 public:
  // Not owned: `bus`, `clock`, and `reset_line` (may be null; requested active-low, so
  // set(true) asserts RESET), all outliving the driver.
  Tca9546a(I2cBus* bus, uint8_t address, GpioOutput* reset_line, Clock* clock);

  uint8_t address() const { return address_; }
  // Connects only `channel` (0..3). Writes only when the selection changes.
  Status select(int channel);
  // Disconnects every channel.
  Status deselect();
  // Reads the control register back and compares it with the cached selection.
  Result<uint8_t> read_control();
  // Pulses RESET (>= 1 us low; 10 us here) if a line is wired, else writes 0.
  Status reset();
  uint32_t errors() const { return errors_; }
  uint32_t writes() const { return writes_; }

 private:
  Status write_control(uint8_t value);
  I2cBus* bus_;
  uint8_t address_;
  GpioOutput* reset_line_;
  Clock* clock_;
  int cached_ = -2;  // -2: unknown, -1: none, 0..3: the selected channel
  uint32_t errors_ = 0, writes_ = 0;
};

}  // namespace skinbus::patch_fw
