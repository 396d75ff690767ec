// Joint trajectories from files (joint_trajectory.h).
#include "skinbus/body_map/joint_trajectory.h"

#include <algorithm>
#include <charconv>
#include <cmath>
#include <set>
#include <sstream>

#include "skinbus/common/csv.h"
#include "skinbus/common/yaml_reader.h"

namespace skinbus::body_map {

namespace {
// Times and positions beyond this are refused: differences of two of them stay finite, so
// interpolation never overflows.
constexpr double kMaxMagnitude = 1e9;
}  // namespace

void JointTrajectory::sample(double t, std::span<double> out) const {
  const std::size_t n = names.size();
  const std::size_t rows_n = rows();
  if (rows_n == 0) return;
  std::size_t hi =
      static_cast<std::size_t>(std::upper_bound(t_s.begin(), t_s.end(), t) - t_s.begin());
  if (hi == 0 || hi >= rows_n) {
    const std::size_t r = hi == 0 ? 0 : rows_n - 1;
    for (std::size_t j = 0; j < n && j < out.size(); ++j) out[j] = q[r * n + j];
    return;
  }
  const std::size_t lo = hi - 1;
  const double w = (t - t_s[lo]) / (t_s[hi] - t_s[lo]);
  for (std::size_t j = 0; j < n && j < out.size(); ++j) {
    out[j] = q[lo * n + j] + w * (q[hi * n + j] - q[lo * n + j]);
  }
}

Result<JointTrajectory> parse_joint_trajectory(const std::string& text, const std::string& name) {
  JointTrajectory t;
  std::istringstream in(text);
  std::string line;
  int line_no = 0;
  bool have_header = false;
  auto fail = [&](const std::string& what) {
    return make_error(ErrorCode::kParse, name + ":" + std::to_string(line_no) + ": " + what);
  };
  while (std::getline(in, line)) {
    ++line_no;
    if (is_csv_comment_or_blank(line)) continue;
    const auto fields = split_csv_fields(line);
    if (!have_header) {
      if (fields.size() < 2 || fields[0] != "time_s") {
        return fail("the header must be 'time_s,<joint>,...'");
      }
      std::set<std::string> seen;
      for (std::size_t i = 1; i < fields.size(); ++i) {
        std::string j(fields[i]);
        if (j.empty()) return fail("empty joint name in column " + std::to_string(i + 1));
        if (!seen.insert(j).second) return fail("joint '" + j + "' named twice");
        t.names.push_back(j);
      }
      have_header = true;
      continue;
    }
    if (fields.size() != t.names.size() + 1) {
      return fail(std::to_string(fields.size()) + " fields, expected " +
                  std::to_string(t.names.size() + 1));
    }
    double v = 0;
    if (!parse_csv_number(fields[0], &v)) return fail("time is not a finite number");
    if (std::abs(v) > kMaxMagnitude) return fail("time beyond +-1e9 s");
    if (!t.t_s.empty() && v <= t.t_s.back()) return fail("times must increase");
    t.t_s.push_back(v);
    for (std::size_t i = 1; i < fields.size(); ++i) {
      if (!parse_csv_number(fields[i], &v)) {
        return fail("joint '" + t.names[i - 1] + "' is not a finite number");
      }
      if (std::abs(v) > kMaxMagnitude) {
        return fail("joint '" + t.names[i - 1] + "' beyond +-1e9 (rad or mm)");
      }
      t.q.push_back(v);
    }
  }
  if (!have_header) return make_error(ErrorCode::kParse, name + ": no header line");
  if (t.t_s.empty()) return make_error(ErrorCode::kParse, name + ": no rows");
  return t;
}

Result<JointTrajectory> load_joint_trajectory(const std::string& path) {
  Result<std::string> text = read_text_file(path, "joint trajectory");
  if (!text.ok()) return text.error();
  return parse_joint_trajectory(*text, path);
}

std::string joint_trajectory_to_csv(const JointTrajectory& t) {
  std::string s = "time_s";
  for (const std::string& n : t.names) s += "," + n;
  s += "\n";
  char buf[32];
  for (std::size_t r = 0; r < t.rows(); ++r) {
    auto put = [&](double x) {
      auto res = std::to_chars(buf, buf + sizeof buf, x);
      s.append(buf, res.ptr);
    };
    put(t.t_s[r]);
    for (std::size_t j = 0; j < t.names.size(); ++j) {
      s += ",";
      put(t.q[r * t.names.size() + j]);
    }
    s += "\n";
  }
  return s;
}

}  // namespace skinbus::body_map
