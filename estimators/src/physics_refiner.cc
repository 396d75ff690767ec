#include "skinbus/estimators/physics_refiner.h"

#include "skinbus/sim/design_file.h"
#include "skinbus/sim/unit_parameters.h"

namespace skinbus::estimators {

namespace {

class PhysicsRefiner : public ContactRefiner {
 public:
  explicit PhysicsRefiner(PhysicsEstimator estimator) : estimator_(std::move(estimator)) {}
  RefinedEstimate refine(std::span<const double> field_ut, std::span<const uint8_t> channel_ok,
                         const ContactEstimate& start) const override {
    const PhysicsEstimate p = estimator_.refine_lm(field_ut, channel_ok, start);
    RefinedEstimate out;
    out.contact = p.contact;
    out.sigma_uv_mm = p.sigma_uv_mm;
    out.reduced_chi2 = p.reduced_chi2;
    if (estimator_.options().fit_shear) out.sigma_shear_n = p.sigma_shear_n;
    return out;
  }

 private:
  PhysicsEstimator estimator_;
};

}  // namespace

Result<std::unique_ptr<ContactRefiner>> make_physics_refiner(const sim::PatchModel& model,
                                                             PhysicsOptions options) {
  options.covariance = true;
  // A one-row start table: a refinement starts from its first estimate; the table is only the
  // last resort of a start that ends in a poor fit.
  options.start_grid.pitch_mm = std::max(model.design().size_u_mm, model.design().size_v_mm);
  options.start_grid.depths_mm = {2.0};
  auto e = PhysicsEstimator::create(model, options);
  if (!e.ok()) return e.error();
  return std::unique_ptr<ContactRefiner>(new PhysicsRefiner(std::move(*e)));
}

Result<std::unique_ptr<ContactRefiner>> make_physics_refiner(const std::string& unit_path,
                                                             const std::string& design_path,
                                                             PhysicsOptions options) {
  auto design = sim::read_design_or_builtin(design_path);
  if (!design.ok()) return design.error();
  auto params = sim::read_unit_parameters(unit_path);
  if (!params.ok()) return params.error();
  auto model = sim::PatchModel::from_parameters(*design, *params);
  if (!model.ok()) {
    return make_error(model.error().code,
                      "unit " + unit_path + " on design " +
                          (design_path.empty() ? std::string("(built-in)") : design_path) + ": " +
                          model.error().message);
  }
  return make_physics_refiner(*model, std::move(options));
}

}  // namespace skinbus::estimators
