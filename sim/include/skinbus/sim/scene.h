// skinbus/sim/scene.h: a whole-body scene: many patches, contacts over time, moving limbs.
//
// Each patch is a fabricated unit (its hardware UID seeds its variation and noise) on a limb
// whose orientation changes over time, so it sees the Earth's field turn (a uniform ambient
// change of up to ~50 uT). Contacts press, hold and release with a ramp; the TPU creeps under a
// held press (first-order lag). Only patches with an active contact evaluate the lattice
// deformation; the others cost one noisy rest-field measurement ("skip what a scene does not
// need"), and a scene can report which patches are touched without measuring at all.
#pragma once

#include <cmath>
#include <cstdint>
#include <limits>
#include <memory>
#include <vector>

#include "skinbus/common/result.h"
#include "skinbus/sim/simulated_patch.h"

namespace skinbus::sim {

struct LimbMotion {
  Vec3<double> axis{1, 0, 0};  // rotation axis of the limb (world frame), need not be unit
  double amplitude_rad = 0;    // orientation swings by +-amplitude
  double period_s = 4;
  double phase_rad = 0;
};

struct SceneContact {
  int patch = 0;
  double t_start_s = 0, t_end_s = 1;  // pressed between these times (ramps included)
  double u_mm = 0, v_mm = 0;
  double depth_mm = 2;         // held depth
  double ramp_s = 0.15;        // press-in and release time
  double tip_radius_mm = 8.0;  // a fingertip
  // A sliding press: it moves at constant speed from (u_mm, v_mm) at t_start_s to (u_end_mm,
  // v_end_mm) at t_end_s (NaN: it stays), dragging the skin along with a shear force of
  // `friction` times its normal force (kinetic friction; 0: none) while it moves.
  double u_end_mm = std::numeric_limits<double>::quiet_NaN();
  double v_end_mm = std::numeric_limits<double>::quiet_NaN();
  double friction = 0;
  bool slides() const { return std::isfinite(u_end_mm) && std::isfinite(v_end_mm); }
};

struct SceneConfig {
  Vec3<double> earth_field_ut{0, 19, -45};  // world frame; |B| ~ 49 uT (mid latitudes)
  double temperature_c = 25;
  double temperature_swing_c = 0;  // slow sinusoidal drift of every patch
  double temperature_period_s = 600;
  double creep_fraction = 0.05;  // held press sinks this fraction further ...
  double creep_tau_s = 2.0;      // ... with this time constant
};

class Scene {
 public:
  explicit Scene(SceneConfig config = {}) : config_(config) {}

  // Adds a fabricated patch; returns its index. The error names what is wrong.
  Result<int> add_patch(uint64_t hardware_uid, const PatchDesign& design,
                        const LimbMotion& limb = {});
  Status add_contact(const SceneContact& c);

  int patch_count() const { return static_cast<int>(patches_.size()); }
  SimulatedPatch& patch(int i) { return patches_[i]->sim; }
  uint64_t uid(int i) const { return patches_[i]->uid; }

  // The contacts pressing patch `i` at `t_s` (depth after ramps and creep; a sliding press where
  // it is then, with its shear), appended to `out`.
  void active_contacts(int i, double t_s, std::vector<Contact>* out);
  // The environment of patch `i` at `t_s`: the Earth's field in its frame, its temperature.
  Environment environment(int i, double t_s) const;

  // Measures patch `i` at `t_s` (absolute field, uT). Times of one patch must not decrease
  // (the creep state moves forward). Returns the saturation mask.
  uint64_t measure(int i, double t_s, std::span<double> field_ut,
                   std::vector<Contact>* truth = nullptr);

  // How many measurements evaluated a deformation, and how many were idle.
  uint64_t deformation_evaluations() const { return deformed_; }
  uint64_t idle_evaluations() const { return idle_; }

 private:
  struct PatchState {
    uint64_t uid;
    SimulatedPatch sim;
    LimbMotion limb;
    std::vector<int> contacts;     // indices into contacts_
    std::vector<double> creep_mm;  // per contact of this patch
    double last_t_s = 0;
  };
  double depth_profile(const SceneContact& c, double t_s) const;

  SceneConfig config_;
  std::vector<std::unique_ptr<PatchState>> patches_;
  std::vector<SceneContact> contacts_;
  uint64_t deformed_ = 0, idle_ = 0;
};

}  // namespace skinbus::sim
