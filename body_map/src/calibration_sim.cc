#include "skinbus/body_map/calibration_sim.h"

#include <algorithm>
#include <cmath>
#include <numbers>
#include <random>

namespace skinbus::body_map {

namespace {

constexpr double kPatchMm = 140;
constexpr double kPi = std::numbers::pi;

Eigen::Vector3d random_unit(std::mt19937_64& rng) {
  std::normal_distribution<double> n(0, 1);
  Eigen::Vector3d v;
  do {
    v = {n(rng), n(rng), n(rng)};
  } while (v.norm() < 1e-6);
  return v.normalized();
}

Eigen::Vector3d gaussian3(std::mt19937_64& rng, double sd) {
  std::normal_distribution<double> n(0, sd);
  return {n(rng), n(rng), n(rng)};
}

}  // namespace

Result<SkinMap> tile_humanoid(const RobotModel& robot, const HumanoidLayout& layout) {
  SkinMap map;
  int node = layout.first_node;
  uint64_t uid = layout.first_uid;
  auto add = [&](const std::string& link, const Eigen::Matrix3d& r, const Eigen::Vector3d& t,
                 const PatchGeometry& g) {
    PatchPlacement p;
    p.node_id = node++;
    p.hardware_uid = uid++;
    p.link = link;
    p.pose_on_link = {r, t};
    p.geometry = g;
    p.model = layout.model;
    map.patches.push_back(p);
  };
  // Patches around a limb: the axis `along` (unit, link frame) from `start` to `end` mm, `around`
  // patches spaced evenly starting at the direction `first` (unit, perpendicular to `along`).
  auto tile_limb = [&](const std::string& link, const char* what, double radius_mm, double start,
                       double end, int around, const Eigen::Vector3d& along,
                       const Eigen::Vector3d& first) -> Status {
    if (robot.find_link(link) < 0) {
      return make_error(ErrorCode::kNotFound, std::string(what) + " link '" + link +
                                                  "' is not in robot '" + robot.name() + "'");
    }
    PatchGeometry g;
    g.kind = SurfaceKind::kCylinder;
    g.radius_mm = radius_mm;
    g.axis = CylinderAxis::kV;
    const Eigen::Vector3d second = along.cross(first);
    const double length = end - start;
    const int n_along = std::max(1, static_cast<int>(length / kPatchMm));
    for (int a = 0; a < n_along; ++a) {
      const double s_mm = start + (a + 0.5) * length / n_along;
      for (int k = 0; k < around; ++k) {
        const double phi = 2 * kPi * k / around;
        const Eigen::Vector3d n = std::cos(phi) * first + std::sin(phi) * second;  // outward
        Eigen::Matrix3d r;
        r.col(0) = along.cross(n);
        r.col(1) = along;  // v along the limb
        r.col(2) = n;
        add(link, r, s_mm * along + radius_mm * n, g);
      }
    }
    return Status::Ok();
  };
  for (const std::string& link : layout.forearm_links) {
    if (Status st = tile_limb(link, "forearm", layout.forearm_radius_mm, layout.forearm_start_mm,
                              layout.forearm_end_mm, layout.patches_around,
                              Eigen::Vector3d::UnitX(), Eigen::Vector3d::UnitY());
        !st.ok()) {
      return st.error();
    }
  }
  for (const std::string& link : layout.upper_arm_links) {
    if (Status st =
            tile_limb(link, "upper arm", layout.upper_arm_radius_mm, layout.upper_arm_start_mm,
                      layout.upper_arm_end_mm, layout.upper_arm_patches_around,
                      -Eigen::Vector3d::UnitZ(), Eigen::Vector3d::UnitX());
        !st.ok()) {
      return st.error();
    }
  }
  if (robot.find_link(layout.torso_link) < 0) {
    return make_error(ErrorCode::kNotFound, "torso link '" + layout.torso_link +
                                                "' is not in robot '" + robot.name() + "'");
  }
  const double wy = layout.chest_y_mm[1] - layout.chest_y_mm[0];
  const double wz = layout.chest_z_mm[1] - layout.chest_z_mm[0];
  const int ny = std::max(1, static_cast<int>(wy / kPatchMm));
  const int nz = std::max(1, static_cast<int>(wz / kPatchMm));
  Eigen::Matrix3d r;
  r.col(0) = Eigen::Vector3d::UnitY();
  r.col(1) = Eigen::Vector3d::UnitZ();
  r.col(2) = Eigen::Vector3d::UnitX();
  for (int iz = 0; iz < nz; ++iz) {
    for (int iy = 0; iy < ny; ++iy) {
      const Eigen::Vector3d t(layout.chest_x_mm, layout.chest_y_mm[0] + (iy + 0.5) * wy / ny,
                              layout.chest_z_mm[0] + (iz + 0.5) * wz / nz);
      add(layout.torso_link, r, t, PatchGeometry{});
    }
  }
  if (Status st = validate_skin_map(map, &robot); !st.ok()) return st.error();
  return map;
}

Result<SimulatedSession> simulate_calibration_session(const RobotModel& robot, const SkinMap& truth,
                                                      const SessionOptions& o) {
  if (o.touches_per_patch < 1 || !(o.probe_noise_mm >= 0) || !(o.estimate_noise_mm >= 0) ||
      !(o.estimate_depth_noise_mm >= 0) || !(o.outlier_fraction >= 0 && o.outlier_fraction <= 1) ||
      !(o.depth_max_mm >= o.depth_min_mm) || !(o.edge_margin_mm >= 0) ||
      !(o.initial_position_error_mm >= 0) || !(o.initial_rotation_error_deg >= 0)) {
    return make_error(ErrorCode::kInvalidArgument,
                      "session options: counts >= 1, noises and errors >= 0, outlier fraction "
                      "0..1, depth_max >= depth_min");
  }
  if (Status st = validate_skin_map(truth, &robot); !st.ok()) return st.error();
  SimulatedSession s;
  s.truth = truth;
  s.initial = truth;
  std::mt19937_64 rng(o.seed);
  std::uniform_real_distribution<double> unit(0, 1);
  std::normal_distribution<double> est(0, o.estimate_noise_mm);
  std::normal_distribution<double> est_depth(0, o.estimate_depth_noise_mm);
  if (o.base_frame) {
    for (int j = 0; j < robot.joint_count(); ++j) s.log.joint_names.push_back(robot.joint_name(j));
  }
  std::vector<double> q(robot.joint_count(), 0.0);
  for (std::size_t pi = 0; pi < truth.patches.size(); ++pi) {
    const PatchPlacement& p = truth.patches[pi];
    const double hu = std::max(0.0, 0.5 * p.geometry.size_u_mm - o.edge_margin_mm);
    const double hv = std::max(0.0, 0.5 * p.geometry.size_v_mm - o.edge_margin_mm);
    const int n = o.touches_per_patch;
    const int n_out = std::clamp(static_cast<int>(std::lround(o.outlier_fraction * n)), 0, n);
    std::vector<bool> is_out(n, false);
    for (int k = 0; k < n_out; ++k) is_out[k] = true;
    std::shuffle(is_out.begin(), is_out.end(), rng);
    const int link = robot.find_link(p.link);
    for (int k = 0; k < n; ++k) {
      const double u = (2 * unit(rng) - 1) * hu, v = (2 * unit(rng) - 1) * hv;
      const double d = o.depth_min_mm + unit(rng) * (o.depth_max_mm - o.depth_min_mm);
      TouchRecord r;
      r.node_id = p.node_id;
      r.probe_mm = link_surface_point(p, u, v, d).point_mm + gaussian3(rng, o.probe_noise_mm);
      r.u_mm = u + est(rng);
      r.v_mm = v + est(rng);
      r.depth_mm = d + est_depth(rng);
      if (is_out[k]) {  // the patch placed this touch somewhere else
        double uo, vo;
        do {
          uo = (2 * unit(rng) - 1) * hu;
          vo = (2 * unit(rng) - 1) * hv;
        } while (std::hypot(uo - u, vo - v) < 10.0);
        r.u_mm = uo;
        r.v_mm = vo;
      }
      if (o.base_frame) {
        r.frame = ProbeFrame::kBase;
        for (int j = 0; j < robot.joint_count(); ++j) {
          const JointLimits& lim = robot.joint_limits(j);
          q[j] = lim.bounded ? lim.lower + unit(rng) * (lim.upper - lim.lower)
                             : (2 * unit(rng) - 1) * kPi;
        }
        Result<Pose> pose = robot.link_pose(q, link);
        if (!pose.ok()) return pose.error();
        r.probe_mm = pose.value().apply(r.probe_mm);
        r.joint_positions = q;
      }
      s.log.touches.push_back(r);
      s.outlier.push_back(is_out[k]);
    }
    PatchPlacement& init = s.initial.patches[pi];
    const Eigen::Matrix3d turn =
        rotation_from_vector(random_unit(rng) * o.initial_rotation_error_deg * kPi / 180.0);
    init.pose_on_link.rotation = turn * p.pose_on_link.rotation;
    init.pose_on_link.translation_mm += random_unit(rng) * o.initial_position_error_mm;
    if (init.geometry.kind == SurfaceKind::kCylinder) {
      init.geometry.radius_mm += o.initial_radius_error_mm;
    }
    init.calibration.reset();
  }
  return s;
}

}  // namespace skinbus::body_map
