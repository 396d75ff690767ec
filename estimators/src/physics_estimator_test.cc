// The physics inversion and the nearest-neighbour lookup: exactness on noise-free model data,
// error against the Cramer-Rao bound with noise, masked and garbage input, refinement from a
// guess, and the lookup's exact search.
#include "skinbus/estimators/physics_estimator.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdlib>
#include <limits>
#include <memory>
#include <string>
#include <vector>

#include "skinbus/estimators/lookup_estimator.h"
#include "skinbus/sim/crlb.h"
#include "skinbus/sim/design_file.h"
#include "skinbus/sim/rng.h"

namespace skinbus::estimators {
namespace {

using sim::Contact;

class PhysicsEstimatorTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    model_ = new sim::PatchModel(sim::PatchModel::nominal(sim::PatchDesign{}).value());
    estimator_ = new PhysicsEstimator(PhysicsEstimator::create(*model_).value());
  }
  static void TearDownTestSuite() {
    delete estimator_;
    delete model_;
  }

  // Noise-free tared field of a press plus a uniform ambient offset (patch frame).
  static std::vector<double> field_of(const Contact& c, const double ambient[3] = nullptr) {
    std::vector<double> f(static_cast<std::size_t>(model_->channel_count()));
    model_->contact_field_ut(std::span<const Contact>(&c, 1), f);
    if (ambient != nullptr) {
      const auto& sensors = model_->sensors();
      for (std::size_t s = 0; s < sensors.size(); ++s) {
        const sim::Vec3<double> a =
            sensors[s].frame.apply(sim::Vec3<double>{ambient[0], ambient[1], ambient[2]});
        f[3 * s + 0] += a.x * sensors[s].gain.x;
        f[3 * s + 1] += a.y * sensors[s].gain.y;
        f[3 * s + 2] += a.z * sensors[s].gain.z;
      }
    }
    return f;
  }

  static sim::PatchModel* model_;
  static PhysicsEstimator* estimator_;
};
sim::PatchModel* PhysicsEstimatorTest::model_ = nullptr;
PhysicsEstimator* PhysicsEstimatorTest::estimator_ = nullptr;

TEST_F(PhysicsEstimatorTest, RecoversNoiseFreePressesWithAnAmbientOffset) {
  const double ambient[3] = {6.0, -9.0, 12.0};
  const Contact presses[] = {{0, 0, 2.0, 5},        {13.3, -7.1, 1.2, 5}, {-41.0, 33.5, 3.6, 5},
                             {58.0, -60.0, 2.5, 5}, {-22.2, 4.4, 0.8, 5}, {7.5, 52.5, 4.0, 5}};
  for (const Contact& c : presses) {
    const std::vector<double> f = field_of(c, ambient);
    const PhysicsEstimate e = estimator_->estimate(f);
    SCOPED_TRACE(testing::Message() << "press " << c.u_mm << ", " << c.v_mm << ", " << c.depth_mm);
    ASSERT_TRUE(e.contact.valid());
    EXPECT_EQ(e.contact.flags & (kEstimateNotConverged | kEstimatePoorFit | kEstimateNoContact),
              0u);
    EXPECT_NEAR(e.contact.u_mm, c.u_mm, 1e-3);
    EXPECT_NEAR(e.contact.v_mm, c.v_mm, 1e-3);
    EXPECT_NEAR(e.contact.depth_mm, c.depth_mm, 1e-3);
    for (int k = 0; k < 3; ++k) EXPECT_NEAR(e.ambient_ut[k], ambient[k], 1e-3);
    EXPECT_NEAR(e.contact.force_n, model_->force_n(c.depth_mm), 1e-2);
    EXPECT_LT(e.chi2, 1e-6);
    EXPECT_GT(e.iterations, 0);
  }
}

TEST_F(PhysicsEstimatorTest, NoisyErrorIsCloseToTheCramerRaoBound) {
  const uint64_t seed = 20240611;
  std::printf("seed %llu\n", static_cast<unsigned long long>(seed));
  sim::Rng rng(seed);
  const ChannelNoise noise = ChannelNoise::of(model_->design());
  double err2_xy = 0, bound2_xy = 0, err2_d = 0, bound2_d = 0, chi2 = 0;
  const int n = 60;
  for (int i = 0; i < n; ++i) {
    const Contact c{rng.uniform(-50, 50), rng.uniform(-50, 50), rng.uniform(1.0, 4.0), 5};
    const double ambient[3] = {rng.uniform(-20, 20), rng.uniform(-20, 20), rng.uniform(-20, 20)};
    std::vector<double> f = field_of(c, ambient);
    for (std::size_t k = 0; k < f.size(); ++k)
      f[k] += noise.sigma(static_cast<int>(k)) * rng.normal();
    const PhysicsEstimate e = estimator_->estimate(f);
    ASSERT_TRUE(e.contact.valid());
    EXPECT_EQ(e.contact.flags & kEstimateNotConverged, 0u);
    const sim::CrlbPoint b = sim::crlb_at(*model_, c, noise.xy_ut, noise.z_ut, true);
    err2_xy += std::pow(e.contact.u_mm - c.u_mm, 2) + std::pow(e.contact.v_mm - c.v_mm, 2);
    err2_d += std::pow(e.contact.depth_mm - c.depth_mm, 2);
    bound2_xy += b.sd_xy_mm * b.sd_xy_mm;
    bound2_d += b.sd_depth_mm * b.sd_depth_mm;
    chi2 += e.reduced_chi2;
  }
  const double ratio_xy = std::sqrt(err2_xy / bound2_xy), ratio_d = std::sqrt(err2_d / bound2_d);
  std::printf(
      "RMS error / CRLB: xy %.3f (RMS %.4f mm), depth %.3f (RMS %.4f mm); mean reduced "
      "chi2 %.3f\n",
      ratio_xy, std::sqrt(err2_xy / n), ratio_d, std::sqrt(err2_d / n), chi2 / n);
  // An efficient estimator reaches the bound; 60 presses estimate the ratio to ~10 %.
  EXPECT_GT(ratio_xy, 0.7);
  EXPECT_LT(ratio_xy, 1.3);
  EXPECT_GT(ratio_d, 0.7);
  EXPECT_LT(ratio_d, 1.3);
  EXPECT_NEAR(chi2 / n, 1.0, 0.15);
}

