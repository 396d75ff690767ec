// The 16-sensor array against 16 emulated MLX90393s behind an emulated TCA9546A, with faults.
#include "skinbus/patch_fw/sensor_array.h"

#include <gtest/gtest.h>

#include <cmath>

#include "skinbus/patch_fw/config.h"
#include "skinbus/patch_sim/emulator.h"
#include "skinbus/patch_sim/fake_gpio.h"
#include "skinbus/sim/rng.h"

namespace skinbus::patch_fw {
namespace {

using patch_sim::EmulatedI2cBus;
using patch_sim::FakeGpioChip;
using patch_sim::FieldSource;

// Sensor i sees (10 i, -5 i, 100 + i) uT plus 1 uT of noise, like a real untouched patch.
class NoisyField final : public FieldSource {
 public:
  sim::Rng rng{42};
  double extra_x[16] = {};
  sim::Vec3<double> field_ut(int i, uint64_t) override {
    return {10.0 * i + extra_x[i] + rng.normal(), -5.0 * i + rng.normal(),
            100.0 + i + rng.normal()};
  }
};

class SensorArrayTest : public ::testing::Test {
 protected:
  void SetUp() override {
    settings = default_settings();
    settings.array.dead_after_failures = 3;
    settings.array.retry_interval_samples = 10;
    settings.array.stuck_after_samples = 8;
    ASSERT_TRUE(bus.add_mux(0x70).ok());
    for (int i = 0; i < 16; ++i) {
      const SensorSlot& s = settings.array.slots[i];
      ASSERT_TRUE(bus.add_mlx90393(s.channel, s.address, i).ok());
    }
  }
  std::unique_ptr<SensorArray> make(std::vector<GpioInput*> drdy = {}) {
    return std::make_unique<SensorArray>(&bus, &mux, &clock, settings.array, drdy);
  }
  PatchNodeSettings settings;
  ManualClock clock{5000};
  NoisyField field;
  EmulatedI2cBus bus{&clock, &field};
  Tca9546a mux{&bus, 0x70, nullptr, &clock};
};

TEST_F(SensorArrayTest, SamplesEverySensorPipelined) {
  auto array = make();
  ASSERT_TRUE(array->init().ok());
  EXPECT_EQ(array->fault_mask(), 0);
  const uint64_t before = bus.transactions();
  const uint64_t t0 = clock.now_us();
  ArraySample s;
  ASSERT_TRUE(array->sample(&s).ok());
  EXPECT_EQ(s.fault_mask, 0);
  for (int i = 0; i < 16; ++i) {
    EXPECT_NEAR(s.field_ut[3 * i], 10.0 * i, 5.0) << i;
    EXPECT_NEAR(s.field_ut[3 * i + 1], -5.0 * i, 5.0) << i;
    EXPECT_NEAR(s.field_ut[3 * i + 2], 100.0 + i, 5.0) << i;
  }
  // Pipelined: one conversion time for all 16, not 16 of them.
  const uint32_t conv = array->driver(0).conversion_time_us();
  EXPECT_EQ(clock.now_us() - t0, conv);
  EXPECT_EQ(s.timestamp_us, t0 + conv / 2);
  // 2 transactions per sensor, one multiplexer write per channel for triggers and reads.
  EXPECT_EQ(bus.transactions() - before, 16u * 2 + 8u);
}

TEST_F(SensorArrayTest, VanishedSensorIsFlaggedOthersKeepPublishingAndItRecovers) {
  auto array = make();
  ASSERT_TRUE(array->init().ok());
  ArraySample s;
  bus.faults(5).nak = true;
  for (int k = 0; k < 3; ++k) {
    ASSERT_TRUE(array->sample(&s).ok());
    EXPECT_EQ(s.fault_mask, 1u << 5) << k;      // no valid reading from it in any of these
    EXPECT_NEAR(s.field_ut[3 * 6], 60.0, 5.0);  // its neighbours are fine
  }
  EXPECT_TRUE(array->health(5).faulty);
  EXPECT_EQ(array->health(5).i2c_errors, 3u);
  EXPECT_NE(array->health(5).last_error.find("NAK"), std::string::npos);
  EXPECT_EQ(s.field_ut[3 * 5], 0.0);
  // Skipped while faulty: no more errors pile up between retries.
  for (int k = 0; k < 5; ++k) ASSERT_TRUE(array->sample(&s).ok());
  EXPECT_LE(array->health(5).i2c_errors, 4u);
  bus.faults(5).nak = false;
  for (int k = 0; k < 10 && array->fault_mask() != 0; ++k) ASSERT_TRUE(array->sample(&s).ok());
  EXPECT_EQ(array->fault_mask(), 0);
  EXPECT_EQ(array->health(5).recoveries, 1u);
  ASSERT_TRUE(array->sample(&s).ok());
  EXPECT_EQ(s.fault_mask, 0);
  EXPECT_NEAR(s.field_ut[3 * 5], 50.0, 5.0);
}

TEST_F(SensorArrayTest, OneErrorBitCostsOneSampleNotTheSensor) {
  auto array = make();
  ASSERT_TRUE(array->init().ok());
  bus.faults(3).error_bit_commands = 1;
  ArraySample s;
  ASSERT_TRUE(array->sample(&s).ok());
  EXPECT_EQ(s.fault_mask, 1u << 3);
  EXPECT_FALSE(array->health(3).faulty);
  ASSERT_TRUE(array->sample(&s).ok());
  EXPECT_EQ(s.fault_mask, 0);
  EXPECT_EQ(array->i2c_errors(), 1u);
}

TEST_F(SensorArrayTest, BrownOutIsReconfiguredAtOnce) {
  settings.array.settings.chip.gain_sel = 4;
  auto array = make();
  ASSERT_TRUE(array->init().ok());
  bus.power_cycle(9);
  ArraySample s;
  ASSERT_TRUE(array->sample(&s).ok());
  EXPECT_EQ(s.fault_mask, 1u << 9);  // the trigger found it reset
  ASSERT_TRUE(array->sample(&s).ok());
  EXPECT_EQ(s.fault_mask, 0);
  EXPECT_EQ((bus.register_value(9, mlx90393::kRegConf1) >> mlx90393::kGainSelShift) & 7u, 4u);
  EXPECT_EQ(array->driver(9).stats().unexpected_resets, 1u);
}

TEST_F(SensorArrayTest, StuckSensorIsFlaggedUntilItMovesAgain) {
  auto array = make();
  ASSERT_TRUE(array->init().ok());
  ArraySample s;
  bus.faults(7).stuck = true;
  int first_flagged = -1;
  for (int k = 0; k < 12; ++k) {
    ASSERT_TRUE(array->sample(&s).ok());
    if (first_flagged < 0 && (s.fault_mask & (1u << 7))) first_flagged = k;
    EXPECT_EQ(s.fault_mask & ~(1u << 7), 0) << "only the stuck sensor is flagged";
  }
  EXPECT_GE(first_flagged, 7);  // needs stuck_after_samples repeats
  EXPECT_LE(first_flagged, 9);
  EXPECT_TRUE(array->health(7).stuck);
  bus.faults(7).stuck = false;
  ASSERT_TRUE(array->sample(&s).ok());
  EXPECT_EQ(s.fault_mask, 0);
  EXPECT_FALSE(array->health(7).stuck);
}

TEST_F(SensorArrayTest, SaturationIsFlaggedPerSensor) {
  auto array = make();
  ASSERT_TRUE(array->init().ok());
  field.extra_x[2] = 1e5;
  ArraySample s;
  ASSERT_TRUE(array->sample(&s).ok());
  EXPECT_EQ(s.saturation_mask, 1u << 2);
  EXPECT_EQ(s.fault_mask, 0);
  EXPECT_TRUE(std::isfinite(s.field_ut[6]));
}

TEST_F(SensorArrayTest, MissingSensorsAtStart) {
  bus.faults(12).nak = true;
  auto array = make();
  ASSERT_TRUE(array->init().ok());
  EXPECT_EQ(array->fault_mask(), 1u << 12);
  for (int i = 0; i < 16; ++i) bus.faults(i).nak = true;
  auto none = make();
  Status st = none->init();
  ASSERT_FALSE(st.ok());
  EXPECT_EQ(st.error().code, ErrorCode::kNotFound);
  EXPECT_NE(st.error().message.find("no MLX90393 answers on emulator"), std::string::npos);
  EXPECT_NE(st.error().message.find("sensor 15 (channel 3, 0x0F)"), std::string::npos);
}

TEST_F(SensorArrayTest, DeadMultiplexerIsAnErrorAtStart) {
  bus.set_mux_nak(true);
  auto array = make();
  Status st = array->init();
  ASSERT_FALSE(st.ok());
  EXPECT_NE(st.error().message.find("multiplexer does not answer"), std::string::npos);
}

TEST_F(SensorArrayTest, DataReadyLinesEndTheWait) {
  FakeGpioChip gpio;
  auto line = gpio.request_input({3, false, true, false}, "drdy");
  ASSERT_TRUE(line.ok());
  auto array = make({line->get()});
  ASSERT_TRUE(array->init().ok());
  ArraySample s;
  gpio.drive(3, true, 1);  // a data-ready edge
  ASSERT_TRUE(array->sample(&s).ok());
  gpio.drive(3, false, 2);
  EXPECT_EQ(array->drdy_events(), 1u);
  ASSERT_TRUE(array->sample(&s).ok());  // no edge: the wait times out, the data is still read
  EXPECT_EQ(array->drdy_timeouts(), 1u);
  EXPECT_EQ(s.fault_mask, 0);
}

TEST_F(SensorArrayTest, CycleTimeFollowsTheConfiguration) {
  SensorArrayConfig c = settings.array;
  const double fast = SensorArray::max_rate_hz(c);
  EXPECT_GT(fast, 41.7);
  c.settings.chip.osr = 3;
  c.settings.chip.dig_filt = 7;
  EXPECT_LT(SensorArray::max_rate_hz(c), 5.0);
  c = settings.array;
  c.i2c_clock_hz = 100000;
  EXPECT_LT(SensorArray::max_rate_hz(c), fast);
}

}  // namespace
}  // namespace skinbus::patch_fw
