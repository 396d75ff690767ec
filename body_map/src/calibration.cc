#include "skinbus/body_map/calibration.h"

#include <ceres/ceres.h>
#include <ceres/manifold.h>

#include <Eigen/SVD>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <memory>
#include <numbers>
#include <random>

namespace skinbus::body_map {

namespace {

constexpr double kRadToDeg = 180.0 / std::numbers::pi;

std::string fmt(const char* f, double a, double b = 0, double c = 0) {
  char buf[256];
  std::snprintf(buf, sizeof buf, f, a, b, c);
  return buf;
}

// Patch-frame points of the touches' estimates.
std::vector<Eigen::Vector3d> patch_points(const PatchGeometry& g, double radius_mm,
                                          std::span<const CalibrationTouch> touches) {
  std::vector<Eigen::Vector3d> q;
  q.reserve(touches.size());
  for (const CalibrationTouch& t : touches)
    q.push_back(patch_point<double>(g, radius_mm, t.u_mm, t.v_mm, t.depth_mm));
  return q;
}

// Closed-form least-squares rigid fit p ~ R q + t over the selected pairs (Kabsch). Returns
// false when the selection cannot fix a rotation (fewer than 3 points or all on a line).
bool kabsch(const std::vector<Eigen::Vector3d>& q, std::span<const CalibrationTouch> touches,
            const std::vector<int>& use, Pose* out) {
  if (use.size() < 3) return false;
  Eigen::Vector3d cq = Eigen::Vector3d::Zero(), cp = Eigen::Vector3d::Zero();
  for (int i : use) {
    cq += q[i];
    cp += touches[i].probe_mm;
  }
  cq /= static_cast<double>(use.size());
  cp /= static_cast<double>(use.size());
  Eigen::Matrix3d h = Eigen::Matrix3d::Zero();
  for (int i : use) h += (q[i] - cq) * (touches[i].probe_mm - cp).transpose();
  Eigen::JacobiSVD<Eigen::Matrix3d> svd(h, Eigen::ComputeFullU | Eigen::ComputeFullV);
  const Eigen::Vector3d s = svd.singularValues();
  if (!(s(1) > 1e-9 * std::max(1.0, s(0)))) return false;
  Eigen::Matrix3d d = Eigen::Matrix3d::Identity();
  d(2, 2) = (svd.matrixV() * svd.matrixU().transpose()).determinant() < 0 ? -1 : 1;
  out->rotation = svd.matrixV() * d * svd.matrixU().transpose();
  out->translation_mm = cp - out->rotation * cq;
  return out->rotation.allFinite() && out->translation_mm.allFinite();
}

// How well a pose explains the touches: inliers within `limit_mm`, and their squared error.
struct Consensus {
  std::vector<int> inliers;
  double sum_sq = 0;
  bool better_than(const Consensus& o) const {
    return inliers.size() != o.inliers.size() ? inliers.size() > o.inliers.size()
                                              : sum_sq < o.sum_sq;
  }
};
Consensus consensus(const Pose& pose, const std::vector<Eigen::Vector3d>& q,
                    std::span<const CalibrationTouch> touches, double limit_mm) {
  Consensus c;
  for (std::size_t i = 0; i < q.size(); ++i) {
    const double e2 = (pose.apply(q[i]) - touches[i].probe_mm).squaredNorm();
    if (e2 <= limit_mm * limit_mm) {
      c.inliers.push_back(static_cast<int>(i));
      c.sum_sq += e2;
    }
  }
  return c;
}

// One touch's residual, whitened: the mismatch (estimate mapped by the pose minus the probe) is
// expressed in the surface's local frame at the touch (along u, along v, along the normal),
// where its covariance is diagonal: probe noise on every axis plus the estimate's noise, which
// is larger across the skin (u, v) than in depth.
struct TouchCost {
  const PatchGeometry* geometry;
  Eigen::Vector3d probe_mm;
  double u_mm, v_mm, depth_mm;
  double inv_sigma_tangent, inv_sigma_normal;

