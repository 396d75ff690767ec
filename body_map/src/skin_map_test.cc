#include "skinbus/body_map/skin_map.h"

#include <gtest/gtest.h>

#include <cmath>
#include <numbers>
#include <random>

namespace skinbus::body_map {
namespace {

constexpr const char* kMap = R"(skin_map_version: 1
robot: robots/skinbot.urdf
patches:
  - node: 3
    uid: 0x5B00000000000003
    link: left_forearm_link
    position_mm: [135, 0, 45]
    rpy_deg: [0, 0, 90]
    geometry: {type: cylinder, radius_mm: 45, axis: v}
    model: models/nominal.skinmodel
  - node: 7
    uid: 0x5B00000000000007
    link: torso_link
    position_mm: [110, -80, 90]
    quaternion_wxyz: [0.5, 0.5, 0.5, 0.5]
)";

TEST(SkinMap, ReadsAFile) {
  Result<SkinMap> m = load_skin_map_text(kMap);
  ASSERT_TRUE(m.ok()) << m.error().to_string();
  ASSERT_EQ(m.value().patches.size(), 2u);
  const PatchPlacement& a = *m.value().find_node(3);
  EXPECT_EQ(a.link, "left_forearm_link");
  EXPECT_EQ(a.hardware_uid, 0x5B00000000000003ull);
  EXPECT_EQ(a.geometry.kind, SurfaceKind::kCylinder);
  EXPECT_NEAR(a.geometry.arc_deg(), 140 / 45.0 * 180 / std::numbers::pi, 1e-9);
  EXPECT_NEAR(
      (a.pose_on_link.rotation * Eigen::Vector3d::UnitX() - Eigen::Vector3d::UnitY()).norm(), 0,
      1e-12);
  const PatchPlacement& b = *m.value().find_node(7);
  EXPECT_EQ(b.geometry.kind, SurfaceKind::kFlat);
  EXPECT_EQ(b.geometry.size_u_mm, 140);
  // q = (1 + i + j + k) / 2 maps x -> y, y -> z, z -> x.
  EXPECT_NEAR(
      (b.pose_on_link.rotation * Eigen::Vector3d::UnitX() - Eigen::Vector3d::UnitY()).norm(), 0,
      1e-12);
  EXPECT_EQ(m.value().find_node(4), nullptr);
}

TEST(SkinMap, WritesWhatItReadsBack) {
  std::mt19937_64 rng(21);
  std::normal_distribution<double> n(0, 1);
  SkinMap m;
  m.robot = "robot file.urdf";
  for (int i = 1; i <= 20; ++i) {
    PatchPlacement p;
    p.node_id = i;
    p.hardware_uid = 0xFFFF000000000000ull + static_cast<uint64_t>(i);
    p.link = i % 5 == 0 ? "null" : i % 2 ? "a_link" : "b link";
    p.pose_on_link = {rotation_from_vector(Eigen::Vector3d(n(rng), n(rng), n(rng))),
                      Eigen::Vector3d(n(rng), n(rng), n(rng)) * 300};
    if (i % 3 == 0) {
      p.geometry.kind = SurfaceKind::kCylinder;
      p.geometry.radius_mm = 30 + 20 * std::abs(n(rng));
      p.geometry.axis = i % 2 ? CylinderAxis::kU : CylinderAxis::kV;
    }
    if (i % 4 == 0) {
      p.calibration = PoseUncertainty{30, 27, 0.61, {0.1, 0.2, 0.3}, {0.01, 0.02, 0.03}, 0.4};
    }
    if (i % 7 == 0) {  // a two- or three-press entry with its proposer and a correction
      p.unit = "units/u.json";
      p.max_contacts = 2 + i % 2;
      p.proposer = "models/my proposer";
      p.correction = "cal/correction.json";
    }
    m.patches.push_back(p);
  }
  Result<SkinMap> back = load_skin_map_text(skin_map_to_yaml(m));
  ASSERT_TRUE(back.ok()) << back.error().to_string() << "\n" << skin_map_to_yaml(m);
  EXPECT_EQ(back.value().robot, m.robot);
  ASSERT_EQ(back.value().patches.size(), m.patches.size());
  for (std::size_t i = 0; i < m.patches.size(); ++i) {
    const PatchPlacement &a = m.patches[i], &b = back.value().patches[i];
    EXPECT_EQ(a.node_id, b.node_id);
    EXPECT_EQ(a.hardware_uid, b.hardware_uid);
    EXPECT_EQ(a.link, b.link);
    EXPECT_LT((a.pose_on_link.translation_mm - b.pose_on_link.translation_mm).norm(), 1e-9);
    EXPECT_LT(rotation_angle_between(a.pose_on_link.rotation, b.pose_on_link.rotation), 1e-11);
    EXPECT_EQ(a.geometry.kind, b.geometry.kind);
    EXPECT_NEAR(a.geometry.radius_mm, b.geometry.radius_mm, 1e-12);
    EXPECT_EQ(a.geometry.axis, b.geometry.axis);
    EXPECT_EQ(a.max_contacts, b.max_contacts);
    EXPECT_EQ(a.proposer, b.proposer);
    EXPECT_EQ(a.correction, b.correction);
    EXPECT_EQ(a.unit, b.unit);
    ASSERT_EQ(a.calibration.has_value(), b.calibration.has_value());
    if (a.calibration) {
      EXPECT_EQ(b.calibration->inliers, 27);
      EXPECT_NEAR(b.calibration->position_sd_mm.z(), 0.3, 1e-12);
    }
  }
  EXPECT_TRUE(validate_skin_map(m).ok());
}

TEST(SkinMap, ErrorsNameTheKeyAndLine) {
  struct Case {
    std::string yaml, says;
  };
  const std::string head = "patches:\n  - node: 3\n    link: l\n    position_mm: [0, 0, 0]\n";
  const std::vector<Case> cases = {
      {"patches: [", "line"},
      {"", "empty"},
      {"patches: 3", "expected a list of patches"},
      {"patchez: []", "patchez (line 1): unknown setting"},
      {head + "    colour: red\n", "patches[0].colour (line 5): unknown setting"},
      {"patches:\n  - node: 3\n    link: l\n", "patches[0].position_mm"},
      {"patches:\n  - node: 300\n    link: l\n    position_mm: [0, 0, 0]\n", "outside 1..125"},
      {head + head.substr(9), "node 3 is already placed (line 2)"},
      {"patches:\n  - node: 3\n    link: l\n    position_mm: [0, 0]\n",
       "expected a list of 3 numbers"},
      {head + "    position_mm: [0, 0, 1]\n", "patches[0].position_mm (line 5): given twice"},
      {head + "    rpy_deg: [0, nan, 0]\n", "'nan' is not a number"},
      {head + "    quaternion_wxyz: [1, 1, 0, 0]\n", "not a unit quaternion"},
      {head + "    geometry: {type: sphere}\n", "'sphere' is not flat or cylinder"},
      {head + "    geometry: {type: cylinder}\n", "needs its radius"},
      {head + "    geometry: {type: cylinder, radius_mm: 2}\n", "outside"},
      {head + "    geometry: {type: cylinder, radius_mm: 20}\n", "more than a full turn"},
      {head + "    geometry: {type: flat, radius_mm: 20}\n", "only a cylinder"},
      {head + "    geometry: {type: cylinder, radius_mm: 45, arc_deg: 90, size_mm: [140, 140]}\n",
       "give one of them"},
      {head + "    uid: 0x1\n  - node: 4\n    uid: 1\n    link: l\n    position_mm: [0, 0, 0]\n",
       "hardware UID 0x0000000000000001 is already node 3"},
      {head + "    uid: -5\n", "not a 64-bit unsigned integer"},
      {head + "    max_contacts: 4\n", "patches[0].max_contacts (line 5)"},
      {head + "    uid: \" -5\"\n", "not a 64-bit unsigned integer"},
      // A patch farther from its link than any robot spans (its contacts would be dropped as
      // absurd downstream, silently).
      {"patches:\n  - node: 3\n    link: l\n    position_mm: [100000000, 45, 0]\n",
       "patches[0].position_mm (line 4): the patch is 100000.000000 m from its link's origin"},
  };
  for (const Case& c : cases) {
    Result<SkinMap> m = load_skin_map_text(c.yaml);
    ASSERT_FALSE(m.ok()) << c.yaml;
    EXPECT_NE(m.error().message.find(c.says), std::string::npos)
        << "expected '" << c.says << "' in: " << m.error().message;
  }
  // An arc alone sets the patch's extent across the axis.
  Result<SkinMap> arc =
      load_skin_map_text(head + "    geometry: {type: cylinder, radius_mm: 50, arc_deg: 90}\n");
  ASSERT_TRUE(arc.ok()) << arc.error().to_string();
  EXPECT_NEAR(arc.value().patches[0].geometry.size_u_mm, 50 * std::numbers::pi / 2, 1e-9);
  EXPECT_EQ(load_skin_map_file("/nonexistent/map.yaml").error().code, ErrorCode::kNotFound);
  EXPECT_NE(load_skin_map_file("/tmp").error().message.find("is a directory"), std::string::npos);
  // 10 m is still a place on a (large) robot.
  EXPECT_TRUE(load_skin_map_text("patches:\n  - node: 3\n    link: l\n    position_mm: [0, 0, "
                                 "10000]\n")
                  .ok());
}

TEST(SkinMap, RefusesImproperRotationsInCode) {
  SkinMap m;
  PatchPlacement p;
  p.node_id = 1;
  p.link = "l";
  p.pose_on_link.rotation(0, 0) = -1;  // a reflection
  m.patches.push_back(p);
  EXPECT_FALSE(validate_skin_map(m).ok());
}

// Patch coordinates -> link point -> patch coordinates is the identity, on both shapes.
TEST(SurfaceMap, RoundTripsAndNormals) {
  std::mt19937_64 rng(5);
  std::uniform_real_distribution<double> pos(-70, 70), depth(-0.5, 8);
  for (int shape = 0; shape < 3; ++shape) {
    PatchPlacement p;
    p.pose_on_link = {rotation_from_rpy(0.4, -1.0, 2.0), Eigen::Vector3d(10, 20, 30)};
    if (shape > 0) {
      p.geometry.kind = SurfaceKind::kCylinder;
      p.geometry.radius_mm = 45;
      p.geometry.axis = shape == 1 ? CylinderAxis::kV : CylinderAxis::kU;
    }
    for (int k = 0; k < 1000; ++k) {
      const double u = pos(rng), v = pos(rng), d = depth(rng);
      const SurfacePoint s = link_surface_point(p, u, v, d);
      EXPECT_NEAR(s.normal.norm(), 1, 1e-12);
      // The tangents are unit, along the surface's own derivatives, right-handed with the normal.
      const double h = 1e-5;
      const Eigen::Vector3d du = (link_surface_point(p, u + h, v, 0).point_mm -
                                  link_surface_point(p, u - h, v, 0).point_mm) /
                                 (2 * h);
      const Eigen::Vector3d dv = (link_surface_point(p, u, v + h, 0).point_mm -
                                  link_surface_point(p, u, v - h, 0).point_mm) /
                                 (2 * h);
      EXPECT_LT((s.tangent_u - du.normalized()).norm(), 1e-6);
      EXPECT_LT((s.tangent_v - dv.normalized()).norm(), 1e-6);
      EXPECT_LT((s.tangent_u.cross(s.tangent_v) - s.normal).norm(), 1e-9);
      // Pressing deeper moves against the normal.
      const SurfacePoint deeper = link_surface_point(p, u, v, d + 1);
      EXPECT_LT((s.point_mm - s.normal - deeper.point_mm).norm(), 1e-9);
      Result<PatchCoordinates> c = link_to_patch_coordinates(p, s.point_mm);
      ASSERT_TRUE(c.ok());
      EXPECT_NEAR(c.value().u_mm, u, 1e-9);
      EXPECT_NEAR(c.value().v_mm, v, 1e-9);
      EXPECT_NEAR(c.value().depth_mm, d, 1e-9);
      EXPECT_TRUE(c.value().inside);
    }
    // The centre of the patch is the patch frame's origin, its normal the frame's z.
    const SurfacePoint centre = link_surface_point(p, 0, 0, 0);
    EXPECT_LT((centre.point_mm - p.pose_on_link.translation_mm).norm(), 1e-12);
    EXPECT_LT((centre.normal - p.pose_on_link.rotation.col(2)).norm(), 1e-12);
    EXPECT_FALSE(link_to_patch_coordinates(p, p.pose_on_link.apply({0, 100, 0})).value().inside);
  }
  // An arc of the cylinder is arc length: a quarter turn of radius 45 is 45 * pi / 2 mm.
  PatchGeometry g;
  g.kind = SurfaceKind::kCylinder;
  g.radius_mm = 45;
  const SurfacePoint q = patch_surface_point(g, 45 * std::numbers::pi / 2, 0, 0);
  EXPECT_LT((q.point_mm - Eigen::Vector3d(45, 0, -45)).norm(), 1e-9);
  EXPECT_LT((q.normal - Eigen::Vector3d::UnitX()).norm(), 1e-12);
  // The axis itself has no patch coordinates.
  Result<PatchCoordinates> axis = patch_coordinates(g, {0, 10, -45});
  ASSERT_FALSE(axis.ok());
  EXPECT_EQ(axis.error().code, ErrorCode::kDegenerate);
  EXPECT_EQ(patch_coordinates(g, {NAN, 0, 0}).error().code, ErrorCode::kInvalidArgument);
}

}  // namespace
}  // namespace skinbus::body_map
