// skinbus/estimators/refiner.h: a second, costlier estimate of one sample, started from a first
// one: the host's refinement of a network's answer (docs/aggregator.md, "Physics refinement").
//
// The interface lives here, with the estimates, so that the host runs refiners without linking
// how they are made; physics_refiner.h makes one that fits the identified unit's physics model
// by Levenberg-Marquardt (Ceres).
#pragma once

#include <limits>
#include <memory>
#include <span>

#include "skinbus/estimators/estimate.h"

namespace skinbus::estimators {

struct RefinedEstimate {
  // The refined contact (mm, patch frame), with the refiner's flags: kEstimatePoorFit when the
  // fit leaves much more than noise (the caller should keep its first estimate), kEstimateRejected
  // when it could not fit (too few channels, non-finite).
  ContactEstimate contact;
  double sigma_uv_mm = std::numeric_limits<double>::quiet_NaN();   // 1-sigma, radial; NaN: none
  double reduced_chi2 = std::numeric_limits<double>::quiet_NaN();  // the fit's, noise units
  // With a refiner that fits the shear (contact.shear_u_n, shear_v_n): its 1-sigma,
  // sqrt(var F_u + var F_v), N; NaN: the shear was not fitted.
  double sigma_shear_n = std::numeric_limits<double>::quiet_NaN();
};

// Every contact a refiner found in one sample (refine_contacts()): the first `count` (1 to
// kMaxContacts).
struct RefinedContacts {
  int count = 1;
  RefinedEstimate contacts[kMaxContacts];
  bool searched = false;  // a search for a second contact was made (whatever it found)
  bool proposed = false;  // the count started from a proposer's presses instead (no search)
  // The single-contact fit's reduced chi-square (what decides a search), NaN if none was made.
  double single_reduced_chi2 = std::numeric_limits<double>::quiet_NaN();
};

class ContactRefiner {
 public:
  virtual ~ContactRefiner() = default;
  // What a refiner carries from one sample of a patch to the next (the physics refiner: the
  // model's Jacobian where its last single fit ended, PhysicsEstimator's WarmJacobian, which
  // spares the next sample's fit computing it). The caller makes one a patch with this refiner's
  // make_memory() (null: the refiner keeps nothing; it allocates) and passes it with that
  // patch's samples only, one refine_contacts() call at a time; every other call stays const
  // and thread-safe.
  class Memory {
   public:
    virtual ~Memory() = default;
  };
  virtual std::unique_ptr<Memory> make_memory() const { return nullptr; }
  // The channels a sample must hold (3 per sensor of the unit's design): refine() and
  // refine_contacts() reject a sample of another length (kEstimateRejected or no contact).
  virtual int channel_count() const = 0;
  // Refines `start` (the first estimate, patch frame) for a tared sample (`field_ut`: the model's
  // channel count in uT; `channel_ok`: 0 for channels to leave out, empty: all). Const and
  // thread-safe; cost: the refiner's (a few Levenberg-Marquardt iterations for the physics one).
  virtual RefinedEstimate refine(std::span<const double> field_ut,
                                 std::span<const uint8_t> channel_ok,
                                 const ContactEstimate& start) const = 0;
  // The same, for a refiner that may find more than one contact in a sample (two fingers on one
  // patch): `previous` holds the same patch's last refined contacts (2 or 3: tried first, at the
  // cost of one solve a count) or nothing; without them, the costly search for a second
  // contact from nothing is made only when the single fit's reduced chi-square is above
  // `search_above_chi2` as well as the refiner's own threshold (the caller rate-limits searches:
  // a unit whose physics the model lacks leaves more than noise on every sample; infinity: no
  // search). `memory`: the patch's (make_memory()), or null. By default the one contact of
  // refine().
  virtual RefinedContacts refine_contacts(std::span<const double> field_ut,
                                          std::span<const uint8_t> channel_ok,
                                          const ContactEstimate& start,
                                          std::span<const ContactEstimate> previous,
                                          double search_above_chi2, Memory* memory) const {
    (void)previous;
    (void)search_above_chi2;
    (void)memory;
    RefinedContacts out;
    out.contacts[0] = refine(field_ut, channel_ok, start);
    return out;
  }
  // The press's depth (mm) for a sample's single refined contact, at the patch's sample time
  // `t_s` (s, increasing), `same_press`: the patch's previous sample was of this press. A refiner
  // fits the plate's bend; on a unit whose lattice creeps (the physics refiner of a unit file
  // with an identified creep, creep.h) the bend lags the press, and this undoes the lag along
  // the press, in the patch's `memory`. By default, and without a memory, the contact's depth.
  // The caller keeps the fitted depth (the bend) for its next warm start. Cost: an exp.
  virtual double press_depth_mm(const ContactEstimate& refined, double t_s, bool same_press,
                                Memory* memory) const {
    (void)t_s;
    (void)same_press;
    (void)memory;
    return refined.depth_mm;
  }
  // One contact searched from the refiner's own starts rather than a given one (the physics
  // refiner: the nearest rows of its start table), for a caller that suspects the press it
  // follows sits in another minimum of the fit (a warm start carried from a press's shallow
  // first samples, where two places can look alike). The caller compares its reduced chi-square
  // with its own fit's. `held`: the fit the caller holds, when valid(); the search may leave out
  // its basin (the physics refiner: start rows within two table pitches of it, and one start
  // fewer). Cost: several refine()s. By default refine() from `held`.
  virtual RefinedEstimate search(std::span<const double> field_ut,
                                 std::span<const uint8_t> channel_ok,
                                 const ContactEstimate& held) const {
    return refine(field_ut, channel_ok, held);
  }
};

}  // namespace skinbus::estimators