TEST_F(PhysicsEstimatorTest, MaskedChannelsAreLeftOut) {
  const Contact c{-12.0, 21.0, 2.5, 5};
  std::vector<double> f = field_of(c);
  std::vector<uint8_t> ok(f.size(), 1);
  f[4] = std::numeric_limits<double>::quiet_NaN();  // NaN
  f[17] = 1e6;                                      // saturated
  f[30] = std::numeric_limits<double>::infinity();  // Inf
  ok[22] = 0;                                       // dead
  f[22] = 12345;                                    // whatever a dead channel says
  ok[23] = 0;
  const PhysicsEstimate e = estimator_->estimate(f, ok);
  ASSERT_TRUE(e.contact.valid());
  EXPECT_NE(e.contact.flags & kEstimateMasked, 0u);
  EXPECT_EQ(e.channels_used, 43);
  EXPECT_NEAR(e.contact.u_mm, c.u_mm, 1e-3);
  EXPECT_NEAR(e.contact.v_mm, c.v_mm, 1e-3);
  EXPECT_NEAR(e.contact.depth_mm, c.depth_mm, 1e-3);

  // Only 9 channels left: rejected with the reason.
  std::vector<uint8_t> few(f.size(), 0);
  for (int k = 0; k < 9; ++k) few[static_cast<std::size_t>(k)] = 1;
  const PhysicsEstimate r = estimator_->estimate(field_of(c), few);
  EXPECT_FALSE(r.contact.valid());
  EXPECT_EQ(r.contact.reason, RejectReason::kTooFewChannels);
  // Wrong shape.
  const std::vector<double> shorter(10, 0.0);
  EXPECT_EQ(estimator_->estimate(shorter).contact.reason, RejectReason::kWrongShape);
}

TEST_F(PhysicsEstimatorTest, GarbageNeverGivesNanOrInf) {
  const std::size_t nc = static_cast<std::size_t>(model_->channel_count());
  auto finite = [](const PhysicsEstimate& e) {
    return std::isfinite(e.contact.u_mm) && std::isfinite(e.contact.v_mm) &&
           std::isfinite(e.contact.depth_mm) && std::isfinite(e.contact.force_n) &&
           std::isfinite(e.chi2) && std::isfinite(e.reduced_chi2) &&
           std::isfinite(e.ambient_ut[0]) && std::isfinite(e.ambient_ut[1]) &&
           std::isfinite(e.ambient_ut[2]);
  };
  // Nothing pressed: a valid, finite estimate that says so.
  const PhysicsEstimate zero = estimator_->estimate(std::vector<double>(nc, 0.0));
  EXPECT_TRUE(finite(zero));
  EXPECT_NE(zero.contact.flags & kEstimateNoContact, 0u);
  // Huge values: saturated, all masked, rejected.
  const PhysicsEstimate huge = estimator_->estimate(std::vector<double>(nc, 1e300));
  EXPECT_FALSE(huge.contact.valid());
  EXPECT_TRUE(finite(huge));
  const PhysicsEstimate inf =
      estimator_->estimate(std::vector<double>(nc, std::numeric_limits<double>::infinity()));
  EXPECT_FALSE(inf.contact.valid());
  EXPECT_TRUE(finite(inf));
  // Large values below saturation and random nonsense: finite, flagged as a poor fit.
  sim::Rng rng(7);
  for (int t = 0; t < 5; ++t) {
    std::vector<double> f(nc);
    for (double& x : f) x = rng.uniform(-5000, 5000);
    const PhysicsEstimate e = estimator_->estimate(f);
    EXPECT_TRUE(finite(e));
    if (e.contact.valid()) {
      EXPECT_NE(e.contact.flags & kEstimatePoorFit, 0u);
    }
  }
}

TEST_F(PhysicsEstimatorTest, RefinesAGuessAFewMillimetresOff) {
  const double ambient[3] = {-4.0, 3.0, 8.0};
  const Contact c{31.0, -17.5, 3.0, 5};
  const std::vector<double> f = field_of(c, ambient);
  ContactEstimate guess;
  guess.u_mm = c.u_mm + 3.5;
  guess.v_mm = c.v_mm - 2.5;
  guess.depth_mm = c.depth_mm - 1.0;
  const PhysicsEstimate e = estimator_->refine(f, {}, guess);
  ASSERT_TRUE(e.contact.valid());
  EXPECT_EQ(e.contact.flags & kEstimateNotConverged, 0u);
  EXPECT_NEAR(e.contact.u_mm, c.u_mm, 1e-3);
  EXPECT_NEAR(e.contact.v_mm, c.v_mm, 1e-3);
  EXPECT_NEAR(e.contact.depth_mm, c.depth_mm, 1e-3);
}

