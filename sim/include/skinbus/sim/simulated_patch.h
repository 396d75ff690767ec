// skinbus/sim/simulated_patch.h: one patch as its sensors would read it.
//
// Adds to the forward model what a real unit adds: the rest field of its magnets, a uniform
// ambient field (the Earth's field seen by a turning limb), the temperature dependence of the
// magnets, sensor noise, quantisation to the chip's LSB and 16-bit saturation.
#pragma once

#include <cstdint>
#include <span>

#include "skinbus/sim/patch_model.h"
#include "skinbus/sim/rng.h"

namespace skinbus::sim {

struct Environment {
  Vec3<double>
      ambient_ut{};  // uniform field in the patch frame (Earth field as the limb turns), uT
  double temperature_c = 25;  // the magnets' remanence falls as they warm
};
inline constexpr double kReferenceTemperatureC = 25;

// The noise seed of the simulated unit with `hardware_uid`, stream `stream`: every tool that
// simulates one unit uses it, so the same UID and stream give the same noise (stream 1: the
// training presses of skinbus-dataset, 2: the benchmarks' test presses, 7: whole-body scenes).
constexpr uint64_t unit_noise_seed(uint64_t hardware_uid, uint64_t stream) {
  return hardware_uid * 0x9E3779B97F4A7C15ull + stream;
}

class SimulatedPatch {
 public:
  SimulatedPatch(PatchModel model, uint64_t noise_seed);

  const PatchModel& model() const { return model_; }
  int channel_count() const { return model_.channel_count(); }
  double noise_xy_ut() const { return noise_xy_ut_; }
  double noise_z_ut() const { return noise_z_ut_; }

  // One measurement of every channel: absolute field in uT (quantised, noisy). Sets bit i of
  // the returned mask (sensor i < 64) when sensor i saturated; `saturated` (if not empty,
  // one entry per sensor) gets every sensor's flag.
  uint64_t measure(std::span<const Contact> contacts, const Environment& env,
                   std::span<double> field_ut, std::span<uint8_t> saturated = {});

  // Captures a baseline as a patch node does on tare: the mean of `samples` untouched
  // measurements. Returned per channel (uT).
  void tare(const Environment& env, int samples, std::span<double> baseline_ut);

 private:
  PatchModel model_;
  Rng rng_;
  double noise_xy_ut_, noise_z_ut_, sens_xy_ut_, sens_z_ut_;
  std::vector<double> rest_;
  std::vector<double> scratch_;
};

}  // namespace skinbus::sim
