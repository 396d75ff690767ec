// LinuxI2cBus: i2c-dev with the I2C_RDWR ioctl (one combined transaction per call).
#include <fcntl.h>
#include <linux/i2c-dev.h>
#include <linux/i2c.h>
#include <sys/ioctl.h>
#include <unistd.h>

#include <array>
#include <cerrno>
#include <cstdio>
#include <cstring>

#include "skinbus/patch_fw/i2c.h"

namespace skinbus::patch_fw {

namespace {
constexpr std::size_t kMaxMessages = 8;  // more than any command of the drivers here
}

Result<std::unique_ptr<LinuxI2cBus>> LinuxI2cBus::open(std::string_view device_path) {
  std::string path(device_path);
  const int fd = ::open(path.c_str(), O_RDWR | O_CLOEXEC);
  if (fd < 0) {
    const int e = errno;
    const ErrorCode code = e == ENOENT ? ErrorCode::kNotFound : ErrorCode::kIo;
    std::string hint =
        e == ENOENT ? " (is the bus enabled and i2c-dev loaded: modprobe i2c-dev?)" : "";
    return make_error(code, "i2c device " + path + ": " + std::strerror(e) + hint);
  }
  unsigned long funcs = 0;
  if (ioctl(fd, I2C_FUNCS, &funcs) < 0 || (funcs & I2C_FUNC_I2C) == 0) {
    ::close(fd);
    return make_error(ErrorCode::kIo,
                      "i2c device " + path + " does not support plain I2C transfers (I2C_RDWR)");
  }
  return std::unique_ptr<LinuxI2cBus>(new LinuxI2cBus(fd, std::move(path)));
}

LinuxI2cBus::~LinuxI2cBus() {
  if (fd_ >= 0) ::close(fd_);
}

Status LinuxI2cBus::transfer(std::span<I2cMessage> messages) {
  if (messages.empty() || messages.size() > kMaxMessages) {
    return make_error(ErrorCode::kInvalidArgument,
                      "i2c transfer of " + std::to_string(messages.size()) + " messages (1.." +
                          std::to_string(kMaxMessages) + ")");
  }
  std::array<i2c_msg, kMaxMessages> msgs{};
  for (std::size_t i = 0; i < messages.size(); ++i) {
    msgs[i].addr = messages[i].address;
    msgs[i].flags = messages[i].read ? I2C_M_RD : 0;
    msgs[i].len = static_cast<uint16_t>(messages[i].data.size());
    msgs[i].buf = messages[i].data.data();
  }
  i2c_rdwr_ioctl_data data{msgs.data(), static_cast<uint32_t>(messages.size())};
  if (ioctl(fd_, I2C_RDWR, &data) < 0) {
    const int e = errno;
    // ENXIO / EREMOTEIO: no acknowledge from the device.
    const ErrorCode code =
        (e == ENXIO || e == EREMOTEIO) ? ErrorCode::kUnavailable : ErrorCode::kIo;
    return make_error(code, path_ + " transfer at " + format_hex_byte(messages[0].address) + ": " +
                                std::strerror(e));
  }
  return Status::Ok();
}

std::string format_hex_byte(unsigned value) {
  char buf[8];
  std::snprintf(buf, sizeof buf, "0x%02X", value & 0xFFu);
  return buf;
}

Status i2c_write(I2cBus& bus, uint8_t address, std::span<const uint8_t> out) {
  I2cMessage m{address, false, {const_cast<uint8_t*>(out.data()), out.size()}};
  return bus.transfer({&m, 1});
}

Status i2c_write_read(I2cBus& bus, uint8_t address, std::span<const uint8_t> out,
                      std::span<uint8_t> in) {
  std::array<I2cMessage, 2> m{
      I2cMessage{address, false, {const_cast<uint8_t*>(out.data()), out.size()}},
      I2cMessage{address, true, in}};
  return bus.transfer(m);
}

}  // namespace skinbus::patch_fw
