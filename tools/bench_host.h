// tools/bench_host.h: the `skinbus-bench host` subcommand (the aggregator's latency and CPU use
// for many patches, some touched).
#pragma once

#include <CLI/CLI.hpp>

#include <string>
#include <vector>

namespace skinbus::tools {

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
  std::string csv;
};

void add_host_options(CLI::App* sub, HostBenchArgs& a);
int bench_host(const HostBenchArgs& a);

}  // namespace skinbus::tools
