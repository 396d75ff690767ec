// tools/bench_models.h: the `skinbus-bench models` subcommand (estimators: run time and error on
// one test split, against the CRLB).
#pragma once

#include <CLI/CLI.hpp>

#include <cstdint>
#include <string>
#include <vector>

namespace skinbus::tools {

struct ModelsBenchArgs {
  std::string test_path;                 // off-grid test split (skinbus-dataset --plan random-test)
  std::string train_path;                // training presses (nearest-neighbour table); optional
  std::vector<std::string> model_paths;  // trained networks
  std::string reference_path;            // model run through LibTorch (default: first width-1 CNN)
  bool bf16 = true;                      // add reduced-precision rows for CNNs
  bool physics = true;                   // add the physics LM row (nominal unit model)
  int latency_samples = 300;             // samples timed at batch 1
  int max_test = 2000;                   // test rows used
  std::string csv, errors_csv, plot;     // outputs
};

void add_models_options(CLI::App* sub, ModelsBenchArgs& a);
int bench_models(const ModelsBenchArgs& a);

}  // namespace skinbus::tools
