#include "skinbus/body_map/calibration_sim.h"

#include <gtest/gtest.h>

#include <cstdlib>
#include <numbers>
#include <sstream>

namespace skinbus::body_map {
namespace {

RobotModel skinbot() {
  const char* root = std::getenv("SKINBUS_SOURCE_DIR");
  Result<RobotModel> r =
      RobotModel::from_urdf_file(std::string(root ? root : ".") + "/body_map/robots/skinbot.urdf");
  EXPECT_TRUE(r.ok()) << r.error().to_string();
  return r.value();
}

TEST(CalibrationSim, TilesForearmsAndChest) {
  const RobotModel robot = skinbot();
  Result<SkinMap> map = tile_humanoid(robot);
  ASSERT_TRUE(map.ok()) << map.error().to_string();
  int cylinders = 0, flats = 0;
  for (const PatchPlacement& p : map.value().patches) {
    if (p.geometry.kind == SurfaceKind::kCylinder) {
      ++cylinders;
      // The patch centre sits on the forearm's surface, its normal radial.
      const Eigen::Vector3d c = p.pose_on_link.translation_mm;
      EXPECT_NEAR(std::hypot(c.y(), c.z()), 45, 1e-9);
      EXPECT_NEAR(p.pose_on_link.rotation.col(2).dot(Eigen::Vector3d(0, c.y(), c.z()) / 45), 1,
                  1e-12);
      // Its edge (u = 70 mm) is still on the cylinder.
      const Eigen::Vector3d e = link_surface_point(p, 70, 0, 0).point_mm;
      EXPECT_NEAR(std::hypot(e.y(), e.z()), 45, 1e-9);
    } else {
      ++flats;
      EXPECT_NEAR(p.pose_on_link.translation_mm.x(), 110, 1e-12);
    }
    EXPECT_NEAR(p.pose_on_link.rotation.determinant(), 1, 1e-12);
  }
  EXPECT_EQ(cylinders, 4);  // 2 around x 1 along, on each forearm
  EXPECT_EQ(flats, 6);      // 2 x 3 on the chest
  HumanoidLayout bad;
  bad.torso_link = "chest";
  EXPECT_NE(tile_humanoid(robot, bad).error().message.find("'chest'"), std::string::npos);
}

TEST(CalibrationSim, TilesUpperArmsFacingForward) {
  const RobotModel robot = skinbot();
  HumanoidLayout layout;
  layout.upper_arm_links = {"left_upper_arm_link", "right_upper_arm_link"};
  Result<SkinMap> map = tile_humanoid(robot, layout);
  ASSERT_TRUE(map.ok()) << map.error().to_string();
  ASSERT_EQ(map->patches.size(), 12u);  // 4 forearm, 2 upper arm, 6 chest
  for (int i = 4; i < 6; ++i) {
    const PatchPlacement& p = map->patches[static_cast<std::size_t>(i)];
    EXPECT_EQ(p.link, i == 4 ? "left_upper_arm_link" : "right_upper_arm_link");
    EXPECT_EQ(p.node_id, i + 1);
    // Centre on the cylinder around -z, 145 mm below the shoulder, facing +x; v runs down.
    const Eigen::Vector3d c = p.pose_on_link.translation_mm;
    EXPECT_NEAR(c.x(), 40, 1e-9);
    EXPECT_NEAR(c.z(), -145, 1e-9);
    EXPECT_NEAR(p.pose_on_link.rotation.col(2).x(), 1, 1e-12);
    EXPECT_NEAR(p.pose_on_link.rotation.col(1).z(), -1, 1e-12);
    const Eigen::Vector3d e = link_surface_point(p, 60, 0, 0).point_mm;
    EXPECT_NEAR(std::hypot(e.x(), e.y()), 40, 1e-9);
  }
  layout.upper_arm_links = {"left_bicep"};
  EXPECT_NE(tile_humanoid(robot, layout).error().message.find("upper arm link 'left_bicep'"),
            std::string::npos);
}

TEST(CalibrationSim, SessionsAreConsistentWithTheTruth) {
  const RobotModel robot = skinbot();
  const SkinMap truth = tile_humanoid(robot).value();
  for (bool base : {false, true}) {
    SessionOptions o;
    o.probe_noise_mm = 0;
    o.estimate_noise_mm = 0;
    o.estimate_depth_noise_mm = 0;
    o.base_frame = base;
    Result<SimulatedSession> s = simulate_calibration_session(robot, truth, o);
    ASSERT_TRUE(s.ok()) << s.error().to_string();
    ASSERT_EQ(s.value().log.touches.size(), truth.patches.size() * 30);
    int outliers = 0;
    for (const PatchPlacement& p : truth.patches) {
      Result<std::vector<CalibrationTouch>> t = link_frame_touches(s.value().log, p, &robot);
      ASSERT_TRUE(t.ok()) << t.error().to_string();
      ASSERT_EQ(t.value().size(), 30u);
      for (const CalibrationTouch& c : t.value()) {
        const double e =
            (link_surface_point(p, c.u_mm, c.v_mm, c.depth_mm).point_mm - c.probe_mm).norm();
        outliers += e > 1e-6;
      }
      // The starting pose is off by what was asked.
      const PatchPlacement& init = *s.value().initial.find_node(p.node_id);
      EXPECT_NEAR((init.pose_on_link.translation_mm - p.pose_on_link.translation_mm).norm(), 10,
                  1e-9);
      EXPECT_NEAR(rotation_angle_between(init.pose_on_link.rotation, p.pose_on_link.rotation) *
                      180 / std::numbers::pi,
                  10, 1e-9);
    }
    EXPECT_EQ(outliers, 3 * static_cast<int>(truth.patches.size()));  // 10% of 30
  }
}

// The whole chain: simulated session -> touch log text -> calibration of every patch.
TEST(CalibrationSim, CalibratesEveryPatchOfASession) {
  const RobotModel robot = skinbot();
  const SkinMap truth = tile_humanoid(robot).value();
  SessionOptions o;
  o.base_frame = true;
  o.initial_position_error_mm = 40;
  o.initial_rotation_error_deg = 60;
  o.seed = 4;
  const SimulatedSession s = simulate_calibration_session(robot, truth, o).value();
  std::istringstream csv(touch_log_to_csv(s.log));
  const TouchLog log = read_touch_log(csv).value();
  CalibrationOptions co;
  co.probe_sigma_mm = o.probe_noise_mm;
  co.estimate_sigma_mm = o.estimate_noise_mm;
  for (const PatchPlacement& start : s.initial.patches) {
    const std::vector<CalibrationTouch> t = link_frame_touches(log, start, &robot).value();
    Result<PatchCalibration> c = calibrate_patch(start, t, co);
    ASSERT_TRUE(c.ok()) << "node " << start.node_id << ": " << c.error().to_string();
    const PatchPlacement& p = *truth.find_node(start.node_id);
    EXPECT_LT((c.value().pose_on_link.translation_mm - p.pose_on_link.translation_mm).norm(), 1.0);
    EXPECT_LT(rotation_angle_between(c.value().pose_on_link.rotation, p.pose_on_link.rotation) *
                  180 / std::numbers::pi,
              0.8);
  }
}

}  // namespace
}  // namespace skinbus::body_map
