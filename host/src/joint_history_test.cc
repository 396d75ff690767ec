#include "skinbus/host/joint_history.h"

#include <gtest/gtest.h>

#include <cmath>
#include <numbers>
#include <vector>

namespace skinbus::host {
namespace {

using Coverage = JointHistory::Coverage;
using AddResult = JointHistory::AddResult;

TEST(JointHistory, InterpolatesBetweenEntriesPerJoint) {
  JointHistory h(2, {});
  EXPECT_TRUE(h.empty());
  std::vector<double> q(2, -7.0);
  EXPECT_EQ(h.pose_at(1000, q), Coverage::kEmpty);
  EXPECT_EQ(q[0], -7.0) << "an empty history leaves the output alone";
  EXPECT_EQ(h.add(1'000'000, std::vector<double>{0.0, 10.0}), AddResult::kAppended);
  EXPECT_EQ(h.add(1'010'000, std::vector<double>{1.0, 8.0}), AddResult::kAppended);
  EXPECT_EQ(h.add(1'020'000, std::vector<double>{1.5, 8.0}), AddResult::kAppended);
  EXPECT_EQ(h.pose_at(1'002'500, q), Coverage::kInterpolated);
  EXPECT_NEAR(q[0], 0.25, 1e-12);
  EXPECT_NEAR(q[1], 9.5, 1e-12);
  EXPECT_EQ(h.pose_at(1'010'000, q), Coverage::kInterpolated);  // exactly at an entry
  EXPECT_NEAR(q[0], 1.0, 1e-12);
  EXPECT_EQ(h.pose_at(1'015'000, q), Coverage::kInterpolated);
  EXPECT_NEAR(q[0], 1.25, 1e-12);
  EXPECT_NEAR(q[1], 8.0, 1e-12);
  EXPECT_EQ(h.pose_at(1'020'000, q), Coverage::kInterpolated);
  EXPECT_NEAR(q[0], 1.5, 1e-12);
  EXPECT_EQ(h.oldest_us(), 1'000'000u);
  EXPECT_EQ(h.newest_us(), 1'020'000u);
}

TEST(JointHistory, ExtrapolatesALittleAndNamesWhatLiesBeyond) {
  JointHistoryOptions o;
  o.extrapolation_us = 30'000;
  JointHistory h(1, {}, o);
  std::vector<double> q(1);
  h.add(1'000'000, std::vector<double>{0.0});
  // One entry: held within the allowance, named outside it.
  EXPECT_EQ(h.pose_at(1'020'000, q), Coverage::kExtrapolated);
  EXPECT_EQ(q[0], 0.0);
  h.add(1'010'000, std::vector<double>{0.1});                   // 10 rad/s
  EXPECT_EQ(h.pose_at(1'030'000, q), Coverage::kExtrapolated);  // 20 ms past the newest
  EXPECT_NEAR(q[0], 0.3, 1e-12);
  EXPECT_EQ(h.pose_at(990'000, q), Coverage::kExtrapolated);  // 10 ms before the oldest
  EXPECT_NEAR(q[0], -0.1, 1e-12);
  EXPECT_EQ(h.pose_at(1'040'001, q), Coverage::kOutside);  // beyond: the newest, as it is
  EXPECT_NEAR(q[0], 0.1, 1e-12);
  EXPECT_EQ(h.pose_at(969'999, q), Coverage::kOutside);  // before: the oldest
  EXPECT_NEAR(q[0], 0.0, 1e-12);
}

TEST(JointHistory, StampsBeyondDoublePrecisionStillInterpolate) {
  // Host times are microseconds; far beyond 2^53 a double cannot tell neighbours apart.
  const uint64_t base = (uint64_t{1} << 62) + 1;
  JointHistory h(1, {});
  h.add(base, std::vector<double>{0.0});
  h.add(base + 10, std::vector<double>{1.0});
  std::vector<double> q(1);
  EXPECT_EQ(h.pose_at(base + 3, q), Coverage::kInterpolated);
  EXPECT_NEAR(q[0], 0.3, 1e-12);
  EXPECT_EQ(h.pose_at(base - 5, q), Coverage::kExtrapolated);
  EXPECT_NEAR(q[0], -0.5, 1e-12);
}

TEST(JointHistory, WrappingJointsTakeTheShorterWay) {
  JointHistory h(2, {true, false});
  const double a = std::numbers::pi - 0.1, b = -std::numbers::pi + 0.1;
  h.add(0, std::vector<double>{a, a});
  h.add(10'000, std::vector<double>{b, b});
  std::vector<double> q(2);
  h.pose_at(5'000, q);
  // Continuous: through pi (0.1 rad each side), not back through 0.
  EXPECT_NEAR(std::abs(std::remainder(q[0] - std::numbers::pi, 2 * std::numbers::pi)), 0.0, 1e-12);
  EXPECT_NEAR(q[1], 0.0, 1e-12);  // revolute: straight
}

TEST(JointHistory, RefusesOlderStampsMergesEqualOnesAndDropsTheOldestWhenFull) {
  JointHistoryOptions o;
  o.capacity = 4;
  JointHistory h(1, {}, o);
  for (int i = 0; i < 4; ++i) {
    EXPECT_EQ(h.add(1000 * static_cast<uint64_t>(i + 1), std::vector<double>{1.0 * i}),
              AddResult::kAppended);
  }
  EXPECT_EQ(h.add(2500, std::vector<double>{99.0}), AddResult::kOutOfOrder);
  EXPECT_EQ(h.size(), 4u);
  EXPECT_EQ(h.add(4000, std::vector<double>{5.0}), AddResult::kMerged);
  EXPECT_EQ(h.newest()[0], 5.0);
  EXPECT_EQ(h.size(), 4u);
  // Full: the oldest (1000) goes; the ring keeps stamp order across its wrap.
  for (int i = 5; i <= 11; ++i) {
    EXPECT_EQ(h.add(1000 * static_cast<uint64_t>(i), std::vector<double>{10.0 * i}),
              AddResult::kAppended);
    EXPECT_EQ(h.size(), 4u);
    EXPECT_EQ(h.oldest_us(), 1000 * static_cast<uint64_t>(i - 3));
  }
  std::vector<double> q(1);
  for (int i = 8; i < 11; ++i) {
    EXPECT_EQ(h.pose_at(1000 * static_cast<uint64_t>(i) + 500, q), Coverage::kInterpolated);
    EXPECT_NEAR(q[0], 10.0 * i + 5.0, 1e-9) << i;
  }
}

}  // namespace
}  // namespace skinbus::host