  template <typename T>
  bool operator()(const T* quaternion_xyzw, const T* translation_mm, const T* radius_mm,
                  T* residual) const {
    using std::cos;
    using std::sin;
    const Eigen::Map<const Eigen::Quaternion<T>> q(quaternion_xyzw);
    const Eigen::Map<const Eigen::Matrix<T, 3, 1>> t(translation_mm);
    const Eigen::Matrix<T, 3, 1> p =
        patch_point<T>(*geometry, radius_mm[0], T(u_mm), T(v_mm), T(depth_mm));
    // The mismatch in the patch frame.
    const Eigen::Matrix<T, 3, 1> m = p + q.conjugate() * (t - probe_mm.cast<T>());
    T along_u = m.x(), along_v = m.y(), normal = m.z();
    if (geometry->kind == SurfaceKind::kCylinder) {
      if (geometry->axis == CylinderAxis::kV) {
        const T theta = T(u_mm) / radius_mm[0];
        along_u = cos(theta) * m.x() - sin(theta) * m.z();
        normal = sin(theta) * m.x() + cos(theta) * m.z();
      } else {
        const T theta = T(v_mm) / radius_mm[0];
        along_v = cos(theta) * m.y() - sin(theta) * m.z();
        normal = sin(theta) * m.y() + cos(theta) * m.z();
      }
    }
    residual[0] = along_u * T(inv_sigma_tangent);
    residual[1] = along_v * T(inv_sigma_tangent);
    residual[2] = normal * T(inv_sigma_normal);
    return true;
  }
};

// The noise of a touch's residual across the skin and along its normal (1 sd, mm).
struct Noise {
  double tangent_mm, normal_mm;
};
Noise noise_of(const CalibrationOptions& o) {
  return {std::hypot(o.probe_sigma_mm, o.estimate_sigma_mm),
          std::hypot(o.probe_sigma_mm, o.estimate_depth_sigma_mm)};
}

TouchCost cost_of(const PatchGeometry& g, const CalibrationTouch& t, Noise n) {
  return {&g, t.probe_mm, t.u_mm, t.v_mm, t.depth_mm, 1.0 / n.tangent_mm, 1.0 / n.normal_mm};
}

ceres::CostFunction* touch_cost(const PatchGeometry& g, const CalibrationTouch& t, Noise n) {
  return new ceres::AutoDiffCostFunction<TouchCost, 3, 4, 3, 1>(new TouchCost(cost_of(g, t, n)));
}

// Whether the radius is a parameter: asked for, and the patch is a cylinder.
bool fits_radius(const PatchGeometry& g, const CalibrationOptions& o) {
  return o.fit_radius && g.kind == SurfaceKind::kCylinder;
}

struct Solve {
  bool converged = false;
  int iterations = 0;
  std::string report;
};

// Least squares over the touches in `use` from the pose in `quaternion`/`translation`.
Solve refine(const PatchGeometry& g, std::span<const CalibrationTouch> touches,
             const std::vector<int>& use, bool robust, const CalibrationOptions& options,
             Noise noise, double* quaternion, double* translation, double* radius,
             ceres::Problem* problem) {
  const bool fit_radius = fits_radius(g, options);
  for (int i : use) {
    problem->AddResidualBlock(touch_cost(g, touches[i], noise),
                              robust ? new ceres::CauchyLoss(3.0) : nullptr, quaternion,
                              translation, radius);
  }
  problem->SetManifold(quaternion, new ceres::EigenQuaternionManifold);
  if (fit_radius) {
    problem->SetParameterLowerBound(radius, 0, 5.0);
    problem->SetParameterUpperBound(radius, 0, 5000.0);
  } else {
    problem->SetParameterBlockConstant(radius);
  }
  ceres::Solver::Options so;
  so.linear_solver_type = ceres::DENSE_QR;
  so.max_num_iterations = options.max_iterations;
  so.function_tolerance = 1e-12;
  so.parameter_tolerance = 1e-12;
  so.gradient_tolerance = 1e-12;
  so.logging_type = ceres::SILENT;
  so.num_threads = 1;
  ceres::Solver::Summary summary;
  ceres::Solve(so, problem, &summary);
  Solve s;
  s.converged = summary.termination_type == ceres::CONVERGENCE && summary.IsSolutionUsable();
  s.iterations = static_cast<int>(summary.iterations.size());
  s.report = summary.BriefReport();
  return s;
}

}  // namespace

Status check_touch_geometry(const PatchGeometry& g, std::span<const CalibrationTouch> touches,
                            const CalibrationOptions& options) {
  const bool fit_radius = fits_radius(g, options);
  const int need = std::max(options.min_touches, fit_radius ? 8 : 3);
  const int n = static_cast<int>(touches.size());
  if (n < need) {
    return make_error(ErrorCode::kDegenerate, std::to_string(n) + " touches: at least " +
                                                  std::to_string(need) + " are needed; add " +
                                                  std::to_string(need - n) +
                                                  " more, spread over the patch");
  }
  // Spread on the patch surface, in (u, v): principal axes of the touch positions.
  Eigen::Vector2d mean = Eigen::Vector2d::Zero();
  for (const CalibrationTouch& t : touches) mean += Eigen::Vector2d(t.u_mm, t.v_mm);
  mean /= n;
  Eigen::Matrix2d cov = Eigen::Matrix2d::Zero();
  for (const CalibrationTouch& t : touches) {
    const Eigen::Vector2d d = Eigen::Vector2d(t.u_mm, t.v_mm) - mean;
    cov += d * d.transpose();
  }
  cov /= n;
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d> eig(cov);
  const double minor = std::sqrt(std::max(0.0, eig.eigenvalues()(0)));
  const double major = std::sqrt(std::max(0.0, eig.eigenvalues()(1)));
  const Eigen::Vector2d dir = eig.eigenvectors().col(1);
  if (major < options.min_spread_mm) {
    return make_error(ErrorCode::kDegenerate,
                      fmt("the touches are clustered within %.1f mm (rms) of (u, v) = (%.1f, "
                          "%.1f) mm: add touches spread over the patch",
                          major, mean.x(), mean.y()));
  }
  if (minor < 0.5 * options.min_spread_mm) {
    return make_error(ErrorCode::kDegenerate,
                      fmt("the touches lie along a line (rms %.1f mm off it) in direction "
                          "(%.2f, %.2f) of (u, v): add touches away from that line",
                          minor, dir.x(), dir.y()));
  }
  if (fit_radius) {
    double m = 0, m2 = 0;
    for (const CalibrationTouch& t : touches) {
      const double a = g.axis == CylinderAxis::kV ? t.u_mm : t.v_mm;
      m += a;
      m2 += a * a;
    }
    m /= n;
    const double spread = std::sqrt(std::max(0.0, m2 / n - m * m));
    if (spread < options.min_spread_mm) {
      return make_error(ErrorCode::kDegenerate,
                        fmt("fitting the radius needs touches spread around the cylinder; they "
                            "spread only %.1f mm (rms) across its axis: add touches there",
                            spread));
    }
  }
  return Status::Ok();
}

Result<PatchCalibration> calibrate_patch(const PatchPlacement& initial,
                                         std::span<const CalibrationTouch> touches,
                                         const CalibrationOptions& options) {
  const PatchGeometry& g = initial.geometry;
  if (Status st = validate_geometry(g); !st.ok()) {
    return make_error(ErrorCode::kInvalidArgument, "geometry: " + st.error().message);
  }
  const Noise noise = noise_of(options);
  if (!(options.probe_sigma_mm >= 0) || !(options.estimate_sigma_mm >= 0) ||
      !(options.estimate_depth_sigma_mm >= 0) || !(noise.tangent_mm > 0) ||
      !(noise.normal_mm > 0) || !std::isfinite(noise.tangent_mm + noise.normal_mm) ||
      !(options.outlier_sigma > 1) || !(options.min_spread_mm > 0) || options.max_iterations < 1 ||
      options.consensus_trials < 0) {
    return make_error(ErrorCode::kInvalidArgument,
                      "calibration options: noises must be finite, >= 0 and not all zero, "
                      "outlier_sigma > 1, min_spread_mm > 0, max_iterations >= 1");
  }
  if (!initial.pose_on_link.rotation.allFinite() ||
      !initial.pose_on_link.translation_mm.allFinite()) {
    return make_error(ErrorCode::kInvalidArgument, "the starting pose is not finite");
  }
  for (std::size_t i = 0; i < touches.size(); ++i) {
    const CalibrationTouch& t = touches[i];
    if (!t.probe_mm.allFinite() || !std::isfinite(t.u_mm) || !std::isfinite(t.v_mm) ||
        !std::isfinite(t.depth_mm)) {
      return make_error(ErrorCode::kInvalidArgument,
                        "touch " + std::to_string(i) + " has a non-finite value");
    }
  }
  if (Status st = check_touch_geometry(g, touches, options); !st.ok()) return st.error();

  const double limit_mm = options.outlier_sigma * noise.tangent_mm;
  const int n = static_cast<int>(touches.size());
  double radius = g.kind == SurfaceKind::kCylinder ? g.radius_mm : 1.0;

  // 2. A start by consensus: the given pose, all touches, and random triples.
  const std::vector<Eigen::Vector3d> q = patch_points(g, radius, touches);
  Pose start = initial.pose_on_link;
  Consensus best = consensus(start, q, touches, limit_mm);
  auto consider = [&](const std::vector<int>& use) {
    Pose p;
    if (!kabsch(q, touches, use, &p)) return;
    Consensus c = consensus(p, q, touches, limit_mm);
    if (c.better_than(best)) {
      best = std::move(c);
      start = p;
    }
  };
  std::vector<int> all(n);
  for (int i = 0; i < n; ++i) all[i] = i;
  consider(all);
  std::mt19937_64 rng(options.seed);
  std::uniform_int_distribution<int> pick(0, n - 1);
  for (int trial = 0; trial < options.consensus_trials; ++trial) {
    const int a = pick(rng), b = pick(rng), c = pick(rng);
    if (a == b || b == c || a == c) continue;
    consider({a, b, c});
  }
  consider(best.inliers);  // polish the start on its own inliers

  // 3. Robust refinement, outliers, then plain least squares on the inliers.
  Eigen::Quaterniond quat(start.rotation);
  double qv[4] = {quat.x(), quat.y(), quat.z(), quat.w()};
  double tv[3] = {start.translation_mm.x(), start.translation_mm.y(), start.translation_mm.z()};
  PatchCalibration out;
  Solve solve;
  {
    ceres::Problem problem;
    solve = refine(g, touches, all, true, options, noise, qv, tv, &radius, &problem);
    out.iterations += solve.iterations;
  }
  std::vector<int> inliers;
  auto classify = [&]() {
    out.residuals.assign(n, {});
    inliers.clear();
    for (int i = 0; i < n; ++i) {
      const CalibrationTouch& tc = touches[i];
      const Eigen::Quaterniond qq(qv[3], qv[0], qv[1], qv[2]);
      TouchResidual& r = out.residuals[i];
      r.residual_mm = qq * patch_point<double>(g, radius, tc.u_mm, tc.v_mm, tc.depth_mm) +
                      Eigen::Vector3d(tv[0], tv[1], tv[2]) - tc.probe_mm;
      Eigen::Vector3d whitened;
      cost_of(g, tc, noise)(qv, tv, &radius, whitened.data());
      r.norm_sigma = whitened.norm();
      r.outlier = !(r.norm_sigma <= options.outlier_sigma);
      if (!r.outlier) inliers.push_back(i);
    }
  };
  classify();
  // Plain least squares on the inliers until the inlier set settles; the last problem is kept
  // for the covariance.
  std::unique_ptr<ceres::Problem> last;
  bool settled = false;
  for (int round = 0; round < 4 && !settled && inliers.size() >= 3; ++round) {
    const std::vector<int> used = inliers;
    last = std::make_unique<ceres::Problem>();
    solve = refine(g, touches, used, false, options, noise, qv, tv, &radius, last.get());
    out.iterations += solve.iterations;
    classify();
    settled = inliers == used;
  }

  // 4. Checks on the answer.
  const int n_in = static_cast<int>(inliers.size());
  if (2 * n_in <= n) {
    return make_error(ErrorCode::kNotConverged,
                      "only " + std::to_string(n_in) + " of " + std::to_string(n) +
                          " touches agree on a pose: check the touches belong to this patch and "
                          "link, and that the stated noise is not too small");
  }
  std::vector<CalibrationTouch> kept;
  kept.reserve(n_in);
  for (int i : inliers) kept.push_back(touches[i]);
  if (Status st = check_touch_geometry(g, kept, options); !st.ok()) {
    return make_error(ErrorCode::kDegenerate, "after removing " + std::to_string(n - n_in) +
                                                  " outlier touches: " + st.error().message);
  }
  if (!solve.converged) {
    return make_error(ErrorCode::kNotConverged, "the solver did not converge: " + solve.report);
  }
  if (!settled) {
    return make_error(ErrorCode::kNotConverged,
                      "touches keep changing between inlier and outlier: the stated noise may be "
                      "too small for these touches");
  }

  const bool fit_radius = fits_radius(g, options);
  const int dof = 6 + (fit_radius ? 1 : 0);
  double sum_sq = 0;
  for (int i : inliers) sum_sq += std::pow(out.residuals[i].norm_sigma, 2);
  out.residual_sigma = std::sqrt(sum_sq / std::max(1, 3 * n_in - dof));
  const double scale = std::max(1.0, out.residual_sigma * out.residual_sigma);

  // Covariance of the final (plain) problem on the inliers.
  {
    ceres::Covariance::Options co;
    co.algorithm_type = ceres::DENSE_SVD;
    co.null_space_rank = 0;
    co.min_reciprocal_condition_number = 1e-12;
    ceres::Covariance covariance(co);
    std::vector<std::pair<const double*, const double*>> blocks = {{qv, qv}, {tv, tv}, {qv, tv}};
    if (fit_radius) blocks.push_back({&radius, &radius});
    if (!covariance.Compute(blocks, last.get())) {
      return make_error(ErrorCode::kDegenerate,
                        "the touches do not determine the pose (rank-deficient covariance): add "
                        "touches spread over the whole patch");
    }
    Eigen::Matrix3d cqq, ctt, cqt;
    covariance.GetCovarianceBlockInTangentSpace(qv, qv, cqq.data());
    covariance.GetCovarianceBlock(tv, tv, ctt.data());
    covariance.GetCovarianceBlockInTangentSpace(qv, tv, cqt.data());
    // Eigen's matrices are column-major, Ceres writes row-major: transpose where it matters.
    cqq.transposeInPlace();
    ctt.transposeInPlace();
    cqt.transposeInPlace();
    // The quaternion manifold's tangent is half the rotation vector (Plus uses cos|d|, sin|d|).
    out.covariance.block<3, 3>(0, 0) = 4.0 * cqq * scale;
    out.covariance.block<3, 3>(3, 3) = ctt * scale;
    out.covariance.block<3, 3>(0, 3) = 2.0 * cqt * scale;
    out.covariance.block<3, 3>(3, 0) = out.covariance.block<3, 3>(0, 3).transpose();
    if (fit_radius) {
      covariance.GetCovarianceBlock(&radius, &radius, &out.radius_variance_mm2);
      out.radius_variance_mm2 *= scale;
    }
  }

  const Eigen::Quaterniond qfinal = Eigen::Quaterniond(qv[3], qv[0], qv[1], qv[2]).normalized();
  out.pose_on_link.rotation = qfinal.toRotationMatrix();
  out.pose_on_link.translation_mm = {tv[0], tv[1], tv[2]};
  out.radius_mm = g.kind == SurfaceKind::kCylinder ? radius : 0.0;
  PoseUncertainty& u = out.uncertainty;
  u.touches = n;
  u.inliers = n_in;
  double rms = 0;
  for (int i : inliers) rms += out.residuals[i].residual_mm.squaredNorm();
  u.rms_residual_mm = std::sqrt(rms / n_in);
  for (int k = 0; k < 3; ++k) {
    u.rotation_sd_deg(k) = std::sqrt(std::max(0.0, out.covariance(k, k))) * kRadToDeg;
    u.position_sd_mm(k) = std::sqrt(std::max(0.0, out.covariance(3 + k, 3 + k)));
  }
  u.radius_sd_mm = std::sqrt(std::max(0.0, out.radius_variance_mm2));
  if (!out.pose_on_link.rotation.allFinite() || !out.pose_on_link.translation_mm.allFinite() ||
      !out.covariance.allFinite() || !std::isfinite(out.radius_mm)) {
    return make_error(ErrorCode::kNotConverged, "the solve produced a non-finite value");
  }
  if (u.position_sd_mm.maxCoeff() > options.max_position_sd_mm ||
      u.rotation_sd_deg.maxCoeff() > options.max_rotation_sd_deg ||
      (fit_radius && u.radius_sd_mm > options.max_radius_sd_mm)) {
    return make_error(
        ErrorCode::kDegenerate,
        fmt("the touches leave the pose uncertain (sd up to %.2f mm, %.2f deg, radius %.2f mm): "
            "add touches, farther apart",
            u.position_sd_mm.maxCoeff(), u.rotation_sd_deg.maxCoeff(), u.radius_sd_mm));
  }
  if (n_in < n) {
    out.warnings.push_back(std::to_string(n - n_in) + " of " + std::to_string(n) +
                           " touches are outliers (beyond " + fmt("%.1f", options.outlier_sigma) +
                           " sd) and were left out");
  }
  if (out.residual_sigma > 2.0) {
    out.warnings.push_back(
        fmt("residuals are %.1f times the stated noise: the noise is larger than stated, or the "
            "geometry (radius, shape) does not match the patch; uncertainties are scaled up",
            out.residual_sigma));
  }
  return out;
}

}  // namespace skinbus::body_map
