// skinbus/common/stats.h: the summary statistics every report uses, defined once.
#pragma once

#include <algorithm>
#include <cmath>
#include <vector>

namespace skinbus {

// The q-quantile (0..1) of `v` as the element at floor(q * size) of the sorted values; NaN
// for an empty list.
inline double quantile(std::vector<double> v, double q) {
  if (v.empty()) return std::nan("");
  std::sort(v.begin(), v.end());
  const auto k = static_cast<std::size_t>(q * static_cast<double>(v.size()));
  return v[std::min(v.size() - 1, k)];
}

// The mean of `v`; NaN for an empty list.
inline double mean(const std::vector<double>& v) {
  double s = 0;
  for (double x : v) s += x;
  return v.empty() ? std::nan("") : s / static_cast<double>(v.size());
}

// The median of the first n (>= 1) values at `v`, reordering them in place (no allocation); the
// mean of the two middle values for even n.
inline double median_in_place(double* v, int n) {
  std::nth_element(v, v + n / 2, v + n);
  const double hi = v[n / 2];
  if (n % 2 == 1) return hi;
  return 0.5 * (hi + *std::max_element(v, v + n / 2));
}

}  // namespace skinbus
