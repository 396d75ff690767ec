// Per-unit parameters and identification: the exact round trip of a unit's parameters, a
// fabricated unit identified from its own simulated presses (held-out residual near the noise,
// better inversion than with the nominal model), an anisotropic lattice fitted along u and v, a
// unit the model class cannot contain (a top that crushes), and degenerate input.
#include "skinbus/estimators/unit_identification.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <vector>

#include "skinbus/estimators/physics_estimator.h"
#include "skinbus/sim/dataset.h"
#include "skinbus/sim/design_file.h"
#include "skinbus/sim/rng.h"
#include "skinbus/sim/simulated_patch.h"

namespace skinbus::estimators {
namespace {

void expect_same_model(const sim::PatchModel& a, const sim::PatchModel& b) {
  EXPECT_EQ(a.spread_u_mm(), b.spread_u_mm());
  EXPECT_EQ(a.spread_v_mm(), b.spread_v_mm());
  EXPECT_EQ(a.lateral_mm(), b.lateral_mm());
  ASSERT_EQ(a.magnets().size(), b.magnets().size());
  for (std::size_t i = 0; i < a.magnets().size(); ++i) {
    EXPECT_EQ(a.magnets()[i].u, b.magnets()[i].u);
    EXPECT_EQ(a.magnets()[i].h, b.magnets()[i].h);
    EXPECT_EQ(a.magnets()[i].m_loc.x, b.magnets()[i].m_loc.x);
    EXPECT_EQ(a.magnets()[i].m_loc.z, b.magnets()[i].m_loc.z);
  }
  ASSERT_EQ(a.sensors().size(), b.sensors().size());
  for (std::size_t i = 0; i < a.sensors().size(); ++i) {
    EXPECT_EQ(a.sensors()[i].pos.z, b.sensors()[i].pos.z);
    EXPECT_EQ(a.sensors()[i].frame.r[1].x, b.sensors()[i].frame.r[1].x);
    EXPECT_EQ(a.sensors()[i].gain.y, b.sensors()[i].gain.y);
  }
  std::vector<double> fa(static_cast<std::size_t>(a.channel_count())), fb(fa.size()), ra(fa.size()),
      rb(fa.size());
  const sim::Contact c{12.5, -31.0, 2.7, 5};
  a.contact_field_ut(std::span<const sim::Contact>(&c, 1), fa);
  b.contact_field_ut(std::span<const sim::Contact>(&c, 1), fb);
  a.rest_field_ut(ra);
  b.rest_field_ut(rb);
  for (std::size_t i = 0; i < fa.size(); ++i) {
    EXPECT_EQ(fa[i], fb[i]);
    EXPECT_EQ(ra[i], rb[i]);
  }
}

TEST(UnitParametersTest, RoundTripIsExact) {
  sim::PatchDesign design;
  const sim::PatchModel unit =
      sim::PatchModel::fabricated(design, 77, sim::FabricationVariation{}).value();
  const sim::PatchModel again = sim::PatchModel::from_parameters(design, unit.parameters()).value();
  expect_same_model(unit, again);
  // An anisotropic unit: the design carries the anisotropy, the parameters one spread.
  design.anisotropy = 0.05;
  const sim::PatchModel aniso =
      sim::PatchModel::fabricated(design, 78, sim::FabricationVariation{}).value();
  EXPECT_NE(aniso.spread_u_mm(), aniso.spread_v_mm());
  expect_same_model(aniso, sim::PatchModel::from_parameters(design, aniso.parameters()).value());
  // A curved patch.
  sim::PatchDesign arm;
  arm.surface = sim::SurfaceKind::kCylinder;
  arm.radius_mm = 45;
  const sim::PatchModel curved =
      sim::PatchModel::fabricated(arm, 79, sim::FabricationVariation{}).value();
  expect_same_model(curved, sim::PatchModel::from_parameters(arm, curved.parameters()).value());
}

TEST(UnitParametersTest, BadParametersNameTheEntry) {
  const sim::PatchDesign design;
  sim::UnitParameters p = sim::PatchModel::nominal(design).value().parameters();
  sim::UnitParameters fewer = p;
  fewer.magnets.pop_back();
  EXPECT_FALSE(sim::PatchModel::from_parameters(design, fewer).ok());
  sim::UnitParameters zero_gain = p;
  zero_gain.sensors[3].gain.y = 0;
  const auto r = sim::PatchModel::from_parameters(design, zero_gain);
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error().message.find("sensor 3"), std::string::npos) << r.error().message;
  sim::UnitParameters skew = p;
  skew.sensors[0].mounting.r[0].y = 0.2;
  EXPECT_FALSE(sim::PatchModel::from_parameters(design, skew).ok());
  sim::UnitParameters bad_spread = p;
  bad_spread.spread_mm = -1;
  EXPECT_FALSE(sim::PatchModel::from_parameters(design, bad_spread).ok());
}

// Presses of one simulated unit: a training grid (ramps) and held-out random static presses.
struct UnitData {
  sim::Dataset train, test;
};
UnitData press_unit(const sim::PatchModel& unit, int grid_n, double pitch_mm, uint64_t seed) {
  sim::SimulatedPatch patch(unit, seed);
  sim::RampProtocol ramp;
  ramp.speed_mm_per_s = 4.0;  // fewer samples per press: only a few are fitted
  UnitData d;
  d.train = sim::generate_ramp_dataset(patch, sim::plan_grid(grid_n, pitch_mm), ramp);
  d.test = sim::generate_random_test_set(patch, 150, 60, 4.0, seed + 1);
  return d;
}

// A fabricated unit built to `design`, pressed on a 13 x 13 grid and at random held-out places.
UnitData press_built(const sim::PatchDesign& design, uint64_t seed) {
  return press_unit(sim::PatchModel::fabricated(design, seed, sim::FabricationVariation{}).value(),
                    13, 11.25, seed);
}

void print_quality(const char* what, const FitQuality& q) {
  std::printf("%s: rows %d, RMS %.3f noise units; by depth:", what, q.rows, q.rms);
  for (const DepthBinResidual& b : q.bins) {
    if (b.rows > 0) std::printf(" [%g,%g) %.3f", b.depth_lo_mm, b.depth_hi_mm, b.rms);
  }
  std::printf("\n");
}

// On a unit the class cannot explain, a clear refusal is allowed, a silent poor fit is not: true
// (and the refusal printed and checked to be kNotConverged) when `id` was refused.
bool refused_clearly(const Result<IdentifiedUnit>& id) {
  if (id.ok()) return false;
  std::printf("refused: %s\n", id.error().to_string().c_str());
  EXPECT_EQ(id.error().code, ErrorCode::kNotConverged);
  return true;
}

TEST(UnitIdentificationTest, FabricatedUnitIsIdentifiedDownToTheNoise) {
  const sim::PatchDesign design;
  const uint64_t seed = 4242;
  std::printf("seed %llu\n", static_cast<unsigned long long>(seed));
  const sim::PatchModel unit =
      sim::PatchModel::fabricated(design, seed, sim::FabricationVariation{}).value();
  const UnitData data = press_unit(unit, 13, 11.25, seed);
  IdentificationOptions opt;
  opt.depths_per_press = 3;
  const Result<IdentifiedUnit> id = identify_unit(design, data.train, opt, &data.test);
  ASSERT_TRUE(id.ok()) << id.error().to_string();
  std::printf("identified from %d presses, %d rows, %d iterations in %.1f s\n", id->presses,
              id->rows_used, id->iterations, id->solve_seconds);
  print_quality("fit, identified", id->fit);
  print_quality("fit, nominal", id->nominal_fit);
  print_quality("held out, identified", id->held_out);
  print_quality("held out, nominal", id->nominal_held_out);
  EXPECT_LT(id->fit.rms, 1.1);
  EXPECT_LT(id->held_out.rms, 1.2);
  EXPECT_NEAR(id->parameters.anisotropy, 0, 0.01);  // an isotropic lattice is found so
  // Pressed in the design's frame: found so.
  EXPECT_LT(std::hypot(id->globals.frame_du_mm, id->globals.frame_dv_mm), 0.2);
  EXPECT_LT(std::fabs(id->globals.frame_yaw_deg), 0.3);
  // Most held-out channels see little of a press, so the nominal model's misfit shows most in
  // the deep bin.
  EXPECT_GT(id->nominal_held_out.rms, id->held_out.rms + 0.2);
  EXPECT_GT(id->nominal_held_out.bins[3].rms, 1.5 * id->held_out.bins[3].rms);
  // The lattice parameters come back close to the unit's.
  EXPECT_NEAR(id->parameters.spread_mm, unit.spread_mm(), 0.02 * unit.spread_mm());
  EXPECT_TRUE(id->chip_turns.empty()) << id->chip_turns.front().text();

  // The inversion with the identified model beats the nominal one on this unit.
  const PhysicsEstimator with_id = PhysicsEstimator::create(id->model).value();
  const PhysicsEstimator with_nominal =
      PhysicsEstimator::create(sim::PatchModel::nominal(design).value()).value();
  double err_id = 0, err_nom = 0, chi_id = 0, chi_nom = 0;
  int n = 0;
  for (std::size_t r = 0; r < data.test.rows(); ++r) {
    if (data.test.depth_mm[r] < 1.0) continue;  // shallow presses: noise dominates either way
    const std::span<const double> f(data.test.field(r),
                                    static_cast<std::size_t>(data.test.channels()));
    const PhysicsEstimate a = with_id.estimate(f), b = with_nominal.estimate(f);
    err_id += std::hypot(a.contact.u_mm - data.test.u_mm[r], a.contact.v_mm - data.test.v_mm[r]);
    err_nom += std::hypot(b.contact.u_mm - data.test.u_mm[r], b.contact.v_mm - data.test.v_mm[r]);
    chi_id += a.reduced_chi2;
    chi_nom += b.reduced_chi2;
    ++n;
  }
  std::printf(
      "LM on held-out presses >= 1 mm (%d): mean xy error identified %.3f mm, nominal "
      "%.3f mm; mean reduced chi2 %.2f vs %.2f\n",
      n, err_id / n, err_nom / n, chi_id / n, chi_nom / n);
  EXPECT_LT(err_id, 0.7 * err_nom);
  EXPECT_LT(chi_id / n, 1.5);
}

// The chips' noise read off a recording's ramps: the design's on a simulated unit, 1.5x when
// the recording carries 1.5x the noise, none from static presses (no consecutive samples), the
// chips' on a patch whose field curves steeply along a ramp.
TEST(UnitIdentificationTest, TheRecordedNoiseIsReadOffTheRamps) {
  const sim::PatchDesign design;
  const uint64_t seed = 4545;
  std::printf("seed %llu\n", static_cast<unsigned long long>(seed));
  const sim::PatchModel unit =
      sim::PatchModel::fabricated(design, seed, sim::FabricationVariation{}).value();
  UnitData data = press_unit(unit, 7, 20, seed);
  const ChannelNoise chip = ChannelNoise::of(design);
  const RecordedNoise as_made = recorded_noise(data.train);
  std::printf("recorded %.3f / %.3f uT against %.3f / %.3f (%lld windows)\n", as_made.noise.xy_ut,
              as_made.noise.z_ut, chip.xy_ut, chip.z_ut, static_cast<long long>(as_made.windows));
  EXPECT_GT(as_made.windows, 1000);
  EXPECT_NEAR(as_made.xy_ratio(chip), 1.0, 0.05);
  EXPECT_NEAR(as_made.z_ratio(chip), 1.0, 0.05);
  EXPECT_NEAR(as_made.residual(chip), 1.0, 0.05);
  sim::Rng rng(seed);
  const std::size_t nc = static_cast<std::size_t>(data.train.channels());
  for (std::size_t i = 0; i < data.train.field_ut.size(); ++i) {
    const double sd = (i % nc) % 3 == 2 ? chip.z_ut : chip.xy_ut;
    data.train.field_ut[i] += sd * std::sqrt(1.5 * 1.5 - 1) * rng.normal();
  }
  const RecordedNoise noisier = recorded_noise(data.train);
  EXPECT_NEAR(noisier.xy_ratio(chip), 1.5, 0.075);
  EXPECT_NEAR(noisier.z_ratio(chip), 1.5, 0.075);
  EXPECT_NEAR(noisier.residual(chip), 1.5, 0.075);
  EXPECT_EQ(recorded_noise(data.test).windows, 0);
  EXPECT_EQ(recorded_noise(data.test).noise.xy_ut, 0);

  // A fingertip whose sensors sit 8 mm under strong magnets: along a ramp the field curves far
  // more than the chips' noise, which second differences read as noise (z 1.8x the chips').
  const char* dir = std::getenv("SKINBUS_SOURCE_DIR");
  Result<sim::PatchDesign> tip_file = sim::read_design_file(
      std::string(dir != nullptr ? dir : ".") + "/docs/benchmarks/design_fingertip_4x4.yaml");
  ASSERT_TRUE(tip_file.ok()) << tip_file.error().to_string();
  sim::PatchDesign tip = tip_file.value();
  sim::SimulatedPatch close(
      sim::PatchModel::fabricated(tip, seed, sim::FabricationVariation{}).value(), seed);
  sim::RampProtocol ramp;
  ramp.speed_mm_per_s = 4;
  ramp.max_depth_mm = 0.95 * tip.max_depth_mm();
  ramp.tip_radius_mm = 4;
  const sim::Dataset pressed = sim::generate_ramp_dataset(close, sim::plan_grid(9, 4.0), ramp);
  const ChannelNoise tip_chip = ChannelNoise::of(tip);
  const RecordedNoise near = recorded_noise(pressed);
  std::printf("fingertip: recorded %.3f / %.3f uT against %.3f / %.3f (%lld windows)\n",
              near.noise.xy_ut, near.noise.z_ut, tip_chip.xy_ut, tip_chip.z_ut,
              static_cast<long long>(near.windows));
  EXPECT_GT(near.windows, 1000);
  EXPECT_NEAR(near.xy_ratio(tip_chip), 1.0, 0.05);
  EXPECT_NEAR(near.z_ratio(tip_chip), 1.0, 0.05);
}

// A lattice that spreads a press 10 % further along u than along v (printed stiffer one way),
// drawn isotropic in its design file: the anisotropy is found and the unit identified to its
// noise. Before the class had it, the same unit was left at 1.2-1.4 noise units held out.
TEST(UnitIdentificationTest, AnAnisotropicLatticeIsFittedAlongUAndV) {
  const sim::PatchDesign drawn;
  sim::PatchDesign built = drawn;
  built.anisotropy = 0.05;
  const uint64_t seed = 99;
  std::printf("seed %llu\n", static_cast<unsigned long long>(seed));
  const UnitData data = press_built(built, seed);
  IdentificationOptions opt;
  opt.depths_per_press = 3;
  const Result<IdentifiedUnit> id = identify_unit(drawn, data.train, opt, &data.test);
  ASSERT_TRUE(id.ok()) << id.error().to_string();
  std::printf("identified in %.1f s: anisotropy %.4f (globals stage %.4f), spread %.3f mm\n",
              id->solve_seconds, id->parameters.anisotropy, id->globals.anisotropy,
              id->parameters.spread_mm);
  print_quality("held out, identified", id->held_out);
  print_quality("held out, nominal", id->nominal_held_out);
  EXPECT_NEAR(id->parameters.anisotropy, 0.05, 0.01);
  EXPECT_NEAR(id->model.spread_u_mm() / id->model.spread_v_mm(), 1.05 / 0.95, 0.02);
  EXPECT_LT(id->held_out.rms, 1.08);
  for (const DepthBinResidual& b : id->held_out.bins) {
    if (b.rows > 0) {
      EXPECT_LT(b.rms, 1.12) << b.depth_lo_mm;
    }
  }
}

// Presses recorded in an indentation robot's frame, 3 mm and -2 mm off the patch's origin and
// turned 5 degrees from its axes, by a robot whose depth zero is 0.25 mm inside the surface (it
// reads 0 with the tip already in): the frame and the zero are found with the globals, every part
// placed in the frame, the unit reading depth as the robot did, and the unit identified to its
// noise as if pressed in the design's frame. Before the frame was fitted, the same recording
// without the zero was fitted to 1.16 noise units with a warning of physics missed, and refined at
// 1.05 / 1.72 / 3.63x its bound at 1-2 / 2-3 / 3-4 mm; before the zero was, the zero alone left
// 1.21 and a refined depth error of 0.117 mm at 1-2 mm (0.055 mm pressed from the surface).
TEST(UnitIdentificationTest, ThePressesFrameAndDepthZeroOffTheDesignsAreFound) {
  const sim::PatchDesign design;
  const uint64_t seed = 4646;
  std::printf("seed %llu\n", static_cast<unsigned long long>(seed));
  const sim::PatchModel unit =
      sim::PatchModel::fabricated(design, seed, sim::FabricationVariation{}).value();
  UnitData data = press_unit(unit, 13, 11.25, seed);
  const double du = 3, dv = -2, yaw_deg = 5, depth_zero_mm = -0.25;
  const double c = std::cos(yaw_deg * M_PI / 180), s = std::sin(yaw_deg * M_PI / 180);
  for (sim::Dataset* d : {&data.train, &data.test}) {
    sim::record_in_press_frame(
        d, {.du_mm = du, .dv_mm = dv, .yaw_deg = yaw_deg, .depth_zero_mm = depth_zero_mm});
  }
  IdentificationOptions opt;
  opt.depths_per_press = 3;
  opt.fit_creep = false;
  const Result<IdentifiedUnit> id = identify_unit(design, data.train, opt, &data.test);
  ASSERT_TRUE(id.ok()) << id.error().to_string();
  std::printf("presses' frame found: (%+.3f, %+.3f) mm, %+.3f deg, depth zero %+.3f mm\n",
              id->globals.frame_du_mm, id->globals.frame_dv_mm, id->globals.frame_yaw_deg,
              id->globals.depth_zero_mm);
  print_quality("fit", id->fit);
  print_quality("held out", id->held_out);
  EXPECT_NEAR(id->globals.frame_du_mm, du, 0.15);
  EXPECT_NEAR(id->globals.frame_dv_mm, dv, 0.15);
  EXPECT_NEAR(id->globals.frame_yaw_deg, yaw_deg, 0.2);
  EXPECT_NEAR(id->globals.depth_zero_mm, depth_zero_mm, 0.03);
  EXPECT_EQ(id->parameters.depth_zero_mm, id->globals.depth_zero_mm);
  EXPECT_EQ(id->model.depth_zero_mm(), id->globals.depth_zero_mm);
  EXPECT_LT(id->fit.rms, 1.05);
  EXPECT_LT(id->held_out.rms, 1.08);
  // The unit's parts in the presses' frame: sensor 0 where the turned and shifted design has it.
  const sim::SensorParameters& s0 = id->parameters.sensors.front();
  const sim::SensorParameters t0 = unit.parameters().sensors.front();
  EXPECT_NEAR(s0.u_mm, c * t0.u_mm - s * t0.v_mm + du, 0.5);
  EXPECT_NEAR(s0.v_mm, s * t0.u_mm + c * t0.v_mm + dv, 0.5);

  // Held at the surface (a robot whose zero was measured: GlobalPriors::depth_zero_sd_mm 0), the
  // zero stays exactly 0 and the same presses show what it misses.
  opt.global_priors.depth_zero_sd_mm = 0;
  const Result<IdentifiedUnit> held = identify_unit(design, data.train, opt, &data.test);
  ASSERT_TRUE(held.ok()) << held.error().to_string();
  print_quality("held out, zero held", held->held_out);
  EXPECT_EQ(held->globals.depth_zero_mm, 0.0);
  EXPECT_EQ(held->parameters.depth_zero_mm, 0.0);
  EXPECT_GT(held->held_out.rms, id->held_out.rms + 0.05);
}

// A lattice whose top crushes under the tip (a deformation law the class does not have): the
// residual says so, and held to a limit below it the fit is refused and kept apart.
TEST(UnitIdentificationTest, AUnitOutsideTheClassIsFlaggedAndItsRefusedFitKeptApart) {
  sim::PatchDesign built;
  built.tip_crush_mm = 12;
  const sim::PatchDesign design;
  const uint64_t seed = 99;
  std::printf("seed %llu\n", static_cast<unsigned long long>(seed));
  const UnitData data = press_built(built, seed);
  IdentificationOptions opt;
  opt.depths_per_press = 3;
  const Result<IdentifiedUnit> id = identify_unit(design, data.train, opt, &data.test);
  ASSERT_TRUE(id.ok()) << id.error().to_string();
  std::printf("identified in %.1f s\n", id->solve_seconds);
  print_quality("fit", id->fit);
  print_quality("held out, identified", id->held_out);
  print_quality("held out, nominal", id->nominal_held_out);
  // The fabricated unit of the test above reaches 1.00; most channels see little of a press, so
  // the misfit shows most in a depth bin of its own. The fit's own rows are flagged too (1.13:
  // the depth zero the globals fit takes up a little of the crush; above 1.15 before).
  EXPECT_GT(id->held_out.rms, 1.15);
  EXPECT_GT(id->fit.rms, kModelMissesResidual);
  double worst_bin = 0;
  for (const DepthBinResidual& b : id->held_out.bins) worst_bin = std::fmax(worst_bin, b.rms);
  EXPECT_GT(worst_bin, 1.3);

  // Held to a residual it exceeds, the same fit is refused, and kept apart when asked: the
  // same parameters, bit for bit (the class's nearest model, for simulating training presses).
  opt.max_residual = 1.1;
  sim::UnitParameters refused;
  const Result<IdentifiedUnit> held = identify_unit(design, data.train, opt, nullptr, &refused);
  ASSERT_FALSE(held.ok());
  EXPECT_EQ(held.error().code, ErrorCode::kNotConverged);
  EXPECT_NE(held.error().message.find("residual"), std::string::npos) << held.error().message;
  EXPECT_EQ(refused.spread_mm, id->parameters.spread_mm);
  EXPECT_EQ(refused.lateral_mm, id->parameters.lateral_mm);
  ASSERT_EQ(refused.magnets.size(), id->parameters.magnets.size());
  for (std::size_t m = 0; m < refused.magnets.size(); ++m) {
    EXPECT_EQ(refused.magnets[m].u_mm, id->parameters.magnets[m].u_mm) << m;
    EXPECT_EQ(refused.magnets[m].h_mm, id->parameters.magnets[m].h_mm) << m;
    EXPECT_EQ(refused.magnets[m].moment_am2.z, id->parameters.magnets[m].moment_am2.z) << m;
  }
  EXPECT_TRUE(sim::PatchModel::from_parameters(design, refused).ok());
}

// A dead channel in a recording (NaN in every row, which the dataset format allows) is left out
// of the fit, not a reason to find "0 usable presses".
TEST(UnitIdentificationTest, ADeadChannelIsLeftOutOfTheFit) {
  const sim::PatchDesign design;
  const uint64_t seed = 77;
  const sim::PatchModel unit =
      sim::PatchModel::fabricated(design, seed, sim::FabricationVariation{}).value();
  UnitData data = press_unit(unit, 9, 15, seed);
  const int nc = data.train.channels();
  for (std::size_t r = 0; r < data.train.rows(); ++r) {
    data.train.field_ut[r * static_cast<std::size_t>(nc) + 22] = std::nan("");
  }
  IdentificationOptions opt;
  opt.depths_per_press = 2;
  std::vector<std::string> progress;
  opt.progress = [&](const std::string& line) { progress.push_back(line); };
  const Result<IdentifiedUnit> id = identify_unit(design, data.train, opt, &data.test);
  ASSERT_TRUE(id.ok()) << id.error().to_string();
  // The fit of every part reported its passes as it ran.
  for (const char* pass : {"pass 1 of 2, iteration 0, residual", "pass 2 of 2, iteration 0"}) {
    EXPECT_TRUE(std::any_of(progress.begin(), progress.end(), [&](const std::string& line) {
      return line.find(pass) != std::string::npos;
    })) << pass;
  }
  EXPECT_EQ(id->presses, 81);
  EXPECT_GT(id->masked_values, 0);
  print_quality("fit, channel 22 dead", id->fit);
  EXPECT_LT(id->fit.rms, 1.15);
  EXPECT_LT(id->held_out.rms, 1.25);  // the held-out set has the channel: it is still fitted
}

// Designs other than the built-in one, each identified on a unit whose global physics differ
// from its design file by more than fabrication scatter: the lattice 30 % softer or stiffer, the
// sensors or magnets 1 mm off, the magnets 10 % stronger or weaker.
struct OffDesignCase {
  const char* name;
  sim::PatchDesign design;  // what the design file says
  sim::PatchDesign truth;   // what was built
};

std::vector<OffDesignCase> off_design_cases() {
  std::vector<OffDesignCase> out;
  {  // The patch: 9 x 9 one polarity at 15 mm, magnets below the surface.
    sim::PatchDesign d;
    d.magnets_u = d.magnets_v = 9;
    d.magnet_pitch_mm = 15;
    d.polarity = sim::Polarity::kUniform;
    d.magnet_centre_height_mm = -1;
    d.sensor_depth_mm = 18;
    sim::PatchDesign t = d;
    t.spread_mm = 1.3 * d.spread_mm;
    t.sensor_depth_mm = d.sensor_depth_mm + 1;
    t.remanence_t = 0.9 * d.remanence_t;
    out.push_back({"9x9 uniform, spread +30 %, sensors 1 mm deeper, moments -10 %", d, t});
  }
  {  // A denser magnet grid.
    sim::PatchDesign d;
    d.magnets_u = d.magnets_v = 10;
    d.magnet_pitch_mm = 12;
    sim::PatchDesign t = d;
    t.spread_mm = 0.7 * d.spread_mm;
    t.sensor_depth_mm = d.sensor_depth_mm - 1;
    t.magnet_centre_height_mm = d.magnet_centre_height_mm + 1;
    t.remanence_t = 1.1 * d.remanence_t;
    out.push_back(
        {"10x10 at 12 mm, spread -30 %, sensors 1 mm shallower, magnets 1 mm higher, "
         "moments +10 %",
         d, t});
  }
  {  // Magnets set into the lattice, and a longer spread length with more lateral coupling.
    sim::PatchDesign d;
    d.magnet_centre_height_mm = -2;
    d.spread_mm = 14;
    d.lateral_mm = 3;
    sim::PatchDesign t = d;
    t.spread_mm = 0.7 * d.spread_mm;
    t.magnet_centre_height_mm = d.magnet_centre_height_mm - 1;
    t.lateral_mm = 2;
    t.remanence_t = 1.1 * d.remanence_t;
    out.push_back(
        {"magnets 2 mm deep, spread 14 mm: spread -30 %, magnets 1 mm deeper, lateral "
         "3 -> 2 mm, moments +10 %",
         d, t});
  }
  return out;
}

void expect_identified_despite_its_design(const OffDesignCase& c, uint64_t seed) {
  std::printf("%s (seed %llu)\n", c.name, static_cast<unsigned long long>(seed));
  const sim::PatchModel unit =
      sim::PatchModel::fabricated(c.truth, seed, sim::FabricationVariation{}).value();
  const UnitData data = press_unit(unit, 13, 11.25, seed);
  IdentificationOptions opt;
  opt.depths_per_press = 3;
  const Result<IdentifiedUnit> id = identify_unit(c.design, data.train, opt, &data.test);
  ASSERT_TRUE(id.ok()) << id.error().to_string();
  const GlobalPhysics& g = id->globals;
  std::printf(
      "globals: spread %.2f mm (unit %.2f, design %.2f), lateral %.2f, magnets %+.2f mm, sensors "
      "%+.2f mm, moments x%.3f, residual %.2f; %.1f s\n",
      g.spread_mm, unit.spread_mm(), c.design.spread_mm, g.lateral_mm, g.magnet_height_offset_mm,
      g.sensor_height_offset_mm, g.moment_scale, g.rms, id->solve_seconds);
  print_quality("fit, identified", id->fit);
  print_quality("held out, identified", id->held_out);
  print_quality("held out, design", id->nominal_held_out);
  EXPECT_LT(id->fit.rms, 1.06);
  EXPECT_LT(id->held_out.rms, 1.1);
  for (const DepthBinResidual& b : id->held_out.bins) {
    if (b.rows >= 10) {
      EXPECT_LT(b.rms, 1.15) << "held-out bin from " << b.depth_lo_mm << " mm";
    }
  }
  EXPECT_NEAR(id->parameters.spread_mm, unit.spread_mm(), 0.05 * unit.spread_mm());
  // Magnets and sensors move together: their distance is what the data see.
  const double gap_off = (c.truth.magnet_centre_height_mm + c.truth.sensor_depth_mm) -
                         (c.design.magnet_centre_height_mm + c.design.sensor_depth_mm);
  EXPECT_NEAR(g.magnet_height_offset_mm - g.sensor_height_offset_mm, gap_off, 0.35);
}

TEST(UnitIdentificationTest, NineByNineUniformWithItsGlobalsOff) {
  expect_identified_despite_its_design(off_design_cases()[0], 311);
}
TEST(UnitIdentificationTest, DenserGridWithItsGlobalsOff) {
  expect_identified_despite_its_design(off_design_cases()[1], 312);
}
TEST(UnitIdentificationTest, SunkenMagnetsAndLongerSpreadWithItsGlobalsOff) {
  expect_identified_despite_its_design(off_design_cases()[2], 313);
}

// Chips mounted turned from the design file (an assembly error, or a design file whose sensors'
// yaw_deg follows another convention): three turned a quarter, a half and three quarters about
// the normal and one upside down; then every chip a quarter turn off. Each is found and fitted so
// turned, and the unit is identified to its noise, where before the globals stage bent the
// magnets' heights by millimetres to explain them and the fit was left well above the noise.
TEST(UnitIdentificationTest, ChipsTurnedFromTheDesignFileAreFoundAndFittedSo) {
  sim::PatchDesign drawn;
  for (int j = 0; j < drawn.sensors_v; ++j) {
    for (int i = 0; i < drawn.sensors_u; ++i) {
      drawn.sensor_list.push_back({(i - 1.5) * drawn.sensor_pitch_mm,
                                   (j - 1.5) * drawn.sensor_pitch_mm, drawn.sensor_depth_mm, 0});
    }
  }
  const uint64_t seed = 4343;
  std::printf("seed %llu\n", static_cast<unsigned long long>(seed));
  IdentificationOptions opt;
  opt.depths_per_press = 3;
  opt.fit_creep = false;
  {
    sim::PatchDesign built = drawn;
    built.sensor_list[2].yaw_deg = 180;
    built.sensor_list[7].yaw_deg = 90;
    built.sensor_list[11].yaw_deg = 270;
    sim::UnitParameters p =
        sim::PatchModel::fabricated(built, seed, sim::FabricationVariation{}).value().parameters();
    sim::Mat3 over = sim::rotation_from_vector({M_PI, 0, 0});  // sensor 13 upside down
    sim::Mat3& m = p.sensors[13].mounting;
    sim::Mat3 turned;
    for (int r = 0; r < 3; ++r) turned.r[r] = over.apply_transposed(m.r[r]);
    m = turned;
    const sim::PatchModel unit = sim::PatchModel::from_parameters(built, p).value();
    const UnitData data = press_unit(unit, 13, 11.25, seed);
    const Result<IdentifiedUnit> id = identify_unit(drawn, data.train, opt, &data.test);
    ASSERT_TRUE(id.ok()) << id.error().to_string();
    for (const ChipTurn& t : id->chip_turns) std::printf("%s\n", t.text().c_str());
    print_quality("held out, identified", id->held_out);
    ASSERT_EQ(id->chip_turns.size(), 4u);
    const double want[4][2] = {{2, 180}, {7, 90}, {11, 270}, {13, 0}};
    for (std::size_t i = 0; i < 4; ++i) {
      EXPECT_EQ(id->chip_turns[i].sensor, want[i][0]);
      EXPECT_EQ(id->chip_turns[i].yaw_deg, want[i][1]);
      EXPECT_EQ(id->chip_turns[i].upside_down, i == 3);
    }
    EXPECT_LT(id->fit.rms, 1.1);
    EXPECT_LT(id->held_out.rms, 1.2);
    // Turned back to the design file, the same unit leaves far more.
    IdentificationOptions as_drawn = opt;
    as_drawn.find_chip_turns = false;
    const Result<IdentifiedUnit> off = identify_unit(drawn, data.train, as_drawn, &data.test);
    if (off.ok()) {
      print_quality("held out, as drawn", off->held_out);
      EXPECT_GT(off->held_out.rms, 1.25 * id->held_out.rms);
    } else {
      EXPECT_TRUE(refused_clearly(off));
    }
  }
  {
    sim::PatchDesign built = drawn;
    for (sim::SensorPlacement& s : built.sensor_list) s.yaw_deg = 90;
    const UnitData data = press_built(built, seed + 1);
    const Result<IdentifiedUnit> id = identify_unit(drawn, data.train, opt, &data.test);
    ASSERT_TRUE(id.ok()) << id.error().to_string();
    EXPECT_EQ(id->chip_turns.size(), 16u);
    for (const ChipTurn& t : id->chip_turns) {
      EXPECT_EQ(t.yaw_deg, 90) << t.text();
      EXPECT_FALSE(t.upside_down) << t.text();
    }
    print_quality("every chip a quarter turn off, held out", id->held_out);
    EXPECT_LT(id->held_out.rms, 1.2);
    EXPECT_NEAR(id->globals.magnet_height_offset_mm, 0, 0.5);
  }
}

// Without the first stage the same unit settles in a poorer fit: the stage is what converges.
TEST(UnitIdentificationTest, WithoutTheGlobalsStageTheFitStaysPoorer) {
  const OffDesignCase c = off_design_cases()[0];
  const UnitData data = press_built(c.truth, 311);
  IdentificationOptions opt;
  opt.depths_per_press = 3;
  opt.fit_globals = false;
  const Result<IdentifiedUnit> kept = identify_unit(c.design, data.train, opt, &data.test);
  opt.fit_globals = true;
  const Result<IdentifiedUnit> fitted = identify_unit(c.design, data.train, opt, &data.test);
  ASSERT_TRUE(fitted.ok()) << fitted.error().to_string();
  // Kept globals: either refused or clearly poorer on held-out presses.
  if (kept.ok()) {
    print_quality("fit, globals kept", kept->fit);
    print_quality("fit, globals fitted", fitted->fit);
    print_quality("held out, globals kept", kept->held_out);
    print_quality("held out, globals fitted", fitted->held_out);
    EXPECT_GT(kept->fit.rms, fitted->fit.rms + 0.03);
    EXPECT_GT(kept->held_out.rms, fitted->held_out.rms + 0.015);
  } else {
    std::printf("globals kept: %s\n", kept.error().to_string().c_str());
  }
}

// A unit outside the model class (another in-plane motion law: the surface dragged toward the
// press), its globals off as well: identified and its residual says the class misses something.
// (A top that crushes under the tip served here until the presses' depth zero was fitted: with
// it, this design's class takes most of a crush up, to a held-out residual of 1.065 at 12 mm and
// 1.095 at 6 mm, where it had been flagged.)
TEST(UnitIdentificationTest, OutsideTheClassWithItsGlobalsOffIsFlagged) {
  OffDesignCase c = off_design_cases()[0];
  c.truth.inplane_drag = 0.15;
  const sim::PatchModel unit =
      sim::PatchModel::fabricated(c.truth, 314, sim::FabricationVariation{}).value();
  const UnitData data = press_unit(unit, 13, 11.25, 314);
  IdentificationOptions opt;
  opt.depths_per_press = 3;
  const Result<IdentifiedUnit> id = identify_unit(c.design, data.train, opt, &data.test);
  if (refused_clearly(id)) return;
  print_quality("held out, identified", id->held_out);
  EXPECT_GT(id->held_out.rms, kModelMissesResidual);
  EXPECT_NEAR(id->parameters.spread_mm, unit.spread_mm(), 0.1 * unit.spread_mm());
}

// A unit whose lattice creeps (its plate lags the press: PatchDesign::creep_fraction), pressed
// in ramps as a lab records it. The static class has no lag: fitted without the creep, ramps at
// other places, loading and unloading, show what it misses (the held-out residual is flagged).
// With it, identification finds the lag's law from the ramps, fits the static physics again to
// the bends that law gives, and the held-out ramps are explained as a unit's inside the class.
TEST(UnitIdentificationTest, ACreepingUnitsLawIsFoundAndItsRampsExplained) {
  const uint64_t seed = 316;
  std::printf("seed %llu\n", static_cast<unsigned long long>(seed));
  sim::PatchDesign creeping;
  creeping.creep_fraction = 0.25;
  const sim::PatchModel unit =
      sim::PatchModel::fabricated(creeping, seed, sim::FabricationVariation{}).value();
  UnitData data = press_unit(unit, 13, 11.25, seed);
  sim::SimulatedPatch patch(unit, seed + 2);
  sim::RampProtocol ramp;
  ramp.speed_mm_per_s = 4.0;
  data.test = sim::generate_ramp_dataset(patch, sim::plan_random(60, 60, seed), ramp);
  IdentificationOptions opt;
  opt.depths_per_press = 3;
  const Result<IdentifiedUnit> id = identify_unit(sim::PatchDesign{}, data.train, opt, &data.test);
  ASSERT_TRUE(id.ok()) << id.error().to_string();
  std::printf("%s\n", id->creep.summary_text().c_str());
  print_quality("fit", id->fit);
  print_quality("held out (ramps)", id->held_out);
  ASSERT_TRUE(id->creep.kept) << id->creep.why;
  EXPECT_NEAR(id->parameters.creep_fraction, creeping.creep_fraction, 0.04);
  EXPECT_NEAR(id->parameters.creep_time_s, creeping.creep_time_s, 0.08);
  EXPECT_EQ(id->model.design().creep_fraction, id->parameters.creep_fraction);
  EXPECT_EQ(id->model.design().creep_time_s, id->parameters.creep_time_s);
  EXPECT_LT(id->held_out.rms, kModelMissesResidual);

  opt.fit_creep = false;
  const Result<IdentifiedUnit> plain =
      identify_unit(sim::PatchDesign{}, data.train, opt, &data.test);
  if (refused_clearly(plain)) return;
  print_quality("without the creep, held out (ramps)", plain->held_out);
  EXPECT_EQ(plain->parameters.creep_fraction, 0.0);
  EXPECT_GT(plain->held_out.rms, kModelMissesResidual);

  // Held to a residual the static fit exceeds, the fit is refused, and the refused parameters
  // carry the law found on them (their field correction and simulated presses then creep too).
  opt.fit_creep = true;
  opt.max_residual = plain->fit.rms - 1e-3;
  sim::UnitParameters refused;
  const Result<IdentifiedUnit> held =
      identify_unit(sim::PatchDesign{}, data.train, opt, nullptr, &refused);
  ASSERT_FALSE(held.ok());
  EXPECT_EQ(held.error().code, ErrorCode::kNotConverged);
  EXPECT_EQ(refused.spread_mm, plain->parameters.spread_mm);
  EXPECT_NEAR(refused.creep_fraction, creeping.creep_fraction, 0.04);
  EXPECT_NEAR(refused.creep_time_s, creeping.creep_time_s, 0.08);
}

// A lattice that bends more on the way up than on the way down (creep, hysteresis): the ramps'
// release halves give 10 % more field than the press halves at the same depth. The fit's rows
// below the deepest come from both halves, so in their depth bins (a third and two thirds of the
// ramps' 4 mm) the fit shows what the class misses as every row of the ramps does. Rows from one
// half only would be explained better than the ramps are: the fit's residual would hide the
// lag (with the press halves only: the [2, 3) mm bin at 0.65 of every row's).
TEST(UnitIdentificationTest, ALagOnTheWayUpIsNotHiddenFromTheFit) {
  const sim::PatchDesign design;
  const uint64_t seed = 4242;
  std::printf("seed %llu\n", static_cast<unsigned long long>(seed));
  const sim::PatchModel unit =
      sim::PatchModel::fabricated(design, seed, sim::FabricationVariation{}).value();
  UnitData data = press_unit(unit, 13, 11.25, seed);
  sim::Dataset& d = data.train;
  const std::size_t nc = static_cast<std::size_t>(d.channels());
  int released = 0;
  for (std::size_t begin = 0; begin < d.rows();) {
    std::size_t end = begin, peak = begin;
    for (; end < d.rows() && d.press[end] == d.press[begin]; ++end) {
      if (d.depth_mm[end] > d.depth_mm[peak]) peak = end;
    }
    for (std::size_t r = peak + 1; r < end; ++r, ++released) {
      for (std::size_t c = 0; c < nc; ++c) d.field_ut[r * nc + c] *= 1.1;
    }
    begin = end;
  }
  ASSERT_GT(released, 0);
  IdentificationOptions opt;
  opt.depths_per_press = 3;
  opt.fit_creep = false;  // the rows the static fit takes are what is checked
  const Result<IdentifiedUnit> id = identify_unit(design, d, opt, &d);
  if (refused_clearly(id)) return;
  print_quality("fit", id->fit);
  print_quality("every row", id->held_out);
  EXPECT_GT(id->fit.rms, kModelMissesResidual);
  ASSERT_GE(id->fit.bins.size(), 3u);
  for (const int bin : {1, 2}) {  // [1, 2) and [2, 3) mm
    EXPECT_GT(id->fit.bins[bin].rms, 0.9 * id->held_out.bins[bin].rms) << bin;
  }
}

// A design file of another patch altogether (the built-in 7 x 7 checkerboard for a 9 x 9 one-
// polarity unit): refused, naming what could not be fitted, never a unit file.
TEST(UnitIdentificationTest, TheWrongDesignIsRefusedNamingWhy) {
  const UnitData data = press_built(off_design_cases()[0].design, 315);
  IdentificationOptions opt;
  opt.depths_per_press = 2;
  opt.max_iterations = 15;
  opt.spread_starts = {1.0};
  std::vector<std::string> progress;
  opt.progress = [&](const std::string& line) { progress.push_back(line); };
  sim::UnitParameters refused;
  const Result<IdentifiedUnit> id =
      identify_unit(sim::PatchDesign{}, data.train, opt, nullptr, &refused);
  ASSERT_FALSE(id.ok());
  std::printf("%s\n", id.error().to_string().c_str());
  EXPECT_EQ(id.error().code, ErrorCode::kNotConverged);
  const std::string& m = id.error().message;
  EXPECT_TRUE(m.find("ran to its bound") != std::string::npos ||
              m.find("does not explain") != std::string::npos)
      << m;
  // A global at its bound ends before any full fit: nothing to keep.
  if (m.find("ran to its bound") != std::string::npos) {
    EXPECT_TRUE(refused.magnets.empty());
  }
  ASSERT_FALSE(progress.empty());  // the start was reported as it ran
  EXPECT_NE(progress.front().find("globals from spread"), std::string::npos) << progress.front();
}

// A recording that leaves one magnet unpressed (a hole in a random plan, a corner the robot did not
// reach): that magnet is held at the design with the globals found, named, and the rest of the
// unit is fitted to its noise; before, the whole recording was refused.
TEST(UnitIdentificationTest, AMagnetNoPressReachedIsHeldAtTheDesign) {
  const sim::PatchDesign design;
  const uint64_t seed = 4545;
  std::printf("seed %llu\n", static_cast<unsigned long long>(seed));
  const sim::PatchModel unit =
      sim::PatchModel::fabricated(design, seed, sim::FabricationVariation{}).value();
  const sim::PatchModel nominal = sim::PatchModel::nominal(design).value();
  const sim::MagnetParameters corner = nominal.parameters().magnets.front();
  std::vector<sim::PressPoint> holed;
  for (const sim::PressPoint& p : sim::plan_grid(13, 11.25)) {
    if (std::hypot(p.u_mm - corner.u_mm, p.v_mm - corner.v_mm) > 16) holed.push_back(p);
  }
  sim::SimulatedPatch patch(unit, seed);
  sim::RampProtocol ramp;
  ramp.speed_mm_per_s = 4.0;
  const sim::Dataset presses = sim::generate_ramp_dataset(patch, holed, ramp);
  IdentificationOptions opt;
  opt.depths_per_press = 3;
  opt.fit_creep = false;
  const Result<IdentifiedUnit> id = identify_unit(design, presses, opt);
  ASSERT_TRUE(id.ok()) << id.error().to_string();
  print_quality("fit", id->fit);
  EXPECT_EQ(id->uncovered_magnets, std::vector<int>{0});
  EXPECT_LT(id->fit.rms, 1.1);
  // Held: where the design draws it (in the presses' frame the globals found), at the globals'
  // height; every covered magnet moved.
  const sim::MagnetParameters& held = id->parameters.magnets.front();
  const double yaw = id->globals.frame_yaw_deg * M_PI / 180;
  EXPECT_NEAR(held.u_mm,
              std::cos(yaw) * corner.u_mm - std::sin(yaw) * corner.v_mm + id->globals.frame_du_mm,
              1e-9);
  EXPECT_NEAR(held.v_mm,
              std::sin(yaw) * corner.u_mm + std::cos(yaw) * corner.v_mm + id->globals.frame_dv_mm,
              1e-9);
  EXPECT_DOUBLE_EQ(held.h_mm, corner.h_mm + id->globals.magnet_height_offset_mm);
  EXPECT_NE(id->parameters.magnets[1].u_mm, nominal.parameters().magnets[1].u_mm);
}

TEST(UnitIdentificationTest, DegenerateInputIsRefused) {
  const sim::PatchDesign design;
  const sim::PatchModel unit =
      sim::PatchModel::fabricated(design, 5, sim::FabricationVariation{}).value();
  sim::SimulatedPatch patch(unit, 5);
  sim::RampProtocol ramp;
  ramp.speed_mm_per_s = 8.0;
  // Too few presses.
  const sim::Dataset few = sim::generate_ramp_dataset(patch, sim::plan_grid(3, 40), ramp);
  const auto r1 = identify_unit(design, few);
  ASSERT_FALSE(r1.ok());
  EXPECT_EQ(r1.error().code, ErrorCode::kDegenerate);
  EXPECT_NE(r1.error().message.find("presses"), std::string::npos) << r1.error().message;
  // Many presses, all on one half of the patch.
  std::vector<sim::PressPoint> half;
  for (const sim::PressPoint& p : sim::plan_grid(15, 9)) {
    if (p.u_mm < 0) half.push_back(p);
  }
  const sim::Dataset one_side = sim::generate_ramp_dataset(patch, half, ramp);
  const auto r2 = identify_unit(design, one_side);
  ASSERT_FALSE(r2.ok());
  EXPECT_EQ(r2.error().code, ErrorCode::kDegenerate);
  EXPECT_NE(r2.error().message.find("do not cover"), std::string::npos) << r2.error().message;
  std::printf("%s\n", r2.error().message.c_str());
  // Another sensor count.
  sim::PatchDesign small;
  small.sensors_u = 2;
  EXPECT_EQ(identify_unit(small, few).error().code, ErrorCode::kInvalidArgument);
}

}  // namespace
}  // namespace skinbus::estimators
