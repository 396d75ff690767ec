// The host's reports: `skinbus-bench host` (the aggregator's latency from frame arrival to
// publication and its CPU use for many patches, some touched, driven through host::HostLoop) and
// `skinbus-bench ambient` (a per-patch model's error when the ambient field turns between tare and
// press, with and without common-mode rejection). Each prints Markdown tables on standard output
// and returns what went wrong as a Status.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "skinbus/common/result.h"
#include "skinbus/host/aggregator.h"

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

struct HostBenchArgs {
  std::vector<int> patches = {16, 64, 200};
  std::vector<double> touched_percent = {100, 10, 0};
  double seconds = 5;
  std::string mode = "stream";
  int threads = 1;
  std::string precision = "float32";  // the network runtime's precision
  std::string isa = "avx512";         // the widest instruction set of its kernels
  double max_lag_ms = 100;            // the aggregator's lag bound (0: none)
  int model_delay_us = 0;             // test aid: every estimate this much slower
  // An MCAP file: each configuration's unpaced run is repeated while recorded into it
  // (record/recorder.h; overwritten), and the added time and the recording's size reported.
  std::string record;
  std::string csv;
};

Status bench_host(const HostBenchArgs& a);

// `skinbus-bench refine`: the host's physics refinement on fabricated units, against the network
// alone and the unit's Cramer-Rao bound, and its cost per touched sample (cold and warm starts).
struct RefineBenchArgs {
  std::vector<uint64_t> uids = {0x5B00000000000001ull, 0x5B00000000000002ull,
                                0x5B00000000000003ull};
  int presses = 40;
  int samples_per_press = 24;
  double half_extent_mm = 55;
  uint64_t seed = 1;
  std::string csv;
  std::string design_path;  // "" the built-in design; it must have the bus's 16 sensors
  std::string model_path;   // the network refined from; "" the shipped seed CNN
  // A unit file (skinbus-identify's, e.g. with a field correction) instead of fabricated units:
  // its model (sim::PatchModel::of_unit_file on the design) is both the unit pressed and the one
  // refined on; `uids`' first seeds its noise. "" fabricated units.
  std::string unit_path;
  double basin_check_mm = host::AggregatorOptions{}.refine_basin_check_mm;  // 0: no checks
};

Status bench_refine(const RefineBenchArgs& a);

}  // namespace skinbus::host_bench
