// The tools' shared helpers: the fixed-memory latency record, appendf, sleeps that a stop ends.
#include "tool_util.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <random>
#include <vector>

namespace skinbus::tools {
namespace {

TEST(LatencyHistogram, QuantilesWithinOnePercentInFixedMemory) {
  std::mt19937_64 rng(3);
  std::lognormal_distribution<double> dist(6.0, 1.2);  // ~400 us, long tail
  LatencyHistogram h;
  std::vector<double> all;
  for (int i = 0; i < 200000; ++i) {
    const double v = dist(rng);
    h.add(v);
    all.push_back(v);
  }
  EXPECT_EQ(h.count(), all.size());
  EXPECT_EQ(h.max(), *std::max_element(all.begin(), all.end()));
  for (double q : {0.5, 0.9, 0.99}) {
    const double exact = quantile(all, q);
    EXPECT_NEAR(h.quantile(q), exact, 0.011 * exact) << q;
  }
  EXPECT_LE(h.quantile(1.0), h.max());
  LatencyHistogram empty;
  EXPECT_EQ(empty.quantile(0.5), 0);
  LatencyHistogram tiny;  // below 1 us and beyond the last bucket: still counted
  tiny.add(0);
  tiny.add(5e12);
  EXPECT_EQ(tiny.count(), 2u);
  EXPECT_EQ(tiny.max(), 5e12);
}

TEST(ToolUtil, AppendfGrowsPastItsBuffer) {
  std::string s = "x";
  appendf(s, "%d-%s", 7, std::string(2000, 'a').c_str());
  EXPECT_EQ(s.size(), 1 + 2 + 2000u);
  EXPECT_EQ(s.substr(0, 3), "x7-");
}

TEST(ToolUtil, ASleepEndsOnAStop) {
  stop_requested().store(false);
  const auto t0 = std::chrono::steady_clock::now();
  EXPECT_TRUE(sleep_unless_stopped(20000));
  EXPECT_GE(std::chrono::steady_clock::now() - t0, std::chrono::milliseconds(20));
  stop_requested().store(true);
  const auto t1 = std::chrono::steady_clock::now();
  EXPECT_FALSE(sleep_unless_stopped(3'600'000'000ull));  // an hour: returns at once
  EXPECT_LT(std::chrono::steady_clock::now() - t1, std::chrono::milliseconds(100));
  stop_requested().store(false);
}

}  // namespace
}  // namespace skinbus::tools
