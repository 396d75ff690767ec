// skinbus/host/joint_history.h: the robot's joint positions over the recent past, so that a
// sample is placed with the pose the robot had when the sample was taken, however late it is
// estimated.
//
// A fixed-capacity ring of (stamp, positions of every movable joint) entries, in stamp order.
// add() appends a state; pose_at() gives the positions at any time:
//
//   oldest - extrapolation_us <= t <= newest + extrapolation_us
//       kInterpolated (between two entries, or exactly at one): per joint, linear between the
//       two entries around t; a joint marked `wrapping` (URDF continuous) takes the shorter way
//       round (its difference reduced to [-pi, pi]), any other joint goes straight.
//       kExtrapolated (outside the entries but within extrapolation_us of an end): linear along
//       the end's segment (the two entries nearest that end); with a single entry, that entry.
//   farther out
//       kOutside: the nearest end entry as it is. The caller must not present that as the pose
//       at t (the aggregator flags the contact kContactStaleKinematics).
//   no entry yet
//       kEmpty: `out` is left as it is.
//
// Extrapolation error: a joint accelerating at a rad/s^2 is off by a*e^2/2 after e seconds, so
// 50 ms at 4 rad/s^2 is 5 mrad, 2.5 mm at 0.5 m from the joint; holding the last entry instead
// would be off by the joint speed times e (25 mrad, 12.5 mm at 0.5 rad/s). A stream of joint
// states at 100 Hz or more is extrapolated by at most a period plus its delivery time; the
// allowance only matters when a state comes late.
//
// Order: add() with a stamp older than the newest entry is refused (kOutOfOrder) and leaves the
// history as it is; an equal stamp overwrites the newest entry (kMerged: several publishers of
// joint subsets at one stamp make one entry). A full ring drops its oldest entry.
//
// Costs: the ring (capacity x joints doubles) is allocated at construction; add() copies one
// entry, O(joints); pose_at() is a binary search, O(log capacity + joints). Nothing allocates
// after construction. Not thread-safe.
#pragma once

#include <cstddef>
#include <cstdint>
#include <span>
#include <vector>

namespace skinbus::host {

struct JointHistoryOptions {
  // Entries kept. At 100 Hz joint states, 512 entries span 5.1 s; at 1 kHz, 0.51 s. The span
  // must exceed the oldest sample the caller still places (the aggregator's max_lag_us).
  std::size_t capacity = 512;
  // How far past either end of the entries pose_at() still extrapolates (kExtrapolated).
  uint64_t extrapolation_us = 50'000;
};

class JointHistory {
 public:
  enum class AddResult { kAppended, kMerged, kOutOfOrder };
  enum class Coverage { kInterpolated, kExtrapolated, kOutside, kEmpty };

  // `wrapping`: one flag per joint (or empty: none wraps). A capacity of 0 is taken as 1.
  JointHistory(std::size_t joints, std::vector<bool> wrapping, JointHistoryOptions options = {});

  // The positions (joints() entries) at `stamp_us`. Positions must be finite (not checked).
  AddResult add(uint64_t stamp_us, std::span<const double> q);

  // The positions at `t_us` into `out` (joints() entries), and how they were found (above).
  Coverage pose_at(uint64_t t_us, std::span<double> out) const;

  bool empty() const { return count_ == 0; }
  std::size_t size() const { return count_; }
  std::size_t joints() const { return joints_; }
  uint64_t oldest_us() const;  // 0 when empty
  uint64_t newest_us() const;  // 0 when empty
  // The newest entry's positions (empty span when there is none).
  std::span<const double> newest() const;
  const JointHistoryOptions& options() const { return options_; }

 private:
  std::size_t ring_index(std::size_t i) const { return (head_ + i) % capacity_; }  // i: 0 oldest
  uint64_t stamp(std::size_t i) const { return stamps_[ring_index(i)]; }
  const double* row(std::size_t i) const { return &q_[ring_index(i) * joints_]; }
  // out = a + w (b - a), per joint, wrapping joints the shorter way; w may lie outside [0, 1].
  void blend(const double* a, const double* b, double w, std::span<double> out) const;

  std::size_t joints_;
  std::vector<bool> wrapping_;
  JointHistoryOptions options_;
  std::size_t capacity_;
  std::vector<uint64_t> stamps_;  // capacity_
  std::vector<double> q_;         // capacity_ x joints_
  std::size_t head_ = 0;          // ring index of the oldest entry
  std::size_t count_ = 0;
};

}  // namespace skinbus::host
