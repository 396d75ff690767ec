// Fuzzes the joint trajectory reader (body_map/joint_trajectory.h): the input is the file's text.
// Invariants beyond "does not crash", for a trajectory that parses:
// - it has at least one joint and one row, unique non-empty names, rows x names positions,
//   finite strictly increasing times and finite positions;
// - sample() at any time (the rows' times, between them, before and after, NaN, +-Inf, huge
//   and tiny values, and every number of the file read as a time) gives finite positions,
//   each within its joint's range over the rows, and at a row's time that row's (== , so -0
//   and +0 are the same);
// - the CSV it writes parses again to the same names and rows, every number bit for bit.
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <set>
#include <string>
#include <vector>

#include "skinbus/body_map/joint_trajectory.h"

using namespace skinbus;
using namespace skinbus::body_map;

namespace {

[[noreturn]] void fail(const char* what, const JointTrajectory& t, double at = 0) {
  std::fprintf(stderr, "fuzz_joint_trajectory: %s (t = %.17g)\n%s\n", what, at,
               joint_trajectory_to_csv(t).c_str());
  std::abort();
}

bool same_bits(double a, double b) {
  return std::memcmp(&a, &b, sizeof a) == 0;
}

void check_parsed(const JointTrajectory& t) {
  if (t.names.empty() || t.rows() == 0) fail("no joints or no rows", t);
  if (t.q.size() != t.rows() * t.names.size()) fail("positions do not fill rows x joints", t);
  std::set<std::string> seen;
  for (const std::string& n : t.names) {
    if (n.empty() || !seen.insert(n).second) fail("an empty or repeated joint name", t);
  }
  for (std::size_t r = 0; r < t.rows(); ++r) {
    if (!std::isfinite(t.t_s[r])) fail("a non-finite time", t);
    if (r > 0 && !(t.t_s[r] > t.t_s[r - 1])) fail("times do not increase", t);
  }
  for (double v : t.q)
    if (!std::isfinite(v)) fail("a non-finite position", t);
}

void check_sample(const JointTrajectory& t, double at, const std::vector<double>& lo,
                  const std::vector<double>& hi) {
  const std::size_t n = t.names.size();
  std::vector<double> out(n, std::numeric_limits<double>::quiet_NaN());
  t.sample(at, out);
  // At a row's time, exactly that row.
  const auto it = std::find(t.t_s.begin(), t.t_s.end(), at);
  const std::size_t row = static_cast<std::size_t>(it - t.t_s.begin());
  for (std::size_t j = 0; j < n; ++j) {
    if (!std::isfinite(out[j])) fail("sample() gives a non-finite position", t, at);
    // Interpolation stays within the joint's range (up to rounding).
    const double slack =
        4 * std::numeric_limits<double>::epsilon() * std::max(std::abs(lo[j]), std::abs(hi[j]));
    if (out[j] < lo[j] - slack || out[j] > hi[j] + slack) {
      fail("sample() leaves the joint's range over the rows", t, at);
    }
    if (it != t.t_s.end() && !(out[j] == t.q[row * n + j])) {
      fail("sample() at a row's time differs from that row", t, at);
    }
  }
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string text(reinterpret_cast<const char*>(data), size);
  Result<JointTrajectory> parsed = parse_joint_trajectory(text, "fuzz");
  if (!parsed.ok()) return 0;
  const JointTrajectory& t = parsed.value();
  check_parsed(t);

  const std::size_t n = t.names.size();
  std::vector<double> lo(n, std::numeric_limits<double>::infinity());
  std::vector<double> hi(n, -std::numeric_limits<double>::infinity());
  for (std::size_t r = 0; r < t.rows(); ++r) {
    for (std::size_t j = 0; j < n; ++j) {
      lo[j] = std::min(lo[j], t.q[r * n + j]);
      hi[j] = std::max(hi[j], t.q[r * n + j]);
    }
  }
  using limits = std::numeric_limits<double>;
  std::vector<double> times = {limits::quiet_NaN(),
                               limits::infinity(),
                               -limits::infinity(),
                               limits::max(),
                               limits::lowest(),
                               limits::denorm_min(),
                               -limits::denorm_min(),
                               0.0,
                               -0.0,
                               1e300,
                               -1e300};
  for (std::size_t r = 0; r < t.rows(); ++r) {
    times.push_back(t.t_s[r]);
    times.push_back(std::nextafter(t.t_s[r], limits::infinity()));
    times.push_back(std::nextafter(t.t_s[r], -limits::infinity()));
    if (r + 1 < t.rows()) {
      times.push_back(t.t_s[r] / 2 + t.t_s[r + 1] / 2);
      times.push_back(t.t_s[r] + (t.t_s[r + 1] - t.t_s[r]) * 0.25);
    }
  }
  for (double v : t.q) times.push_back(v);
  for (double at : times) check_sample(t, at, lo, hi);

  const std::string printed = joint_trajectory_to_csv(t);
  Result<JointTrajectory> again = parse_joint_trajectory(printed, "fuzz (printed)");
  if (!again.ok()) {
    fail(("the printed trajectory does not parse: " + again.error().to_string()).c_str(), t);
  }
  const JointTrajectory& b = again.value();
  if (b.names != t.names || b.t_s.size() != t.t_s.size() || b.q.size() != t.q.size()) {
    fail("the printed trajectory parses to other names or another shape", t);
  }
  for (std::size_t r = 0; r < t.rows(); ++r)
    if (!same_bits(b.t_s[r], t.t_s[r])) fail("a time differs after printing", t, t.t_s[r]);
  for (std::size_t i = 0; i < t.q.size(); ++i)
    if (!same_bits(b.q[i], t.q[i])) fail("a position differs after printing", t);
  return 0;
}
