#include "skinbus/estimators/estimate.h"

#include <cmath>

namespace skinbus::estimators {

SampleCheck check_sample(std::span<const double> field_ut, std::span<uint8_t> channel_ok,
                         const InputLimits& limits) {
  SampleCheck c;
  if (field_ut.size() != channel_ok.size()) {  // outside the contract: nothing is usable
    for (uint8_t& ok : channel_ok) ok = 0;
    c.masked =
        static_cast<int>(channel_ok.size() > field_ut.size() ? channel_ok.size() : field_ut.size());
    c.first_reason = RejectReason::kWrongShape;
    return c;
  }
  const std::size_t n = field_ut.size();
  for (std::size_t i = 0; i < n; ++i) {
    RejectReason r = RejectReason::kNone;
    const double b = field_ut[i];
    if (channel_ok[i] == 0) {
      r = RejectReason::kDead;
      ++c.dead;
    } else if (!std::isfinite(b)) {
      r = RejectReason::kNonFinite;
      ++c.non_finite;
    } else if (std::fabs(b) >= limits.saturation_ut) {
      r = RejectReason::kSaturated;
      ++c.saturated;
    }
    channel_ok[i] = r == RejectReason::kNone ? 1 : 0;
    if (r != RejectReason::kNone) {
      ++c.masked;
      if (c.first_reason == RejectReason::kNone) c.first_reason = r;
    }
  }
  return c;
}

void flag_range(ContactEstimate& e, double half_u_mm, double half_v_mm, double max_depth_mm,
                double margin_mm, double margin_depth_mm) {
  if (!std::isfinite(e.u_mm) || !std::isfinite(e.v_mm) || !std::isfinite(e.depth_mm) ||
      !std::isfinite(e.force_n)) {
    e = ContactEstimate{};
    e.flags = kEstimateRejected;
    e.reason = RejectReason::kNonFinite;
    return;
  }
  if (std::fabs(e.u_mm) > half_u_mm + margin_mm || std::fabs(e.v_mm) > half_v_mm + margin_mm) {
    e.flags |= kEstimateOutsidePatch;
  }
  if (e.depth_mm < -margin_depth_mm || e.depth_mm > max_depth_mm) e.flags |= kEstimateDepthRange;
}

}  // namespace skinbus::estimators
