// skinbus/estimators/physics_estimator.h: the physics inversion: least-squares fit of one contact
// to a tared sample through the simulator's forward model.
//
// Unknowns: the contact (u, v, depth; mm, patch frame) and a uniform ambient field offset
// (3 values, uT, patch frame: what the Earth's field adds as the limb turns after the tare),
// which reaches each channel through the sensor's rotation and gain. Residual of channel c:
//   (contact_field_ut(u, v, depth)[c] + ambient projected on c - sample[c]) / sigma_c,
// sigma the sensor noise of the design's configuration (sim/mlx90393.h), so the final cost is
// in noise units: a correct model leaves a reduced chi-square near 1. Masked channels
// (channel_ok == 0 from the caller, NaN/Inf, saturated) are left out. Solved by Ceres'
// Levenberg-Marquardt with the exact Jacobian (forward-mode jets, Ceres', through the
// simulator's template), depth bounded to
// [1e-3, max_depth_mm()], (u, v) to the patch extent plus a margin.
//
// Start: the nearest row of a lookup table (skinbus/estimators/lookup_estimator.h; a coarse grid of
// the same model by default), or a given guess (refine(): e.g. "refine the network's answer").
//
// Flags (skinbus/estimators/estimate.h): kEstimateMasked, kEstimateRejected with kTooFewChannels,
// kEstimateNotConverged (iteration limit or solver failure), kEstimatePoorFit (reduced
// chi-square above options.poor_fit_ratio: the model or the sample is off), kEstimateNoContact
// (the fitted contact's whitened signal energy is below options.no_contact_snr^2), range flags by
// flag_range(); a non-finite result becomes a rejection. Force from PatchModel::force_n(depth).
//
// Cost: one forward Jacobian (~30 magnets x 16 sensors dipoles in jets) per iteration, about
// 3 iterations on average, plus the lookup for the start (times: docs/physics_estimator.md). A
// start ending in a poor fit is retried from the next nearest rows (up to 3 starts). estimate() is
// const and thread-safe (each call builds its own small Ceres problem; it allocates).
#pragma once

#include <cstdint>
#include <limits>
#include <span>
#include <vector>

#include "skinbus/common/result.h"
#include "skinbus/estimators/estimate.h"
#include "skinbus/estimators/lookup_estimator.h"
#include "skinbus/sim/patch_model.h"

