// skinbus/patch_fw/i2c.h: an I2C bus as Linux i2c-dev exposes it.
//
// One call = one combined transaction (the I2C_RDWR ioctl): a list of messages, each a write or
// a read of a number of bytes at a 7-bit address, separated by repeated STARTs and ended by one
// STOP. The MLX90393 driver and the TCA9546A driver speak only through this interface, so the
// same driver code runs on a real bus (LinuxI2cBus) and on the chip emulators in tests and in
// the simulated patch (patch_sim::EmulatedI2cBus, skinbus/patch_sim/emulator.h).
#pragma once

#include <cstdint>
#include <memory>
#include <span>
#include <string>
#include <string_view>

#include "skinbus/common/result.h"

namespace skinbus::patch_fw {

struct I2cMessage {
  uint8_t address = 0;  // 7-bit address
  bool read = false;    // false: write `data` to the device; true: fill `data` from it
  std::span<uint8_t> data;
};

class I2cBus {
 public:
  virtual ~I2cBus() = default;
  // Runs one combined transaction. Errors: kUnavailable when a device did not acknowledge
  // (NAK: absent, busy or vanished), kIo for other bus failures. The caller's buffers are not
  // retained after the call.
  virtual Status transfer(std::span<I2cMessage> messages) = 0;
  // Where the bus is, for messages: "/dev/i2c-1", "emulator".
  virtual std::string_view name() const = 0;
};

// The Linux i2c-dev character device. open() fails with kNotFound when the device node does not
// exist, kIo when it cannot be opened or does not support I2C_RDWR (I2C_FUNC_I2C).
class LinuxI2cBus final : public I2cBus {
 public:
  static Result<std::unique_ptr<LinuxI2cBus>> open(std::string_view device_path);
  ~LinuxI2cBus() override;
  LinuxI2cBus(const LinuxI2cBus&) = delete;
  LinuxI2cBus& operator=(const LinuxI2cBus&) = delete;

  Status transfer(std::span<I2cMessage> messages) override;
  std::string_view name() const override { return path_; }

 private:
  LinuxI2cBus(int fd, std::string path) : fd_(fd), path_(std::move(path)) {}
  int fd_ = -1;
  std::string path_;
};

// "0x0C": how addresses, registers and status bytes appear in messages and settings.
std::string format_hex_byte(unsigned value);

// Convenience: one write message, or a write followed by a read (repeated START).
Status i2c_write(I2cBus& bus, uint8_t address, std::span<const uint8_t> out);
Status i2c_write_read(I2cBus& bus, uint8_t address, std::span<const uint8_t> out,
                      std::span<uint8_t> in);

}  // namespace skinbus::patch_fw
