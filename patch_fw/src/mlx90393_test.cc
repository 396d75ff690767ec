// The MLX90393 and TCA9546A drivers against the chip emulators, at the I2C transaction level.
#include "skinbus/patch_fw/mlx90393.h"

#include <gtest/gtest.h>

#include <cmath>

#include "skinbus/patch_fw/tca9546a.h"
#include "skinbus/patch_sim/emulator.h"

namespace skinbus::patch_fw {
namespace {

namespace m = mlx90393;
using patch_sim::EmulatedI2cBus;
using patch_sim::FieldSource;

class FixedField final : public FieldSource {
 public:
  sim::Vec3<double> field[4] = {{12.3, -45.6, 78.9}, {-300, 200, -100}, {0, 0, 0}, {0, 0, 0}};
  sim::Vec3<double> field_ut(int sensor, uint64_t) override { return field[sensor]; }
  double temperature_c(int, uint64_t) override { return temperature; }
  double temperature = 25.0;
};

class DriverTest : public ::testing::Test {
 protected:
  void SetUp() override {
    ASSERT_TRUE(bus.add_mux(0x70).ok());
    ASSERT_TRUE(bus.add_mlx90393(0, 0x0C, 0).ok());
    ASSERT_TRUE(bus.add_mlx90393(1, 0x0C, 1).ok());
    ASSERT_TRUE(mux.select(0).ok());
  }
  Status measure(Mlx90393& d, Mlx90393Reading* r) {
    if (Status st = d.start_single(m::kAxesXyz); !st.ok()) return st;
    clock.advance_us(d.conversion_time_us());
    return d.read_measurement(r);
  }
  ManualClock clock{1000};
  FixedField field;
  EmulatedI2cBus bus{&clock, &field};
  Tca9546a mux{&bus, 0x70, nullptr, &clock};
  Mlx90393 chip{&bus, 0x0C, &clock};
};

TEST_F(DriverTest, ResetConfigureMeasure) {
  ASSERT_TRUE(chip.reset().ok());
  Mlx90393Settings s;
  s.chip.gain_sel = 5;
  s.chip.osr = 2;
  s.chip.dig_filt = 3;
  s.chip.res_z = 1;
  ASSERT_TRUE(chip.configure(s).ok());
  EXPECT_EQ(bus.register_value(0, m::kRegConf1), (5u << m::kGainSelShift) | m::kHallconfDefault);
  EXPECT_EQ(bus.register_value(0, m::kRegConf3),
            (2u << m::kOsrShift) | (3u << m::kDigFiltShift) | (1u << m::kResZShift));
  EXPECT_TRUE(bus.register_value(0, m::kRegConf2) & (1u << m::kTrigIntBit));
  EXPECT_EQ(chip.conversion_time_us(),
            static_cast<uint32_t>(std::ceil(m::conversion_time_us(s.chip))));
  Mlx90393Reading r;
  ASSERT_TRUE(measure(chip, &r).ok());
  // The reading is the field quantised to the configured sensitivity.
  const double sxy = m::sensitivity_xy_ut(s.chip);
  const double sz = m::sensitivity_z_ut(s.chip);
  EXPECT_NEAR(r.field_ut[0], 12.3, sxy / 2 + 1e-9);
  EXPECT_NEAR(r.field_ut[1], -45.6, sxy / 2 + 1e-9);
  EXPECT_NEAR(r.field_ut[2], 78.9, sz / 2 + 1e-9);
  EXPECT_EQ(r.code[1], static_cast<int32_t>(std::lround(-45.6 / sxy)));
  EXPECT_FALSE(r.saturated[0] || r.saturated[1] || r.saturated[2]);
  EXPECT_EQ(chip.stats().measurements, 1u);
}

TEST_F(DriverTest, UnsignedResolutionAndSaturation) {
  ASSERT_TRUE(chip.reset().ok());
  Mlx90393Settings s;
  s.chip.res_xy = 2;  // unsigned codes around 32768
  ASSERT_TRUE(chip.configure(s).ok());
  field.field[0] = {-20.0, 1e6, 3.0};  // y far beyond the range
  Mlx90393Reading r;
  ASSERT_TRUE(measure(chip, &r).ok());
  EXPECT_GT(r.code[0], 30000);  // unsigned, below the 32768 zero
  EXPECT_NEAR(r.field_ut[0], -20.0, m::sensitivity_xy_ut(s.chip));
  EXPECT_TRUE(r.saturated[1]);
  EXPECT_FALSE(r.saturated[0]);
  EXPECT_FALSE(r.saturated[2]);
}

TEST_F(DriverTest, ReadingTooEarlyIsTheErrorBit) {
  ASSERT_TRUE(chip.reset().ok());
  ASSERT_TRUE(chip.configure({}).ok());
  ASSERT_TRUE(chip.start_single(m::kAxesXyz).ok());
  Mlx90393Reading r;
  Status st = chip.read_measurement(&r);
  ASSERT_FALSE(st.ok());
  EXPECT_EQ(st.error().code, ErrorCode::kIo);
  EXPECT_NE(st.error().message.find("error bit"), std::string::npos);
  EXPECT_EQ(chip.stats().error_bits, 1u);
  clock.advance_us(chip.conversion_time_us());
  EXPECT_TRUE(chip.read_measurement(&r).ok());
}

// The die temperature through a T-only single measurement: the chip's code read back with the
// datasheet's transfer, after the conversion time with T (the emulator refuses an early read).
TEST_F(DriverTest, MeasuresTheDieTemperature) {
  ASSERT_TRUE(chip.reset().ok());
  Mlx90393Settings s;
  s.chip.osr = 2;
  ASSERT_TRUE(chip.configure(s).ok());
  for (double t : {25.0, -12.3, 61.7}) {
    field.temperature = t;
    const uint64_t before = clock.now_us();
    Result<double> got = chip.measure_temperature_c();
    ASSERT_TRUE(got.ok()) << got.error().to_string();
    EXPECT_NEAR(*got, t, 0.5 / m::kTemperatureLsbPerC + 1e-9) << t;
    m::Config with_t = s.chip;
    with_t.temperature = true;
    EXPECT_GE(clock.now_us() - before, m::conversion_time_us(with_t));
  }
  // A field measurement still works after it.
  Mlx90393Reading r;
  EXPECT_TRUE(measure(chip, &r).ok());
  bus.faults(0).nak = true;
  Result<double> gone = chip.measure_temperature_c();
  ASSERT_FALSE(gone.ok());
  EXPECT_EQ(gone.error().code, ErrorCode::kUnavailable);
}

TEST_F(DriverTest, NakWhenTheChipVanishes) {
  ASSERT_TRUE(chip.reset().ok());
  ASSERT_TRUE(chip.configure({}).ok());
  bus.faults(0).nak = true;
  Mlx90393Reading r;
  Status st = measure(chip, &r);
  ASSERT_FALSE(st.ok());
  EXPECT_EQ(st.error().code, ErrorCode::kUnavailable);
  EXPECT_NE(st.error().message.find("0x0C"), std::string::npos);
  EXPECT_EQ(chip.stats().naks, 1u);
  bus.faults(0).nak = false;
  EXPECT_TRUE(measure(chip, &r).ok());
}

TEST_F(DriverTest, UnexpectedResetIsDetectedAndNeedsConfiguration) {
  ASSERT_TRUE(chip.reset().ok());
  Mlx90393Settings s;
  s.chip.gain_sel = 3;
  ASSERT_TRUE(chip.configure(s).ok());
  bus.power_cycle(0);  // brown-out: registers back to defaults
  Mlx90393Reading r;
  Status st = measure(chip, &r);
  ASSERT_FALSE(st.ok());
  EXPECT_NE(st.error().message.find("reset itself"), std::string::npos);
  EXPECT_FALSE(chip.configured());
  EXPECT_EQ(chip.stats().unexpected_resets, 1u);
  ASSERT_TRUE(chip.reset().ok());
  ASSERT_TRUE(chip.configure(s).ok());
  EXPECT_EQ((bus.register_value(0, m::kRegConf1) >> m::kGainSelShift) & 7u, 3u);
  EXPECT_TRUE(measure(chip, &r).ok());
}

TEST_F(DriverTest, WrongDataCountAndErrorBitsAreCounted) {
  ASSERT_TRUE(chip.reset().ok());
  ASSERT_TRUE(chip.configure({}).ok());
  bus.faults(0).wrong_data_count = 1;
  Mlx90393Reading r;
  Status st = measure(chip, &r);
  ASSERT_FALSE(st.ok());
  EXPECT_NE(st.error().message.find("data bytes"), std::string::npos);
  EXPECT_EQ(chip.stats().bad_data_counts, 1u);
  bus.faults(0).error_bit_commands = 2;
  EXPECT_FALSE(chip.nop().ok());
  EXPECT_FALSE(chip.nop().ok());
  EXPECT_TRUE(chip.nop().ok());
  EXPECT_EQ(chip.stats().error_bits, 2u);
}

TEST_F(DriverTest, RegisterVerificationCatchesACorruptBus) {
  ASSERT_TRUE(chip.reset().ok());
  bus.faults(0).corrupt_register_reads = true;
  Status st = chip.configure({});
  ASSERT_FALSE(st.ok());
  EXPECT_NE(st.error().message.find("reads back"), std::string::npos);
  EXPECT_EQ(chip.stats().verify_failures, 1u);
  EXPECT_FALSE(chip.configured());
}

TEST_F(DriverTest, RejectsAnOutOfRangeConfiguration) {
  Mlx90393Settings s;
  s.chip.osr = 4;
  Status st = chip.configure(s);
  ASSERT_FALSE(st.ok());
  EXPECT_EQ(st.error().code, ErrorCode::kInvalidArgument);
}

TEST_F(DriverTest, MuxSelectsWhichChipAnswers) {
  Mlx90393 other(&bus, 0x0C, &clock);  // same address, channel 1
  ASSERT_TRUE(chip.reset().ok());
  ASSERT_TRUE(chip.configure({}).ok());
  ASSERT_TRUE(mux.select(1).ok());
  ASSERT_TRUE(other.reset().ok());
  ASSERT_TRUE(other.configure({}).ok());
  Mlx90393Reading r;
  ASSERT_TRUE(measure(other, &r).ok());
  EXPECT_NEAR(r.field_ut[0], -300, 0.2);  // sensor 1's field
  ASSERT_TRUE(mux.select(0).ok());
  ASSERT_TRUE(measure(chip, &r).ok());
  EXPECT_NEAR(r.field_ut[0], 12.3, 0.2);
  // Selecting the same channel again costs no transaction.
  const uint32_t writes = mux.writes();
  ASSERT_TRUE(mux.select(0).ok());
  EXPECT_EQ(mux.writes(), writes);
  Result<uint8_t> ctl = mux.read_control();
  ASSERT_TRUE(ctl.ok());
  EXPECT_EQ(*ctl, 0x01);
}

TEST_F(DriverTest, MuxErrorsAndReset) {
  bus.set_mux_nak(true);
  Status st = mux.select(2);
  ASSERT_FALSE(st.ok());
  EXPECT_EQ(st.error().code, ErrorCode::kUnavailable);
  EXPECT_NE(st.error().message.find("TCA9546A at 0x70"), std::string::npos);
  EXPECT_EQ(mux.errors(), 1u);
  bus.set_mux_nak(false);
  ASSERT_TRUE(mux.select(2).ok());
  EXPECT_EQ(bus.mux_control(), 0x04);
  EXPECT_FALSE(mux.select(4).ok());
  ASSERT_TRUE(mux.reset().ok());  // no reset line: writes 0
  EXPECT_EQ(bus.mux_control(), 0x00);
}

}  // namespace
}  // namespace skinbus::patch_fw
