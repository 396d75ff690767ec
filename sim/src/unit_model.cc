#include "skinbus/sim/unit_model.h"

#include <utility>

namespace skinbus::sim {

Result<UnitModel> read_unit_model(const std::string& unit_path, const PatchDesign& design,
                                  double anisotropy) {
  UnitFileNote note;
  Result<UnitParameters> params = read_unit_parameters(unit_path, &note);  // names the file
  if (!params.ok()) return params.error();
  Result<PatchModel> model = PatchModel::of_unit_file(design, *params);
  if (model.ok() && anisotropy != 0) {  // the same class and creep, on another lattice
    PatchDesign d = model->design();
    d.anisotropy = anisotropy;
    model = PatchModel::from_parameters(d, *params);
  }
  if (!model.ok()) return make_error(model.error().code, unit_path + ": " + model.error().message);
  return UnitModel{std::move(model).value(), std::move(note)};
}

}  // namespace skinbus::sim
