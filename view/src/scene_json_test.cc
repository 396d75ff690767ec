#include "skinbus/view/scene_json.h"

#include <gtest/gtest.h>

#include <cmath>
#include <nlohmann/json.hpp>

namespace skinbus::view {
namespace {

body_map::SkinMap two_patches() {
  body_map::SkinMap map;
  body_map::PatchPlacement flat;
  flat.node_id = 7;
  flat.hardware_uid = 0x5b00000000000007;
  flat.link = "torso_link";
  flat.pose_on_link.translation_mm = {100, 20, 300};
  flat.geometry.size_u_mm = 140;
  flat.geometry.size_v_mm = 100;
  body_map::PatchPlacement arm;
  arm.node_id = 1;
  arm.hardware_uid = 0x5b00000000000001;
  arm.link = "left_forearm_link";
  arm.pose_on_link.rotation = body_map::rotation_from_rpy(0, -M_PI / 2, 0);
  arm.pose_on_link.translation_mm = {135, 45, 0};
  arm.geometry.kind = body_map::SurfaceKind::kCylinder;
  arm.geometry.radius_mm = 45;
  map.patches = {flat, arm};
  return map;
}

TEST(SceneJson, EveryPatchSurfaceIsTheHostsPlacementInTheLinkFrame) {
  const auto map = two_patches();
  const auto scene = nlohmann::json::parse(scene_to_json(map, "/robot/r.urdf", "base_link", true));
  EXPECT_EQ(scene["type"], "scene");
  EXPECT_EQ(scene["robot_url"], "/robot/r.urdf");
  EXPECT_EQ(scene["read_only"], true);
  ASSERT_EQ(scene["patches"].size(), 2u);
  for (std::size_t k = 0; k < 2; ++k) {
    const auto& p = scene["patches"][k];
    const auto& placement = map.patches[k];
    EXPECT_EQ(p["node"], placement.node_id);
    EXPECT_EQ(p["link"], placement.link);
    const int n = kSceneGridPoints;
    ASSERT_EQ(p["grid"]["points_mm"].size(), static_cast<std::size_t>(n * n));
    // The grid's middle is the centre; its corner is (-size_u/2, -size_v/2).
    const auto& middle = p["grid"]["points_mm"][(n / 2) * n + n / 2];
    const auto& corner = p["grid"]["points_mm"][0];
    const auto centre = body_map::link_surface_point(placement, 0, 0, 0).point_mm;
    const auto edge = body_map::link_surface_point(placement, -placement.geometry.size_u_mm / 2,
                                                   -placement.geometry.size_v_mm / 2, 0)
                          .point_mm;
    for (int a = 0; a < 3; ++a) {
      EXPECT_NEAR(middle[a].get<double>(), centre[a], 1e-9);
      EXPECT_NEAR(p["centre_mm"][a].get<double>(), centre[a], 1e-9);
      EXPECT_NEAR(corner[a].get<double>(), edge[a], 1e-9);
    }
  }
  EXPECT_EQ(scene["patches"][0]["kind"], "flat");
  EXPECT_EQ(scene["patches"][0]["centre_mm"], nlohmann::json::array({100.0, 20.0, 300.0}));
  EXPECT_EQ(scene["patches"][1]["kind"], "cylinder");
  EXPECT_EQ(scene["patches"][1]["radius_mm"], 45.0);
  EXPECT_EQ(scene["patches"][1]["hardware_uid"], "5b00000000000001");
}

TEST(SceneJson, NonFiniteJointPositionsAndBadBytesStillGiveJson) {
  const std::vector<std::string> names = {"elbow", std::string("bad\xff", 4)};
  const std::vector<double> q = {0.5, std::nan("")};
  const auto j = nlohmann::json::parse(joint_state_to_json(12, names, q));
  EXPECT_EQ(j["type"], "joint_state");
  EXPECT_EQ(j["positions"][0], 0.5);
  EXPECT_TRUE(j["positions"][1].is_null());
  EXPECT_EQ(j["names"].size(), 2u);
  EXPECT_EQ(nlohmann::json::parse(heartbeat_to_json(5, -1))["host_age_ms"], -1);
  EXPECT_EQ(nlohmann::json::parse(hello_to_json(true))["read_only"], true);
}

}  // namespace
}  // namespace skinbus::view