TEST_F(PhysicsEstimatorTest, LookupSearchIsExactAndFindsGridPresses) {
  LookupGrid grid;
  grid.pitch_mm = 5;
  grid.depths_mm = {1, 2, 3};
  const LookupEstimator lookup = LookupEstimator::from_model(*model_, grid).value();
  EXPECT_EQ(lookup.rows(), 29 * 29 * 3);
  // A press on the grid is found exactly.
  const Contact on{15, -35, 2, 5};
  const ContactEstimate e = lookup.estimate(field_of(on));
  ASSERT_TRUE(e.valid());
  EXPECT_EQ(e.u_mm, 15);
  EXPECT_EQ(e.v_mm, -35);
  EXPECT_EQ(e.depth_mm, 2);
  // Early exit returns the same neighbours as a full scan, also with masked channels.
  sim::Rng rng(11);
  const ChannelNoise noise = lookup.noise();
  for (int t = 0; t < 20; ++t) {
    const Contact c{rng.uniform(-60, 60), rng.uniform(-60, 60), rng.uniform(0.5, 3.5), 5};
    std::vector<double> f = field_of(c);
    std::vector<uint8_t> ok(f.size(), 1);
    if (t % 2) ok[static_cast<std::size_t>(t)] = 0;
    std::vector<double> w(f.size());
    for (std::size_t k = 0; k < f.size(); ++k)
      w[k] = (f[k] + noise.sigma(static_cast<int>(k)) * rng.normal()) /
             noise.sigma(static_cast<int>(k));
    LookupNeighbour nb[3];
    ASSERT_EQ(lookup.nearest(w, ok, nb), 3);
    // Brute force.
    double best = std::numeric_limits<double>::infinity();
    int best_row = -1;
    for (int r = 0; r < lookup.rows(); ++r) {
      const Contact rc{lookup.row_u_mm(r), lookup.row_v_mm(r), lookup.row_depth_mm(r), 5};
      const std::vector<double> rf = field_of(rc);
      double d2 = 0;
      for (std::size_t k = 0; k < f.size(); ++k) {
        if (ok[k]) d2 += std::pow(w[k] - rf[k] / noise.sigma(static_cast<int>(k)), 2);
      }
      if (d2 < best) best = d2, best_row = r;
    }
    EXPECT_EQ(nb[0].row, best_row);
    EXPECT_NEAR(nb[0].distance2, best, 1e-3 * (1 + best));
    EXPECT_LE(nb[0].distance2, nb[1].distance2);
    EXPECT_LE(nb[1].distance2, nb[2].distance2);
  }
  // Nothing pressed: flagged; too few channels: rejected.
  const std::vector<double> zero(static_cast<std::size_t>(model_->channel_count()), 0.0);
  EXPECT_NE(lookup.estimate(zero).flags & kEstimateNoContact, 0u);
  std::vector<uint8_t> few(zero.size(), 0);
  few[0] = 1;
  EXPECT_EQ(lookup.estimate(zero, few).reason, RejectReason::kTooFewChannels);
}

TEST_F(PhysicsEstimatorTest, LookupFromADatasetInterpolatesWithNeighbours) {
  sim::Dataset data;
  data.sensors.resize(16);
  for (double u = -60; u <= 60; u += 7.5) {
    for (double v = -60; v <= 60; v += 7.5) {
      for (double d : {1.0, 2.0, 3.0}) {
        const std::vector<double> f = field_of(Contact{u, v, d, 5});
        data.append(0, 0, u, v, d, model_->force_n(d), f.data());
      }
    }
  }
  LookupOptions opt;
  opt.neighbours = 4;
  const LookupEstimator lookup =
      LookupEstimator::from_dataset(model_->design(), data, 1, opt).value();
  EXPECT_EQ(static_cast<std::size_t>(lookup.rows()), data.rows());
  const Contact c{3.0, -4.0, 2.0, 5};
  const ContactEstimate e = lookup.estimate(field_of(c));
  ASSERT_TRUE(e.valid());
  EXPECT_LT(std::hypot(e.u_mm - c.u_mm, e.v_mm - c.v_mm), 7.5);
  EXPECT_NEAR(e.depth_mm, c.depth_mm, 1.0);
  // A dataset for another sensor count is refused.
  sim::Dataset other;
  other.sensors.resize(4);
  EXPECT_FALSE(LookupEstimator::from_dataset(model_->design(), other).ok());
}

}  // namespace
}  // namespace skinbus::estimators