namespace skinbus::estimators {

struct PhysicsOptions {
  double tip_radius_mm = 5.0;  // the indenter's round tip (sim::RampProtocol's default)
  bool fit_ambient = true;     // fit the uniform ambient offset (else held at 0)
  int max_iterations = 30;
  double function_tolerance = 1e-7;   // Ceres' relative cost change for convergence
  double parameter_tolerance = 1e-8;  // Ceres' relative step size for convergence
  int min_channels = 12;              // fewer usable channels: rejected (kTooFewChannels)
  double poor_fit_ratio = 4.0;        // reduced chi-square above this: kEstimatePoorFit
  double no_contact_snr = 5.0;        // fitted contact signal (whitened norm) below: kNoContact
  double uv_margin_mm = 15.0;         // (u, v) bounds: the patch extent plus this
  ChannelNoise noise{0, 0};           // 0: the design's sensor noise
  InputLimits limits;                 // saturation threshold for check_sample()
  // The start table built by create() when none is given: a coarse grid of the model. Pitch 0:
  // start_pitch_mm(design), which follows the magnets (a start must fall within the basin of
  // the field pattern, which repeats at the magnet spacing). Its rows are pressed with
  // tip_radius_mm above (the grid's own tip is not used).
  LookupGrid start_grid{0.0, {0.5, 1.0, 2.0, 3.0, 4.0, 5.5}, 5.0};
  // Also compute the fit's covariance (PhysicsEstimate::sigma_*): one more Jacobian and a 6 x 6
  // inverse per sample.
  bool covariance = false;
  // Also fit a tangential (shear) force at the contact (ContactEstimate::shear_u_n, shear_v_n;
  // the model's shear law, sim::PatchDesign::shear_stiffness_n_per_mm): 2 more unknowns, each
  // component within +-100 N. refine_lm() fits it jointly; estimate() and refine() make their fit
  // without it and then refine_lm() from there. Costs the position some precision (the shear
  // moves the magnets as a shifted press partly does: skinbus-crlb --shear).
  bool fit_shear = false;
  // estimate() and refine(): besides the nearest start, fit from up to this many rows of the
  // start table that are nearest the sample in field but at least 2 start pitches (half the
  // magnet spacing, at most 10 mm) from the fit and from each other; the lowest chi-square wins.
  // Where the field is ambiguous (presses beyond the magnets, a one-polarity grid) two places
  // fit nearly alike and the nearest start may find the wrong one (docs/benchmarks/designs.md).
  // Each costs one more fit. 0: only the nearest starts.
  int other_basins = 2;
};

// The start table's pitch for a design: the magnets' spacing (their grid pitch, or the median
// nearest-neighbour distance of a listed layout) / kStartPitchPerMagnetSpacing, at most 5 mm
// (the built-in design's 20 mm pitch gives 5 mm).
inline constexpr double kStartPitchPerMagnetSpacing = 4.0;
double start_pitch_mm(const sim::PatchDesign& design);

struct PhysicsEstimate {
  ContactEstimate contact;
  double ambient_ut[3] = {0, 0, 0};  // fitted uniform ambient offset, patch frame, uT
  int iterations = 0;                // Levenberg-Marquardt iterations
  double chi2 = 0;                   // final sum of squared whitened residuals (noise units)
  double reduced_chi2 = 0;           // chi2 / (channels used - unknowns); ~1 for a good fit
  int channels_used = 0;
  // The lean fit's costs (refine_lm(), search_lm(): summed over its starts): field evaluations
  // (sim::PatchModel::contact_field_ut) and exact Jacobians computed (contact_field_jacobian_ut,
  // about two evaluations' time each). 0 from the Ceres fits.
  int field_evaluations = 0;
  int jacobians = 0;
  // With PhysicsOptions::covariance: 1-sigma uncertainties from the fit's covariance (the inverse
  // of J^T J of the whitened residuals over the contact and the ambient offset, scaled by the
  // reduced chi-square when it is above 1: a fit worse than the noise widens them): the
  // position's radial sigma sqrt(var u + var v) and the depth's, mm. NaN otherwise, or when the
  // fit is singular (e.g. a contact beyond every magnet's reach).
  double sigma_uv_mm = std::numeric_limits<double>::quiet_NaN();
  double sigma_depth_mm = std::numeric_limits<double>::quiet_NaN();
  // With covariance and fit_shear: the shear force's sqrt(var F_u + var F_v), N.
  double sigma_shear_n = std::numeric_limits<double>::quiet_NaN();
};

// How many contacts a sample holds (0 to max_contacts, at most kMaxContacts) and where:
// PhysicsEstimator::estimate_contacts(). One more contact is fitted only when the fit of one
// fewer leaves more than noise (reduced chi-square above `try_ratio`), by Levenberg-Marquardt
// over every contact's (u, v, depth) and the ambient offset, started from the fewer contacts and
// a single fit of what they leave, then from each of them split `start_offset_mm` each way along
// 4 directions (the best of the starts is kept); it is kept only when it explains the sample to
// near the noise (reduced chi-square <= `max_reduced_chi2`), lowers the chi-square by at least
// `min_chi2_drop` (noise units; 3 ln(48) = 11.6 is the Bayesian information criterion's price of
// 3 more unknowns on 48 channels), improves the reduced chi-square `min_improvement` times, and
// its contacts are each at least `min_separation_mm` from the others and `min_depth_mm` deep. A
// model mismatch the fewer contacts cannot absorb must not become one more press: 3 more unknowns
// absorb much of a mismatch too (a single press on a unit outside the model class, fitted at
// 2-20x the noise, is fitted near the noise by two: improvements up to 15x seen in ~1000 such
// presses), so the improvement asked is larger than a mismatch gives; 97 % of two presses 30 mm
// apart give more (docs/benchmarks/two_contacts.md; three: docs/benchmarks/three_contacts.md).
struct ContactCountOptions {
  int max_contacts = 2;  // 1 to kMaxContacts
  double try_ratio = 1.5;
  double max_reduced_chi2 = 1.6;
  double min_chi2_drop = 11.6;
  double min_improvement = 20;
  double min_separation_mm = 8;
  double min_depth_mm = 0.3;
  double start_offset_mm = 10;
};

struct ContactCountEstimate {
  int count = 0;                           // contacts in the sample: 0 to max_contacts
  ContactEstimate contacts[kMaxContacts];  // the first `count` are valid
  // With PhysicsOptions::covariance: each contact's radial 1-sigma (a several-contact fit's from
  // its covariance), mm; NaN otherwise or when singular.
  double sigma_uv_mm[kMaxContacts] = {std::numeric_limits<double>::quiet_NaN(),
                                      std::numeric_limits<double>::quiet_NaN(),
                                      std::numeric_limits<double>::quiet_NaN()};
  // With fit_shear, several contacts carry each its own shear (ContactEstimate::shear_u_n,
  // shear_v_n) and, with covariance, its 1-sigma sqrt(var F_u + var F_v), N; NaN otherwise.
  double sigma_shear_n[kMaxContacts] = {std::numeric_limits<double>::quiet_NaN(),
                                        std::numeric_limits<double>::quiet_NaN(),
                                        std::numeric_limits<double>::quiet_NaN()};
  double ambient_ut[3] = {0, 0, 0};  // the kept fit's ambient offset, patch frame, uT
  PhysicsEstimate single;            // the single-contact fit (always made)
  bool pair_tried = false;           // the two-contact fit was made
  double pair_chi2 = 0;              // its chi-square (noise units), when tried
  double pair_reduced_chi2 = 0;      // chi2 / (channels used - unknowns)
  int pair_iterations = 0;
  bool triple_tried = false;  // the three-contact fit was made (max_contacts 3, two kept)
  double triple_chi2 = 0;
  double triple_reduced_chi2 = 0;
  int triple_iterations = 0;
};

// The model's Jacobian where a single-contact fit ended, kept for the next sample of the same
// press (presses move a fraction of a millimetre between samples): refine_lm() given one that
// holds a Jacobian within 0.5 mm of its start begins from it, corrected along the way (Broyden's
// rank-one update, from the field change the move made), instead of computing it
// (sim::PatchModel::contact_field_jacobian_ut, about two field evaluations' time), and leaves
// its own in it. At most kMaxUses fits in a row reuse it; the next computes it again, so updates
// do not drift. A fit that begins exactly where the last one ended (the host's warm start, the
// last published contact) takes that fit's field at its start from it too: the model's field
// depends on the contact alone, so one evaluation fewer, the same fit to the bit. One a press,
// owned by the caller, one fit at a time; about 37 KB. No allocation.
struct WarmJacobian {
  static constexpr int kMaxUses = 4;
  bool valid = false;
  int unknowns = 0;  // the contact's: 3 (u, v, depth), 5 with the shear
  int uses = 0;      // fits in a row that began from it since it was last computed
  double at[5] = {};
  double field_ut[kMaxChannels] = {};      // the contact's field change at `at`
  double jacobian[kMaxChannels * 5] = {};  // row-major, channels x unknowns
};

class PhysicsEstimator {
 public:
  // An estimator over `model` (copied), with its own start table from options.start_grid
  // (~5k rows, ~0.1 s to build). Errors: invalid options.
  static Result<PhysicsEstimator> create(const sim::PatchModel& model,
                                         const PhysicsOptions& options = {});
  // The same with a given start table (e.g. one built from the unit's training presses); its
  // channel count must match the model's.
  static Result<PhysicsEstimator> create(const sim::PatchModel& model,
                                         const PhysicsOptions& options, LookupEstimator start);

