// skinbus/estimators/field_correction_fit.h: learns what a unit's field does beyond its identified
// model, from the unit's own presses: a sim::FieldCorrection (skinbus/sim/field_correction.h).
//
// Input: the identified model (estimators/unit_identification.h) and the presses it was
// identified on, at known (u, v, depth). Every sample at least min_depth_mm deep gives the
// residual (measured - modelled field change) at its press; per channel, the correction's
// coefficients minimise the squared residual left plus a smoothing penalty (squared second
// differences of the coefficients along u and along v, `smoothing` times the data's mean
// normal-equation diagonal) and a small ridge, one shared factorisation for every channel.
//
// Choice, by held-out error: the press places fall into cells of their spacing (the median
// distance to the nearest other place) and the cells into `folds` folds by (i + 2 j) mod folds,
// so no held-out place has a held-out neighbour; each fold's samples are predicted by a
// correction fitted on the others, at every knot spacing (`steps_rel` x the place spacing) and
// smoothing tried. The pair with the lowest held-out residual (RMS over every channel of every
// held-out sample, noise units) is fitted again on every sample and returned. The correction
// helps (FieldCorrectionReport::helps) when that held-out residual is at least min_gain below
// the model's own on the same samples: a check on places the fit never saw, as a new press's
// place is.
//
// Cost: per spacing, one pass over the samples (16 x kDepthTerms basis weights each, their outer
// products into a dense normal matrix of nu nv kDepthTerms unknowns) and folds x smoothings + 1
// dense Cholesky factorisations of it; for the seed's 361 presses (19 x 19 at 6 mm) a few
// seconds on one core, memory (folds + 3) x that matrix (about 14 MB each at 6 mm knots).
#pragma once

#include <memory>
#include <string>
#include <vector>

#include "skinbus/common/result.h"
#include "skinbus/estimators/creep.h"
#include "skinbus/estimators/lookup_estimator.h"
#include "skinbus/sim/dataset.h"
#include "skinbus/sim/field_correction.h"
#include "skinbus/sim/patch_model.h"
#include "skinbus/sim/unit_parameters.h"

