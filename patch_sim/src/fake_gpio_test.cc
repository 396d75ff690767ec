#include "skinbus/patch_sim/fake_gpio.h"

#include <gtest/gtest.h>
#include <poll.h>
#include <sys/stat.h>

#include <string>

namespace skinbus::patch_sim {
namespace {

using patch_fw::GpioEdge;
using patch_fw::GpioEvent;

// True when poll() reports `fd` readable right now.
bool readable(int fd) {
  pollfd p{fd, POLLIN, 0};
  return ::poll(&p, 1, 0) == 1 && (p.revents & POLLIN) != 0;
}

bool contains(const std::string& text, const std::string& part) {
  return text.find(part) != std::string::npos;
}

TEST(FakeGpioTest, OutputStartsAtInitialLevel) {
  FakeGpioChip chip("chipA", 8);
  auto low = chip.request_output({.offset = 1, .active_low = false, .initial = false}, "low");
  auto high = chip.request_output({.offset = 2, .active_low = false, .initial = true}, "high");
  ASSERT_TRUE(low.ok() && high.ok());
  EXPECT_FALSE(chip.level(1));
  EXPECT_TRUE(chip.level(2));
  EXPECT_EQ(chip.transitions(2), 0);  // the initial level is not a transition
  EXPECT_EQ(chip.consumer(2), "high");
}

TEST(FakeGpioTest, ActiveLowOutputInvertsAndCountsTransitions) {
  FakeGpioChip chip;
  // Like the multiplexer's RESET: active low, initially inactive (physically high).
  auto reset = chip.request_output({.offset = 5, .active_low = true, .initial = false}, "reset");
  ASSERT_TRUE(reset.ok());
  EXPECT_TRUE(chip.level(5));
  ASSERT_TRUE((*reset)->set(true).ok());  // assert: physically low
  EXPECT_FALSE(chip.level(5));
  ASSERT_TRUE((*reset)->set(true).ok());  // no change, no transition
  ASSERT_TRUE((*reset)->set(false).ok());
  EXPECT_TRUE(chip.level(5));
  EXPECT_EQ(chip.transitions(5), 2);
}

TEST(FakeGpioTest, InputGetReturnsLogicalValue) {
  FakeGpioChip chip;
  auto plain = chip.request_input({.offset = 0, .active_low = false}, "plain");
  auto inverted = chip.request_input({.offset = 1, .active_low = true}, "inverted");
  ASSERT_TRUE(plain.ok() && inverted.ok());
  chip.drive(0, true);
  chip.drive(1, true);
  EXPECT_TRUE(*(*plain)->get());
  EXPECT_FALSE(*(*inverted)->get());
  chip.drive(1, false);
  EXPECT_TRUE(*(*inverted)->get());
}

TEST(FakeGpioTest, RisingEdgesQueueInOrderWithTimestamps) {
  FakeGpioChip chip;
  auto in = chip.request_input({.offset = 3, .rising = true, .falling = false}, "drdy");
  ASSERT_TRUE(in.ok());
  chip.drive(3, true, 100);
  chip.drive(3, true, 150);   // no edge: already high
  chip.drive(3, false, 200);  // falling: not asked for
  chip.drive(3, true, 300);
  GpioEvent ev;
  ASSERT_TRUE(*(*in)->wait_event(0, &ev));
  EXPECT_EQ(ev.edge, GpioEdge::kRising);
  EXPECT_EQ(ev.timestamp_us, 100u);
  ASSERT_TRUE(*(*in)->wait_event(0, &ev));
  EXPECT_EQ(ev.edge, GpioEdge::kRising);
  EXPECT_EQ(ev.timestamp_us, 300u);
  Result<bool> none = (*in)->wait_event(1'000'000, &ev);  // returns at once
  ASSERT_TRUE(none.ok());
  EXPECT_FALSE(*none);
}

TEST(FakeGpioTest, FallingAndBothEdges) {
  FakeGpioChip chip;
  auto falling = chip.request_input({.offset = 0, .rising = false, .falling = true}, "f");
  auto both = chip.request_input({.offset = 1, .rising = true, .falling = true}, "b");
  ASSERT_TRUE(falling.ok() && both.ok());
  for (unsigned line : {0u, 1u}) {
    chip.drive(line, true, 10);
    chip.drive(line, false, 20);
  }
  GpioEvent ev;
  ASSERT_TRUE(*(*falling)->wait_event(0, &ev));
  EXPECT_EQ(ev.edge, GpioEdge::kFalling);
  EXPECT_EQ(ev.timestamp_us, 20u);
  EXPECT_FALSE(*(*falling)->wait_event(0, &ev));
  ASSERT_TRUE(*(*both)->wait_event(0, &ev));
  EXPECT_EQ(ev.edge, GpioEdge::kRising);
  EXPECT_EQ(ev.timestamp_us, 10u);
  ASSERT_TRUE(*(*both)->wait_event(0, &ev));
  EXPECT_EQ(ev.edge, GpioEdge::kFalling);
  EXPECT_EQ(ev.timestamp_us, 20u);
  EXPECT_FALSE(*(*both)->wait_event(0, &ev));
}

TEST(FakeGpioTest, ActiveLowInputReportsLogicalEdges) {
  FakeGpioChip chip;
  chip.drive(4, true);  // idle high before the request
  auto sync = chip.request_input({.offset = 4, .active_low = true, .rising = true}, "sync");
  ASSERT_TRUE(sync.ok());
  chip.drive(4, false, 7);  // physical fall = logical rise: reported
  chip.drive(4, true, 8);   // physical rise = logical fall: not asked for
  GpioEvent ev;
  ASSERT_TRUE(*(*sync)->wait_event(0, &ev));
  EXPECT_EQ(ev.edge, GpioEdge::kRising);
  EXPECT_EQ(ev.timestamp_us, 7u);
  EXPECT_FALSE(*(*sync)->wait_event(0, &ev));
}

TEST(FakeGpioTest, EventFdIsReadableExactlyWhileEventsPend) {
  FakeGpioChip chip;
  auto in = chip.request_input({.offset = 2, .rising = true, .falling = true}, "drdy");
  ASSERT_TRUE(in.ok());
  const int fd = (*in)->event_fd();
  ASSERT_GE(fd, 0);
  EXPECT_FALSE(readable(fd));
  chip.drive(2, true, 1);
  chip.drive(2, false, 2);
  EXPECT_TRUE(readable(fd));
  GpioEvent ev;
  ASSERT_TRUE(*(*in)->wait_event(0, &ev));
  EXPECT_TRUE(readable(fd));  // one still pending
  ASSERT_TRUE(*(*in)->wait_event(0, &ev));
  EXPECT_FALSE(readable(fd));
  chip.drive(2, true, 3);
  EXPECT_TRUE(readable(fd));
}

TEST(FakeGpioTest, EventFdIsClosedOnRelease) {
  FakeGpioChip chip;
  auto in = chip.request_input({.offset = 2}, "drdy");
  ASSERT_TRUE(in.ok());
  const int fd = (*in)->event_fd();
  struct stat st {};
  ASSERT_EQ(::fstat(fd, &st), 0);
  in->reset();
  EXPECT_NE(::fstat(fd, &st), 0);  // nothing else opened a descriptor in between
}

TEST(FakeGpioTest, InputWithoutEdgesHasNoEventFd) {
  FakeGpioChip chip("chipB");
  auto in = chip.request_input({.offset = 6, .rising = false, .falling = false}, "level");
  ASSERT_TRUE(in.ok());
  EXPECT_EQ((*in)->event_fd(), -1);
  chip.drive(6, true);
  EXPECT_TRUE(*(*in)->get());
  GpioEvent ev;
  Result<bool> r = (*in)->wait_event(0, &ev);
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().code, ErrorCode::kInvalidArgument);
}

TEST(FakeGpioTest, DoubleRequestIsUnavailableUntilReleased) {
  FakeGpioChip chip("chipC", 8);
  auto first = chip.request_output({.offset = 3}, "led");
  ASSERT_TRUE(first.ok());
  auto second = chip.request_input({.offset = 3}, "sync");
  ASSERT_FALSE(second.ok());
  EXPECT_EQ(second.error().code, ErrorCode::kUnavailable);
  EXPECT_TRUE(contains(second.error().message, "\"led\"")) << second.error().message;
  EXPECT_TRUE(contains(second.error().message, "line 3 of chipC")) << second.error().message;
  EXPECT_EQ(chip.consumer(3), "led");

  first->reset();  // releases the line
  EXPECT_EQ(chip.consumer(3), "");
  auto again = chip.request_input({.offset = 3}, "sync");
  ASSERT_TRUE(again.ok()) << again.error().message;
  EXPECT_EQ(chip.consumer(3), "sync");
}

TEST(FakeGpioTest, OffsetPastTheChipIsOutOfRange) {
  FakeGpioChip chip("chipD", 4);
  EXPECT_EQ(chip.line_count(), 4u);
  auto out = chip.request_output({.offset = 4}, "x");
  ASSERT_FALSE(out.ok());
  EXPECT_EQ(out.error().code, ErrorCode::kOutOfRange);
  EXPECT_TRUE(contains(out.error().message, "line 4 of chipD")) << out.error().message;
  auto in = chip.request_input({.offset = 100}, "x");
  ASSERT_FALSE(in.ok());
  EXPECT_EQ(in.error().code, ErrorCode::kOutOfRange);
  EXPECT_TRUE(chip.request_input({.offset = 3}, "x").ok());  // the last line is fine
}

TEST(FakeGpioTest, FailNextFailsExactlyOneOperation) {
  FakeGpioChip chip("chipE");
  auto out = chip.request_output({.offset = 1}, "led");
  auto in = chip.request_input({.offset = 2, .rising = true}, "drdy");
  ASSERT_TRUE(out.ok() && in.ok());

  chip.fail_next(1);
  Status s = (*out)->set(true);
  ASSERT_FALSE(s.ok());
  EXPECT_EQ(s.error().code, ErrorCode::kIo);
  EXPECT_EQ(s.error().message, "line 1 of chipE: I/O error (injected)");
  EXPECT_FALSE(chip.level(1));  // the failed set did not drive the line
  EXPECT_TRUE((*out)->set(true).ok());
  EXPECT_TRUE(chip.level(1));

  chip.fail_next(2);
  Result<bool> g = (*in)->get();
  ASSERT_FALSE(g.ok());
  EXPECT_EQ(g.error().code, ErrorCode::kIo);
  EXPECT_TRUE((*in)->get().ok());

  chip.drive(2, true, 5);
  chip.fail_next(2);
  GpioEvent ev;
  Result<bool> w = (*in)->wait_event(0, &ev);
  ASSERT_FALSE(w.ok());
  EXPECT_EQ(w.error().code, ErrorCode::kIo);
  ASSERT_TRUE(*(*in)->wait_event(0, &ev));  // the event was kept
  EXPECT_EQ(ev.timestamp_us, 5u);
}

}  // namespace
}  // namespace skinbus::patch_sim
