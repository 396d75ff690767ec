// Common-mode (ambient) rejection (ambient.h).
#include "skinbus/host/ambient.h"

#include <algorithm>
#include <array>
#include <cmath>

#include "skinbus/common/stats.h"

namespace skinbus::host {

namespace {

constexpr int kMaxSensors = 64;

}  // namespace

double CommonModeEstimate::magnitude_ut() const {
  return std::sqrt(field_ut[0] * field_ut[0] + field_ut[1] * field_ut[1] +
                   field_ut[2] * field_ut[2]);
}

CommonModeEstimate estimate_common_mode(std::span<const double> field_ut,
                                        std::span<const uint8_t> channel_ok,
                                        const CommonModeOptions& options) {
  CommonModeEstimate e;
  if (options.method == CommonModeMethod::kNone || field_ut.size() % 3 != 0) return e;
  const int sensors = std::min(static_cast<int>(field_ut.size() / 3), kMaxSensors);
  const bool have_mask = channel_ok.size() == field_ut.size();
  std::array<int, kMaxSensors> use{};
  int n = 0;
  for (int s = 0; s < sensors; ++s) {
    bool ok = true;
    for (int a = 0; a < 3; ++a) {
      const std::size_t c = static_cast<std::size_t>(3 * s + a);
      if (!std::isfinite(field_ut[c]) || (have_mask && channel_ok[c] == 0)) ok = false;
    }
    if (ok) use[static_cast<std::size_t>(n++)] = s;
  }
  if (n < std::max(options.min_sensors, 3)) return e;
  std::array<double, kMaxSensors> tmp{};
  double med[3];
  for (int a = 0; a < 3; ++a) {
    for (int i = 0; i < n; ++i) tmp[static_cast<std::size_t>(i)] = field_ut[3 * use[i] + a];
    med[a] = median_in_place(tmp.data(), n);
  }
  if (options.method == CommonModeMethod::kMedian) {
    for (int a = 0; a < 3; ++a) e.field_ut[a] = med[a];
    e.sensors_used = n;
    e.valid = true;
    return e;
  }
  // kQuietMean: the sensors whose vector is closest to the median vector, averaged.
  std::array<std::pair<double, int>, kMaxSensors> dist{};
  for (int i = 0; i < n; ++i) {
    double d2 = 0;
    for (int a = 0; a < 3; ++a) {
      const double d = field_ut[3 * use[i] + a] - med[a];
      d2 += d * d;
    }
    dist[static_cast<std::size_t>(i)] = {d2, use[i]};
  }
  const int k = std::clamp(static_cast<int>(std::lround(options.quiet_fraction * n)), 3, n);
  std::nth_element(dist.begin(), dist.begin() + (k - 1), dist.begin() + n);
  for (int i = 0; i < k; ++i) {
    for (int a = 0; a < 3; ++a) e.field_ut[a] += field_ut[3 * dist[i].second + a];
  }
  for (int a = 0; a < 3; ++a) e.field_ut[a] /= k;
  e.sensors_used = k;
  e.valid = true;
  return e;
}

void remove_common_mode(std::span<double> field_ut, const CommonModeEstimate& e) {
  if (!e.valid) return;
  for (std::size_t c = 0; c + 2 < field_ut.size(); c += 3) {
    for (std::size_t a = 0; a < 3; ++a) field_ut[c + a] -= e.field_ut[a];
  }
}

}  // namespace skinbus::host