  const sim::PatchModel& model() const { return model_; }
  const PhysicsOptions& options() const { return options_; }
  const LookupEstimator& start_table() const { return start_; }

  // One tared sample (model().channel_count() values, uT; `channel_ok` as in
  // LookupEstimator::estimate()) to a contact, started from the lookup's nearest row.
  PhysicsEstimate estimate(std::span<const double> field_ut,
                           std::span<const uint8_t> channel_ok = {}) const;
  // The same started from `guess` (its u, v, depth; another estimator's answer).
  PhysicsEstimate refine(std::span<const double> field_ut, std::span<const uint8_t> channel_ok,
                         const ContactEstimate& guess) const;
  // The same fit as refine() by a lean Levenberg-Marquardt of its own (no Ceres; the exact
  // Jacobian of the vectorised field, PatchModel::contact_field_jacobian_ut, and after a step
  // shorter than 0.5 mm updated along it instead (Broyden), with no field evaluation; it ends
  // when a step gains less than 1e-3 in chi-square, or is predicted to by the exact Jacobian's
  // linear model (then unevaluated); the ambient
  // offset's columns are constant; with options().fit_shear the shear too, started from
  // `start`'s), for the host's refinement of every touched sample: from a start within a few
  // millimetres it reaches the same minimum, to a few percent of the fit's own uncertainty (tested
  // against refine()), at a fraction of the cost (docs/benchmarks/refinement.md). One start only;
  // a fit that ends poor is flagged (kEstimatePoorFit), not retried. With `warm` (the same
  // press's previous fit's; WarmJacobian) it begins from that Jacobian when it lies near `start`
  // (and from that fit's field when `start` is where it ended) and leaves its own there. No
  // allocation.
  PhysicsEstimate refine_lm(std::span<const double> field_ut, std::span<const uint8_t> channel_ok,
                            const ContactEstimate& start, WarmJacobian* warm = nullptr) const;
  // refine_lm() from up to `starts` (1-8) rows of the start table: the nearest the sample in
  // field, then the next nearest at least 2 of the table's pitches from those taken (other
  // basins of the field); the lowest chi-square kept. With `apart_from` (a fit the caller holds),
  // no row within 2 pitches of it either: that basin is the caller's already. A row's fit that
  // comes within 1 mm (in u, v) of `apart_from` or of an earlier row's converged fit stops there
  // without a fit of its own (that basin's minimum is known). A search of the table at the lean
  // fit's cost (`starts` fits at most), for a fit from another estimator's answer that ended
  // poor. kEstimateRejected when no start gave a fit of its own. No allocation.
  PhysicsEstimate search_lm(std::span<const double> field_ut, std::span<const uint8_t> channel_ok,
                            int starts = 3, const ContactEstimate* apart_from = nullptr) const;
  // The number of contacts in the sample (0 to count.max_contacts) and each one
  // (ContactCountOptions). Cost: estimate(), and when the single fit leaves more than noise, a
  // single fit of what it leaves and up to 5 two-contact solves (the lean Levenberg-Marquardt of
  // refine_lm() over both contacts and the ambient offset; each ~2-3x a single one); with
  // max_contacts 3, when the pair still leaves more than noise, up to 9 three-contact solves.
  // With fit_shear each contact has its own shear (5 unknowns a contact; the information
  // criterion's drop is then min_chi2_drop x 5/3).
  ContactCountEstimate estimate_contacts(std::span<const double> field_ut,
                                         std::span<const uint8_t> channel_ok = {},
                                         const ContactCountOptions& count = {}) const;
  // The same from a single-contact fit already made of this sample (`single`: estimate(),
  // refine() or refine_lm()), and the contacts to try first when given (`previous`: 2 or 3, e.g.
  // the previous sample's): the host's refinement counts contacts after its own single fit and
  // follows several presses from sample to sample at the cost of one solve a count. With
  // previous contacts given, a single fit that found nothing (kEstimateNoContact: started between
  // two presses, it can run off the patch) does not end the count: they are still tried. With
  // three given, the pair is fitted from the deepest two only (one solve), the three next.
  ContactCountEstimate count_contacts(std::span<const double> field_ut,
                                      std::span<const uint8_t> channel_ok,
                                      const PhysicsEstimate& single,
                                      const ContactCountOptions& count = {},
                                      std::span<const ContactEstimate> previous = {}) const;

