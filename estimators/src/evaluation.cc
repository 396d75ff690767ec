#include "skinbus/estimators/evaluation.h"

#include <algorithm>
#include <cmath>
#include <vector>

#include "skinbus/common/stats.h"

namespace skinbus::estimators {
namespace {

struct Accumulator {
  std::vector<double> xy;
  double depth = 0, force = 0;
  int rejected = 0, no_contact = 0, flagged = 0;

  ErrorStats finish() {
    ErrorStats s;
    s.count = static_cast<int>(xy.size());
    s.rejected = rejected;
    s.no_contact = no_contact;
    s.flagged = flagged;
    const double scored = static_cast<double>(xy.size()) + no_contact;
    // Nothing to average is not a perfect score.
    s.depth_mean_mm = scored > 0 ? depth / scored : std::nan("");
    s.force_mean_n = scored > 0 ? force / scored : std::nan("");
    if (xy.empty()) {
      s.xy_mean_mm = s.xy_p95_mm = std::nan("");
      return s;
    }
    s.xy_mean_mm = mean(xy);
    s.xy_p95_mm = quantile(std::move(xy), 0.95);
    return s;
  }
};

}  // namespace

std::string depth_bin_name(int bin) {
  static const char* kNames[kDepthBins] = {"0-0.5", "0.5-1", "1-2", "2-3", "3-4"};
  return bin >= 0 && bin < kDepthBins ? kNames[bin] : "none";
}

int depth_bin(double depth_mm) {
  if (!(depth_mm >= 0)) return -1;
  for (int b = 0; b < kDepthBins - 1; ++b) {
    if (depth_mm < kDepthBinEdgesMm[static_cast<std::size_t>(b + 1)]) return b;
  }
  return kDepthBins - 1;
}

double xy_mean_from_bin(const ErrorSummary& s, int first_bin) {
  double sum = 0;
  int n = 0;
  for (int b = std::max(first_bin, 0); b < kDepthBins; ++b) {
    const ErrorStats& st = s.bins[static_cast<std::size_t>(b)];
    if (st.count == 0) continue;  // its mean is NaN
    sum += st.xy_mean_mm * st.count;
    n += st.count;
  }
  return n > 0 ? sum / n : std::nan("");
}

ErrorSummary summarize_errors(std::span<const ContactEstimate> estimates, const Truth& truth) {
  Accumulator all;
  std::array<Accumulator, kDepthBins> bins;
  const std::size_t n = std::min({estimates.size(), truth.u_mm.size(), truth.v_mm.size(),
                                  truth.depth_mm.size(), truth.force_n.size()});
  for (std::size_t i = 0; i < n; ++i) {
    const ContactEstimate& e = estimates[i];
    const int b = depth_bin(truth.depth_mm[i]);
    Accumulator* targets[2] = {&all, b >= 0 ? &bins[static_cast<std::size_t>(b)] : nullptr};
    for (Accumulator* a : targets) {
      if (a == nullptr) continue;
      if (!e.valid()) {
        ++a->rejected;
        continue;
      }
      if ((e.flags & kEstimateNoContact) != 0) {
        ++a->no_contact;
        a->depth += std::fabs(truth.depth_mm[i]);
        a->force += std::fabs(truth.force_n[i]);
        continue;
      }
      if ((e.flags & ~static_cast<uint32_t>(kEstimateMasked)) != 0) ++a->flagged;
      a->xy.push_back(std::hypot(e.u_mm - truth.u_mm[i], e.v_mm - truth.v_mm[i]));
      a->depth += std::fabs(e.depth_mm - truth.depth_mm[i]);
      a->force += std::fabs(e.force_n - truth.force_n[i]);
    }
  }
  ErrorSummary s;
  s.all = all.finish();
  for (int b = 0; b < kDepthBins; ++b) {
    s.bins[static_cast<std::size_t>(b)] = bins[static_cast<std::size_t>(b)].finish();
  }
  return s;
}

}  // namespace skinbus::estimators
