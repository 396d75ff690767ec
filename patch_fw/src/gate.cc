#include "skinbus/patch_fw/gate.h"

#include <algorithm>
#include <cmath>

#include "skinbus/common/stats.h"

namespace skinbus::patch_fw {

namespace {
constexpr int kN = bus::kSensorCount;

// The deviation common to the sensors of `mask` (n of them), per axis: the median, or 0 with
// fewer than 3 sensors.
void common_mode(const double* dev, uint16_t mask, int n, double common[3]) {
  double axis_vals[kN];
  for (int a = 0; a < 3; ++a) {
    common[a] = 0;
    if (n < 3) continue;
    int k = 0;
    for (int i = 0; i < kN; ++i)
      if (mask & (1u << i)) axis_vals[k++] = dev[3 * i + a];
    common[a] = median_in_place(axis_vals, k);
  }
}
}  // namespace

ContactGate::ContactGate(GateConfig config) : config_(config) {
  start_tare();
}

void ContactGate::start_tare() {
  restart_capture();
  based_ = 0;
  smooth_.fill(0);
  contact_ = false;
  below_ = 0;
}

void ContactGate::restart_capture() {
  tare_left_ = std::max(config_.tare_samples, 1);
  tare_taken_ = 0;
  tare_sum_.fill(0);
  tare_count_.fill(0);
}

void ContactGate::finish_capture() {
  tare_left_ = 0;
  for (int i = 0; i < kN; ++i) {
    if (tare_count_[i] == 0) continue;
    for (int a = 0; a < 3; ++a) baseline_[3 * i + a] = tare_sum_[3 * i + a] / tare_count_[i];
    based_ = static_cast<uint16_t>(based_ | 1u << i);
  }
}

double ContactGate::capture_change_ut(const ArraySample& s, uint16_t healthy) const {
  // Each sensor's reading against its capture mean so far, the change common to all sensors (the
  // per-axis median) removed: the gate's score, with the capture as the baseline.
  double dev[3 * kN];
  uint16_t seen = 0;
  int n = 0;
  for (int i = 0; i < kN; ++i) {
    if (!(healthy & (1u << i)) || tare_count_[i] == 0) continue;
    seen = static_cast<uint16_t>(seen | 1u << i);
    ++n;
    for (int a = 0; a < 3; ++a) {
      dev[3 * i + a] = s.field_ut[3 * i + a] - tare_sum_[3 * i + a] / tare_count_[i];
    }
  }
  double common[3];
  common_mode(dev, seen, n, common);
  double largest = 0;
  for (int i = 0; i < kN; ++i) {
    if (!(seen & (1u << i))) continue;
    double sq = 0;
    for (int a = 0; a < 3; ++a) sq += (dev[3 * i + a] - common[a]) * (dev[3 * i + a] - common[a]);
    largest = std::max(largest, std::sqrt(sq));
  }
  return largest;
}

void ContactGate::update(const ArraySample& s, GateOutput* out) {
  const double dt_s = have_time_ && s.timestamp_us > last_time_us_
                          ? static_cast<double>(s.timestamp_us - last_time_us_) * 1e-6
                          : 0.0;
  have_time_ = true;
  last_time_us_ = s.timestamp_us;
  uint16_t healthy = 0;
  for (int i = 0; i < kN; ++i) {
    const double* f = &s.field_ut[3 * i];
    const bool finite = std::isfinite(f[0]) && std::isfinite(f[1]) && std::isfinite(f[2]);
    if (finite && !(s.fault_mask & (1u << i))) healthy = static_cast<uint16_t>(healthy | 1u << i);
  }
  out->drift_tracking = false;
  out->tared_ut.fill(0);

  out->tare_changed_ut = 0;
  if (tare_left_ > 0 && tare_taken_ > 0) {
    // A capture takes only a steady field: a reading the gate would call a touch against the
    // capture so far stops it. With kTareMinSamples or more behind it, what came before is the
    // baseline and this reading is gated below (a press that landed during the capture); with
    // fewer, the capture starts again from this reading.
    const double change = capture_change_ut(s, healthy);
    if (change > config_.on_threshold_ut) {
      out->tare_changed_ut = change;
      if (tare_taken_ >= std::min(kTareMinSamples, std::max(config_.tare_samples, 1))) {
        finish_capture();
      } else {
        restart_capture();
      }
    }
  }
  if (tare_left_ > 0) {
    ++tare_taken_;
    for (int i = 0; i < kN; ++i) {
      if (!(healthy & (1u << i))) continue;
      for (int a = 0; a < 3; ++a) tare_sum_[3 * i + a] += s.field_ut[3 * i + a];
      ++tare_count_[i];
    }
    if (--tare_left_ == 0) finish_capture();
    out->tare_active = tare_left_ > 0;
    out->contact = false;
    out->tared = tare_left_ == 0 && based_ != 0;
    out->score_ut = 0;
    out->rms_ut = 0;
    out->unbased_mask = static_cast<uint16_t>(~based_);
    return;
  }
  out->tare_active = false;

  // Deviation of every healthy, based sensor; common mode removed for the score.
  const uint16_t usable = healthy & based_;
  double dev[3 * kN];
  int n_usable = 0;
  for (int i = 0; i < kN; ++i) {
    if (!(usable & (1u << i))) continue;
    ++n_usable;
    for (int a = 0; a < 3; ++a) dev[3 * i + a] = s.field_ut[3 * i + a] - baseline_[3 * i + a];
  }
  double common[3];
  common_mode(dev, usable, n_usable, common);
  const double smooth_alpha = 1.0 / std::max(config_.rms_smoothing_samples, 1);
  double score = 0, total_sq = 0;
  for (int i = 0; i < kN; ++i) {
    if (!(usable & (1u << i))) {
      for (int a = 0; a < 3; ++a) smooth_[3 * i + a] = 0;
      continue;
    }
    double sq = 0;
    for (int a = 0; a < 3; ++a) {
      const double d = dev[3 * i + a] - common[a];
      sq += d * d;
      double& m = smooth_[3 * i + a];
      m += smooth_alpha * (d - m);
      total_sq += m * m;
    }
    score = std::max(score, std::sqrt(sq));
    for (int a = 0; a < 3; ++a) out->tared_ut[3 * i + a] = dev[3 * i + a];
  }
  const double rms = n_usable > 0 ? std::sqrt(total_sq / (3.0 * n_usable)) : 0.0;
  out->score_ut = score;
  out->rms_ut = rms;

  // Hysteresis. A contact the score saw ends by the score alone (the smoothed rms would hold it
  // a few samples past the release); one only the rms saw ends by both.
  const bool score_on = score > config_.on_threshold_ut;
  if (contact_ && score_on) score_seen_ = true;
  if (!contact_) {
    if (score_on || rms > config_.rms_on_threshold_ut) {
      contact_ = true;
      score_seen_ = score_on;
      below_ = 0;
    }
  } else if (score < config_.off_threshold_ut &&
             (score_seen_ || rms < config_.rms_off_threshold_ut)) {
    if (++below_ >= config_.off_samples) {
      contact_ = false;
      // The rms path starts afresh: its smoothed deviations would otherwise still carry the
      // press for a few samples and turn a contact the score ended straight back on.
      smooth_.fill(0);
    }
  } else {
    below_ = 0;
  }
  if (contact_) last_contact_us_ = s.timestamp_us;

  // Drift: only untouched, after the hold-off; a sensor without a baseline takes its reading.
  const bool quiet = !contact_ && (last_contact_us_ == 0 ||
                                   static_cast<double>(s.timestamp_us - last_contact_us_) * 1e-6 >=
                                       config_.drift_holdoff_s);
  if (quiet) {
    const double alpha = config_.drift_tau_s > 0 ? std::min(1.0, dt_s / config_.drift_tau_s) : 0;
    const double max_step = config_.drift_max_ut_per_s * dt_s;
    for (int i = 0; i < kN; ++i) {
      if (!(healthy & (1u << i))) continue;
      if (!(based_ & (1u << i))) {
        for (int a = 0; a < 3; ++a) baseline_[3 * i + a] = s.field_ut[3 * i + a];
        based_ = static_cast<uint16_t>(based_ | 1u << i);
        continue;
      }
      for (int a = 0; a < 3; ++a) {
        const double step = std::clamp(alpha * dev[3 * i + a], -max_step, max_step);
        if (step != 0) out->drift_tracking = true;
        baseline_[3 * i + a] += step;
      }
    }
  }
  out->contact = contact_;
  out->tared = based_ != 0;
  out->unbased_mask = static_cast<uint16_t>(~based_ & 0xFFFF);
}

}  // namespace skinbus::patch_fw
