// bench_time.h (internal to the estimators' reports): timing a call, as the reports print it.
#pragma once

#include <chrono>

namespace skinbus::estimators_bench {

using Clock = std::chrono::steady_clock;

// Microseconds since `t0`.
inline double us_since(Clock::time_point t0) {
  return std::chrono::duration<double, std::micro>(Clock::now() - t0).count();
}

}  // namespace skinbus::estimators_bench
