// skinbus/patch_fw/sensor_array.h: the patch's 16 MLX90393s behind a TCA9546A, sampled as one.
//
// A sample is pipelined: every healthy sensor is triggered (SM, grouped by multiplexer
// channel), the array waits one conversion time (and, when data-ready lines are wired, for an
// edge on each of them, at most twice the conversion time: whichever is later), then
// reads every sensor (RM). The sample's timestamp is the middle of the conversion window.
//
// Health, per sensor:
//  * a failed command (NAK, error bit, bad data count, unexpected reset) counts as an I2C error;
//    after `dead_after_failures` failed samples in a row the sensor is faulty: it is skipped
//    (its bit set in the fault mask) and every `retry_interval_samples` samples the array tries
//    to bring it back (reset + configure). A recovered sensor rejoins at once.
//  * identical codes on all three axes for `stuck_after_samples` samples in a row: stuck (a
//    frozen ADC; real noise makes repeats rare), faulty until the codes move again;
//  * a code at its clip limit: saturated (its bit in the saturation mask; the value is valid
//    only as a bound).
// A faulty sensor's field values are 0. Costs per sample: 2 transactions per sensor plus one
// multiplexer write per channel (skipped when the channel is already selected).
#pragma once

#include <array>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "skinbus/bus/protocol.h"
#include "skinbus/patch_fw/clock.h"
#include "skinbus/patch_fw/gpio.h"
#include "skinbus/patch_fw/i2c.h"
#include "skinbus/patch_fw/mlx90393.h"
#include "skinbus/patch_fw/tca9546a.h"

namespace skinbus::patch_fw {

struct SensorSlot {
  int channel = -1;  // multiplexer channel 0..3, -1: on the trunk (no multiplexer)
  uint8_t address = mlx90393::kAddressMin;
};

struct SensorArrayConfig {
  std::vector<SensorSlot> slots;  // sensor i (row-major grid index); bus::kSensorCount entries
  Mlx90393Settings settings;
  int dead_after_failures = 3;
  int retry_interval_samples = 25;
  int stuck_after_samples = 25;
  // I2C timing, for the fastest rate a configuration allows (max_rate_hz).
  uint32_t i2c_clock_hz = 400000;
  uint32_t transaction_overhead_us = 60;  // kernel + controller cost of one I2C_RDWR
};

struct SensorHealth {
  bool faulty = false;  // skipped: dead (failures) or stuck
  bool stuck = false;
  bool saturated = false;  // in the last sample
  uint32_t consecutive_failures = 0;
  uint32_t i2c_errors = 0;  // failed commands since start
  uint32_t recoveries = 0;  // times it came back after being faulty
  uint32_t identical_samples = 0;
  std::string last_error;
};

struct ArraySample {
  uint64_t timestamp_us = 0;  // middle of the conversion window, Clock microseconds
  std::array<double, bus::kChannelCount> field_ut{};  // sensor-major x, y, z
  uint16_t fault_mask = 0;
  uint16_t saturation_mask = 0;
};

class SensorArray {
 public:
  // Not owned, outliving the array: bus, mux (null when every slot is on the trunk), clock,
  // and the data-ready lines (may be empty; each is waited for in turn, see above).
  SensorArray(I2cBus* bus, Tca9546a* mux, Clock* clock, SensorArrayConfig config,
              std::vector<GpioInput*> drdy_lines = {});

  // Resets and configures every sensor. Sensors that fail start faulty (retried later). Errors:
  // the multiplexer does not answer, or no sensor answers at all (names the bus and addresses).
  Status init();
  // Takes one sample (blocks for one conversion time through the Clock).
  Status sample(ArraySample* out);
  // The die temperature of the first healthy sensor that answers, degC
  // (Mlx90393::measure_temperature_c: blocks for one conversion with T, ~2-4 ms). Call between
  // samples. A sensor that fails is counted as in sample() and the next is tried; kUnavailable
  // when none answers.
  Result<double> temperature_c();
  // How long temperature_c() blocks when the first sensor answers, microseconds.
  uint32_t temperature_time_us() const;

  const SensorArrayConfig& config() const { return config_; }
  const SensorHealth& health(int sensor) const { return health_[sensor]; }
  const Mlx90393& driver(int sensor) const { return sensors_[sensor]; }
  uint32_t i2c_errors() const;  // all sensors and the multiplexer
  uint16_t fault_mask() const;
  uint64_t drdy_events() const { return drdy_events_; }
  uint64_t drdy_timeouts() const { return drdy_timeouts_; }

  // Time one sample occupies: triggers, conversion, reads (microseconds), and the fastest
  // sample rate that leaves for a configuration.
  static uint32_t cycle_time_us(const SensorArrayConfig& config);
  static double max_rate_hz(const SensorArrayConfig& config);

 private:
  Status select(int channel);
  bool bring_up(int i);  // reset + configure; true on success
  void fail(int i, const Error& e);

  I2cBus* bus_;
  Tca9546a* mux_;
  Clock* clock_;
  SensorArrayConfig config_;
  std::vector<GpioInput*> drdy_;
  std::vector<Mlx90393> sensors_;
  std::vector<SensorHealth> health_;
  std::vector<std::array<int32_t, 3>> last_code_;
  std::vector<uint8_t> triggered_;
  std::vector<int> order_;  // sensor indices grouped by channel
  uint64_t samples_ = 0;
  uint64_t drdy_events_ = 0, drdy_timeouts_ = 0;
};

}  // namespace skinbus::patch_fw
