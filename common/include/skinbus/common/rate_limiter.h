// skinbus/common/rate_limiter.h: report bad input loudly but not endlessly.
//
// A stream with a broken sender can produce thousands of bad frames a second; a tool should
// print the first few, then a count of what it held back, and keep going. Costs O(1), no
// allocation.
#pragma once

#include <cstdint>

namespace skinbus {

class RateLimiter {
 public:
  // At most `burst` reports in any `window_us` window.
  RateLimiter(uint32_t burst = 10, uint64_t window_us = 1000000)
      : burst_(burst), window_us_(window_us) {}

  // True if a report at `now_us` may be printed. When it returns true, `suppressed()` holds the
  // number of reports held back since the last one printed (print it, then it resets).
  bool allow(uint64_t now_us) {
    if (now_us - window_start_us_ >= window_us_ || now_us < window_start_us_) {
      window_start_us_ = now_us;
      used_ = 0;
    }
    if (used_ < burst_) {
      ++used_;
      last_suppressed_ = suppressed_;
      suppressed_ = 0;
      return true;
    }
    ++suppressed_;
    ++total_suppressed_;
    return false;
  }
  // Reports held back just before the one allow() last let through.
  uint64_t suppressed() const { return last_suppressed_; }
  // Reports held back and not yet followed by a printed one.
  uint64_t pending_suppressed() const { return suppressed_; }
  uint64_t total_suppressed() const { return total_suppressed_; }

 private:
  uint32_t burst_;
  uint64_t window_us_;
  uint64_t window_start_us_ = 0;
  uint32_t used_ = 0;
  uint64_t suppressed_ = 0;
  uint64_t last_suppressed_ = 0;
  uint64_t total_suppressed_ = 0;
};

}  // namespace skinbus
