#include "skinbus/body_map/joint_map.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <string>
#include <vector>

namespace skinbus::body_map {
namespace {

// base -> slide (prismatic) -> carriage -> hinge (revolute) -> arm -> finger (prismatic mimic of
// the hinge, 0.02 m/rad + 0.01 m); carriage -> spin (continuous) -> wheel -> wheel_mirror
// (revolute mimic of the slide, 2 rad/m); base -> bolt (fixed) -> plate.
constexpr const char* kRobot = R"(<?xml version="1.0"?>
<robot name="mapped">
  <link name="base"/><link name="carriage"/><link name="arm"/><link name="finger"/>
  <link name="wheel"/><link name="wheel2"/><link name="plate"/>
  <joint name="slide" type="prismatic">
    <parent link="base"/><child link="carriage"/>
    <axis xyz="1 0 0"/>
    <limit lower="-0.2" upper="0.3" effort="1" velocity="1"/>
  </joint>
  <joint name="hinge" type="revolute">
    <parent link="carriage"/><child link="arm"/>
    <origin xyz="0 0 0.2"/>
    <axis xyz="0 0 1"/>
    <limit lower="-1" upper="1" effort="1" velocity="1"/>
  </joint>
  <joint name="finger_joint" type="prismatic">
    <parent link="arm"/><child link="finger"/>
    <origin xyz="0.3 0 0"/>
    <axis xyz="1 0 0"/>
    <limit lower="0" upper="0.05" effort="1" velocity="1"/>
    <mimic joint="hinge" multiplier="0.02" offset="0.01"/>
  </joint>
  <joint name="spin" type="continuous">
    <parent link="carriage"/><child link="wheel"/>
    <axis xyz="0 1 0"/>
  </joint>
  <joint name="wheel_mirror" type="revolute">
    <parent link="wheel"/><child link="wheel2"/>
    <axis xyz="0 1 0"/>
    <limit lower="-1" upper="1" effort="1" velocity="1"/>
    <mimic joint="slide" multiplier="2" offset="0.1"/>
  </joint>
  <joint name="bolt" type="fixed">
    <parent link="base"/><child link="plate"/>
  </joint>
</robot>)";

class JointMapTest : public ::testing::Test {
 protected:
  void SetUp() override {
    auto r = RobotModel::from_urdf_string(kRobot);
    ASSERT_TRUE(r.ok()) << r.error().to_string();
    robot_ = std::move(*r);
    ASSERT_EQ(robot_.joint_count(), 3);  // slide, hinge, spin
  }
  int q_of(const char* name) const { return robot_.find_joint(name); }
  std::vector<double> zero() const {
    return std::vector<double>(static_cast<std::size_t>(robot_.joint_count()), 0.0);
  }
  // Position of the joint above `link` for q, by the model's mimic rule (forward kinematics).
  Eigen::Vector3d origin_of(const char* link, const std::vector<double>& q) const {
    auto pose = robot_.link_pose(q, robot_.find_link(link));
    EXPECT_TRUE(pose.ok());
    return pose->translation_mm;
  }
  RobotModel robot_;
};

TEST_F(JointMapTest, KindsAndUnits) {
  const std::vector<std::string> names = {"hinge", "finger_joint", "ghost",       "slide",
                                          "bolt",  "spin",         "wheel_mirror"};
  const JointMap metres(robot_, names, PrismaticUnit::kMetres);
  ASSERT_EQ(metres.size(), names.size());
  EXPECT_EQ(metres.kind(0), JointMap::Kind::kJoint);
  EXPECT_EQ(metres.kind(1), JointMap::Kind::kMimic);
  EXPECT_EQ(metres.kind(2), JointMap::Kind::kUnknown);
  EXPECT_EQ(metres.kind(3), JointMap::Kind::kJoint);
  EXPECT_EQ(metres.kind(4), JointMap::Kind::kUnknown);  // fixed
  EXPECT_EQ(metres.kind(5), JointMap::Kind::kJoint);    // continuous
  EXPECT_EQ(metres.kind(6), JointMap::Kind::kMimic);
  EXPECT_EQ(metres.unknown_count(), 2);
  EXPECT_EQ(metres.q_index(0), q_of("hinge"));
  EXPECT_EQ(metres.q_index(1), -1);  // a mimic joint has no entry of q
  EXPECT_EQ(metres.q_index(3), q_of("slide"));
  // Each joint's own type: the prismatic follower of a revolute leader is in metres, the
  // revolute leader is not; the revolute follower of a prismatic leader is not either.
  EXPECT_DOUBLE_EQ(metres.to_model(0), 1.0);
  EXPECT_DOUBLE_EQ(metres.to_model(1), 1000.0);
  EXPECT_DOUBLE_EQ(metres.to_model(3), 1000.0);
  EXPECT_DOUBLE_EQ(metres.to_model(5), 1.0);
  EXPECT_DOUBLE_EQ(metres.to_model(6), 1.0);
  const JointMap mm(robot_, names, PrismaticUnit::kMillimetres);
  for (std::size_t i = 0; i < names.size(); ++i) EXPECT_DOUBLE_EQ(mm.to_model(i), 1.0) << i;
  EXPECT_TRUE(metres.same_source(names, PrismaticUnit::kMetres));
  EXPECT_FALSE(metres.same_source(names, PrismaticUnit::kMillimetres));
  EXPECT_FALSE(metres.same_source(std::span(names).first(3), PrismaticUnit::kMetres));
  EXPECT_FALSE(JointMap().same_source({}, PrismaticUnit::kMillimetres));
}

TEST_F(JointMapTest, ApplySetsJointsInModelUnitsAndIgnoresTheRest) {
  const std::vector<std::string> names = {"slide", "ghost", "hinge", "bolt", "spin"};
  const JointMap map(robot_, names, PrismaticUnit::kMetres);
  std::vector<double> q = zero();
  q[static_cast<std::size_t>(q_of("spin"))] = 9.0;
  const std::vector<double> v = {0.05, 123.0, 0.5, 7.0, 7.5};
  EXPECT_EQ(map.apply(v, q), 3);
  EXPECT_DOUBLE_EQ(q[static_cast<std::size_t>(q_of("slide"))], 50.0);  // 0.05 m
  EXPECT_DOUBLE_EQ(q[static_cast<std::size_t>(q_of("hinge"))], 0.5);
  EXPECT_DOUBLE_EQ(q[static_cast<std::size_t>(q_of("spin"))], 7.5);  // continuous: not wrapped
  // Non-finite values (or an overflow of the scaling) leave the entry; short spans are fine.
  const std::vector<double> bad = {std::numeric_limits<double>::quiet_NaN(), 0.0,
                                   std::numeric_limits<double>::infinity()};
  EXPECT_EQ(map.apply(bad, q), 0);
  EXPECT_DOUBLE_EQ(q[static_cast<std::size_t>(q_of("slide"))], 50.0);
  EXPECT_DOUBLE_EQ(q[static_cast<std::size_t>(q_of("hinge"))], 0.5);
  const std::vector<double> huge = {std::numeric_limits<double>::max()};
  EXPECT_EQ(map.apply(huge, q), 0);
  EXPECT_DOUBLE_EQ(q[static_cast<std::size_t>(q_of("slide"))], 50.0);
  EXPECT_TRUE(map.covers(q_of("slide")));
  EXPECT_TRUE(map.covers(q_of("spin")));
  const JointMap partial(robot_, std::vector<std::string>{"hinge"}, PrismaticUnit::kMetres);
  EXPECT_FALSE(partial.covers(q_of("slide")));
  EXPECT_FALSE(partial.covers(-1));
}

// A mimic joint's position is multiplier * leader + offset, prismatic and revolute alike: its own
// value in the source does not move it, its leader's does.
TEST_F(JointMapTest, MimicJointsFollowTheirLeader) {
  const std::vector<std::string> names = {"hinge", "finger_joint", "slide", "wheel_mirror"};
  const JointMap map(robot_, names, PrismaticUnit::kMetres);
  std::vector<double> q = zero();
  // The followers' values disagree with their leaders: they must not count.
  EXPECT_EQ(map.apply(std::vector<double>{0.5, 0.9, 0.1, -3.0}, q), 2);
  std::vector<double> expected = zero();
  expected[static_cast<std::size_t>(q_of("hinge"))] = 0.5;
  expected[static_cast<std::size_t>(q_of("slide"))] = 100.0;
  EXPECT_EQ(q, expected);
  // The prismatic follower of the revolute hinge: (0.02 m/rad * 0.5 rad + 0.01 m) = 20 mm along
  // its axis, which the arm turns by the hinge's 0.5 rad.
  const Eigen::Vector3d arm = origin_of("arm", q), finger = origin_of("finger", q);
  const double along_mm = 300.0 + 20.0;
  EXPECT_NEAR((finger - arm).x(), along_mm * std::cos(0.5), 1e-9);
  EXPECT_NEAR((finger - arm).y(), along_mm * std::sin(0.5), 1e-9);
  // Only the follower given: its leader keeps its value (here the zero pose).
  const JointMap only_follower(robot_, std::vector<std::string>{"finger_joint"},
                               PrismaticUnit::kMetres);
  std::vector<double> q2 = zero();
  EXPECT_EQ(only_follower.apply(std::vector<double>{0.04}, q2), 0);
  EXPECT_EQ(q2, zero());
  EXPECT_EQ(only_follower.unknown_count(), 0);  // a mimic joint is known
  const Status st = only_follower.check_all_joints();
  ASSERT_FALSE(st.ok());
  EXPECT_EQ(st.error().code, ErrorCode::kNotFound);
  EXPECT_EQ(st.error().message, "joint 'finger_joint' is not a movable joint of robot 'mapped'");
}

TEST_F(JointMapTest, OrderDoesNotMatter) {
  std::vector<std::pair<std::string, double>> pairs = {
      {"slide", 0.02}, {"hinge", -0.3}, {"finger_joint", 0.04}, {"ghost", 5.0},
      {"spin", 4.0},   {"bolt", 1.0},   {"wheel_mirror", 0.7}};
  std::sort(pairs.begin(), pairs.end());
  std::vector<double> first;
  int permutations = 0;
  do {
    std::vector<std::string> names;
    std::vector<double> values;
    for (const auto& [n, v] : pairs) {
      names.push_back(n);
      values.push_back(v);
    }
    const JointMap map(robot_, names, PrismaticUnit::kMetres);
    std::vector<double> q = zero();
    EXPECT_EQ(map.apply(values, q), 3);
    EXPECT_EQ(map.unknown_count(), 2);
    if (first.empty()) {
      first = q;
    } else {
      ASSERT_EQ(q, first);
    }
    ++permutations;
  } while (std::next_permutation(pairs.begin(), pairs.end()) && permutations < 720);
  EXPECT_DOUBLE_EQ(first[static_cast<std::size_t>(q_of("slide"))], 20.0);
  // A name given twice: its first value counts, wherever the two are.
  const std::vector<std::string> twice = {"hinge", "slide", "hinge"};
  const JointMap map(robot_, twice, PrismaticUnit::kMillimetres);
  std::vector<double> q = zero();
  EXPECT_EQ(map.apply(std::vector<double>{0.1, 5.0, 0.2}, q), 2);
  EXPECT_DOUBLE_EQ(q[static_cast<std::size_t>(q_of("hinge"))], 0.1);
}

TEST_F(JointMapTest, CheckAllJoints) {
  EXPECT_TRUE(
      JointMap(robot_, std::vector<std::string>{"spin", "slide"}, PrismaticUnit::kMillimetres)
          .check_all_joints()
          .ok());
  const Status st =
      JointMap(robot_, std::vector<std::string>{"slide", "bolt"}, PrismaticUnit::kMillimetres)
          .check_all_joints();
  ASSERT_FALSE(st.ok());
  EXPECT_EQ(st.error().message, "joint 'bolt' is not a movable joint of robot 'mapped'");
}

}  // namespace
}  // namespace skinbus::body_map
