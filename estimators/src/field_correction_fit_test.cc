// The field correction learned from a unit's own presses: it recovers a smooth field the class
// misses, leaves a unit the class explains alone, explains most of what units with physics
// outside the class (not fitted: a crushing top, anisotropy, in-plane drag) leave, and brings
// their inversion nearer the truth; degenerate input is refused.
#include "skinbus/estimators/field_correction_fit.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <limits>
#include <memory>
#include <vector>

#include "skinbus/common/test_seed.h"
#include "skinbus/estimators/physics_estimator.h"
#include "skinbus/estimators/unit_identification.h"
#include "skinbus/sim/dataset.h"
#include "skinbus/sim/simulated_patch.h"

namespace skinbus::estimators {
namespace {

// The seed's protocol (a 19 x 19 grid at 6 mm, 4 mm/s ramps) on `unit`.
sim::Dataset grid_presses(const sim::PatchModel& unit, uint64_t seed) {
  sim::SimulatedPatch patch(unit, seed);
  sim::RampProtocol ramp;
  ramp.speed_mm_per_s = 4.0;
  return sim::generate_ramp_dataset(patch, sim::plan_grid(19, 6), ramp);
}

// A smooth field over the patch no class contains: a few broad bumps per channel (uT).
std::shared_ptr<const sim::FieldCorrection> smooth_field(int channels, uint64_t seed) {
  sim::FieldCorrection::Grid g;
  g.u0_mm = -81;  // knots 18 mm apart over +-63 mm
  g.v0_mm = -81;
  g.step_mm = 18;
  g.nu = g.nv = 10;
  g.max_depth_mm = 4;
  sim::Rng rng(seed);
  std::vector<double> coef(g.terms() * static_cast<std::size_t>(channels));
  for (double& c : coef) c = 4 * rng.normal();
  return std::make_shared<const sim::FieldCorrection>(
      sim::FieldCorrection::make(g, channels, std::move(coef)).value());
}

sim::PatchModel with_correction(const sim::PatchModel& m,
                                std::shared_ptr<const sim::FieldCorrection> f) {
  sim::UnitParameters p = m.parameters();
  p.field_correction = std::move(f);
  return sim::PatchModel::from_parameters(m.design(), p).value();
}

TEST(FieldCorrectionFitTest, LearnsASmoothFieldTheClassMisses) {
  const uint64_t seed = test_seed("FieldCorrectionFitTest.LearnsASmoothField");
  const sim::PatchDesign design;
  const sim::PatchModel unit =
      sim::PatchModel::fabricated(design, seed, sim::FabricationVariation{}).value();
  const sim::PatchModel truth = with_correction(unit, smooth_field(48, seed));
  const sim::Dataset presses = grid_presses(truth, seed);
  FieldCorrectionReport report;
  const Result<sim::FieldCorrection> f =
      fit_field_correction(unit, presses, 5.0, FieldCorrectionOptions{}, &report);
  ASSERT_TRUE(f.ok()) << f.error().to_string();
  std::printf("%s\n", report.summary_text().c_str());
  EXPECT_EQ(report.places, 361);
  EXPECT_NEAR(report.place_spacing_mm, 6.0, 1e-9);
  EXPECT_GT(report.rms_model, 2.0);
  EXPECT_LT(report.rms_held_out, 1.1);
  EXPECT_TRUE(report.helps);
  EXPECT_EQ(f->channels(), 48);
  // A model's own correction is not used: the residual is the class's.
  FieldCorrectionReport again;
  ASSERT_TRUE(fit_field_correction(truth, presses, 5.0, {}, &again).ok());
  EXPECT_EQ(again.rms_model, report.rms_model);
  EXPECT_EQ(again.rms_held_out, report.rms_held_out);

  // A dead channel (NaN in every row): the others are learned as before, it is left out.
  sim::Dataset dead = presses;
  for (std::size_t r = 0; r < dead.rows(); ++r) {
    dead.field_ut[r * 48 + 7] = std::numeric_limits<double>::quiet_NaN();
  }
  FieldCorrectionReport dead_report;
  ASSERT_TRUE(fit_field_correction(unit, dead, 5.0, {}, &dead_report).ok());
  EXPECT_EQ(dead_report.samples, report.samples);
  EXPECT_LT(dead_report.rms_held_out, 1.1);
  EXPECT_TRUE(dead_report.helps);
}

TEST(FieldCorrectionFitTest, AUnitTheClassExplainsIsNotHelped) {
  const uint64_t seed = test_seed("FieldCorrectionFitTest.AUnitTheClassExplains");
  const sim::PatchDesign design;
  const sim::PatchModel unit =
      sim::PatchModel::fabricated(design, seed, sim::FabricationVariation{}).value();
  FieldCorrectionReport report;
  ASSERT_TRUE(fit_field_correction(unit, grid_presses(unit, seed), 5.0, {}, &report).ok());
  std::printf("%s\n", report.summary_text().c_str());
  EXPECT_LT(report.rms_model, 1.03);
  EXPECT_GT(report.rms_held_out, 0.98 * report.rms_model);
  EXPECT_FALSE(report.helps);
}

// Units whose physics the class does not contain, with the class's own parameters exact (as a
// perfect identification would leave them): the correction explains most of the residual on
// places it was not fitted on, and the inversion with it is nearer the presses.
TEST(FieldCorrectionFitTest, ExplainsPhysicsOutsideTheClassAndPlacesPressesNearer) {
  const uint64_t seed = test_seed("FieldCorrectionFitTest.ExplainsPhysicsOutsideTheClass");
  sim::PatchDesign truth_design;
  truth_design.tip_crush_mm = 12;
  truth_design.anisotropy = 0.1;
  truth_design.inplane_drag = 0.1;
  const sim::PatchModel truth =
      sim::PatchModel::fabricated(truth_design, seed, sim::FabricationVariation{}).value();
  const sim::PatchModel model =
      sim::PatchModel::of_unit_file(truth_design, truth.parameters()).value();
  FieldCorrectionReport report;
  const Result<sim::FieldCorrection> f =
      fit_field_correction(model, grid_presses(truth, seed), 5.0, {}, &report);
  ASSERT_TRUE(f.ok()) << f.error().to_string();
  std::printf("%s\n", report.summary_text().c_str());
  ASSERT_TRUE(report.helps);
  // Of the residual's excess over the noise, at least three quarters gone at held-out places.
  EXPECT_GT(report.rms_model * report.rms_model - 1, 1.0);
  EXPECT_GT(report.explained(), 0.75);
  EXPECT_NEAR(report.explained(),
              1 - (report.rms_held_out * report.rms_held_out - 1) /
                      (report.rms_model * report.rms_model - 1),
              1e-12);
  for (const FieldCorrectionReport::Bin& b : report.bins) {
    if (b.samples > 0) {
      EXPECT_TRUE(std::isfinite(b.rms_held_out) && b.rms_held_out > 0);
    }
  }

  // The inversion on held-out static presses, with and without the correction.
  const sim::PatchModel corrected =
      with_correction(model, std::make_shared<const sim::FieldCorrection>(*f));
  Result<PhysicsEstimator> plain_r = PhysicsEstimator::create(model);
  Result<PhysicsEstimator> better_r = PhysicsEstimator::create(corrected);
  ASSERT_TRUE(plain_r.ok() && better_r.ok())
      << (plain_r.ok() ? better_r.error() : plain_r.error()).to_string();
  const PhysicsEstimator& plain = *plain_r;
  const PhysicsEstimator& better = *better_r;
  sim::SimulatedPatch patch(truth, seed + 1);
  const sim::Dataset test = sim::generate_random_test_set(patch, 150, 54, 4.0, seed + 2);
  double err_plain = 0, err_better = 0;
  int n = 0;
  for (std::size_t r = 0; r < test.rows(); ++r) {
    if (test.depth_mm[r] < 1.0) continue;
    const std::span<const double> x(test.field(r), static_cast<std::size_t>(test.channels()));
    const PhysicsEstimate a = plain.estimate(x), b = better.estimate(x);
    ASSERT_TRUE(std::isfinite(b.contact.u_mm) && std::isfinite(b.contact.depth_mm));
    err_plain += std::hypot(a.contact.u_mm - test.u_mm[r], a.contact.v_mm - test.v_mm[r]);
    err_better += std::hypot(b.contact.u_mm - test.u_mm[r], b.contact.v_mm - test.v_mm[r]);
    ++n;
  }
  ASSERT_GT(n, 50);
  std::printf("XY mean on %d held-out presses >= 1 mm: class alone %.3f mm, corrected %.3f mm\n", n,
              err_plain / n, err_better / n);
  EXPECT_LT(err_better, 0.8 * err_plain);
}

TEST(FieldCorrectionFitTest, TooFewPlacesOrAnotherChannelCountIsRefused) {
  const sim::PatchDesign design;
  const sim::PatchModel unit = sim::PatchModel::nominal(design).value();
  sim::SimulatedPatch patch(unit, 3);
  sim::RampProtocol ramp;
  ramp.speed_mm_per_s = 4.0;
  const sim::Dataset few = sim::generate_ramp_dataset(patch, sim::plan_grid(6, 20), ramp);
  const Result<sim::FieldCorrection> r = fit_field_correction(unit, few, 5.0, {}, nullptr);
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().code, ErrorCode::kDegenerate);
  EXPECT_NE(r.error().message.find("36 press places"), std::string::npos) << r.error().message;
  sim::PatchDesign other;
  other.sensors_u = 3;
  const sim::PatchModel three = sim::PatchModel::nominal(other).value();
  const Result<sim::FieldCorrection> wrong = fit_field_correction(three, few, 5.0, {}, nullptr);
  ASSERT_FALSE(wrong.ok());
  EXPECT_EQ(wrong.error().code, ErrorCode::kInvalidArgument);
}

}  // namespace
}  // namespace skinbus::estimators
