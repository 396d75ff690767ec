#include "skinbus/host/ambient.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <random>
#include <vector>

namespace skinbus::host {
namespace {

// 16 sensors: a uniform change everywhere plus a strong local pattern on `touched` sensors.
std::vector<double> sample(const double change[3], int touched, std::mt19937_64& rng) {
  std::normal_distribution<double> noise(0, 0.5);
  std::vector<double> f(48);
  for (int s = 0; s < 16; ++s) {
    for (int a = 0; a < 3; ++a) {
      f[static_cast<std::size_t>(3 * s + a)] =
          change[a] + noise(rng) + (s < touched ? 200.0 * (a + 1) * (s % 2 ? -1 : 1) : 0);
    }
  }
  return f;
}

TEST(CommonMode, RecoversAUniformChangeUnderALocalPress) {
  const uint64_t seed = std::random_device{}();
  std::printf("seed %llu\n", static_cast<unsigned long long>(seed));
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(-100, 100);
  for (auto method : {CommonModeMethod::kMedian, CommonModeMethod::kQuietMean}) {
    for (int trial = 0; trial < 200; ++trial) {
      const double change[3] = {u(rng), u(rng), u(rng)};
      auto f = sample(change, 5, rng);  // 5 of 16 sensors pressed hard
      CommonModeOptions o;
      o.method = method;
      const CommonModeEstimate e = estimate_common_mode(f, {}, o);
      ASSERT_TRUE(e.valid);
      for (int a = 0; a < 3; ++a) EXPECT_NEAR(e.field_ut[a], change[a], 1.0);
      remove_common_mode(f, e);
      EXPECT_NEAR(f[47], 0, 3.0);  // an untouched sensor is back near zero
    }
  }
}

TEST(CommonMode, NoneLeavesTheSampleAlone) {
  std::vector<double> f(48, 7.0);
  CommonModeOptions o;
  o.method = CommonModeMethod::kNone;
  const CommonModeEstimate e = estimate_common_mode(f, {}, o);
  EXPECT_FALSE(e.valid);
  remove_common_mode(f, e);
  EXPECT_EQ(f[0], 7.0);
}

TEST(CommonMode, BadSensorsAreLeftOutAndTooFewGiveNoEstimate) {
  std::vector<double> f(48, 10.0);
  std::vector<uint8_t> ok(48, 1);
  f[0] = std::numeric_limits<double>::quiet_NaN();
  f[3] = 1e6;
  ok[3] = 0;  // dead
  const CommonModeEstimate e = estimate_common_mode(f, ok);
  ASSERT_TRUE(e.valid);
  EXPECT_EQ(e.sensors_used, 7);  // the quiet half of the 14 usable sensors
  for (double v : e.field_ut) EXPECT_DOUBLE_EQ(v, 10.0);
  EXPECT_DOUBLE_EQ(e.magnitude_ut(), std::sqrt(300.0));
  std::fill(ok.begin(), ok.begin() + 33, 0);  // 5 sensors left
  EXPECT_FALSE(estimate_common_mode(f, ok).valid);
  EXPECT_FALSE(estimate_common_mode(std::vector<double>(47, 0.0)).valid);  // not x,y,z triples
}

}  // namespace
}  // namespace skinbus::host
