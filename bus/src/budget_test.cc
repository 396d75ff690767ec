#include "skinbus/bus/budget.h"

#include <gtest/gtest.h>

namespace skinbus::bus {
namespace {

TEST(BudgetTest, FrameTimesMatchHandCounts) {
  // Classic, 8 bytes: 98 stuffed bits + 24 stuff bits + 13 trailing = 135 bits at 1 Mbit/s.
  EXPECT_DOUBLE_EQ(frame_time_us(BusTiming{false, 1e6, 1e6}, 8), 135.0);
  // FD, 64 bytes at 1/5 Mbit/s: 34 nominal bits; data 517 + 129 stuff + 25 + 7 fixed = 678.
  EXPECT_NEAR(frame_time_us(BusTiming{true, 1e6, 5e6}, 64), 34.0 + 678.0 / 5.0, 1e-9);
}

TEST(BudgetTest, IdlePatchesAreNearlySilent) {
  const BusTiming fd{true, 1e6, 5e6};
  const BudgetResult stream = compute_budget(fd, PatchTraffic{41.7, 1.0, 1.0}, 64, 0.7);
  const BudgetResult idle = compute_budget(fd, PatchTraffic{41.7, 0.0, 1.0}, 64, 0.7);
  EXPECT_EQ(stream.sample_frames, 2);
  EXPECT_GT(stream.frames_per_s_per_patch / idle.frames_per_s_per_patch, 20.0);
  EXPECT_EQ(idle.max_patches, kNodeMax);
  EXPECT_GT(stream.load_total, 0.7);  // 64 streaming patches do not fit one 1/5 Mbit/s bus
  EXPECT_LT(stream.max_patches, 64);
  const BudgetResult classic =
      compute_budget(BusTiming{false, 1e6, 1e6}, PatchTraffic{41.7, 1.0, 1.0}, 1, 0.7);
  EXPECT_EQ(classic.sample_frames, 18);
  EXPECT_GT(classic.load_per_patch, stream.load_per_patch);
}

}  // namespace
}  // namespace skinbus::bus
