// skinbus/estimators/physics_refiner.h: the host's refinement on an identified unit: a
// ContactRefiner (refiner.h) that fits the unit's physics model (PhysicsEstimator::refine) from
// the first estimate, and gives the fit's covariance as the uncertainty.
#pragma once

#include <memory>
#include <optional>
#include <string>

#include "skinbus/common/result.h"
#include "skinbus/estimators/bias_correction.h"
#include "skinbus/estimators/physics_estimator.h"
#include "skinbus/estimators/refiner.h"
#include "skinbus/sim/pressed_area.h"

namespace skinbus::estimators {

// The refiner of the unit in `unit_path` (a unit file, sim/unit_parameters.h, as skinbus-identify
// writes it) built on `design_path` (a design file, docs/design_file.md; empty: the built-in
// design). `options.covariance` is set. A refinement starts from its first estimate; the start
// table is for fits that end poor there (`search_when_poor`) and for counting contacts: with
// `max_contacts` 1 it is coarse (twice start_pitch_mm(design): half the magnet spacing, at most
// 10 mm; depths 1, 2.5 and 4 mm: 675 rows on the built-in design), with 2 or more
// PhysicsOptions' full one. Errors name the file: kNotFound / kParse / kInvalidArgument (a unit
// that does not fit the design, or a fit identification refused: sim::UnitFileNote). Cost: the
// unit's rest field table and the start table, tens of milliseconds (0.1 s with the full table).
//
// search_when_poor: a single-contact fit from the first estimate that ends poor
// (kEstimatePoorFit, or not a contact: a first estimate far from the press, e.g. a network
// trained briefly or meeting a place it was not trained on, leaves the fit in another basin of
// the field) is made again by PhysicsEstimator::search_lm from 3 rows of the start table (the
// nearest in field, then the next nearest 2 table pitches apart) and the lower chi-square kept.
// Cost: three lean fits (each about a refinement's) for those samples only
// (docs/benchmarks/designs.md, "25 sensors"). refine_contacts() with `max_contacts` 2 or 3
// leaves a poor single fit to the contact count's own search (a poor single fit is what starts
// a count); refine() always searches. search() is that search alone (with search_when_poor off
// the start table is one row, the patch centre, and it is one fit from there); given a valid
// held fit, from 2 rows at least 2 table pitches from it (the held fit is its basin's answer).
//
// max_contacts 2 or 3: refine_contacts() counts the contacts of a sample whose single fit leaves
// more than noise (PhysicsEstimator::count_contacts with `count`, its max_contacts set to this
// one), trying the previous sample's contacts first; several contacts carry their fit's reduced
// chi-square and uncertainties. Cost: the single fit, and for a sample with two presses one
// two-contact solve from the previous pair (about 0.5 ms; three presses: one solve a count), or
// when they first appear the full search (a few milliseconds, tens with three).
//
// With a proposer (`proposer`: a model path stem, contact_proposal.h), a sample whose single fit
// leaves more than noise and that holds no previous contacts is first shown to the proposer (one
// network run, ~20 us); when it proposes two or more presses the count starts from them (one
// solve a count) instead of searching from nothing (RefinedContacts::proposed). Errors name the
// proposer's file, or say it is not a proposer.
//
// With a correction (`correction`: a correction file, bias_correction.h, as skinbus-evaluate
// --fit-correction writes it from the unit's own presses), every single-contact fit is corrected
// by it (BiasCorrection::apply: what it was chosen to correct, position and/or depth, at one
// basis evaluation a sample); its uncertainty and reduced chi-square stay the fit's. Two or three
// contacts are not corrected (the correction was learned from single presses). Errors name the
// file.
//
// The indenter the fits assume: the design file's (indenter.tip_radius_mm, the tip the unit was
// calibrated with); `options.physics.tip_radius_mm` is replaced by it.
//
// A unit whose creep identification found (its model's design's creep_fraction: a unit file's
// `creep`) has it undone along each press by press_depth_mm() in the patch's memory
// (CreepCompensator): the fits give the plate's bend, the host publishes the press's depth.
//
// With a pressed area (`pressed_area`: the unit file's, sim::UnitFileNote, which the path
// version sets), every refined contact placed outside it (widened by sim::kPressedAreaMarginMm)
// carries kEstimateExtrapolated: the unit's model was not fitted there, and its uncertainty is
// the model's.
struct RefinerOptions {
  PhysicsOptions physics;
  int max_contacts = 1;  // 1 to kMaxContacts
  ContactCountOptions count;
  std::string proposer;    // "" none
  std::string correction;  // "" none
  bool search_when_poor = true;
  std::optional<sim::PressedArea> pressed_area;  // none: nothing is flagged extrapolated
};
Result<std::unique_ptr<ContactRefiner>> make_physics_refiner(const std::string& unit_path,
                                                             const std::string& design_path,
                                                             const RefinerOptions& options = {});

// The same over a model (tests, benchmarks).
Result<std::unique_ptr<ContactRefiner>> make_physics_refiner(const sim::PatchModel& model,
                                                             const RefinerOptions& options = {});

}  // namespace skinbus::estimators
