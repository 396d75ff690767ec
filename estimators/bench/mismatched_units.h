// mismatched_units.h (internal to the estimators' reports): the units whose physics the nominal
// design's model lacks, on which the count reports measure what a mismatch does.
#pragma once

#include <vector>

#include "skinbus/sim/patch_model.h"

namespace skinbus::estimators_bench {

struct MismatchedUnit {
  const char* name;
  sim::PatchModel truth;
};

// An anisotropic lattice (spread 20 % longer along u than v), a stiffer in-plane coupling, and a
// fabricated unit (UID 7), each of `design` (a design the model cannot hold: aborts).
inline std::vector<MismatchedUnit> mismatched_units(const sim::PatchDesign& design) {
  sim::PatchDesign anisotropic = design, lateral = design;
  anisotropic.anisotropy = 0.1;
  lateral.lateral_mm = 2.6;
  std::vector<MismatchedUnit> out;
  out.push_back({"anisotropic 0.1", sim::PatchModel::nominal(anisotropic).value()});
  out.push_back({"lateral 2.6 mm", sim::PatchModel::nominal(lateral).value()});
  out.push_back({"fabricated (UID 7)",
                 sim::PatchModel::fabricated(design, 7, sim::FabricationVariation{}).value()});
  return out;
}

}  // namespace skinbus::estimators_bench
