// skinbus/sim/unit_model.h: a unit file modelled on its design, the one way the tools and the
// host's refiner model an identified unit.
#pragma once

#include <string>

#include "skinbus/common/result.h"
#include "skinbus/sim/patch_model.h"
#include "skinbus/sim/unit_parameters.h"

namespace skinbus::sim {

struct UnitModel {
  PatchModel model;   // PatchModel::of_unit_file(design, the file's parameters)
  UnitFileNote note;  // what the file says of itself (a refused fit, where it was pressed)
};

// Reads the unit file `unit_path` (read_unit_parameters) and models it on `design` by
// PatchModel::of_unit_file: the design's model class with the file's identified creep; with a
// non-zero `anisotropy` that anisotropy on top (a simulation of the unit on a lattice it was not
// identified on, skinbus-dataset --anisotropy). Errors: the reader's, naming the file; the
// model's (the file does not fit the design), kInvalidArgument or as from_parameters, prefixed
// with the file's path. Cost: the model's rest field table.
Result<UnitModel> read_unit_model(const std::string& unit_path, const PatchDesign& design,
                                  double anisotropy = 0);

}  // namespace skinbus::sim
