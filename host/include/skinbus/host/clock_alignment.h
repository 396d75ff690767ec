// skinbus/host/clock_alignment.h: host time for a patch's sample timestamps.
//
// Each patch stamps its samples with its own free-running clock (Sample::timestamp_us: 32 bits of
// microseconds, wrapping every 2^32 us = 71.6 min) whose rate differs from the host's by up to a
// few hundred ppm. The host knows when a sample's last frame arrived (CLOCK_REALTIME, us), which
// is the send time plus a delay that is never negative: bus arbitration and queueing, typically
// 0.2-2 ms, now and then tens of milliseconds, seconds when the host stalls.
//
// One ClockAligner per patch estimates the line
//
//   host(p) = p + offset_us() + drift_ppm() * 1e-6 * (p - p_newest)
//
// where p is the patch time unwrapped to 64 bits and p_newest that of the newest sample: the
// offset is host - patch at the newest sample, and drift > 0 means the patch clock runs slow
// (the host's clock advances 1 + drift us per patch us), as in PatchStatus.
//
// Method: the lower envelope. Every arrival lies on or above the line "send time + minimum
// delay", so the aligner fits the lower convex hull of the points (patch time, host - patch) and
// takes the hull edge above the window's mean patch time: the line that lies below every point
// and is as high as possible there (the linear-programming fit of a one-sided error). Late
// samples and outliers lie above the hull and do not move it at all. The points are kept in a
// fixed window: patch time is cut into buckets of `bucket_us` and each bucket keeps only its
// earliest-arriving sample (relative to the current line), so 128 points of 100 ms cover 12.8 s
// of a 41.7 Hz stream or many minutes of an event-mode patch that sends only while pressed.
// Until the window spans `min_span_us` only the offset is fitted (drift 0, or the drift known
// from before the last detected jump).
//
// What the mapped time means: the host time at which the sample would have arrived with the
// smallest delay seen in the window, i.e. the true send time plus the bus's minimum latency
// (about 0.2 ms on a quiet CAN FD bus). Subtract a known fixed latency if it matters.
//
// Accuracy: bounded by clock_alignment_test.cc on a simulated bus (tens of microseconds after
// 10 s; figures and conditions in docs/aggregator.md, "Clock alignment").
//
// Unwrapping: a sample whose 32-bit stamp is behind the newest by at most `reorder_us` is
// reordering (it is used for the fit and reported kReordered); one further behind means the
// patch clock went back (reboot): the history is reset and kJumped reported. After a silence
// longer than 2^30 us (17.9 min; event mode) the number of wraps is taken from the host time
// that passed, so gaps of any length unwrap correctly.
//
// Jumps: once 16 samples are in the history, each sample's residual (its arrival minus the line)
// is checked against what the line's own error can explain (max_drift_ppm times the sample's
// distance from the fit's centre) plus a margin:
//  - earlier than the line by more than `jump_back_us`: delays are never negative, so the host
//    clock stepped back or the patch clock leapt forward. The history is reset at once and
//    kJumped reported.
//  - later than the line by more than `jump_ahead_us` for `jump_confirm_us` of patch time, and
//    not draining (the residual fell by less than half the patch time that passed; a host that
//    stalled and then reads its backlog sees residuals fall at one us per us): the host clock
//    stepped forward or the patch restarted unnoticed. Until then such samples count as late
//    (the old line is kept, so their mapped times are early by the step); then the history is
//    reset and kJumped reported.
// After a jump the drift estimated before it is kept as the drift of the offset-only phase (the
// crystal is the same). A host clock step smaller than these margins is absorbed as delay: for up
// to one window span the drift reads wrong and mapped times are off by up to about the step (NTP
// daemons slew such small corrections rather than step). The first samples after a congested
// start can lie well above the later minimum; a sample that then undercuts them by more than
// jump_back_us is reported as a jump too (harmless: the history restarts from the lower point).
//
// Costs: update() is O(window) (one insertion into a sorted array and one hull), to_host_us() is
// O(1); nothing allocates after the first update. Not thread-safe: one aligner per patch, used from
// one thread. The caller should call reset() when it knows the patch rebooted (heartbeat uptime
// went back); the aligner detects most reboots itself but not all (a restart whose new stamps
// happen to continue close to the old ones is only found after jump_confirm_us).
#pragma once

#include <cstdint>
#include <vector>

#include "skinbus/common/result.h"

