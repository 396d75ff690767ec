// skinbus/patch_fw/clock.h: the patch node's time, injectable.
//
// The sampling loop waits for conversions and schedules samples through a Clock, so tests run
// the whole node on a manual clock (no sleeping, exact timestamps) and the daemon on
// CLOCK_MONOTONIC.
#pragma once

#include <cstdint>

namespace skinbus::patch_fw {

class Clock {
 public:
  virtual ~Clock() = default;
  virtual uint64_t now_us() = 0;  // monotonic microseconds
  // Returns when now_us() >= deadline_us (at once if already past).
  virtual void sleep_until_us(uint64_t deadline_us) = 0;
};

// CLOCK_MONOTONIC, sleeping with clock_nanosleep(TIMER_ABSTIME).
class MonotonicClock final : public Clock {
 public:
  uint64_t now_us() override;
  void sleep_until_us(uint64_t deadline_us) override;
};

// Time moves only when told to: sleep_until_us jumps to the deadline.
class ManualClock final : public Clock {
 public:
  explicit ManualClock(uint64_t start_us = 0) : now_us_(start_us) {}
  uint64_t now_us() override { return now_us_; }
  void sleep_until_us(uint64_t deadline_us) override {
    if (deadline_us > now_us_) now_us_ = deadline_us;
  }
  void advance_us(uint64_t dt_us) { now_us_ += dt_us; }

 private:
  uint64_t now_us_;
};

}  // namespace skinbus::patch_fw
