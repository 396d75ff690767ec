// skinbus/estimators/physics_refiner.h: the host's refinement on an identified unit: a
// ContactRefiner (refiner.h) that fits the unit's physics model (PhysicsEstimator::refine) from
// the first estimate, and gives the fit's covariance as the uncertainty.
#pragma once

#include <memory>
#include <string>

#include "skinbus/common/result.h"
#include "skinbus/estimators/physics_estimator.h"
#include "skinbus/estimators/refiner.h"

namespace skinbus::estimators {

// The refiner of the unit in `unit_path` (a unit file, sim/unit_parameters.h, as skinbus-identify
// writes it) built on `design_path` (a design file, docs/design_file.md; empty: the built-in
// design). `options.covariance` is set; no start table is built (a refinement starts from its
// first estimate). Errors name the file: kNotFound / kParse / kInvalidArgument (a unit that does
// not fit the design). Cost: the unit's rest field table, a few milliseconds.
Result<std::unique_ptr<ContactRefiner>> make_physics_refiner(const std::string& unit_path,
                                                             const std::string& design_path,
                                                             PhysicsOptions options = {});

// The same over a model (tests, benchmarks).
Result<std::unique_ptr<ContactRefiner>> make_physics_refiner(const sim::PatchModel& model,
                                                             PhysicsOptions options = {});

}  // namespace skinbus::estimators
