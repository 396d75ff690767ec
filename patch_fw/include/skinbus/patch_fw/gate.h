// skinbus/patch_fw/gate.h: baseline, slow drift tracking and contact gating of one patch.
//
// The baseline is the untouched field of every channel: captured as the mean of `tare_samples`
// samples at start and on the tare command. A capture takes only a steady field: a reading that
// moved against the capture's mean so far as much as the gate would call a touch (the score
// below over `on_threshold_ut`, common mode removed) stops it. After kTareMinSamples or more
// readings, those readings are the baseline and the moved reading is gated as usual (a press that
// landed during the capture is a contact, not part of the rest field); after fewer, the capture
// starts again from the moved reading. What a patch cannot tell from its field alone: a press held
// still through a whole capture is taken as the rest field (its release then reads as a touch),
// and a press lifting during a capture's first readings is taken as the rest field too. Tare an
// untouched patch (docs/patch_node.md). While the patch is untouched it follows slow drift
// (temperature, a slowly turning limb) with a first-order filter of time constant
// `drift_tau_s`, each step clamped to `drift_max_ut_per_s`, and only after `drift_holdoff_s`
// without contact, so a held press is never absorbed: during contact the baseline is frozen.
//
// Contact gating with hysteresis on two scores of the deviations from the baseline after removing
// the deviation common to all sensors (the per-axis median), so a uniform ambient change (the
// Earth's field as a limb turns) does not read as a touch while a local press does:
//  * score: the largest over the healthy sensors (vector norm, uT): a press near a sensor;
//  * rms: the RMS over every healthy channel (uT) of those deviations smoothed over about
//    `rms_smoothing_samples` samples (an exponential average, reset by a tare): a press that
//    moves many sensors a little, such as one at the patch's centre, where the checkerboard of
//    magnets keeps every single sensor's change small (a 4 mm press there: score under 6 uT at
//    any depth). The smoothing trades a few samples of latency on this path for a third of
//    the noise; the score path stays immediate.
// Contact starts when either exceeds its on threshold and ends after `off_samples` samples below
// the off thresholds: the score's alone once the score has crossed its on threshold during the
// contact (the smoothing would hold a strong press a few samples past its release), both for a
// contact only the rms has seen.
//
// A sensor that turns faulty keeps its old baseline; one without a baseline (faulty through the
// tare, or newly recovered) takes its next untouched reading as baseline and is left out of the
// score and reported faulty until then. All arithmetic is on finite values: non-finite inputs
// are treated as a faulty sensor.
#pragma once

#include <array>
#include <cstdint>

#include "skinbus/bus/protocol.h"
#include "skinbus/patch_fw/sensor_array.h"

namespace skinbus::patch_fw {

struct GateConfig {
  double on_threshold_ut = 9.0;  // idle noise peaks near 6.5 uT in an hour (gate_test.cc)
  double off_threshold_ut = 6.0;
  double rms_on_threshold_ut = 0.75;  // idle rms peaks near 0.52 uT in an hour (gate_test.cc)
  double rms_off_threshold_ut = 0.65;
  int rms_smoothing_samples = 4;
  int off_samples = 3;
  int tare_samples = 16;
  double drift_tau_s = 20.0;
  double drift_max_ut_per_s = 2.0;
  double drift_holdoff_s = 2.0;
};

struct GateOutput {
  bool contact = false;
  bool tare_active = false;     // baseline capture in progress (no contact decisions)
  bool tared = false;           // a baseline is held for every healthy sensor
  bool drift_tracking = false;  // the baseline moved this sample
  double score_ut = 0;          // largest sensor deviation (see above)
  double rms_ut = 0;            // RMS channel deviation (see above)
  uint16_t unbased_mask = 0;    // sensors without a baseline yet (report them faulty)
  // Field minus baseline, uT (0 for faulty or unbased sensors).
  std::array<double, bus::kChannelCount> tared_ut{};
  // > 0 on a sample that a baseline capture did not take: the reading moved this much (uT,
  // largest sensor, common mode removed) against the capture so far (see ContactGate).
  double tare_changed_ut = 0;
};

class ContactGate {
 public:
  explicit ContactGate(GateConfig config = {});
  const GateConfig& config() const { return config_; }
  // A capture whose steady part before a change is at least this long keeps that part.
  static constexpr int kTareMinSamples = 4;

  // Starts a baseline capture over the next tare_samples samples (contact state is cleared).
  void start_tare();
  // Feeds one sample taken at `time_us`.
  void update(const ArraySample& sample, GateOutput* out);
  bool contact() const { return contact_; }
  const std::array<double, bus::kChannelCount>& baseline_ut() const { return baseline_; }

 private:
  GateConfig config_;
  std::array<double, bus::kChannelCount> baseline_{};
  std::array<double, bus::kChannelCount> tare_sum_{};
  std::array<double, bus::kChannelCount> smooth_{};  // smoothed deviations (rms path)
  std::array<int, bus::kSensorCount> tare_count_{};
  uint16_t based_ = 0;  // bit i: sensor i has a baseline
  int tare_left_ = 0;
  int tare_taken_ = 0;  // samples in the capture so far

  void restart_capture();
  // Ends the capture: the mean of its readings is the baseline of every sensor it has.
  void finish_capture();
  // The largest sensor change of `s` against the capture's mean so far (uT, common mode removed).
  double capture_change_ut(const ArraySample& s, uint16_t healthy) const;
  bool contact_ = false;
  bool score_seen_ = false;  // the score crossed its on threshold during this contact
  int below_ = 0;
  uint64_t last_time_us_ = 0;
  uint64_t last_contact_us_ = 0;
  bool have_time_ = false;
};

}  // namespace skinbus::patch_fw