 private:
  PhysicsEstimator(const sim::PatchModel& model, const PhysicsOptions& options,
                   LookupEstimator start);
  PhysicsEstimate solve(std::span<const double> field_ut, std::span<const uint8_t> channel_ok,
                        const ContactEstimate* guess) const;
  // A fit of several contacts as count_contacts() keeps it from one count to the next, whether or
  // not it was accepted: its contacts, ambient offset and chi-square.
  struct CountFit {
    int count = 0;
    ContactEstimate contacts[kMaxContacts];
    double ambient_ut[3] = {0, 0, 0};
    double chi2 = 0, reduced_chi2 = 0;
  };
  // count_contacts()'s fit of K contacts (each with its shear when Shear) from `base` (K - 1
  // contacts: the single fit, or the best pair fit whether kept or not), judged against it;
  // the best fit into `fitted`.
  template <int K, bool Shear>
  ContactCountEstimate count_more(std::span<const double> field_ut,
                                  std::span<const uint8_t> channel_ok,
                                  const ContactCountOptions& count,
                                  std::span<const ContactEstimate> previous, const CountFit& base,
                                  CountFit* fitted, ContactCountEstimate out) const;
  void covariance(const sim::Contact& c, const uint8_t* ok, const double* inv_sigma,
                  PhysicsEstimate* out) const;

  sim::PatchModel model_;
  PhysicsOptions options_;
  LookupEstimator start_;
  double other_basin_mm_ = 0;        // PhysicsOptions::other_basins: 2 start pitches
  std::vector<double> ambient_jac_;  // channels x 3: d channel / d ambient (patch frame)
};

}  // namespace skinbus::estimators
