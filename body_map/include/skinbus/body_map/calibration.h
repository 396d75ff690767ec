// skinbus/body_map/calibration.h: a patch's pose on its link (and optionally its cylinder
// radius) from calibration touches, with Ceres Solver.
//
// A calibration touch pairs where a probe pressed (known, in the patch's parent link frame) with
// where the patch says it was pressed (its own estimate u, v, depth). The calibrator finds the
// pose that maps the patch's estimates onto the probe positions:
//
//   1. checks the touch set: enough touches, not clustered, not collinear (on the patch), and
//      for a fitted radius, spread around the cylinder; a set that cannot fix the pose is refused
//      with kDegenerate and a message saying what touches to add;
//   2. finds a start by consensus: closed-form rigid fits (Kabsch) of random touch triples and of
//      the given pose, scored by how many touches they explain, so the given pose may be off by
//      any amount (tens of mm, any rotation);
//   3. refines with Ceres (rotation on the quaternion manifold, Cauchy loss on residuals in
//      noise units), marks touches whose residual exceeds `outlier_sigma` as outliers, and
//      re-solves on the inliers without the robust loss;
//   4. checks the answer: the inliers must be most touches and still a well-spread set, Ceres must
//      report convergence, and the covariance (ceres::Covariance) must exist; otherwise
//      kDegenerate or kNotConverged. A residual well above the stated noise is kept as a warning
//      (`residual_sigma`), since the pose may still be right while the noise is misstated.
//
// Noise model: a touch's residual is taken in the skin's local frame at the touch (across the
// skin along u and v, and along the normal), where its standard deviation is
// sqrt(probe_sigma_mm^2 + estimate_sigma_mm^2) across and
// sqrt(probe_sigma_mm^2 + estimate_depth_sigma_mm^2) along the normal.
#pragma once

#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include "skinbus/body_map/skin_map.h"
#include "skinbus/common/result.h"

namespace skinbus::body_map {

struct CalibrationTouch {
  Eigen::Vector3d probe_mm;  // the probe tip's position in the patch's parent link frame
  double u_mm = 0, v_mm = 0, depth_mm = 0;  // the patch's own estimate of the touch
};

struct CalibrationOptions {
  double probe_sigma_mm = 0.5;           // probe position noise, 1 sd per axis
  double estimate_sigma_mm = 0.5;        // error of the patch's estimates in u and v, 1 sd
  double estimate_depth_sigma_mm = 0.2;  // and in depth
  bool fit_radius = false;               // also fit a cylinder patch's radius
  double outlier_sigma = 4.5;  // residual norm (noise units) beyond which a touch is an outlier
  int min_touches = 6;         // at least this many (inliers too); 8 when fitting the radius
  double min_spread_mm = 15;   // rms distance of the touches from their centroid, along 2 axes
  int consensus_trials = 64;   // random triples tried for the start
  uint64_t seed = 1;           // for the triples: the result is a function of the inputs and seed
  int max_iterations = 100;
  // A pose whose standard deviation (from the covariance) exceeds these is refused as
  // kDegenerate: the touches do not pin it down.
  double max_position_sd_mm = 1.0;
  double max_rotation_sd_deg = 1.0;
  double max_radius_sd_mm = 2.0;
};

struct TouchResidual {
  Eigen::Vector3d residual_mm;  // estimate mapped by the fitted pose minus the probe, link frame
  double norm_sigma = 0;        // |residual| in noise units (whitened by the noise model)
  bool outlier = false;
};

struct PatchCalibration {
  Pose pose_on_link;            // the fitted pose
  double radius_mm = 0;         // the fitted (or given) cylinder radius; 0 for flat patches
  PoseUncertainty uncertainty;  // sd from the covariance, scaled up when residuals exceed noise
  // Covariance of [rotation vector (rad, about the link axes); translation (mm)]; of the radius
  // (mm^2) when fitted.
  Eigen::Matrix<double, 6, 6> covariance = Eigen::Matrix<double, 6, 6>::Zero();
  double radius_variance_mm2 = 0;
  std::vector<TouchResidual> residuals;  // one per touch, in input order
  double residual_sigma = 0;  // rms inlier residual per axis in noise units (about 1 if the
                              // noise is as stated; well above 1: the model misses something)
  int iterations = 0;         // Ceres iterations, both solves
  std::vector<std::string> warnings;
};

// Checks that `touches` can fix a pose on a patch of geometry `g` (see step 1). Ok or
// kDegenerate with what to add.
Status check_touch_geometry(const PatchGeometry& g, std::span<const CalibrationTouch> touches,
                            const CalibrationOptions& options);

// Calibrates one patch: `initial` gives its link, geometry and a starting pose. Errors:
// kInvalidArgument (non-finite touch, bad options or geometry), kDegenerate, kNotConverged; a
// result is never a silent wrong pose and never holds NaN.
Result<PatchCalibration> calibrate_patch(const PatchPlacement& initial,
                                         std::span<const CalibrationTouch> touches,
                                         const CalibrationOptions& options = {});

}  // namespace skinbus::body_map
