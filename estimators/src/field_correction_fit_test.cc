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

// A unit whose top crushes under the tip and whose lattice creeps, its class's parameters exact:
// the creep fitted on the class's model alone (as identify_unit fits it) takes part of the crush
// for lag; chosen with the correction, the law comes nearer the unit's and the model with it
// predicts the field at held-out places better. On static presses (relaxed, no lag), the depth
// inverted on the model is nearer with the law chosen so.
TEST(FieldCorrectionFitTest, TheCreepChosenWithTheCorrectionIsNotTheCrushTakenForLag) {
  const uint64_t seed = test_seed("FieldCorrectionFitTest.TheCreepChosenWithTheCorrection");
  const sim::PatchDesign design;
  sim::PatchDesign truth_design = design;
  truth_design.tip_crush_mm = 5;
  truth_design.creep_fraction = 0.12;
  truth_design.creep_time_s = 0.35;
  const sim::PatchModel truth =
      sim::PatchModel::fabricated(truth_design, seed, sim::FabricationVariation{}).value();
  sim::UnitParameters unit = truth.parameters();
  const sim::PatchModel model = sim::PatchModel::of_unit_file(design, unit).value();
  const sim::Dataset presses = grid_presses(truth, seed);
  CreepFitOptions co;
  const Result<CreepFit> alone = fit_creep(model, presses, co);
  ASSERT_TRUE(alone.ok()) << alone.error().to_string();
  std::printf("class alone: %s\n", alone->summary_text().c_str());
  ASSERT_TRUE(alone->kept);
  alone->law.write_to(&unit);

  const Result<CreepAndCorrection> both =
      fit_creep_and_correction(design, unit, presses, 5.0, {}, co);
  ASSERT_TRUE(both.ok()) << both.error().to_string();
  std::printf("%s\n%s\n", both->summary_text().c_str(), both->report.summary_text().c_str());
  ASSERT_GE(both->candidates.size(), 3u);
  EXPECT_EQ(both->candidates[0].what, "identified");
  EXPECT_EQ(both->candidates[1].what, "none");
  EXPECT_TRUE(both->candidates[1].law.none());
  ASSERT_NE(both->correction, nullptr);
  const CreepAndCorrection::Candidate& chosen =
      both->candidates[static_cast<std::size_t>(both->chosen)];
  for (const CreepAndCorrection::Candidate& c : both->candidates) {
    EXPECT_TRUE(std::isfinite(c.held_out_rms) && c.held_out_rms > 0) << c.what;
    EXPECT_LE(chosen.held_out_rms, c.held_out_rms) << c.what;
  }
  EXPECT_EQ(both->report.rms_held_out, chosen.held_out_rms);
  EXPECT_EQ(both->law.fraction, chosen.law.fraction);
  // The identified law is not kept, and the chosen one is nearer the unit's time constant.
  EXPECT_NE(chosen.what, "identified");
  EXPECT_LT(chosen.held_out_rms, both->candidates[0].held_out_rms);
  EXPECT_LT(std::fabs(std::log(both->law.time_s / 0.35)),
            std::fabs(std::log(alone->law.time_s / 0.35)));

  // Static presses, relaxed: the depth inverted on each model with its correction.
  auto corrected = [&](const CreepLaw& law, const sim::Dataset& bent_on) {
    sim::UnitParameters p = unit;
    p.field_correction.reset();
    law.write_to(&p);
    const sim::PatchModel m = sim::PatchModel::of_unit_file(design, p).value();
    p.field_correction = std::make_shared<const sim::FieldCorrection>(
        fit_field_correction(m, bent_dataset(law, bent_on), 5.0, {}, nullptr).value());
    return PhysicsEstimator::create(sim::PatchModel::of_unit_file(design, p).value()).value();
  };
  const PhysicsEstimator old_route = corrected(alone->law, presses);
  const PhysicsEstimator new_route = corrected(both->law, presses);
  sim::SimulatedPatch patch(truth, seed + 1);
  const sim::Dataset test = sim::generate_random_test_set(patch, 150, 54, 4.0, seed + 2);
  double err_old = 0, err_new = 0;
  int n = 0;
  for (std::size_t r = 0; r < test.rows(); ++r) {
    if (test.depth_mm[r] < 2.0) continue;
    const std::span<const double> x(test.field(r), static_cast<std::size_t>(test.channels()));
    const PhysicsEstimate a = old_route.estimate(x), b = new_route.estimate(x);
    ASSERT_TRUE(std::isfinite(b.contact.depth_mm));
    err_old += std::fabs(a.contact.depth_mm - test.depth_mm[r]);
    err_new += std::fabs(b.contact.depth_mm - test.depth_mm[r]);
    ++n;
  }
  ASSERT_GT(n, 50);
  std::printf(
      "depth mean on %d static presses >= 2 mm: creep of the class alone %.3f mm, chosen "
      "with the correction %.3f mm\n",
      n, err_old / n, err_new / n);
  EXPECT_LT(err_new, err_old);
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