namespace skinbus::host {

struct ClockAlignerOptions {
  int window = 128;                      // points kept (2..65536)
  uint64_t bucket_us = 100'000;          // patch time per point; 0: every sample is a point
  double max_drift_ppm = 1000;           // a fitted drift beyond +-this is clamped (and flagged)
  uint64_t min_span_us = 2'000'000;      // window span before the drift is estimated
  uint64_t reorder_us = 1'000'000;       // a stamp at most this far behind the newest: reordering
  uint64_t jump_back_us = 5'000;         // earlier than the line by more: a jump
  uint64_t jump_ahead_us = 100'000;      // later than the line by more ...
  uint64_t jump_confirm_us = 1'000'000;  // ... for this much patch time: a jump
};

// kInvalidArgument naming the field when an option is outside its range (window outside
// 2..65536, max_drift_ppm not finite or outside 0..1e5). The constructor clamps instead.
Status check_options(const ClockAlignerOptions& options);

class ClockAligner {
 public:
  enum class Update : uint8_t {
    kOk,         // the sample was used
    kReordered,  // older than the newest sample (within reorder_us): used, or dropped if it
                 // contradicts the line
    kJumped,     // a clock went back or leapt: the history was reset and starts at this sample
  };

  // Out-of-range options are clamped (see check_options). Allocates nothing: the window (about
  // 28 bytes a point) is allocated at the first update, once.
  explicit ClockAligner(const ClockAlignerOptions& options = {});

  // One sample: its patch timestamp and the host time its last frame arrived. host_rx_us is
  // taken as at most 2^61 (any CLOCK_REALTIME value until the year 73,000). O(window), no
  // allocation.
  Update update(uint32_t patch_time_us, uint64_t host_rx_us);

  // The host time of a patch timestamp, unwrapped to the nearest of its 2^32 us aliases around
  // the newest sample (so within +-35.8 min of it). kUnavailable before the first update;
  // kOutOfRange if the mapped time would be negative or beyond 2^63 us. Never NaN or Inf.
  Result<uint64_t> to_host_us(uint32_t patch_time_us) const;

  // host - patch at the newest sample, us (0 before the first update).
  double offset_us() const;
  // Patch clock rate error, ppm; positive: the patch clock runs slow. 0 before estimated.
  double drift_ppm() const;
  // The drift comes from the current window (it spans min_span_us and the hull has an edge).
  bool drift_estimated() const { return estimated_; }
  // The fitted drift was beyond max_drift_ppm and is clamped: the input is not one clock.
  bool drift_clamped() const { return clamped_; }
  // Samples used since the last reset or jump.
  uint64_t samples() const { return samples_; }
  // Points in the window (<= window).
  int points() const { return static_cast<int>(points_.size()); }
  // Jumps detected since construction or reset().
  uint64_t jumps() const { return jumps_; }
  const ClockAlignerOptions& options() const { return options_; }

  // Forgets everything, the drift and the jump count included (as newly constructed).
  void reset();

 private:
  struct Point {
    int64_t x;    // unwrapped patch time, us
    int64_t y;    // host arrival - x, us
    int64_t key;  // bucket: floor(x / bucket)
  };

  void seed(uint32_t raw, int64_t host);
  void jump(uint32_t raw, int64_t host);
  // Adds (x, y) to the window; false when the window is unchanged (the point lost to its
  // bucket's or fell off the full window), so the line need not be refitted.
  bool insert(int64_t x, int64_t y);
  void refit();
  int64_t bucket_of(int64_t x) const;
  // Host time - x of the line at unwrapped patch time x (relative to ref_y_).
  double line_dy(int64_t x) const { return a_ + b_ * static_cast<double>(x - ref_x_); }

  ClockAlignerOptions options_;
  int64_t bucket_ = 1;
  std::vector<Point> points_;  // sorted by key (and so by x), capacity window
  std::vector<int> hull_;      // indices into points_, capacity window

  bool have_ = false;
  uint32_t last_raw_ = 0;  // newest sample: its stamp, unwrapped time and arrival
  int64_t last_x_ = 0;
  int64_t last_host_ = 0;

  // The line: y(x) = ref_y_ + a_ + b_ * (x - ref_x_), ref = the newest point.
  int64_t ref_x_ = 0, ref_y_ = 0;
  double a_ = 0, b_ = 0;
  double center_dx_ = 0;  // the window's mean x relative to ref_x_ (where the fit is best)
  bool estimated_ = false, clamped_ = false;

  bool has_prior_ = false;
  double prior_drift_ = 0;

  bool run_active_ = false;  // samples later than jump_ahead_us since run_start_x_
  int64_t run_start_x_ = 0;
  double run_start_residual_ = 0;

  uint64_t samples_ = 0;
  uint64_t jumps_ = 0;
};

}  // namespace skinbus::host
