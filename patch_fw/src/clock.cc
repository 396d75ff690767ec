#include "skinbus/patch_fw/clock.h"

#include <cerrno>
#include <ctime>

namespace skinbus::patch_fw {

uint64_t MonotonicClock::now_us() {
  timespec ts{};
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return static_cast<uint64_t>(ts.tv_sec) * 1000000u + static_cast<uint64_t>(ts.tv_nsec) / 1000u;
}

void MonotonicClock::sleep_until_us(uint64_t deadline_us) {
  timespec ts{};
  ts.tv_sec = static_cast<time_t>(deadline_us / 1000000u);
  ts.tv_nsec = static_cast<long>((deadline_us % 1000000u) * 1000u);
  while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, nullptr) == EINTR) {
  }
}

}  // namespace skinbus::patch_fw