namespace skinbus::estimators {
namespace {

// Presses beyond the magnets of a one-polarity 9 x 9 grid: two places some millimetres apart
// explain a sample nearly alike, and the fit from the nearest start alone lands in the wrong one
// often enough to put the mean error well above the bound; with the other basins tried it is at
// the bound (the mean radial error of an efficient estimator is 0.89x the RMS bound).
TEST(PhysicsEstimatorBasins, OtherBasinsBringPressesBeyondTheMagnetsToTheBound) {
  // The design docs/benchmarks/designs.md measures (the example patch).
  const char* dir = std::getenv("SKINBUS_SOURCE_DIR");
  const auto read = sim::read_design_file(std::string(dir != nullptr ? dir : ".") +
                                          "/docs/benchmarks/design_9x9_uniform.yaml");
  ASSERT_TRUE(read.ok()) << read.error().to_string();
  const sim::PatchDesign& design = *read;
  const sim::PatchModel model = sim::PatchModel::nominal(design).value();
  PhysicsOptions nearest_only;
  nearest_only.other_basins = 0;
  const PhysicsEstimator one = PhysicsEstimator::create(model, nearest_only).value();
  const PhysicsEstimator basins = PhysicsEstimator::create(model).value();
  const uint64_t seed = 20261125;
  std::printf("seed %llu\n", static_cast<unsigned long long>(seed));
  sim::Rng rng(seed);
  const ChannelNoise noise = ChannelNoise::of(design);
  double err_one = 0, err_basins = 0, bound = 0;
  const int n = 150;
  for (int i = 0; i < n; ++i) {
    // The band between the outer magnets (+-60 mm) and the patch edge (+-70 mm), and just inside.
    const double along = rng.uniform(-67.5, 67.5), across = rng.uniform(50, 67.5);
    const bool flip = rng.uniform(0, 1) < 0.5, negative = rng.uniform(0, 1) < 0.5;
    const double u = flip ? along : (negative ? -across : across);
    const double v = flip ? (negative ? -across : across) : along;
    const Contact c{u, v, rng.uniform(1.0, 4.0), 5};
    const std::vector<double> f = noisy_field(model, std::span<const Contact>(&c, 1), rng);
    const PhysicsEstimate a = one.estimate(f), b = basins.estimate(f);
    ASSERT_TRUE(a.contact.valid() && b.contact.valid());
    err_one += std::hypot(a.contact.u_mm - u, a.contact.v_mm - v);
    err_basins += std::hypot(b.contact.u_mm - u, b.contact.v_mm - v);
    EXPECT_LE(b.chi2, a.chi2 * (1 + 1e-9));  // never a worse fit
    bound += sim::crlb_at(model, c, noise.xy_ut, noise.z_ut, true).sd_xy_mm;
  }
  std::printf(
      "presses beyond the magnets: mean XY error / mean bound %.2f nearest start only, "
      "%.2f with the other basins\n",
      err_one / bound, err_basins / bound);
  EXPECT_LT(err_basins, 0.85 * err_one);
  EXPECT_LT(err_basins / bound, 1.2);
}

TEST(PhysicsStartPitch, FollowsTheMagnetSpacingAtMostFiveMillimetres) {
  sim::PatchDesign d;  // the built-in 7 x 7 at 20 mm
  EXPECT_DOUBLE_EQ(start_pitch_mm(d), 5.0);
  d.magnet_pitch_mm = 15;
  EXPECT_DOUBLE_EQ(start_pitch_mm(d), 15.0 / kStartPitchPerMagnetSpacing);
  d.magnet_pitch_mm = 40;
  EXPECT_DOUBLE_EQ(start_pitch_mm(d), 5.0);
  // A listed layout: a row at 12 mm with one magnet 30 mm away; the median spacing is 12 mm.
  for (double u : {-24.0, -12.0, 0.0, 12.0, 24.0}) d.magnet_list.push_back({u, 0, 0.75, +1});
  d.magnet_list.push_back({0, 30, 0.75, -1});
  EXPECT_DOUBLE_EQ(start_pitch_mm(d), 12.0 / kStartPitchPerMagnetSpacing);
  d.magnet_list = {{0, 0, 0.75, +1}};  // one magnet: no spacing
  EXPECT_DOUBLE_EQ(start_pitch_mm(d), 5.0);
}

}  // namespace
}  // namespace skinbus::estimators

