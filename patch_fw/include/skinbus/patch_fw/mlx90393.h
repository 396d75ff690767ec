// skinbus/patch_fw/mlx90393.h: the MLX90393 driver, over any I2cBus.
//
// One Mlx90393 object per chip. Every command is one combined transaction (command write,
// repeated START, status + data read); every status byte is checked:
//  * ERROR set            -> kIo "error bit" (command rejected, or no measurement ready);
//  * RS set unexpectedly  -> the chip reset itself (brown-out): kUnavailable, and the driver
//                            marks itself unconfigured until configure() runs again;
//  * D bits disagreeing with the bytes the command returns -> kIo "data count".
// A NAK comes back from the bus as kUnavailable. The driver counts each kind per chip
// (Mlx90393Stats). It allocates nothing after construction.
//
// Typical use (what SensorArray does for 16 chips, pipelined):
//   reset(); configure(config);                      // once, and again after any error
//   start_single(mlx90393::kAxesXyz); sleep conversion_time_us(); read_measurement(&reading);
#pragma once

#include <cstdint>

#include "skinbus/common/result.h"
#include "skinbus/mlx90393/measurement.h"
#include "skinbus/mlx90393/protocol.h"
#include "skinbus/patch_fw/clock.h"
#include "skinbus/patch_fw/i2c.h"

namespace skinbus::patch_fw {

struct Mlx90393Settings {
  mlx90393::Config chip;                  // gain, resolution, oversampling, digital filter
  bool temperature_compensation = false;  // TCMP_EN (register 0x01 bit 10)
  bool drdy_interrupt = true;             // TRIG_INT = 1: the INT pin signals data ready
};

struct Mlx90393Reading {
  int32_t code[3] = {0, 0, 0};  // raw output codes x, y, z (signed for RES 0/1, else unsigned)
  double field_ut[3] = {0, 0, 0};
  bool saturated[3] = {false, false, false};  // code at its clip limit
};

struct Mlx90393Stats {
  uint32_t naks = 0;               // no acknowledge (absent, vanished)
  uint32_t error_bits = 0;         // status with ERROR set
  uint32_t bad_data_counts = 0;    // D bits disagreed with the command
  uint32_t unexpected_resets = 0;  // RS seen without a reset command
  uint32_t verify_failures = 0;    // register read back differs from what was written
  uint32_t resets = 0;             // reset() calls
  uint32_t measurements = 0;       // readings returned
};

class Mlx90393 {
 public:
  // `bus` and `clock` are not owned and must outlive the driver.
  Mlx90393(I2cBus* bus, uint8_t address, Clock* clock);

  uint8_t address() const { return address_; }
  bool configured() const { return configured_; }
  const Mlx90393Settings& settings() const { return settings_; }
  const Mlx90393Stats& stats() const { return stats_; }

  // EX then RT; waits the chip's reset time and checks the RS bit of the next status.
  Status reset();
  // Writes registers 0x00..0x02 from `settings` (read-modify-write of fields it does not own),
  // reads each back and compares: kIo naming the register on a mismatch. kInvalidArgument
  // for values outside the chip's ranges.
  Status configure(const Mlx90393Settings& settings);
  Status nop();
  Status exit();
  Result<uint16_t> read_register(uint8_t reg);
  Status write_register(uint8_t reg, uint16_t value);
  // SM with the axes nibble (mlx90393::kAxis*).
  Status start_single(uint8_t axes);
  // RM of x, y, z (kAxesXyz); codes converted with the configured sensitivity.
  Status read_measurement(Mlx90393Reading* out);
  // One XYZ conversion, microseconds, for the configured settings.
  uint32_t conversion_time_us() const;
  // The die temperature, degC: SM of T, a wait of the conversion time with T, RM of T, the
  // datasheet's typical transfer (46244 LSB at 25 degC, 45.2 LSB/degC; uncalibrated, a few degC
  // off on a real chip). Errors as the commands'. Blocks for the conversion (~2-4 ms at the
  // default settings); the chip must not be converting already.
  Result<double> measure_temperature_c();
  // One conversion with T (what measure_temperature_c() waits) for `chip`, microseconds.
  static uint32_t temperature_conversion_time_us(const mlx90393::Config& chip);

 private:
  // Sends `cmd` and reads the status and `data_len` data bytes into `in` (1 + data_len).
  Status command(std::span<const uint8_t> cmd, std::span<uint8_t> in, bool expect_reset);
  I2cBus* bus_;
  uint8_t address_;
  Clock* clock_;
  Mlx90393Settings settings_;
  bool configured_ = false;
  Mlx90393Stats stats_;
};

}  // namespace skinbus::patch_fw
