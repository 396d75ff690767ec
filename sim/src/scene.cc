#include "skinbus/sim/scene.h"

#include <algorithm>
#include <cmath>
#include <string>

namespace skinbus::sim {

Result<int> Scene::add_patch(uint64_t hardware_uid, const PatchDesign& design,
                             const LimbMotion& limb) {
  for (const auto& p : patches_) {
    if (p->uid == hardware_uid) {
      return make_error(ErrorCode::kInvalidArgument,
                        "scene: hardware UID " + std::to_string(hardware_uid) + " used twice");
    }
  }
  auto model = PatchModel::fabricated(design, hardware_uid, FabricationVariation{});
  if (!model.ok()) return model.error();
  patches_.push_back(std::unique_ptr<PatchState>(
      new PatchState{hardware_uid,
                     SimulatedPatch(std::move(model).value(), unit_noise_seed(hardware_uid, 7)),
                     limb,
                     {},
                     {},
                     0}));
  return static_cast<int>(patches_.size()) - 1;
}

Status Scene::add_contact(const SceneContact& c) {
  if (c.patch < 0 || c.patch >= patch_count())
    return make_error(ErrorCode::kInvalidArgument,
                      "scene: contact on unknown patch " + std::to_string(c.patch));
  if (!(c.t_end_s > c.t_start_s) || !(c.ramp_s >= 0) || !(c.depth_mm >= 0) ||
      !std::isfinite(c.u_mm) || !std::isfinite(c.v_mm) || !(c.friction >= 0) ||
      !(c.friction <= 2) || std::isinf(c.u_end_mm) || std::isinf(c.v_end_mm) ||
      std::isnan(c.u_end_mm) != std::isnan(c.v_end_mm)) {
    return make_error(ErrorCode::kInvalidArgument,
                      "scene: contact needs t_end_s > t_start_s, ramp_s >= 0, depth_mm >= 0, "
                      "finite positions (both ends of a slide or neither), friction in [0, 2]");
  }
  contacts_.push_back(c);
  patches_[c.patch]->contacts.push_back(static_cast<int>(contacts_.size()) - 1);
  patches_[c.patch]->creep_mm.push_back(0);
  return Status::Ok();
}

double Scene::depth_profile(const SceneContact& c, double t) const {
  if (t <= c.t_start_s || t >= c.t_end_s) return 0;
  const double ramp = std::min(c.ramp_s, (c.t_end_s - c.t_start_s) / 2);
  if (ramp <= 0) return c.depth_mm;
  const double in = (t - c.t_start_s) / ramp, out = (c.t_end_s - t) / ramp;
  return c.depth_mm * std::clamp(std::min(in, out), 0.0, 1.0);
}

void Scene::active_contacts(int i, double t_s, std::vector<Contact>* out) {
  PatchState& p = *patches_[i];
  const double dt = std::max(0.0, t_s - p.last_t_s);
  const double k = config_.creep_tau_s > 0 ? 1 - std::exp(-dt / config_.creep_tau_s) : 1;
  for (std::size_t j = 0; j < p.contacts.size(); ++j) {
    const SceneContact& c = contacts_[p.contacts[j]];
    const double d = depth_profile(c, t_s);
    // Creep follows a fraction of the depth with a lag; it also relaxes after release.
    p.creep_mm[j] += (config_.creep_fraction * d - p.creep_mm[j]) * k;
    const double total = d > 0 ? d + p.creep_mm[j] : 0.0;
    if (!(total > 0)) continue;
    Contact now{c.u_mm, c.v_mm, total, c.tip_radius_mm};
    if (c.slides()) {
      const double f = std::clamp((t_s - c.t_start_s) / (c.t_end_s - c.t_start_s), 0.0, 1.0);
      const double du = c.u_end_mm - c.u_mm, dv = c.v_end_mm - c.v_mm;
      now.u_mm += f * du;
      now.v_mm += f * dv;
      const double len = std::hypot(du, dv);
      if (len > 0 && c.friction > 0) {
        const double shear = c.friction * p.sim.model().force_n(total);
        now.shear_u_n = shear * du / len;
        now.shear_v_n = shear * dv / len;
      }
    }
    out->push_back(now);
  }
  p.last_t_s = std::max(p.last_t_s, t_s);
}

Environment Scene::environment(int i, double t_s) const {
  const PatchState& p = *patches_[i];
  const double angle =
      p.limb.amplitude_rad * std::sin(2 * M_PI * t_s / p.limb.period_s + p.limb.phase_rad);
  const double n = std::sqrt(dot(p.limb.axis, p.limb.axis));
  Environment e;
  // The patch frame turns with the limb: the world field seen in it turns the other way.
  const Mat3 r = rotation_from_vector(n > 0 ? p.limb.axis * (angle / n) : Vec3<double>{});
  e.ambient_ut = r.apply_transposed(config_.earth_field_ut);
  e.temperature_c =
      config_.temperature_c +
      config_.temperature_swing_c * std::sin(2 * M_PI * t_s / config_.temperature_period_s);
  return e;
}

uint64_t Scene::measure(int i, double t_s, std::span<double> field_ut,
                        std::vector<Contact>* truth) {
  std::vector<Contact> local;
  std::vector<Contact>* cs = truth ? truth : &local;
  cs->clear();
  active_contacts(i, t_s, cs);
  (cs->empty() ? idle_ : deformed_) += 1;
  return patches_[i]->sim.measure(*cs, environment(i, t_s), field_ut);
}

}  // namespace skinbus::sim