namespace skinbus::estimators {

struct FieldCorrectionOptions {
  std::vector<double> steps_rel = {1.0, 1.5, 2.0};     // knot spacings, x the place spacing
  std::vector<double> smoothing = {1e-3, 1e-2, 1e-1};  // penalties tried (see above)
  double ridge = 1e-6;                                 // x the mean diagonal, always added
  double min_depth_mm = 0.3;                           // shallower samples are not used
  int folds = 5;
  double min_gain = 0.02;    // helps: held-out RMS at most (1 - min_gain) x the model's
  ChannelNoise noise{0, 0};  // 0: the design's sensor noise
  std::vector<double> depth_bin_edges_mm = {0, 1, 2, 3, 4, 9};
};

struct FieldCorrectionReport {
  int samples = 0, places = 0;
  double place_spacing_mm = 0;
  struct Tried {
    double step_mm = 0, smoothing = 0;
    double held_out_rms = 0;  // noise units, with the correction fitted without the samples' places
  };
  std::vector<Tried> tried;
  double step_mm = 0, smoothing = 0;  // chosen
  // Residual RMS (noise units) over every used sample: the model's own, the chosen correction's
  // at held-out places, and on the samples it was fitted on.
  double rms_model = 0, rms_held_out = 0, rms_fitted = 0;
  // Per depth bin (options' edges): the same three, and the samples in it.
  struct Bin {
    double depth_lo_mm = 0, depth_hi_mm = 0;
    int samples = 0;
    double rms_model = 0, rms_held_out = 0, rms_fitted = 0;
  };
  std::vector<Bin> bins;
  bool helps = false;
  // How much of what the model leaves above the noise the correction explains at held-out
  // places: 1 - (rms_held_out^2 - 1) / (rms_model^2 - 1), each excess at least 0 (0 when the
  // model leaves none; below 0 when the correction adds error).
  double explained() const;
  // One line for a tool's log: "field correction: residual M -> H noise units at held-out places
  // (F fitted; E % of the residual's excess over the noise explained), knots S mm, smoothing L,
  // N samples at P places: helps|does not help", then the bins.
  std::string summary_text() const;
};

// Learns the correction of `model` (its own correction, if any, is not used: the residual is
// taken against the class) from `presses` (rows with depth >= options.min_depth_mm and at least
// half their channels finite: a value that is not, a dead channel's, adds nothing to its
// channel's fit, which it pulls toward 0, and is left out of every residual) pressed with a round
// tip of `tip_radius_mm`. Press places closer than 1 mm count as 1 mm apart for the knots. Errors:
// kInvalidArgument for a channel count other than the model's or empty option lists; kDegenerate
// for fewer than 10 x folds press places or fewer samples than twice the unknowns at the finest
// spacing tried.
Result<sim::FieldCorrection> fit_field_correction(const sim::PatchModel& model,
                                                  const sim::Dataset& presses, double tip_radius_mm,
                                                  const FieldCorrectionOptions& options,
                                                  FieldCorrectionReport* report);

// The creep and the field correction of a unit whose model class leaves physics, found in turn.
// A creep fitted on the class's model alone (identify_unit) can take that physics for lag: a top
// that crushes under the tip bends less the deeper it is pressed, as a slow lag's bends on the
// way down do. The candidates, each a law and the correction learned at the bends it gives:
// - the unit's own law (as identified), when it has one;
// - no creep: the correction learned on the presses as recorded, where a ramp's two ways,
//   pressing and releasing, weigh alike and a lag only spreads the residual;
// - round r = 1..rounds: a one-lag law fitted (fit_creep without its second lag: on a corrected
//   model, its pairs' search can take one lag for a fast and a slow one) on the unit's model
//   corrected by the previous round's correction (round 1: the no-creep one's), and the
//   correction learned again at its bends; rounds stop early when no law is kept there.
// The candidate whose correction leaves the lowest residual at held-out places
// (FieldCorrectionReport::rms_held_out: the whole model, law and correction, predicting fields
// at press places its correction never saw) is chosen.
struct CreepAndCorrection {
  struct Candidate {
    std::string what;  // "identified", "none", "round 1", ...
    CreepLaw law;
    double held_out_rms = 0;  // noise units
  };
  std::vector<Candidate> candidates;
  int chosen = 0;  // index into candidates
  CreepLaw law;    // the chosen law (none(): no creep)
  // The chosen correction (as sim::UnitParameters::field_correction holds it) and its report.
  std::shared_ptr<const sim::FieldCorrection> correction;
  FieldCorrectionReport report;
  // "creep with the field correction: identified (F of the bend lags by T s) 1.423, none 2.496,
  // round 1 (...) 1.400 noise units at held-out places: round 1 kept".
  std::string summary_text() const;
};

// `unit`: the identified parameters (its own field correction is not used; its creep is the
// first candidate). With `choose_creep` false (a unit its class explains) the unit's own law is
// the only candidate ("identified", or "none" when it has none): the correction learned at its
// bends alone. Errors: those of fit_field_correction for the candidates (a candidate whose law is
// not kept by fit_creep just ends the rounds); kInvalidArgument for a channel count other than
// the unit's. Cost: 2 + rounds corrections and `rounds` creep fits (each a few seconds for the
// seed's 361 ramps), one correction without choose_creep; allocates.
Result<CreepAndCorrection> fit_creep_and_correction(
    const sim::PatchDesign& design, const sim::UnitParameters& unit, const sim::Dataset& presses,
    double tip_radius_mm, const FieldCorrectionOptions& correction_options,
    const CreepFitOptions& creep_options, bool choose_creep = true, int rounds = 2);

}  // namespace skinbus::estimators
