// The joint-state history (joint_history.h).
#include "skinbus/host/joint_history.h"

#include <algorithm>
#include <cmath>
#include <numbers>

namespace skinbus::host {

JointHistory::JointHistory(std::size_t joints, std::vector<bool> wrapping,
                           JointHistoryOptions options)
    : joints_(joints),
      wrapping_(std::move(wrapping)),
      options_(options),
      capacity_(std::max<std::size_t>(options.capacity, 1)),
      stamps_(capacity_, 0),
      q_(capacity_ * joints, 0.0) {
  wrapping_.resize(joints_, false);
}

JointHistory::AddResult JointHistory::add(uint64_t stamp_us, std::span<const double> q) {
  const std::size_t n = std::min(q.size(), joints_);
  double* dst = nullptr;
  AddResult result = AddResult::kAppended;
  if (count_ > 0 && stamp_us < newest_us()) return AddResult::kOutOfOrder;
  if (count_ > 0 && stamp_us == newest_us()) {
    dst = &q_[ring_index(count_ - 1) * joints_];
    result = AddResult::kMerged;
  } else {
    if (count_ == capacity_) {  // full: the oldest entry makes room
      head_ = (head_ + 1) % capacity_;
      --count_;
    }
    const std::size_t k = ring_index(count_);
    stamps_[k] = stamp_us;
    dst = &q_[k * joints_];
    ++count_;
  }
  std::copy_n(q.begin(), n, dst);
  return result;
}

uint64_t JointHistory::oldest_us() const {
  return count_ == 0 ? 0 : stamp(0);
}

uint64_t JointHistory::newest_us() const {
  return count_ == 0 ? 0 : stamp(count_ - 1);
}

std::span<const double> JointHistory::newest() const {
  if (count_ == 0) return {};
  return {row(count_ - 1), joints_};
}

void JointHistory::blend(const double* a, const double* b, double w, std::span<double> out) const {
  const std::size_t n = std::min(out.size(), joints_);
  for (std::size_t j = 0; j < n; ++j) {
    double d = b[j] - a[j];
    if (wrapping_[j]) d = std::remainder(d, 2 * std::numbers::pi);  // the shorter way round
    out[j] = a[j] + w * d;
  }
}

JointHistory::Coverage JointHistory::pose_at(uint64_t t_us, std::span<double> out) const {
  if (count_ == 0) return Coverage::kEmpty;
  const std::size_t n = std::min(out.size(), joints_);
  const uint64_t first = oldest_us(), last = newest_us();
  const uint64_t ext = options_.extrapolation_us;
  auto copy_row = [&](std::size_t i) { std::copy_n(row(i), n, out.begin()); };
  // Outside: the nearest end, as it is.
  if ((t_us < first && first - t_us > ext) || (t_us > last && t_us - last > ext)) {
    copy_row(t_us < first ? 0 : count_ - 1);
    return Coverage::kOutside;
  }
  if (count_ == 1) {
    copy_row(0);
    return t_us == first ? Coverage::kInterpolated : Coverage::kExtrapolated;
  }
  // The segment [lo, lo + 1] holding t (or the end segment t lies beyond).
  std::size_t lo;
  Coverage coverage = Coverage::kInterpolated;
  if (t_us <= first) {
    lo = 0;
    if (t_us < first) coverage = Coverage::kExtrapolated;
  } else if (t_us >= last) {
    lo = count_ - 2;
    if (t_us > last) coverage = Coverage::kExtrapolated;
  } else {
    // The first entry whose stamp exceeds t; 0 < hi < count_ here.
    std::size_t a = 0, b = count_ - 1;  // stamp(a) <= t < stamp(b)
    while (b - a > 1) {
      const std::size_t mid = a + (b - a) / 2;
      if (stamp(mid) <= t_us) {
        a = mid;
      } else {
        b = mid;
      }
    }
    lo = a;
  }
  // Differences first: exact for any stamps (strictly increasing, so the span is not 0).
  const uint64_t t0 = stamp(lo), span = stamp(lo + 1) - t0;
  const double offset =
      t_us >= t0 ? static_cast<double>(t_us - t0) : -static_cast<double>(t0 - t_us);
  blend(row(lo), row(lo + 1), offset / static_cast<double>(span), out.first(n));
  return coverage;
}

}  // namespace skinbus::host
