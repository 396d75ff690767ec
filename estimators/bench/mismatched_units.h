// mismatched_units.h (internal to the estimators' reports): the units the count reports measure:
// the unit itself, and units whose physics the nominal design's model lacks, on which they
// measure what a mismatch does.
#pragma once

#include <vector>

#include "skinbus/estimators/physics_estimator.h"
#include "skinbus/sim/patch_model.h"

namespace skinbus::estimators_bench {

// A unit and the estimator that looks at it (not owned: the caller's, outliving the case).
struct CountCase {
  const char* unit;
  const char* model;  // the estimator's model, as the tables name it
  sim::PatchModel truth;
  const estimators::PhysicsEstimator* estimator;
};

// `unit` with `own` (the estimator on its own model), then, each with `nominal` (the estimator
// on the nominal model of `design`), an anisotropic lattice (spread 20 % longer along u than v),
// a stiffer in-plane coupling and a fabricated unit (UID 7) of `design` (a design the model
// cannot hold: aborts).
inline std::vector<CountCase> count_cases(const sim::PatchDesign& design,
                                          const sim::PatchModel& unit,
                                          const estimators::PhysicsEstimator* own,
                                          const estimators::PhysicsEstimator* nominal) {
  sim::PatchDesign anisotropic = design, lateral = design;
  anisotropic.anisotropy = 0.1;
  lateral.lateral_mm = 2.6;
  std::vector<CountCase> out;
  out.push_back({"fabricated", "its own", unit, own});
  out.push_back({"anisotropic 0.1", "nominal design", sim::PatchModel::nominal(anisotropic).value(),
                 nominal});
  out.push_back(
      {"lateral 2.6 mm", "nominal design", sim::PatchModel::nominal(lateral).value(), nominal});
  out.push_back({"fabricated (UID 7)", "nominal design",
                 sim::PatchModel::fabricated(design, 7, sim::FabricationVariation{}).value(),
                 nominal});
  return out;
}

}  // namespace skinbus::estimators_bench
