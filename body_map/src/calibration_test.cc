#include "skinbus/body_map/calibration.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <numbers>
#include <random>

namespace skinbus::body_map {
namespace {

constexpr double kDeg = std::numbers::pi / 180.0;

PatchPlacement flat_patch() {
  PatchPlacement p;
  p.node_id = 1;
  p.link = "torso_link";
  p.pose_on_link = {rotation_from_rpy(0.3, -0.2, 1.1), Eigen::Vector3d(110, -40, 250)};
  return p;
}

PatchPlacement cylinder_patch(double radius_mm = 45) {
  PatchPlacement p = flat_patch();
  p.link = "left_forearm_link";
  p.geometry.kind = SurfaceKind::kCylinder;
  p.geometry.radius_mm = radius_mm;
  p.pose_on_link = {rotation_from_rpy(1.2, 0.1, -0.4), Eigen::Vector3d(135, 20, 40)};
  return p;
}

struct Touches {
  std::vector<CalibrationTouch> touches;
  std::vector<bool> outlier;
};

// Touches on `truth` at uniform points; probe and estimate noise as given; `outliers` of them
// with an estimate elsewhere on the patch.
Touches make_touches(const PatchPlacement& truth, int n, double probe_sd, double est_sd,
                     int outliers, std::mt19937_64& rng) {
  std::uniform_real_distribution<double> pos(-60, 60), depth(1, 3);
  std::normal_distribution<double> probe(0, probe_sd), est(0, est_sd), est_d(0, 0.2 * est_sd);
  Touches t;
  for (int i = 0; i < n; ++i) {
    const double u = pos(rng), v = pos(rng), d = depth(rng);
    CalibrationTouch c;
    c.probe_mm = link_surface_point(truth, u, v, d).point_mm +
                 Eigen::Vector3d(probe(rng), probe(rng), probe(rng));
    c.u_mm = u + est(rng);
    c.v_mm = v + est(rng);
    c.depth_mm = d + est_d(rng);
    const bool out = i < outliers;
    if (out) {
      do {
        c.u_mm = pos(rng);
        c.v_mm = pos(rng);
      } while (std::hypot(c.u_mm - u, c.v_mm - v) < 10);
    }
    t.touches.push_back(c);
    t.outlier.push_back(out);
  }
  return t;
}

PatchPlacement disturbed(const PatchPlacement& truth, double mm, double deg, std::mt19937_64& rng) {
  std::normal_distribution<double> n(0, 1);
  PatchPlacement p = truth;
  const Eigen::Vector3d axis = Eigen::Vector3d(n(rng), n(rng), n(rng)).normalized();
  const Eigen::Vector3d dir = Eigen::Vector3d(n(rng), n(rng), n(rng)).normalized();
  p.pose_on_link.rotation = rotation_from_vector(axis * deg * kDeg) * truth.pose_on_link.rotation;
  p.pose_on_link.translation_mm += dir * mm;
  return p;
}

double position_error_mm(const PatchCalibration& c, const PatchPlacement& truth) {
  return (c.pose_on_link.translation_mm - truth.pose_on_link.translation_mm).norm();
}
double rotation_error_deg(const PatchCalibration& c, const PatchPlacement& truth) {
  return rotation_angle_between(c.pose_on_link.rotation, truth.pose_on_link.rotation) / kDeg;
}

uint64_t test_seed() {
  const uint64_t seed = std::random_device{}();
  std::printf("seed %llu\n", static_cast<unsigned long long>(seed));
  return seed;
}

TEST(Calibration, ExactTouchesGiveTheExactPoseFromAnyStart) {
  std::mt19937_64 rng(7);
  for (const PatchPlacement& truth : {flat_patch(), cylinder_patch()}) {
    const Touches t = make_touches(truth, 12, 0, 0, 0, rng);
    for (double deg : {0.0, 30.0, 90.0, 179.0}) {
      const PatchPlacement start = disturbed(truth, 80, deg, rng);
      Result<PatchCalibration> c = calibrate_patch(start, t.touches);
      ASSERT_TRUE(c.ok()) << c.error().to_string();
      EXPECT_LT(position_error_mm(c.value(), truth), 1e-6);
      EXPECT_LT(rotation_error_deg(c.value(), truth), 1e-6);
      EXPECT_EQ(c.value().uncertainty.inliers, 12);
      EXPECT_TRUE(c.value().warnings.empty());
    }
  }
}

// The goal (0.5 mm, 0.3 degrees from 30 touches at 0.5 mm probe noise), with the patch's
// own estimates 0.5 mm off in u and v and 10% outliers. A fixed seed: a mean over 100 sessions
// is near the goal, and this test must not flake.
TEST(Calibration, ThirtyNoisyTouchesWithOutliersMeetTheGoal) {
  std::mt19937_64 rng(1);
  double sum_mm = 0, sum_deg = 0;
  int flagged = 0, outliers = 0, false_flags = 0;
  const int trials = 100;
  for (int k = 0; k < trials; ++k) {
    const PatchPlacement truth = k % 2 ? flat_patch() : cylinder_patch();
    const Touches t = make_touches(truth, 30, 0.5, 0.5, 3, rng);
    Result<PatchCalibration> c = calibrate_patch(disturbed(truth, 30, 45, rng), t.touches);
    ASSERT_TRUE(c.ok()) << c.error().to_string();
    sum_mm += position_error_mm(c.value(), truth);
    sum_deg += rotation_error_deg(c.value(), truth);
    for (std::size_t i = 0; i < t.touches.size(); ++i) {
      outliers += t.outlier[i];
      flagged += t.outlier[i] && c.value().residuals[i].outlier;
      false_flags += !t.outlier[i] && c.value().residuals[i].outlier;
    }
  }
  std::printf("mean error %.3f mm %.3f deg; outliers flagged %d/%d, inliers flagged %d\n",
              sum_mm / trials, sum_deg / trials, flagged, outliers, false_flags);
  EXPECT_LT(sum_mm / trials, 0.5);
  EXPECT_LT(sum_deg / trials, 0.3);
  EXPECT_GE(flagged, outliers * 9 / 10);
  EXPECT_LE(false_flags, trials);  // < 1 per patch
}

// The reported standard deviations match the scatter of the results over repeated sessions.
TEST(Calibration, CovarianceMatchesTheScatter) {
  const uint64_t seed = test_seed();
  std::mt19937_64 rng(seed);
  const PatchPlacement truth = flat_patch();
  const int trials = 300;
  Eigen::Matrix<double, 6, 1> sum_sq = Eigen::Matrix<double, 6, 1>::Zero();
  Eigen::Matrix<double, 6, 1> reported = Eigen::Matrix<double, 6, 1>::Zero();
  for (int k = 0; k < trials; ++k) {
    const Touches t = make_touches(truth, 30, 0.5, 0.5, 0, rng);
    CalibrationOptions o;
    o.outlier_sigma = 100;            // no outliers here: keep every touch
    o.estimate_depth_sigma_mm = 0.1;  // the noise as simulated
    Result<PatchCalibration> c = calibrate_patch(truth, t.touches, o);
    ASSERT_TRUE(c.ok()) << c.error().to_string();
    const Eigen::Matrix3d dr =
        c.value().pose_on_link.rotation * truth.pose_on_link.rotation.transpose();
    const Eigen::AngleAxisd aa(dr);
    Eigen::Matrix<double, 6, 1> e;
    e << aa.axis() * aa.angle(),
        c.value().pose_on_link.translation_mm - truth.pose_on_link.translation_mm;
    sum_sq += e.cwiseProduct(e);
    reported += c.value().covariance.diagonal();
  }
  for (int i = 0; i < 6; ++i) {
    const double ratio = std::sqrt(sum_sq(i) / reported(i));
    std::printf("parameter %d: scatter / reported sd = %.3f\n", i, ratio);
    EXPECT_GT(ratio, 0.8);
    EXPECT_LT(ratio, 1.25);
  }
}

TEST(Calibration, FitsTheCylinderRadius) {
  std::mt19937_64 rng(11);
  const PatchPlacement truth = cylinder_patch(48);
  const Touches t = make_touches(truth, 40, 0.2, 0.2, 0, rng);
  PatchPlacement start = disturbed(truth, 10, 10, rng);
  start.geometry.radius_mm = 42;
  CalibrationOptions o;
  o.fit_radius = true;
  Result<PatchCalibration> c = calibrate_patch(start, t.touches, o);
  ASSERT_TRUE(c.ok()) << c.error().to_string();
  EXPECT_NEAR(c.value().radius_mm, 48, 0.5);
  EXPECT_GT(c.value().uncertainty.radius_sd_mm, 0);
  EXPECT_LT(position_error_mm(c.value(), truth), 0.5);
  // Without fitting, the wrong radius shows in the residuals.
  o.fit_radius = false;
  Result<PatchCalibration> fixed = calibrate_patch(start, t.touches, o);
  if (fixed.ok()) {
    EXPECT_GT(fixed.value().residual_sigma, 1.2 * c.value().residual_sigma);
  }
}

TEST(Calibration, RefusesDegenerateTouchSets) {
  std::mt19937_64 rng(3);
  const PatchPlacement truth = flat_patch();
  auto on = [&](double u, double v) {
    CalibrationTouch c;
    c.probe_mm = link_surface_point(truth, u, v, 2).point_mm;
    c.u_mm = u;
    c.v_mm = v;
    c.depth_mm = 2;
    return c;
  };
  auto expect_degenerate = [&](const std::vector<CalibrationTouch>& t, const char* says,
                               CalibrationOptions o = {}) {
    Result<PatchCalibration> c = calibrate_patch(truth, t, o);
    ASSERT_FALSE(c.ok()) << says;
    EXPECT_EQ(c.error().code, ErrorCode::kDegenerate) << c.error().to_string();
    EXPECT_NE(c.error().message.find(says), std::string::npos) << c.error().message;
    EXPECT_NE(c.error().message.find("add"), std::string::npos) << c.error().message;
  };
  // Too few.
  expect_degenerate({on(0, 0), on(50, 0), on(0, 50), on(-50, -50), on(30, -40)}, "at least 6");
  // Collinear (a diagonal line), exactly and with estimate noise.
  std::vector<CalibrationTouch> line;
  for (int i = 0; i < 20; ++i) line.push_back(on(-60 + 6.0 * i, -60 + 6.0 * i));
  expect_degenerate(line, "line");
  std::normal_distribution<double> n(0, 0.5);
  for (CalibrationTouch& c : line) c.v_mm += n(rng);
  expect_degenerate(line, "line");
  // Clustered.
  std::vector<CalibrationTouch> cluster;
  for (int i = 0; i < 20; ++i) cluster.push_back(on(20 + n(rng) * 8, -10 + n(rng) * 8));
  expect_degenerate(cluster, "clustered");
  // Collinear inliers made to look spread by outliers: refused once the outliers are out.
  std::vector<CalibrationTouch> tricked = line;
  for (int i = 0; i < 3; ++i) {
    CalibrationTouch c = on(-50 + 40.0 * i, 55);
    c.u_mm += 20;  // and wrong
    tricked.push_back(c);
  }
  expect_degenerate(tricked, "line");
  // Fitting a radius with touches only along the cylinder's axis.
  const PatchPlacement cyl = cylinder_patch();
  std::vector<CalibrationTouch> along;
  for (int i = 0; i < 20; ++i) {
    const double u = (i % 2 ? 2.0 : -2.0), v = -60 + 6.0 * i;
    along.push_back({link_surface_point(cyl, u, v, 2).point_mm, u, v, 2});
  }
  CalibrationOptions fit;
  fit.fit_radius = true;
  fit.min_spread_mm = 3;
  Result<PatchCalibration> c = calibrate_patch(cyl, along, fit);
  ASSERT_FALSE(c.ok());
  EXPECT_EQ(c.error().code, ErrorCode::kDegenerate);
  EXPECT_NE(c.error().message.find("around the cylinder"), std::string::npos) << c.error().message;
}

TEST(Calibration, RefusesNonFiniteInputsAndBadOptions) {
  std::mt19937_64 rng(5);
  const PatchPlacement truth = flat_patch();
  Touches t = make_touches(truth, 20, 0.5, 0.5, 0, rng);
  t.touches[4].u_mm = std::nan("");
  Result<PatchCalibration> c = calibrate_patch(truth, t.touches);
  ASSERT_FALSE(c.ok());
  EXPECT_EQ(c.error().code, ErrorCode::kInvalidArgument);
  EXPECT_NE(c.error().message.find("touch 4"), std::string::npos);
  t.touches[4].u_mm = 0;
  t.touches[7].probe_mm.z() = INFINITY;
  EXPECT_FALSE(calibrate_patch(truth, t.touches).ok());
  t.touches[7].probe_mm.z() = 0;
  CalibrationOptions o;
  o.probe_sigma_mm = 0;
  o.estimate_sigma_mm = 0;
  EXPECT_EQ(calibrate_patch(truth, t.touches, o).error().code, ErrorCode::kInvalidArgument);
  PatchPlacement bad = truth;
  bad.pose_on_link.translation_mm.x() = std::nan("");
  EXPECT_EQ(calibrate_patch(bad, t.touches).error().code, ErrorCode::kInvalidArgument);
}

TEST(Calibration, MostlyWrongTouchesAreNotAPose) {
  std::mt19937_64 rng(9);
  const PatchPlacement truth = flat_patch();
  const Touches t = make_touches(truth, 20, 0.5, 0.5, 14, rng);  // 70% outliers
  Result<PatchCalibration> c = calibrate_patch(truth, t.touches);
  ASSERT_FALSE(c.ok());
  EXPECT_TRUE(c.error().code == ErrorCode::kNotConverged ||
              c.error().code == ErrorCode::kDegenerate)
      << c.error().to_string();
}

// A flat patch calibrated with touches from a curved reality: never a silent answer.
TEST(Calibration, AModelMismatchIsReported) {
  std::mt19937_64 rng(13);
  const PatchPlacement real = cylinder_patch(60);
  const Touches t = make_touches(real, 30, 0.3, 0.3, 0, rng);
  PatchPlacement assumed = real;
  assumed.geometry = PatchGeometry{};
  Result<PatchCalibration> c = calibrate_patch(assumed, t.touches);
  if (c.ok()) {
    EXPECT_GT(c.value().residual_sigma, 2.0);
    EXPECT_FALSE(c.value().warnings.empty());
  } else {
    std::printf("refused: %s\n", c.error().to_string().c_str());
  }
}

// Many random sessions over a wide range: each result either meets what its own uncertainty
// promises or is refused as degenerate / not converged. Never NaN.
TEST(Calibration, StressNeverASilentWrongPose) {
  const uint64_t seed = test_seed();
  std::mt19937_64 rng(seed);
  std::uniform_int_distribution<int> touches(4, 60);
  std::uniform_real_distribution<double> unit(0, 1);
  int accepted = 0, refused = 0, goal_cases = 0, goal_met = 0;
  for (int k = 0; k < 300; ++k) {
    PatchPlacement truth = k % 3 ? flat_patch() : cylinder_patch(20 + 400 * unit(rng));
    if (truth.geometry.kind == SurfaceKind::kCylinder && truth.geometry.radius_mm < 45) {
      truth.geometry.size_u_mm = 2 * truth.geometry.radius_mm;  // at most ~115 degrees of arc
    }
    truth.pose_on_link.translation_mm *= (k % 7 == 0 ? 20.0 : 1.0);  // metres away
    const int n = touches(rng);
    const double noise = 0.1 + 2.0 * unit(rng);
    const int outliers = static_cast<int>(n * 0.4 * unit(rng));
    const Touches t = make_touches(truth, n, noise, 0.5, outliers, rng);
    const PatchPlacement start = disturbed(truth, 100 * unit(rng), 180 * unit(rng), rng);
    CalibrationOptions o;
    o.probe_sigma_mm = noise;
    o.seed = k;
    Result<PatchCalibration> c = calibrate_patch(start, t.touches, o);
    if (!c.ok()) {
      ++refused;
      EXPECT_TRUE(c.error().code == ErrorCode::kDegenerate ||
                  c.error().code == ErrorCode::kNotConverged)
          << c.error().to_string();
      continue;
    }
    ++accepted;
    const PatchCalibration& r = c.value();
    ASSERT_TRUE(r.pose_on_link.rotation.allFinite() && r.pose_on_link.translation_mm.allFinite());
    ASSERT_TRUE(r.covariance.allFinite());
    const double pos_bound = 5 * std::sqrt(r.covariance.block<3, 3>(3, 3).trace());
    const double rot_bound = 5 * std::sqrt(r.covariance.block<3, 3>(0, 0).trace()) / kDeg;
    EXPECT_LT(position_error_mm(r, truth), pos_bound) << "case " << k << " n " << n;
    EXPECT_LT(rotation_error_deg(r, truth), rot_bound) << "case " << k << " n " << n;
    if (n >= 30 && noise <= 0.5 && truth.geometry.kind == SurfaceKind::kFlat) {
      ++goal_cases;
      goal_met += position_error_mm(r, truth) <= 0.5 && rotation_error_deg(r, truth) <= 0.5;
    }
  }
  std::printf("accepted %d, refused %d; %d/%d cases in the goal's regime within 0.5 mm/0.5 deg\n",
              accepted, refused, goal_met, goal_cases);
  EXPECT_GT(accepted, 150);
  EXPECT_GE(goal_met, goal_cases * 9 / 10);
}

}  // namespace
}  // namespace skinbus::body_map