namespace skinbus::estimators {
namespace {

// An estimator with covariances over a fabricated unit of the built-in design.
PhysicsEstimator covariance_estimator(uint64_t hardware_uid) {
  const sim::PatchModel unit =
      sim::PatchModel::fabricated(sim::PatchDesign{}, hardware_uid, sim::FabricationVariation{})
          .value();
  PhysicsOptions options;
  options.covariance = true;
  return PhysicsEstimator::create(unit, options).value();
}

// The lean Levenberg-Marquardt (refine_lm) reaches the minimum the Ceres fit (refine) reaches,
// from the same starts, with the same flags; degenerate input is refused or flagged, never NaN.
// "The same": within 5 % of the fit's own 1-sigma uncertainty (its convergence test stops when
// what is left moves the contact by a few percent of it; the Jacobian it updates along its steps
// instead of computing it again puts its end a few micrometres off), and the same chi-square.
TEST(PhysicsEstimatorLeanTest, RefineLmReachesTheCeresFitsMinimum) {
  const uint64_t seed = 4242;
  std::printf("seed %llu\n", static_cast<unsigned long long>(seed));
  const PhysicsEstimator est = covariance_estimator(0x5B0000000000000Aull);
  const sim::PatchModel& unit = est.model();
  sim::Rng rng(seed);
  for (int i = 0; i < 40; ++i) {
    const sim::Contact c{rng.uniform(-55, 55), rng.uniform(-55, 55), rng.uniform(0.8, 4.5), 5};
    const std::vector<double> f = noisy_field(unit, std::span<const sim::Contact>(&c, 1), rng);
    ContactEstimate start;
    start.u_mm = c.u_mm + rng.uniform(-2, 2);
    start.v_mm = c.v_mm + rng.uniform(-2, 2);
    start.depth_mm = c.depth_mm + rng.uniform(-0.3, 0.3);
    const PhysicsEstimate a = est.refine(f, {}, start);
    const PhysicsEstimate b = est.refine_lm(f, {}, start);
    SCOPED_TRACE(testing::Message() << "press " << c.u_mm << ", " << c.v_mm << ", " << c.depth_mm);
    ASSERT_TRUE(a.contact.valid());
    ASSERT_TRUE(b.contact.valid());
    ASSERT_TRUE(std::isfinite(b.sigma_uv_mm) && std::isfinite(b.sigma_depth_mm));
    EXPECT_LE(std::hypot(b.contact.u_mm - a.contact.u_mm, b.contact.v_mm - a.contact.v_mm),
              0.05 * b.sigma_uv_mm);  // sigma: 0.1-0.3 mm here
    EXPECT_LE(std::fabs(b.contact.depth_mm - a.contact.depth_mm),
              0.05 * b.sigma_depth_mm);  // sigma: 0.01-0.03 mm
    EXPECT_NEAR(b.chi2, a.chi2, 1e-3 * a.chi2 + 1e-6);
    EXPECT_EQ(b.contact.flags & (kEstimatePoorFit | kEstimateNotConverged), 0u);
    EXPECT_LE(b.iterations, 12);
  }
}

// search_lm() finds a press from the start table alone; a held fit far from the press leaves
// the search as it was; one at the press leaves out the rows beside it (the caller's basin), and
// a fit from another row that comes within 1 mm of it stops there: the search yields a fit 1 mm
// or more from the held one or none (rejected), never a lower chi-square than the search
// without it, never NaN.
TEST(PhysicsEstimatorLeanTest, SearchLmFindsThePressAndLeavesOutAHeldFitsBasin) {
  const uint64_t seed = 7171;
  std::printf("seed %llu\n", static_cast<unsigned long long>(seed));
  const sim::PatchModel unit = sim::PatchModel::nominal(sim::PatchDesign{}).value();
  const PhysicsEstimator est = PhysicsEstimator::create(unit).value();
  sim::Rng rng(seed);
  int joined = 0;  // presses whose search with the held fit at the press found no other basin
  for (int i = 0; i < 12; ++i) {
    const sim::Contact c{rng.uniform(-45, 45), rng.uniform(-45, 45), rng.uniform(1.5, 4.0), 5};
    const std::vector<double> f = noisy_field(unit, std::span<const sim::Contact>(&c, 1), rng);
    SCOPED_TRACE(testing::Message() << "press " << c.u_mm << ", " << c.v_mm << ", " << c.depth_mm);
    const PhysicsEstimate all = est.search_lm(f, {}, 2);
    ASSERT_TRUE(all.contact.valid());
    EXPECT_LT(std::hypot(all.contact.u_mm - c.u_mm, all.contact.v_mm - c.v_mm), 1.0);
    ContactEstimate far;  // a held fit across the patch: no row near the press is left out
    far.u_mm = c.u_mm > 0 ? -60 : 60;
    far.v_mm = c.v_mm > 0 ? -60 : 60;
    const PhysicsEstimate apart = est.search_lm(f, {}, 2, &far);
    ASSERT_TRUE(apart.contact.valid());
    EXPECT_EQ(apart.contact.u_mm, all.contact.u_mm);
    EXPECT_EQ(apart.contact.v_mm, all.contact.v_mm);
    EXPECT_EQ(apart.chi2, all.chi2);
    ContactEstimate held;  // a held fit at the press: the search looks elsewhere
    held.u_mm = c.u_mm;
    held.v_mm = c.v_mm;
    const PhysicsEstimate elsewhere = est.search_lm(f, {}, 2, &held);
    EXPECT_GT(elsewhere.field_evaluations, 0);
    if (elsewhere.contact.valid()) {
      EXPECT_TRUE(std::isfinite(elsewhere.contact.u_mm) && std::isfinite(elsewhere.chi2));
      EXPECT_GE(std::hypot(elsewhere.contact.u_mm - held.u_mm, elsewhere.contact.v_mm - held.v_mm),
                1.0);
      EXPECT_GE(elsewhere.chi2, all.chi2 * (1 - 1e-3));
    } else {
      ++joined;
    }
  }
  // This design has one basin a press: the fits from farther rows mostly reach the press, and
  // stop on coming within 1 mm of it.
  EXPECT_GE(joined, 6);
}

// A press held and sliding 0.1 mm a sample, each sample refined from the last one's answer: with
// the press's WarmJacobian the fits begin from the last fit's Jacobian (at most kMaxUses in a
// row, then one computed) and reach the minimum the fits without it reach, within 5 % of the
// fit's own uncertainty, with the same flags. A start beyond 0.5 mm of it computes its own.
TEST(PhysicsEstimatorLeanTest, RefineLmFromTheLastFitsJacobianReachesTheSameMinimum) {
  const uint64_t seed = 5150;
  std::printf("seed %llu\n", static_cast<unsigned long long>(seed));
  const PhysicsEstimator est = covariance_estimator(0x5B0000000000000Bull);
  const sim::PatchModel& unit = est.model();
  sim::Rng rng(seed);
  int began_warm = 0, max_uses = 0;
  for (int press = 0; press < 6; ++press) {
    sim::Contact c{rng.uniform(-45, 45), rng.uniform(-45, 45), rng.uniform(1.2, 4.0), 5};
    auto warm = std::make_unique<WarmJacobian>();
    ContactEstimate start;
    start.u_mm = c.u_mm + 0.5;
    start.v_mm = c.v_mm - 0.5;
    start.depth_mm = c.depth_mm;
    for (int k = 0; k < 16; ++k) {
      c.u_mm += 0.1;
      const std::vector<double> f = noisy_field(unit, std::span<const sim::Contact>(&c, 1), rng);
      const PhysicsEstimate a = est.refine_lm(f, {}, start);
      const int uses_before = warm->valid ? warm->uses : -1;
      const PhysicsEstimate b = est.refine_lm(f, {}, start, warm.get());
      SCOPED_TRACE(testing::Message() << "press " << press << " sample " << k);
      ASSERT_TRUE(a.contact.valid() && b.contact.valid());
      EXPECT_LE(std::hypot(b.contact.u_mm - a.contact.u_mm, b.contact.v_mm - a.contact.v_mm),
                0.05 * a.sigma_uv_mm);
      EXPECT_LE(std::fabs(b.contact.depth_mm - a.contact.depth_mm), 0.05 * a.sigma_depth_mm);
      EXPECT_EQ(b.contact.flags, a.contact.flags);
      ASSERT_TRUE(warm->valid);
      EXPECT_LE(warm->uses, WarmJacobian::kMaxUses);
      if (warm->uses > 0) {
        ++began_warm;
        EXPECT_EQ(warm->uses, uses_before + 1);
      }
      max_uses = std::max(max_uses, warm->uses);
      start = b.contact;
    }
    // A start 3 mm away: the fit computes its own Jacobian (uses back to 0).
    ContactEstimate away = start;
    away.u_mm += 3;
    const std::vector<double> f = noisy_field(unit, std::span<const sim::Contact>(&c, 1), rng);
    est.refine_lm(f, {}, away, warm.get());
    EXPECT_EQ(warm->uses, 0);
  }
  std::printf("%d of 96 fits began from the last fit's Jacobian\n", began_warm);
  EXPECT_GE(began_warm, 48);
  EXPECT_EQ(max_uses, WarmJacobian::kMaxUses);
}

// A fit that begins where the press's last fit ended takes that fit's field from the memory
// instead of evaluating it (the model's field depends on the contact, not on the sample): the
// memory holds the model's field at its point to the bit, and a fit from there is the same to
// the bit as one that evaluates it, at one evaluation fewer.
TEST(PhysicsEstimatorLeanTest, AFitFromTheLastFitsEndReusesItsField) {
  const uint64_t seed = 6160;
  std::printf("seed %llu\n", static_cast<unsigned long long>(seed));
  const PhysicsEstimator est = covariance_estimator(0x5B0000000000000Cull);
  const sim::PatchModel& unit = est.model();
  const std::size_t nc = static_cast<std::size_t>(unit.channel_count());
  sim::Rng rng(seed);
  for (int press = 0; press < 8; ++press) {
    SCOPED_TRACE(testing::Message() << "press " << press);
    sim::Contact c{rng.uniform(-45, 45), rng.uniform(-45, 45), rng.uniform(1.2, 4.0), 5};
    ContactEstimate start;
    start.u_mm = c.u_mm + 0.4;
    start.v_mm = c.v_mm - 0.3;
    start.depth_mm = c.depth_mm;
    WarmJacobian memory;
    const PhysicsEstimate first = est.refine_lm(
        noisy_field(unit, std::span<const sim::Contact>(&c, 1), rng), {}, start, &memory);
    ASSERT_TRUE(first.contact.valid() && memory.valid);
    // The memory's field is the model's at its point.
    const sim::Contact at{memory.at[0], memory.at[1], memory.at[2], est.options().tip_radius_mm};
    std::vector<double> model_field(nc);
    unit.contact_field_ut(std::span<const sim::Contact>(&at, 1), model_field);
    for (std::size_t i = 0; i < nc; ++i) ASSERT_EQ(memory.field_ut[i], model_field[i]) << i;
    // The next sample from that point. Both memories have spent their Jacobian's uses, so both
    // fits compute it afresh at the start; the one whose memory lies 1 mm away evaluates the
    // start's field too.
    c.u_mm += 0.1;
    const std::vector<double> f = noisy_field(unit, std::span<const sim::Contact>(&c, 1), rng);
    ContactEstimate from = first.contact;
    from.u_mm = memory.at[0];
    from.v_mm = memory.at[1];
    from.depth_mm = memory.at[2];
    WarmJacobian here = memory, apart = memory;
    here.uses = apart.uses = WarmJacobian::kMaxUses;
    apart.at[0] += 1.0;
    const PhysicsEstimate reused = est.refine_lm(f, {}, from, &here);
    const PhysicsEstimate evaluated = est.refine_lm(f, {}, from, &apart);
    EXPECT_EQ(reused.contact.u_mm, evaluated.contact.u_mm);
    EXPECT_EQ(reused.contact.v_mm, evaluated.contact.v_mm);
    EXPECT_EQ(reused.contact.depth_mm, evaluated.contact.depth_mm);
    EXPECT_EQ(reused.chi2, evaluated.chi2);
    EXPECT_EQ(reused.jacobians, evaluated.jacobians);
    EXPECT_EQ(reused.field_evaluations + 1, evaluated.field_evaluations);
    EXPECT_GE(reused.jacobians, 1);
  }
}

TEST(PhysicsEstimatorLeanTest, DegenerateInputIsRefusedOrFlaggedNeverNaN) {
  const sim::PatchModel unit = sim::PatchModel::nominal(sim::PatchDesign{}).value();
  const PhysicsEstimator est = PhysicsEstimator::create(unit).value();
  const std::size_t nc = static_cast<std::size_t>(unit.channel_count());
  ContactEstimate start;
  start.u_mm = 3;
  start.v_mm = 4;
  start.depth_mm = 1;
  // Nothing pressed: flagged no contact, finite.
  const std::vector<double> zero(nc, 0.0);
  const PhysicsEstimate z = est.refine_lm(zero, {}, start);
  EXPECT_NE(z.contact.flags & kEstimateNoContact, 0u);
  EXPECT_TRUE(std::isfinite(z.contact.u_mm) && std::isfinite(z.contact.depth_mm));
  // A NaN start, and a start far outside the patch: clamped, finite.
  ContactEstimate bad;
  bad.u_mm = std::numeric_limits<double>::quiet_NaN();
  bad.v_mm = 1e9;
  bad.depth_mm = -5;
  std::vector<double> f(nc);
  const sim::Contact c{10, -10, 2, 5};
  unit.contact_field_ut(std::span<const sim::Contact>(&c, 1), f);
  const PhysicsEstimate n = est.refine_lm(f, {}, bad);
  EXPECT_TRUE(std::isfinite(n.contact.u_mm) && std::isfinite(n.contact.v_mm) &&
              std::isfinite(n.contact.depth_mm) && std::isfinite(n.chi2));
  // Too few channels, and the wrong shape: rejected with the reason.
  std::vector<uint8_t> ok(nc, 0);
  for (int i = 0; i < 6; ++i) ok[static_cast<std::size_t>(i)] = 1;
  EXPECT_EQ(est.refine_lm(f, ok, start).contact.reason, RejectReason::kTooFewChannels);
  EXPECT_EQ(est.refine_lm(std::span<const double>(f.data(), 5), {}, start).contact.reason,
            RejectReason::kWrongShape);
  // Non-finite channels are masked, not used.
  f[3] = std::numeric_limits<double>::infinity();
  f[7] = std::numeric_limits<double>::quiet_NaN();
  const PhysicsEstimate m = est.refine_lm(f, {}, start);
  EXPECT_NE(m.contact.flags & kEstimateMasked, 0u);
  // Noise-free: at the press, to the fit's stopping resolution (a chi-square gain of 1e-3 left:
  // a few micrometres here), explaining the sample to far below the noise; NaN or a used
  // infinity would be far off.
  EXPECT_NEAR(m.contact.u_mm, 10, 0.01);
  EXPECT_NEAR(m.contact.v_mm, -10, 0.01);
  EXPECT_LT(m.reduced_chi2, 0.01);
}

// The shear force (PhysicsOptions::fit_shear): exact on noise-free presses, at its Cramer-Rao
// bound with noise, signs right wherever the force is well above the bound; a press without
// shear is fitted as one; without the shear in the fit, a sheared press is misplaced.
TEST(PhysicsEstimatorShearTest, RecoversTheShearForceAtItsBound) {
  const uint64_t seed = 7311;
  std::printf("seed %llu\n", static_cast<unsigned long long>(seed));
  const sim::PatchModel unit =
      sim::PatchModel::fabricated(sim::PatchDesign{}, 0x5B00000000000031ull,
                                  sim::FabricationVariation{})
          .value();
  PhysicsOptions with;
  with.fit_shear = true;
  with.covariance = true;
  const PhysicsEstimator shear = PhysicsEstimator::create(unit, with).value();
  const PhysicsEstimator plain = PhysicsEstimator::create(unit).value();
  const ChannelNoise noise = ChannelNoise::of(unit.design());
  const std::size_t nc = static_cast<std::size_t>(unit.channel_count());
  sim::Rng rng(seed);
  double norm2 = 0, err2 = 0, bound2 = 0, stated2 = 0, xy2_shear = 0, xy2_plain = 0, xy2_bound = 0;
  int told = 0, signs_right = 0;
  const int n = 60;
  for (int i = 0; i < n; ++i) {
    sim::Contact c{rng.uniform(-50, 50), rng.uniform(-50, 50), rng.uniform(1.0, 4.0), 5};
    // Up to a friction coefficient of 0.5, in any direction; every fourth press without shear.
    const double mag = i % 4 == 0 ? 0.0 : rng.uniform(0, 0.5) * unit.force_n(c.depth_mm);
    const double dir = rng.uniform(0, 2 * M_PI);
    c.shear_u_n = mag * std::cos(dir);
    c.shear_v_n = mag * std::sin(dir);
    if (i < 4) {  // noise-free: exact
      std::vector<double> exact(nc);
      unit.contact_field_ut(std::span<const sim::Contact>(&c, 1), exact);
      const PhysicsEstimate e = shear.estimate(exact);
      ASSERT_TRUE(e.contact.valid());
      EXPECT_NEAR(e.contact.shear_u_n, c.shear_u_n, 1e-3) << i;
      EXPECT_NEAR(e.contact.shear_v_n, c.shear_v_n, 1e-3) << i;
      EXPECT_NEAR(e.contact.u_mm, c.u_mm, 1e-3) << i;
    }
    const std::vector<double> f = noisy_field(unit, std::span<const sim::Contact>(&c, 1), rng);
    const PhysicsEstimate e = shear.estimate(f);
    const PhysicsEstimate p = plain.estimate(f);
    SCOPED_TRACE(testing::Message() << "press " << c.u_mm << ", " << c.v_mm << ", " << c.depth_mm
                                    << " shear " << c.shear_u_n << ", " << c.shear_v_n);
    ASSERT_TRUE(e.contact.valid());
    EXPECT_EQ(e.contact.flags & (kEstimateNotConverged | kEstimatePoorFit), 0u);
    ASSERT_TRUE(std::isfinite(e.sigma_shear_n));
    const sim::CrlbShear b = sim::crlb_shear_at(unit, c, noise.xy_ut, noise.z_ut, true);
    ASSERT_TRUE(b.identifiable);
    const double eu = e.contact.shear_u_n - c.shear_u_n, ev = e.contact.shear_v_n - c.shear_v_n;
    err2 += eu * eu + ev * ev;
    bound2 += b.sd_shear_n * b.sd_shear_n;
    norm2 += (eu * eu + ev * ev) / (b.sd_shear_n * b.sd_shear_n);
    stated2 += e.sigma_shear_n * e.sigma_shear_n;
    xy2_shear += std::pow(e.contact.u_mm - c.u_mm, 2) + std::pow(e.contact.v_mm - c.v_mm, 2);
    xy2_plain += std::pow(p.contact.u_mm - c.u_mm, 2) + std::pow(p.contact.v_mm - c.v_mm, 2);
    xy2_bound += b.contact.sd_xy_mm * b.contact.sd_xy_mm;
    for (int k = 0; k < 2; ++k) {
      const double truth = k == 0 ? c.shear_u_n : c.shear_v_n;
      const double got = k == 0 ? e.contact.shear_u_n : e.contact.shear_v_n;
      const double sd = k == 0 ? b.sd_shear_u_n : b.sd_shear_v_n;
      if (std::fabs(truth) > 4 * sd) {
        ++told;
        signs_right += (got > 0) == (truth > 0);
      }
    }
  }
  // Each press's error in units of its own bound (the bound varies 10x over the patch).
  const double ratio = std::sqrt(norm2 / n), stated = std::sqrt(stated2 / bound2);
  std::printf(
      "shear RMS error %.3f N, bound %.3f N, RMS of error / bound %.2f, stated sigma / bound "
      "%.2f; position RMS with the shear fitted %.3f mm (bound %.3f), without %.3f mm; signs "
      "right %d of %d\n",
      std::sqrt(err2 / n), std::sqrt(bound2 / n), ratio, stated, std::sqrt(xy2_shear / n),
      std::sqrt(xy2_bound / n), std::sqrt(xy2_plain / n), signs_right, told);
  EXPECT_GT(ratio, 0.7);
  EXPECT_LT(ratio, 1.3);
  EXPECT_NEAR(stated, 1.0, 0.25);  // the fit's covariance states the bound
  EXPECT_GT(told, 40);
  EXPECT_EQ(signs_right, told);
  EXPECT_LT(std::sqrt(xy2_shear / xy2_bound), 1.3);
  EXPECT_GT(xy2_plain, 2 * xy2_shear);  // a shear left out of the model misplaces the press
}

TEST(PhysicsEstimatorShearTest, DegenerateInputNeverGivesNaN) {
  const sim::PatchModel unit = sim::PatchModel::nominal(sim::PatchDesign{}).value();
  PhysicsOptions with;
  with.fit_shear = true;
  with.covariance = true;
  const PhysicsEstimator est = PhysicsEstimator::create(unit, with).value();
  const std::size_t nc = static_cast<std::size_t>(unit.channel_count());
  ContactEstimate start;
  start.shear_u_n = std::numeric_limits<double>::quiet_NaN();
  start.shear_v_n = 1e9;
  for (const std::vector<double>& f :
       {std::vector<double>(nc, 0.0), std::vector<double>(nc, 1e3),
        std::vector<double>(nc, std::numeric_limits<double>::quiet_NaN())}) {
    for (const PhysicsEstimate& e : {est.estimate(f), est.refine_lm(f, {}, start)}) {
      EXPECT_TRUE(std::isfinite(e.contact.shear_u_n) && std::isfinite(e.contact.shear_v_n));
      EXPECT_TRUE(std::isfinite(e.contact.u_mm) && std::isfinite(e.contact.depth_mm));
      EXPECT_LE(std::fabs(e.contact.shear_v_n), 100.0);
    }
  }
}

}  // namespace
}  // namespace skinbus::estimators
