// The MLX90393's datasheet facts: sensitivity, conversion time, output codes, temperature.
#include "skinbus/mlx90393/measurement.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>

namespace skinbus::mlx90393 {
namespace {

TEST(Mlx90393Test, SensitivityConversionTimeQuantisationSaturation) {
  Config c;
  c.gain_sel = 7;
  c.res_xy = 0;
  c.res_z = 0;
  EXPECT_DOUBLE_EQ(sensitivity_xy_ut(c), 0.150);
  EXPECT_DOUBLE_EQ(sensitivity_z_ut(c), 0.242);
  c.gain_sel = 0;
  c.res_xy = 1;
  EXPECT_DOUBLE_EQ(sensitivity_xy_ut(c), 0.751 * 2);
  c.osr = 0;
  c.dig_filt = 0;
  EXPECT_DOUBLE_EQ(conversion_time_us(c), 3 * (67 + 64 * 3));
  c.osr = 1;
  c.dig_filt = 2;
  EXPECT_DOUBLE_EQ(conversion_time_us(c), 3 * (67 + 64 * 2 * 6));
  EXPECT_DOUBLE_EQ(samples_per_axis(c), 12);
  c.temperature = true;
  EXPECT_DOUBLE_EQ(conversion_time_us(c), 3 * (67 + 64 * 2 * 6) + 67 + 192 * 2);

  bool sat = true;
  EXPECT_EQ(output_code(15.0, 0.15, 0, &sat), 100);
  EXPECT_FALSE(sat);
  EXPECT_EQ(output_code(15.07, 0.15, 0, &sat), 100);  // quantised to the LSB
  EXPECT_EQ(output_code(1e6, 0.15, 0, &sat), 32767);
  EXPECT_TRUE(sat);
  EXPECT_EQ(output_code(-1e6, 0.15, 0, &sat), -32767);
  EXPECT_TRUE(sat);
  EXPECT_EQ(output_code(std::nan(""), 0.15, 0, &sat), 0);
  EXPECT_TRUE(sat);
  EXPECT_EQ(output_code(0.0, 0.15, 2, &sat), 32768);  // RES 2: unsigned around 32768
  EXPECT_NEAR(field_ut(output_code(-300.0, 0.3, 2, &sat), 0.3, 2), -300.0, 1e-9);
  EXPECT_EQ(output_code(1e6, 0.15, 3, &sat), 16383 + 16384);
  EXPECT_TRUE(sat);
}

TEST(Mlx90393Test, OutputCodesRoundHalfAwayFromZeroAndSaturate) {
  bool sat = true;
  // Sensitivity 0.5 uT/LSB: fields that fall exactly between two codes.
  EXPECT_EQ(output_code(0.25, 0.5, 0, &sat), 1);
  EXPECT_FALSE(sat);
  EXPECT_EQ(output_code(-0.25, 0.5, 0, &sat), -1);
  EXPECT_EQ(output_code(0.75, 0.5, 0, &sat), 2);
  EXPECT_EQ(output_code(0.2, 0.5, 0, &sat), 0);
  // The last code inside the range is not saturated; one LSB more is.
  EXPECT_EQ(output_code(32767 * 0.5, 0.5, 1, &sat), 32767);
  EXPECT_FALSE(sat);
  EXPECT_EQ(output_code(32768 * 0.5, 0.5, 1, &sat), 32767);
  EXPECT_TRUE(sat);
  EXPECT_EQ(output_code(-32768 * 0.5, 0.5, 2, &sat), 0);  // RES 2 reaches -32768
  EXPECT_FALSE(sat);
  EXPECT_EQ(output_code(-32769 * 0.5, 0.5, 2, &sat), 0);
  EXPECT_TRUE(sat);
  EXPECT_EQ(output_code(-16385 * 0.5, 0.5, 3, &sat), 0);  // RES 3: 15 bits
  EXPECT_TRUE(sat);
  EXPECT_EQ(output_code(std::numeric_limits<double>::infinity(), 0.5, 2, &sat), 32768);
  EXPECT_TRUE(sat);
}

TEST(Mlx90393Test, CodeWordsRoundTrip) {
  EXPECT_EQ(code_word(-1), 0xFFFF);
  EXPECT_EQ(code_word(-32767), 0x8001);
  EXPECT_EQ(code_from_word(0xFFFF, 0), -1);
  EXPECT_EQ(code_from_word(0x8001, 1), -32767);
  EXPECT_EQ(code_from_word(0xFFFF, 2), 65535);
  EXPECT_EQ(code_from_word(0x8000, 3), 32768);
  for (uint8_t res = 0; res <= 3; ++res) {
    for (double f : {-1e9, -1234.5, -0.3, 0.0, 0.3, 1234.5, 1e9}) {
      bool sat = false;
      const int32_t code = output_code(f, 0.15, res, &sat);
      EXPECT_EQ(code_from_word(code_word(code), res), code) << int{res} << " " << f;
    }
  }
}

TEST(Mlx90393Test, ConfigRangesAndClipLimits) {
  EXPECT_TRUE(config_valid(Config{}));
  EXPECT_TRUE(config_valid(Config{0, 3, 3, 3, 7, true}));
  EXPECT_FALSE(config_valid(Config{8, 0, 0, 0, 0, false}));
  EXPECT_FALSE(config_valid(Config{7, 4, 0, 0, 0, false}));
  EXPECT_FALSE(config_valid(Config{7, 0, 4, 0, 0, false}));
  EXPECT_FALSE(config_valid(Config{7, 0, 0, 4, 0, false}));
  EXPECT_FALSE(config_valid(Config{7, 0, 0, 0, 8, false}));
  // Every saturated code sits at a limit; one LSB inside does not.
  for (uint8_t res = 0; res <= 3; ++res) {
    bool sat = false;
    EXPECT_TRUE(code_at_limit(output_code(1e9, 0.15, res, &sat), res)) << int{res};
    EXPECT_TRUE(code_at_limit(output_code(-1e9, 0.15, res, &sat), res)) << int{res};
    EXPECT_FALSE(code_at_limit(output_code(1e9, 0.15, res, &sat) - 1, res)) << int{res};
    EXPECT_FALSE(code_at_limit(output_code(0.0, 0.15, res, &sat), res)) << int{res};
  }
}

TEST(Mlx90393Test, TemperatureTransferRoundTripsAndClamps) {
  EXPECT_EQ(temperature_code(25.0), 46244);
  EXPECT_DOUBLE_EQ(temperature_c_from_code(46244), 25.0);
  for (double t = -40; t <= 125; t += 7.3) {
    EXPECT_NEAR(temperature_c_from_code(temperature_code(t)), t, 0.5 / kTemperatureLsbPerC + 1e-9);
  }
  EXPECT_EQ(temperature_code(1e6), 65535);
  EXPECT_EQ(temperature_code(-1e6), 0);
  EXPECT_EQ(temperature_code(std::nan("")), 0);
}

}  // namespace
}  // namespace skinbus::mlx90393
