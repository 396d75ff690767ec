// skinbus/estimators/evaluation.h: how far estimates are from the truth, per depth bin. One place
// for the numbers every estimator is judged by (the training tool's test metrics, the benchmark).
#pragma once

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
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
  int count = 0;     // estimates that placed a contact: those in the XY means
  int rejected = 0;  // truth rows the estimator gave no estimate for (in no mean)
  // Estimates that found nothing pressed (kEstimateNoContact: the estimate's fields are a fit to
  // noise, and the host never publishes an estimate so flagged). They count in the depth and force
  // means as depth 0 and force 0, what a consumer is told, and in no XY mean: a press the estimator
  // misses costs its whole depth.
  int no_contact = 0;
  int flagged = 0;  // placed estimates with any flag other than kEstimateMasked
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
// estimates are counted, not averaged; those that found nothing pressed are scored as such
// (ErrorStats::no_contact). Statistics of an empty set are NaN, never 0.
ErrorSummary summarize_errors(std::span<const ContactEstimate> estimates, const Truth& truth);

// Which estimate is which press, for several contacts of one sample: the order of `estimates`
// that makes the summed in-plane distance to `presses` least (every order is tried: n! for n
// contacts, n = presses.size() <= kMaxContacts and <= estimates.size(); otherwise false, `match`
// untouched). match[k]: the index into `estimates` of press k's (in order when no sum is
// finite). The summed distance, mm, into `total_mm` when given. A press: anything with u_mm and
// v_mm (sim::Contact, a ContactEstimate).
template <typename Press>
bool match_contacts(std::span<const ContactEstimate> estimates, std::span<const Press> presses,
                    std::span<int> match, double* total_mm = nullptr) {
  const std::size_t n = presses.size();
  if (n > static_cast<std::size_t>(kMaxContacts) || n > estimates.size() || match.size() < n) {
    return false;
  }
  std::array<int, kMaxContacts> order{};
  for (std::size_t k = 0; k < n; ++k) match[k] = order[k] = static_cast<int>(k);
  const auto end = order.begin() + static_cast<std::ptrdiff_t>(n);
  double best = std::numeric_limits<double>::infinity();
  do {
    double sum = 0;
    for (std::size_t k = 0; k < n; ++k) {
      const ContactEstimate& e = estimates[static_cast<std::size_t>(order[k])];
      sum += std::hypot(e.u_mm - presses[k].u_mm, e.v_mm - presses[k].v_mm);
    }
    if (sum < best) {
      best = sum;
      std::copy(order.begin(), end, match.begin());
    }
  } while (std::next_permutation(order.begin(), end));
  if (total_mm != nullptr) *total_mm = n == 0 ? 0.0 : best;
  return true;
}

}  // namespace skinbus::estimators
