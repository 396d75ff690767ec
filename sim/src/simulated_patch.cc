#include "skinbus/sim/simulated_patch.h"

namespace skinbus::sim {

SimulatedPatch::SimulatedPatch(PatchModel model, uint64_t noise_seed)
    : model_(std::move(model)),
      rng_(noise_seed),
      rest_(model_.channel_count()),
      scratch_(model_.channel_count()) {
  const mlx90393::Config& c = model_.design().sensor_config;
  noise_xy_ut_ = mlx90393_noise_xy_ut(c);
  noise_z_ut_ = mlx90393_noise_z_ut(c);
  sens_xy_ut_ = mlx90393::sensitivity_xy_ut(c);
  sens_z_ut_ = mlx90393::sensitivity_z_ut(c);
  model_.rest_field_ut(rest_);
}

uint64_t SimulatedPatch::measure(std::span<const Contact> contacts, const Environment& env,
                                 std::span<double> field_ut, std::span<uint8_t> saturated) {
  const int nc = channel_count();
  if (contacts.empty()) {
    for (int i = 0; i < nc; ++i) scratch_[i] = 0;
  } else {
    model_.contact_field_ut(contacts, scratch_);
  }
  const double temp_scale =
      1 + model_.design().remanence_tempco_per_c * (env.temperature_c - kReferenceTemperatureC);
  const mlx90393::Config& cfg = model_.design().sensor_config;
  uint64_t mask = 0;
  const auto& sensors = model_.sensors();
  for (int s = 0; s < nc / 3; ++s) {
    const Vec3<double> amb = sensors[s].frame.apply(env.ambient_ut);
    const double a[3] = {amb.x * sensors[s].gain.x, amb.y * sensors[s].gain.y,
                         amb.z * sensors[s].gain.z};
    bool sat_any = false;
    for (int k = 0; k < 3; ++k) {
      const int i = 3 * s + k;
      const double truth = (rest_[i] + scratch_[i]) * temp_scale + a[k];
      const double noisy = truth + (k < 2 ? noise_xy_ut_ : noise_z_ut_) * rng_.normal();
      const double sens = k < 2 ? sens_xy_ut_ : sens_z_ut_;
      const uint8_t res = k < 2 ? cfg.res_xy : cfg.res_z;
      bool sat = false;
      field_ut[i] = mlx90393::field_ut(mlx90393::output_code(noisy, sens, res, &sat), sens, res);
      sat_any = sat_any || sat;
    }
    if (sat_any && s < 64) mask |= 1ull << s;
    if (!saturated.empty()) saturated[s] = sat_any;
  }
  return mask;
}

void SimulatedPatch::tare(const Environment& env, int samples, std::span<double> baseline_ut) {
  const int nc = channel_count();
  std::vector<double> m(nc);
  for (int i = 0; i < nc; ++i) baseline_ut[i] = 0;
  for (int k = 0; k < samples; ++k) {
    measure({}, env, m);
    for (int i = 0; i < nc; ++i) baseline_ut[i] += m[i] / samples;
  }
}

}  // namespace skinbus::sim
