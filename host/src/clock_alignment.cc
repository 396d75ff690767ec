// Per-patch clock alignment by the lower envelope of arrival times (clock_alignment.h).
#include "skinbus/host/clock_alignment.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <string>

namespace skinbus::host {
namespace {

constexpr int kMinWindow = 2;
constexpr int kMaxWindow = 65536;
constexpr double kMaxDriftPpmLimit = 1e5;
constexpr double kDefaultMaxDriftPpm = 1000;
constexpr uint64_t kSettleSamples = 16;                // before jumps are checked
constexpr int64_t kLongGapUs = int64_t{1} << 30;       // beyond: wraps from host time
constexpr int64_t kWrapUs = int64_t{1} << 32;          // the patch clock's period
constexpr int64_t kMaxHostUs = int64_t{1} << 61;       // host_rx_us contract
constexpr int64_t kMaxUnwrappedUs = int64_t{1} << 60;  // bound of unwrapped patch time
constexpr uint64_t kMaxOptionUs = uint64_t{1} << 40;   // 12.7 days: bounds every us option

int64_t clamp_us(uint64_t v) {
  return static_cast<int64_t>(std::min(v, kMaxOptionUs));
}

ClockAlignerOptions sanitised(ClockAlignerOptions o) {
  o.window = std::clamp(o.window, kMinWindow, kMaxWindow);
  if (!std::isfinite(o.max_drift_ppm) || o.max_drift_ppm < 0) o.max_drift_ppm = kDefaultMaxDriftPpm;
  o.max_drift_ppm = std::min(o.max_drift_ppm, kMaxDriftPpmLimit);
  o.bucket_us = std::min(o.bucket_us, kMaxOptionUs);
  o.min_span_us = std::min(o.min_span_us, kMaxOptionUs);
  o.reorder_us = std::min(o.reorder_us, kMaxOptionUs);
  o.jump_back_us = std::min(o.jump_back_us, kMaxOptionUs);
  o.jump_ahead_us = std::min(o.jump_ahead_us, kMaxOptionUs);
  o.jump_confirm_us = std::min(o.jump_confirm_us, kMaxOptionUs);
  return o;
}

// Floor division for a positive divisor.
int64_t floor_div(int64_t a, int64_t b) {
  const int64_t q = a / b;
  return (a % b != 0 && a < 0) ? q - 1 : q;
}

// z component of (b - a) x (c - a): > 0 when a, b, c turn counter-clockwise. Exact.
__int128 cross(int64_t ax, int64_t ay, int64_t bx, int64_t by, int64_t cx, int64_t cy) {
  return static_cast<__int128>(bx - ax) * (cy - ay) - static_cast<__int128>(by - ay) * (cx - ax);
}

}  // namespace

Status check_options(const ClockAlignerOptions& o) {
  if (o.window < kMinWindow || o.window > kMaxWindow) {
    return make_error(ErrorCode::kInvalidArgument,
                      "clock alignment: window " + std::to_string(o.window) + " outside 2..65536");
  }
  if (!std::isfinite(o.max_drift_ppm) || o.max_drift_ppm < 0 ||
      o.max_drift_ppm > kMaxDriftPpmLimit) {
    return make_error(
        ErrorCode::kInvalidArgument,
        "clock alignment: max_drift_ppm " + std::to_string(o.max_drift_ppm) + " outside 0..1e5");
  }
  return Status::Ok();
}

ClockAligner::ClockAligner(const ClockAlignerOptions& options) : options_(sanitised(options)) {
  bucket_ = std::max<int64_t>(1, clamp_us(options_.bucket_us));
}

void ClockAligner::reset() {
  points_.clear();
  hull_.clear();
  have_ = false;
  last_raw_ = 0;
  last_x_ = last_host_ = 0;
  ref_x_ = ref_y_ = 0;
  a_ = b_ = center_dx_ = 0;
  estimated_ = clamped_ = false;
  has_prior_ = false;
  prior_drift_ = 0;
  run_active_ = false;
  run_start_x_ = 0;
  run_start_residual_ = 0;
  samples_ = 0;
  jumps_ = 0;
}

int64_t ClockAligner::bucket_of(int64_t x) const {
  return floor_div(x, bucket_);
}

void ClockAligner::seed(uint32_t raw, int64_t host) {
  // The window is allocated here, once: an aligner that never sees a sample costs nothing, and
  // a copied aligner (whose vectors lose their spare capacity) gets it back.
  points_.reserve(static_cast<std::size_t>(options_.window));
  hull_.reserve(static_cast<std::size_t>(options_.window));
  points_.clear();
  have_ = true;
  last_raw_ = raw;
  last_x_ = raw;
  last_host_ = host;
  run_active_ = false;
  samples_ = 1;
  // The first line of a history is flat at the prior drift through this one point.
  b_ = has_prior_ ? prior_drift_ : 0;
  insert(last_x_, host - last_x_);
  refit();
}

void ClockAligner::jump(uint32_t raw, int64_t host) {
  if (estimated_ && !clamped_) {
    has_prior_ = true;
    prior_drift_ = b_;
  }
  ++jumps_;
  seed(raw, host);
}

ClockAligner::Update ClockAligner::update(uint32_t patch_time_us, uint64_t host_rx_us) {
  const int64_t host = static_cast<int64_t>(std::min<uint64_t>(host_rx_us, kMaxHostUs));
  if (!have_) {
    seed(patch_time_us, host);
    return Update::kOk;
  }

  // Unwrap: the nearest alias of the stamp to the newest one, or after a long silence the alias
  // nearest to the patch time the host's clock says has passed.
  const auto d = static_cast<int32_t>(patch_time_us - last_raw_);
  const int64_t host_gap = host - last_host_;
  int64_t x = last_x_ + d;
  if (host_gap >= kLongGapUs) {
    const double expected = static_cast<double>(host_gap) / (1.0 + b_);
    const double wraps = std::round((expected - d) / static_cast<double>(kWrapUs));
    if (std::isfinite(wraps) && std::abs(wraps) < 1e9) x += static_cast<int64_t>(wraps) * kWrapUs;
  }
  if (x > kMaxUnwrappedUs || x < -kMaxUnwrappedUs) {
    jump(patch_time_us, host);  // only nonsense input gets here: start again
    return Update::kJumped;
  }
  const bool backward = x < last_x_;
  if (backward && last_x_ - x > clamp_us(options_.reorder_us)) {
    jump(patch_time_us, host);  // the patch clock went back: a reboot
    return Update::kJumped;
  }

  // The residual against the current line, and what the line's own error may explain.
  const double residual = static_cast<double>((host - x) - ref_y_) - line_dy(x);
  const double line_error =
      options_.max_drift_ppm * 1e-6 * std::abs(static_cast<double>(x - ref_x_) - center_dx_);
  const bool settled = samples_ >= kSettleSamples;
  const bool too_early =
      settled && residual < -(static_cast<double>(clamp_us(options_.jump_back_us)) + line_error);

  if (backward) {
    // A reordered sample earlier than the line allows cannot be trusted either way: drop it.
    if (too_early) return Update::kReordered;
    ++samples_;
    if (insert(x, host - x)) refit();
    return Update::kReordered;
  }

  if (too_early) {
    jump(patch_time_us, host);  // earlier than any delay allows: host stepped back
    return Update::kJumped;
  }
  if (settled && residual > static_cast<double>(clamp_us(options_.jump_ahead_us)) + line_error) {
    if (!run_active_) {
      run_active_ = true;
      run_start_x_ = x;
      run_start_residual_ = residual;
    } else {
      const double run_us = static_cast<double>(x - run_start_x_);
      const bool draining = residual - run_start_residual_ < -0.5 * run_us;
      if (run_us >= static_cast<double>(clamp_us(options_.jump_confirm_us)) && !draining) {
        jump(patch_time_us, host);  // late for too long: host stepped forward
        return Update::kJumped;
      }
    }
  } else {
    run_active_ = false;
  }

  last_raw_ = patch_time_us;
  last_x_ = x;
  last_host_ = host;
  ++samples_;
  if (insert(x, host - x)) refit();
  return Update::kOk;
}

bool ClockAligner::insert(int64_t x, int64_t y) {
  const int64_t key = bucket_of(x);
  std::size_t i = points_.size();
  while (i > 0 && points_[i - 1].key > key) --i;
  if (i > 0 && points_[i - 1].key == key) {
    // Same bucket: keep the earlier arrival relative to the current line's slope.
    Point& p = points_[i - 1];
    const double score_new = static_cast<double>(y) - b_ * static_cast<double>(x - p.x);
    if (score_new >= static_cast<double>(p.y)) return false;
    p = Point{x, y, key};
    return true;
  }
  if (points_.size() >= static_cast<std::size_t>(options_.window)) {
    if (i == 0) return false;  // older than everything the full window keeps
    points_.erase(points_.begin());
    --i;
  }
  points_.insert(points_.begin() + static_cast<std::ptrdiff_t>(i), Point{x, y, key});
  return true;
}

void ClockAligner::refit() {
  const std::size_t n = points_.size();
  if (n == 0) return;
  const Point& ref = points_.back();
  ref_x_ = ref.x;
  ref_y_ = ref.y;

  double mean_dx = 0;
  for (const Point& p : points_) mean_dx += static_cast<double>(p.x - ref_x_);
  mean_dx /= static_cast<double>(n);
  center_dx_ = mean_dx;

  estimated_ = false;
  clamped_ = false;
  double b = has_prior_ ? prior_drift_ : 0.0;
  double a = 0;
  bool have_edge = false;

  const int64_t span = points_.back().x - points_.front().x;
  if (n >= 2 && span >= clamp_us(options_.min_span_us)) {
    // Lower convex hull (Andrew's monotone chain; x strictly increasing), exact arithmetic.
    hull_.clear();
    for (std::size_t i = 0; i < n; ++i) {
      while (hull_.size() >= 2) {
        const Point& o = points_[static_cast<std::size_t>(hull_[hull_.size() - 2])];
        const Point& m = points_[static_cast<std::size_t>(hull_.back())];
        if (cross(o.x, o.y, m.x, m.y, points_[i].x, points_[i].y) > 0) break;
        hull_.pop_back();
      }
      hull_.push_back(static_cast<int>(i));
    }
    // The edge above the mean x: the line below all points that is highest there.
    if (hull_.size() >= 2) {
      std::size_t k = 0;
      while (k + 2 < hull_.size() &&
             static_cast<double>(points_[static_cast<std::size_t>(hull_[k + 1])].x - ref_x_) <
                 mean_dx) {
        ++k;
      }
      const Point& p0 = points_[static_cast<std::size_t>(hull_[k])];
      const Point& p1 = points_[static_cast<std::size_t>(hull_[k + 1])];
      const double dx = static_cast<double>(p1.x - p0.x);  // >= 1
      const double slope = static_cast<double>(p1.y - p0.y) / dx;
      if (std::isfinite(slope)) {
        b = slope;
        a = static_cast<double>(p0.y - ref_y_) - b * static_cast<double>(p0.x - ref_x_);
        have_edge = true;
        estimated_ = true;
      }
    }
  }

  const double max_drift = options_.max_drift_ppm * 1e-6;
  if (std::abs(b) > max_drift || !std::isfinite(b)) {
    b = std::isfinite(b) ? std::clamp(b, -max_drift, max_drift) : 0.0;
    clamped_ = estimated_;
    have_edge = false;
  }
  if (!have_edge) {
    // Offset only (or a clamped slope): the highest line of slope b below every point.
    a = std::numeric_limits<double>::infinity();
    for (const Point& p : points_) {
      a = std::min(a, static_cast<double>(p.y - ref_y_) - b * static_cast<double>(p.x - ref_x_));
    }
  }
  b_ = b;
  a_ = std::isfinite(a) ? a : 0.0;
}

Result<uint64_t> ClockAligner::to_host_us(uint32_t patch_time_us) const {
  if (!have_) {
    return make_error(ErrorCode::kUnavailable, "clock alignment: no sample of this patch yet");
  }
  const int64_t x = last_x_ + static_cast<int32_t>(patch_time_us - last_raw_);
  const double correction = line_dy(x);  // host - x - ref_y_
  if (!std::isfinite(correction) || std::abs(correction) > static_cast<double>(kMaxHostUs)) {
    return make_error(ErrorCode::kOutOfRange, "clock alignment: mapped time out of range");
  }
  const int64_t host = x + ref_y_ + static_cast<int64_t>(std::llround(correction));
  if (host < 0) {
    return make_error(ErrorCode::kOutOfRange, "clock alignment: patch time " +
                                                  std::to_string(patch_time_us) +
                                                  " maps before the host clock's epoch");
  }
  return static_cast<uint64_t>(host);
}

double ClockAligner::offset_us() const {
  if (!have_) return 0;
  return static_cast<double>(ref_y_) + line_dy(last_x_);
}

double ClockAligner::drift_ppm() const {
  return b_ * 1e6;
}

}  // namespace skinbus::host
