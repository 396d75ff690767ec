// The host's reports (`skinbus-bench ambient`): a per-patch model's error when the ambient field
// turns between tare and press, with and without common-mode rejection. Prints Markdown tables on
// standard output and returns what went wrong as a Status.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "skinbus/common/result.h"

namespace skinbus::host_bench {

struct AmbientBenchArgs {
  std::string model_path = "estimators/models/nominal_seed_cnn";
  std::vector<std::string> units = {"nominal", "fabricated"};
  uint64_t uid = 0x5B00000000000001ull;
  int count = 1000;
  double field_ut = 50;       // magnitude of the ambient field
  double max_turn_deg = 180;  // largest turn between tare and press
  double half_extent_mm = 60;
  double min_depth_mm = 0.5, max_depth_mm = 4;
  std::string csv;
};

Status bench_ambient(const AmbientBenchArgs& a);

}  // namespace skinbus::host_bench
