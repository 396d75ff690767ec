// The body map's reports (`skinbus-bench calibration | fk`). Each prints a Markdown table on
// standard output (progress on standard error), writes the CSV and plot its arguments name, and
// returns what went wrong as a Status.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "skinbus/common/result.h"

namespace skinbus::body_map_bench {

// Patch pose calibration on simulated sessions: pose error and solve time per patch against
// touches per patch and probe noise.
struct CalibrationArgs {
  std::string robot;  // URDF tiled by the default humanoid layout (required)
  std::vector<int> touches = {10, 20, 30, 60};
  std::vector<double> noises = {0.2, 0.5, 1.0};
  int sessions = 30;
  double estimate_noise = 0.5, depth_noise = 0.1, outliers = 0.1;
  double position_error = 20, rotation_error = 30;
  bool base_frame = false;
  uint64_t seed = 1;
  std::string csv, plot;
};

Status bench_calibration(const CalibrationArgs& a);

// Forward kinematics of every link of the robot in `urdf_path`: median time of `calls` calls.
Status bench_fk(const std::string& urdf_path, int calls);

}  // namespace skinbus::body_map_bench
