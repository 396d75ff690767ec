#include "skinbus/common/result.h"

#include <gtest/gtest.h>

#include <memory>

namespace skinbus {
namespace {

Result<int> parse_positive(int x) {
  if (x <= 0)
    return make_error(ErrorCode::kOutOfRange, "x must be positive, got " + std::to_string(x));
  return x;
}

TEST(ResultTest, CarriesValueOrError) {
  auto good = parse_positive(3);
  ASSERT_TRUE(good.ok());
  EXPECT_EQ(*good, 3);
  auto bad = parse_positive(-1);
  ASSERT_FALSE(bad.ok());
  EXPECT_EQ(bad.error().code, ErrorCode::kOutOfRange);
  EXPECT_EQ(bad.error().to_string(), "out_of_range: x must be positive, got -1");
}

TEST(ResultTest, MovesOnlyTypes) {
  Result<std::unique_ptr<int>> r(std::make_unique<int>(7));
  ASSERT_TRUE(r.ok());
  std::unique_ptr<int> p = std::move(r).value();
  EXPECT_EQ(*p, 7);
}

TEST(StatusTest, DefaultIsOk) {
  Status s;
  EXPECT_TRUE(s.ok());
  Status e = make_error(ErrorCode::kIo, "write failed");
  EXPECT_FALSE(e.ok());
  EXPECT_EQ(e.error().code, ErrorCode::kIo);
}

}  // namespace
}  // namespace skinbus

#include "skinbus/common/rate_limiter.h"

namespace skinbus {
namespace {

TEST(RateLimiterTest, BurstThenSuppressThenReport) {
  RateLimiter rl(3, 1000);
  int printed = 0;
  for (int i = 0; i < 10; ++i) printed += rl.allow(100);
  EXPECT_EQ(printed, 3);
  EXPECT_EQ(rl.pending_suppressed(), 7u);
  EXPECT_TRUE(rl.allow(1200));  // next window
  EXPECT_EQ(rl.suppressed(), 7u);
  EXPECT_EQ(rl.pending_suppressed(), 0u);
  EXPECT_EQ(rl.total_suppressed(), 7u);
}

}  // namespace
}  // namespace skinbus
