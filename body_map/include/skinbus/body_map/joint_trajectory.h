// skinbus/body_map/joint_trajectory.h: joint positions over time, from a file.
//
// The host aggregator takes joint states from DDS (`rt/joint_states`), from a simulated scene,
// or from a file of this format, so that a replayed log can be placed on a moving robot:
//
//   # comment lines start with '#'
//   time_s,r_shoulder_pitch,r_elbow,...     header: time, then joint names (radians / mm)
//   0.0,0.0,0.5
//   2.0,0.3,0.9
//
// Times are seconds from the start of the run, strictly increasing. Between rows the positions
// are interpolated linearly; before the first and after the last row they hold.
#pragma once

#include <span>
#include <string>
#include <vector>

#include "skinbus/common/result.h"

namespace skinbus::body_map {

struct JointTrajectory {
  std::vector<std::string> names;  // joint names, in column order
  std::vector<double> t_s;         // one per row
  std::vector<double> q;           // rows x names, row-major

  std::size_t rows() const { return t_s.size(); }
  // The positions at `t_s` into `out` (names.size() entries). Requires rows() > 0. A NaN time
  // gives the last row; the result is always finite for a trajectory the reader accepted.
  void sample(double t_s, std::span<double> out) const;
};

// Reads the format above. Errors (kParse, kNotFound) name the file, the line and what is wrong:
// a missing header, a duplicate joint name, a row with the wrong number of fields, a non-finite
// number or one beyond +-1e9 (s, rad or mm), times that do not increase, no rows.
Result<JointTrajectory> parse_joint_trajectory(const std::string& text, const std::string& name);
Result<JointTrajectory> load_joint_trajectory(const std::string& path);

// Writes the format above.
std::string joint_trajectory_to_csv(const JointTrajectory& t);

}  // namespace skinbus::body_map
