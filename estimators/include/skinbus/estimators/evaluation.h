// skinbus/estimators/evaluation.h: how far estimates are from the truth, per depth bin. One place
// for the numbers every estimator is judged by (the training tool's test metrics, the benchmark).
#pragma once

#include <array>
#include <span>
#include <string>

#include "skinbus/estimators/estimate.h"

namespace skinbus::estimators {

// The depth bins of the reports (mm): [0, 0.5), [0.5, 1), [1, 2), [2, 3), [3, 4]; deeper presses
// count in the last bin.
inline constexpr std::array<double, 6> kDepthBinEdgesMm = {0, 0.5, 1, 2, 3, 4};
inline constexpr int kDepthBins = 5;
std::string depth_bin_name(int bin);  // "0-0.5", ...
int depth_bin(double depth_mm);       // -1 for depth < 0

struct ErrorStats {
  int count = 0;     // estimates compared
  int rejected = 0;  // truth rows the estimator gave no estimate for (not in the means)
  int flagged = 0;   // estimates with any flag other than kEstimateMasked
  double xy_mean_mm = 0, xy_p95_mm = 0, depth_mean_mm = 0, force_mean_n = 0;
};

struct ErrorSummary {
  ErrorStats all;
  std::array<ErrorStats, kDepthBins> bins;
};

struct Truth {
  std::span<const double> u_mm, v_mm, depth_mm, force_n;  // one entry per estimate
};

// Mean XY error over the bins from `first_bin` on (weighted by their counts); with the default,
// the presses at least 1 mm deep: those an estimator can localise. NaN when they are empty.
double xy_mean_from_bin(const ErrorSummary& s, int first_bin = 2);

// Compares `estimates` with `truth` (same length; only the common length is compared). Rejected
// estimates are counted, not averaged. Statistics of an empty set are NaN, never 0.
ErrorSummary summarize_errors(std::span<const ContactEstimate> estimates, const Truth& truth);

}  // namespace skinbus::estimators
