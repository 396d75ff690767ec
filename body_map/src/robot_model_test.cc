#include "skinbus/body_map/robot_model.h"

#include <console_bridge/console.h>
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <atomic>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <limits>
#include <new>
#include <random>
#include <sstream>
#include <string>
#include <vector>

// Counts operator new calls, to check that forward kinematics allocates nothing.
namespace {
std::atomic<long> g_allocations{0};
// Out of line so that the compiler does not pair a malloc seen through operator new with this free.
[[gnu::noinline]] void release(void* p) noexcept {
  std::free(p);
}
}  // namespace

void* operator new(std::size_t size) {
  g_allocations.fetch_add(1, std::memory_order_relaxed);
  if (void* p = std::malloc(size == 0 ? 1 : size)) return p;
  throw std::bad_alloc();
}
void operator delete(void* p) noexcept {
  release(p);
}
void operator delete(void* p, std::size_t) noexcept {
  release(p);
}

namespace skinbus::body_map {
namespace {

using ::testing::HasSubstr;

constexpr double kTolMm = 1e-9;
constexpr double kTolRotation = 1e-12;

// ---- Independent hand kinematics: plain 3x3 arrays, metres, nothing from the library. ----

struct Mat3 {
  double m[3][3];
};
struct Vec3 {
  double v[3];
};

Mat3 mul(const Mat3& a, const Mat3& b) {
  Mat3 c{};
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j)
      for (int k = 0; k < 3; ++k) c.m[i][j] += a.m[i][k] * b.m[k][j];
  return c;
}
Vec3 mul(const Mat3& a, const Vec3& x) {
  Vec3 y{};
  for (int i = 0; i < 3; ++i)
    for (int k = 0; k < 3; ++k) y.v[i] += a.m[i][k] * x.v[k];
  return y;
}
Vec3 add(const Vec3& a, const Vec3& b) {
  return {{a.v[0] + b.v[0], a.v[1] + b.v[1], a.v[2] + b.v[2]}};
}

Mat3 rot_x(double a) {
  const double c = std::cos(a), s = std::sin(a);
  return {{{1, 0, 0}, {0, c, -s}, {0, s, c}}};
}
Mat3 rot_y(double a) {
  const double c = std::cos(a), s = std::sin(a);
  return {{{c, 0, s}, {0, 1, 0}, {-s, 0, c}}};
}
Mat3 rot_z(double a) {
  const double c = std::cos(a), s = std::sin(a);
  return {{{c, -s, 0}, {s, c, 0}, {0, 0, 1}}};
}

struct Frame {
  Mat3 r{{{1, 0, 0}, {0, 1, 0}, {0, 0, 1}}};
  Vec3 t_m{};
};

// One joint copied by hand from the URDF text: origin xyz (m), rpy (rad), axis 'x', 'y', 'z' (a
// unit axis; every G1 joint has one) or 0 for a fixed joint.
struct HandJoint {
  const char* name;
  double xyz[3];
  double rpy[3];
  char axis;
};

// Composes the chain from the root: T = T1 * T2 * ..., Ti = [Rz(y) Ry(p) Rx(r) | xyz] * Raxis(q).
Frame hand_chain(const std::vector<HandJoint>& chain, const RobotModel& model,
                 const std::vector<double>& q) {
  Frame f;
  for (const HandJoint& j : chain) {
    const Mat3 origin_r = mul(rot_z(j.rpy[2]), mul(rot_y(j.rpy[1]), rot_x(j.rpy[0])));
    Mat3 motion = Frame{}.r;
    if (j.axis != 0) {
      const int qi = model.find_joint(j.name);
      EXPECT_GE(qi, 0) << j.name;
      const double a = q[qi];
      motion = j.axis == 'x' ? rot_x(a) : j.axis == 'y' ? rot_y(a) : rot_z(a);
    }
    f.t_m = add(f.t_m, mul(f.r, Vec3{{j.xyz[0], j.xyz[1], j.xyz[2]}}));
    f.r = mul(f.r, mul(origin_r, motion));
  }
  return f;
}

void expect_pose_near(const Pose& got, const Frame& want, const std::string& what) {
  for (int i = 0; i < 3; ++i) {
    EXPECT_NEAR(got.translation_mm[i], want.t_m.v[i] * 1000.0, kTolMm) << what << " t[" << i << "]";
    for (int k = 0; k < 3; ++k)
      EXPECT_NEAR(got.rotation(i, k), want.r.m[i][k], kTolRotation) << what << " R" << i << k;
  }
}

void expect_pose_near(const Pose& got, const Pose& want, const std::string& what) {
  for (int i = 0; i < 3; ++i) {
    EXPECT_NEAR(got.translation_mm[i], want.translation_mm[i], kTolMm) << what << " t[" << i << "]";
    for (int k = 0; k < 3; ++k)
      EXPECT_NEAR(got.rotation(i, k), want.rotation(i, k), kTolRotation) << what << " R" << i << k;
  }
}

void expect_point_near(const Eigen::Vector3d& got, double x, double y, double z,
                       const std::string& what) {
  EXPECT_NEAR(got.x(), x, kTolMm) << what;
  EXPECT_NEAR(got.y(), y, kTolMm) << what;
  EXPECT_NEAR(got.z(), z, kTolMm) << what;
}

// ---- Chains of the G1, copied by hand from g1_29dof.urdf. ----

const std::vector<HandJoint> kG1LeftLeg = {
    {"left_hip_pitch_joint", {0, 0.064452, -0.1027}, {0, 0, 0}, 'y'},
    {"left_hip_roll_joint", {0, 0.052, -0.030465}, {0, -0.1749, 0}, 'x'},
    {"left_hip_yaw_joint", {0.025001, 0, -0.12412}, {0, 0, 0}, 'z'},
    {"left_knee_joint", {-0.078273, 0.0021489, -0.17734}, {0, 0.1749, 0}, 'y'},
};

const std::vector<HandJoint> kG1Waist = {
    {"waist_yaw_joint", {0, 0, 0}, {0, 0, 0}, 'z'},
    {"waist_roll_joint", {-0.0039635, 0, 0.035}, {0, 0, 0}, 'x'},
    {"waist_pitch_joint", {0, 0, 0.019}, {0, 0, 0}, 'y'},
};

const std::vector<HandJoint> kG1LeftArm = {
    {"left_shoulder_pitch_joint",
     {0.0039563, 0.10022, 0.23778},
     {0.27931, 5.4949E-05, -0.00019159},
     'y'},
    {"left_shoulder_roll_joint", {0, 0.038, -0.013831}, {-0.27925, 0, 0}, 'x'},
    {"left_shoulder_yaw_joint", {0, 0.00624, -0.1032}, {0, 0, 0}, 'z'},
    {"left_elbow_joint", {0.015783, 0, -0.080518}, {0, 0, 0}, 'y'},
    {"left_wrist_roll_joint", {0.100, 0.00188791, -0.010}, {0, 0, 0}, 'x'},
    {"left_wrist_pitch_joint", {0.038, 0, 0}, {0, 0, 0}, 'y'},
    {"left_wrist_yaw_joint", {0.046, 0, 0}, {0, 0, 0}, 'z'},
    {"left_hand_palm_joint", {0.0415, 0.003, 0}, {0, 0, 0}, 0},
};

const HandJoint kG1D435 = {
    "d435_joint", {0.0576235, 0.01753, 0.41987}, {0, 0.8307767239493009, 0}, 0};

std::vector<HandJoint> first(const std::vector<HandJoint>& chain, std::size_t n) {
  return {chain.begin(), chain.begin() + static_cast<std::ptrdiff_t>(n)};
}
std::vector<HandJoint> concat(std::vector<HandJoint> a, const std::vector<HandJoint>& b) {
  a.insert(a.end(), b.begin(), b.end());
  return a;
}

std::string source_dir() {
  if (const char* env = std::getenv("SKINBUS_SOURCE_DIR")) return env;
  // Run by hand: this file is <source>/body_map/src/robot_model_test.cc.
  return std::filesystem::path(__FILE__).parent_path().parent_path().parent_path().string();
}

std::string g1_path() {
  return source_dir() + "/../shared/robots/unitree_g1/g1_29dof.urdf";
}
std::string skinbot_path() {
  return source_dir() + "/body_map/robots/skinbot.urdf";
}

std::string read_text(const std::string& path) {
  std::ifstream in(path);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

class G1Test : public ::testing::Test {
 protected:
  void SetUp() override {
    if (!std::filesystem::exists(g1_path())) {
      GTEST_SKIP() << "the G1 description is not at " << g1_path();
    }
    auto model = RobotModel::from_urdf_file(g1_path());
    ASSERT_TRUE(model.ok()) << model.error().to_string();
    model_ = std::move(model).value();
  }

  std::vector<double> q_zero() const { return std::vector<double>(model_.joint_count(), 0.0); }
  void set(std::vector<double>& q, const char* joint, double value) const {
    const int j = model_.find_joint(joint);
    ASSERT_GE(j, 0) << joint;
    q[j] = value;
  }
  std::vector<Pose> fk(const std::vector<double>& q) const {
    std::vector<Pose> poses(model_.link_count());
    const Status s = model_.forward_kinematics(q, poses);
    EXPECT_TRUE(s.ok()) << s.error().to_string();
    return poses;
  }
  const Pose& pose_of(const std::vector<Pose>& poses, const char* link) const {
    const int i = model_.find_link(link);
    EXPECT_GE(i, 0) << link;
    return poses[i < 0 ? 0 : i];
  }

  RobotModel model_;
};

TEST_F(G1Test, TreeShapeJointsAndLimits) {
  EXPECT_EQ(model_.name(), "g1_29dof");
  EXPECT_EQ(model_.link_count(), 40);
  EXPECT_EQ(model_.joint_count(), 29);
  EXPECT_EQ(model_.link(0).name, "pelvis");
  EXPECT_EQ(model_.link(0).parent, -1);
  EXPECT_TRUE(model_.link(0).joint.joint_name.empty());
  for (int i = 1; i < model_.link_count(); ++i) {
    EXPECT_GE(model_.link(i).parent, 0) << model_.link(i).name;
    EXPECT_LT(model_.link(i).parent, i) << model_.link(i).name;
  }
  for (int j = 0; j < model_.joint_count(); ++j) {
    EXPECT_EQ(model_.find_joint(model_.joint_name(j)), j);
    EXPECT_TRUE(model_.joint_limits(j).bounded) << model_.joint_name(j);
  }
  // Model order (depth-first, children by joint name) is the file's joint order here.
  const std::vector<std::string> expected = {
      "left_hip_pitch_joint",      "left_hip_roll_joint",        "left_hip_yaw_joint",
      "left_knee_joint",           "left_ankle_pitch_joint",     "left_ankle_roll_joint",
      "right_hip_pitch_joint",     "right_hip_roll_joint",       "right_hip_yaw_joint",
      "right_knee_joint",          "right_ankle_pitch_joint",    "right_ankle_roll_joint",
      "waist_yaw_joint",           "waist_roll_joint",           "waist_pitch_joint",
      "left_shoulder_pitch_joint", "left_shoulder_roll_joint",   "left_shoulder_yaw_joint",
      "left_elbow_joint",          "left_wrist_roll_joint",      "left_wrist_pitch_joint",
      "left_wrist_yaw_joint",      "right_shoulder_pitch_joint", "right_shoulder_roll_joint",
      "right_shoulder_yaw_joint",  "right_elbow_joint",          "right_wrist_roll_joint",
      "right_wrist_pitch_joint",   "right_wrist_yaw_joint"};
  ASSERT_EQ(model_.joint_count(), static_cast<int>(expected.size()));
  for (int j = 0; j < model_.joint_count(); ++j) EXPECT_EQ(model_.joint_name(j), expected[j]);

  const int knee = model_.find_joint("left_knee_joint");
  EXPECT_DOUBLE_EQ(model_.joint_limits(knee).lower, -0.087267);
  EXPECT_DOUBLE_EQ(model_.joint_limits(knee).upper, 2.8798);
  const Link& knee_link = model_.link(model_.find_link("left_knee_link"));
  EXPECT_EQ(knee_link.joint.joint_name, "left_knee_joint");
  EXPECT_EQ(knee_link.joint.type, JointType::kRevolute);
  EXPECT_EQ(knee_link.joint.q_index, knee);
  EXPECT_EQ(model_.link(knee_link.parent).name, "left_hip_yaw_link");

  const Link& head = model_.link(model_.find_link("head_link"));
  EXPECT_EQ(head.joint.type, JointType::kFixed);
  EXPECT_EQ(head.joint.q_index, -1);
  EXPECT_EQ(model_.find_joint("head_joint"), -1);  // fixed joints have no entry in q
  EXPECT_EQ(model_.find_joint("no_such_joint"), -1);
  EXPECT_EQ(model_.find_link("no_such_link"), -1);
  EXPECT_EQ(model_.find_link("world"), -1);
}

TEST_F(G1Test, ForwardKinematicsMatchesHandComputation) {
  std::vector<std::vector<double>> qs;
  qs.push_back(q_zero());

  std::vector<double> q = q_zero();
  set(q, "left_hip_pitch_joint", -0.4);
  set(q, "left_hip_roll_joint", 0.3);
  set(q, "left_hip_yaw_joint", -0.2);
  set(q, "left_knee_joint", 0.9);
  set(q, "waist_yaw_joint", 0.5);
  set(q, "waist_roll_joint", -0.1);
  set(q, "waist_pitch_joint", 0.2);
  set(q, "left_shoulder_pitch_joint", -0.7);
  set(q, "left_shoulder_roll_joint", 0.6);
  set(q, "left_shoulder_yaw_joint", 0.4);
  set(q, "left_elbow_joint", 1.1);
  set(q, "left_wrist_roll_joint", -0.5);
  set(q, "left_wrist_pitch_joint", 0.3);
  set(q, "left_wrist_yaw_joint", -0.25);
  qs.push_back(q);

  q = q_zero();
  set(q, "left_hip_pitch_joint", 1.7);
  set(q, "left_hip_roll_joint", -0.45);
  set(q, "left_hip_yaw_joint", 2.1);
  set(q, "left_knee_joint", 2.5);
  set(q, "waist_yaw_joint", -2.2);
  set(q, "waist_roll_joint", 0.45);
  set(q, "waist_pitch_joint", -0.5);
  set(q, "left_shoulder_pitch_joint", -2.9);
  set(q, "left_shoulder_roll_joint", -1.2);
  set(q, "left_shoulder_yaw_joint", -2.4);
  set(q, "left_elbow_joint", -0.9);
  set(q, "left_wrist_roll_joint", 1.8);
  set(q, "left_wrist_pitch_joint", -1.5);
  set(q, "left_wrist_yaw_joint", 1.4);
  qs.push_back(q);

  // Every joint moved, including those off the checked chains.
  for (int j = 0; j < model_.joint_count(); ++j) q[j] = 0.05 * (j + 1) * (j % 2 == 0 ? 1 : -1);
  qs.push_back(q);

  for (std::size_t n = 0; n < qs.size(); ++n) {
    SCOPED_TRACE("joint set " + std::to_string(n));
    const std::vector<Pose> poses = fk(qs[n]);
    expect_pose_near(pose_of(poses, "pelvis"), Frame{}, "pelvis");
    expect_pose_near(pose_of(poses, "left_hip_pitch_link"),
                     hand_chain(first(kG1LeftLeg, 1), model_, qs[n]), "left_hip_pitch_link");
    expect_pose_near(pose_of(poses, "left_knee_link"), hand_chain(kG1LeftLeg, model_, qs[n]),
                     "left_knee_link");
    expect_pose_near(pose_of(poses, "torso_link"), hand_chain(kG1Waist, model_, qs[n]),
                     "torso_link");
    expect_pose_near(pose_of(poses, "d435_link"),
                     hand_chain(concat(kG1Waist, {kG1D435}), model_, qs[n]), "d435_link");
    expect_pose_near(pose_of(poses, "left_elbow_link"),
                     hand_chain(concat(kG1Waist, first(kG1LeftArm, 4)), model_, qs[n]),
                     "left_elbow_link");
    expect_pose_near(pose_of(poses, "left_wrist_yaw_link"),
                     hand_chain(concat(kG1Waist, first(kG1LeftArm, 7)), model_, qs[n]),
                     "left_wrist_yaw_link");
    expect_pose_near(pose_of(poses, "left_rubber_hand"),
                     hand_chain(concat(kG1Waist, kG1LeftArm), model_, qs[n]), "left_rubber_hand");
  }

  // One literal value, worked out on paper: at q = 0 the hip pitch link sits at the joint origin.
  const std::vector<Pose> zero = fk(q_zero());
  expect_point_near(pose_of(zero, "left_hip_pitch_link").translation_mm, 0, 64.452, -102.7,
                    "left_hip_pitch_link at q = 0");
}

TEST_F(G1Test, LinkPoseEqualsForwardKinematicsAtRandomJointPositions) {
  const unsigned seed = std::random_device{}();
  std::cout << "[          ] random seed " << seed << "\n";
  SCOPED_TRACE("random seed " + std::to_string(seed));
  std::mt19937 rng(seed);
  std::vector<double> q(model_.joint_count());
  std::vector<Pose> poses(model_.link_count());
  for (int trial = 0; trial < 20; ++trial) {
    for (int j = 0; j < model_.joint_count(); ++j) {
      const JointLimits& l = model_.joint_limits(j);
      std::uniform_real_distribution<double> d(l.bounded ? l.lower : -M_PI,
                                               l.bounded ? l.upper : M_PI);
      q[j] = d(rng);
    }
    ASSERT_TRUE(model_.forward_kinematics(q, poses).ok());
    for (int i = 0; i < model_.link_count(); ++i) {
      const Result<Pose> one = model_.link_pose(q, i);
      ASSERT_TRUE(one.ok()) << one.error().to_string();
      expect_pose_near(*one, poses[i], model_.link(i).name);
      // Rotations stay orthonormal.
      EXPECT_NEAR(
          (poses[i].rotation.transpose() * poses[i].rotation - Eigen::Matrix3d::Identity()).norm(),
          0.0, 1e-12);
    }
  }
}

TEST_F(G1Test, ForwardKinematicsAllocatesNothing) {
  std::vector<double> q(model_.joint_count(), 0.3);
  std::vector<Pose> poses(model_.link_count());
  const long before = g_allocations.load();
  const Status s = model_.forward_kinematics(q, poses);
  const long after = g_allocations.load();
  ASSERT_TRUE(s.ok());
  EXPECT_EQ(after - before, 0);
}

TEST_F(G1Test, BadJointPositionsAreRefused) {
  std::vector<double> q(model_.joint_count() - 1, 0.0);
  std::vector<Pose> poses(model_.link_count());
  Status s = model_.forward_kinematics(q, poses);
  ASSERT_FALSE(s.ok());
  EXPECT_EQ(s.error().code, ErrorCode::kInvalidArgument);
  EXPECT_THAT(s.error().message, HasSubstr("q has 28 entries"));
  EXPECT_THAT(s.error().message, HasSubstr("29"));
  EXPECT_FALSE(model_.link_pose(q, 3).ok());

  q.assign(model_.joint_count(), 0.0);
  std::vector<Pose> few(model_.link_count() - 1);
  s = model_.forward_kinematics(q, few);
  ASSERT_FALSE(s.ok());
  EXPECT_EQ(s.error().code, ErrorCode::kInvalidArgument);
  EXPECT_THAT(s.error().message, HasSubstr("link_poses"));

  q[model_.find_joint("left_knee_joint")] = std::numeric_limits<double>::quiet_NaN();
  s = model_.forward_kinematics(q, poses);
  ASSERT_FALSE(s.ok());
  EXPECT_EQ(s.error().code, ErrorCode::kInvalidArgument);
  EXPECT_THAT(s.error().message, HasSubstr("left_knee_joint"));
  const Result<Pose> one = model_.link_pose(q, model_.find_link("torso_link"));
  ASSERT_FALSE(one.ok());
  EXPECT_EQ(one.error().code, ErrorCode::kInvalidArgument);
  EXPECT_THAT(one.error().message, HasSubstr("left_knee_joint"));

  q[model_.find_joint("left_knee_joint")] = std::numeric_limits<double>::infinity();
  EXPECT_FALSE(model_.forward_kinematics(q, poses).ok());

  q.assign(model_.joint_count(), 0.0);
  const Result<Pose> outside = model_.link_pose(q, model_.link_count());
  ASSERT_FALSE(outside.ok());
  EXPECT_EQ(outside.error().code, ErrorCode::kInvalidArgument);
  EXPECT_THAT(outside.error().message, HasSubstr("link index 40"));
  EXPECT_FALSE(model_.link_pose(q, -1).ok());
}

// A world link and a floating joint above the G1's pelvis (as the vendor's file has them
// commented out) are dropped.
TEST_F(G1Test, WorldLinkAboveThePelvisIsDropped) {
  std::string text = read_text(g1_path());
  const std::string anchor = "<robot name=\"g1_29dof\">";
  const std::size_t at = text.find(anchor);
  ASSERT_NE(at, std::string::npos);
  text.insert(at + anchor.size(),
              "<link name=\"world\"></link><joint name=\"floating_base_joint\" type=\"floating\">"
              "<origin xyz=\"1 2 0.8\" rpy=\"0 0 1\"/>"
              "<parent link=\"world\"/><child link=\"pelvis\"/></joint>");
  auto with_world = RobotModel::from_urdf_string(text);
  ASSERT_TRUE(with_world.ok()) << with_world.error().to_string();
  EXPECT_EQ(with_world->link_count(), model_.link_count());
  EXPECT_EQ(with_world->joint_count(), model_.joint_count());
  EXPECT_EQ(with_world->link(0).name, "pelvis");
  EXPECT_EQ(with_world->find_link("world"), -1);
  EXPECT_EQ(with_world->find_joint("floating_base_joint"), -1);
}

// ---- Small inline robots. ----

constexpr const char* kSlider = R"(<robot name="slider">
  <link name="base"><visual><geometry><box size="0.1 0.1 0.1"/></geometry></visual></link>
  <link name="carriage"/>
  <link name="arm"/>
  <link name="arm2"/>
  <link name="finger"/>
  <link name="finger2"/>
  <joint name="slide" type="prismatic">
    <parent link="base"/><child link="carriage"/>
    <origin xyz="0.1 0 0.05" rpy="0 0 1.5707963267948966"/>
    <axis xyz="2 0 0"/>
    <limit lower="-0.2" upper="0.3" effort="1" velocity="1"/>
  </joint>
  <joint name="hinge" type="revolute">
    <parent link="carriage"/><child link="arm"/>
    <origin xyz="0 0 0.2"/>
    <axis xyz="0 0 1"/>
    <limit lower="-1" upper="1" effort="1" velocity="1"/>
  </joint>
  <joint name="hinge_mirror" type="revolute">
    <parent link="carriage"/><child link="arm2"/>
    <origin xyz="0 0.1 0.2"/>
    <axis xyz="0 0 1"/>
    <limit lower="-1" upper="1" effort="1" velocity="1"/>
    <mimic joint="hinge" multiplier="-1" offset="0.1"/>
  </joint>
  <joint name="finger_joint" type="prismatic">
    <parent link="arm"/><child link="finger"/>
    <origin xyz="0.3 0 0"/>
    <axis xyz="1 0 0"/>
    <limit lower="0" upper="0.05" effort="1" velocity="1"/>
    <mimic joint="hinge" multiplier="0.02" offset="0.01"/>
  </joint>
  <joint name="finger2_joint" type="prismatic">
    <parent link="finger"/><child link="finger2"/>
    <axis xyz="0 1 0"/>
    <limit lower="0" upper="0.05" effort="1" velocity="1"/>
    <mimic joint="finger_joint" multiplier="2" offset="0.001"/>
  </joint>
</robot>)";

TEST(RobotModelTest, PrismaticAndMimicJointsByHand) {
  auto model = RobotModel::from_urdf_string(kSlider);
  ASSERT_TRUE(model.ok()) << model.error().to_string();
  ASSERT_EQ(model->joint_count(), 2);
  EXPECT_EQ(model->joint_name(0), "slide");
  EXPECT_EQ(model->joint_name(1), "hinge");
  EXPECT_EQ(model->find_joint("finger_joint"), -1);  // mimic joints have no entry in q
  EXPECT_EQ(model->find_joint("hinge_mirror"), -1);
  EXPECT_EQ(model->link_count(), 6);
  // Units of q: the slide in mm; the hinge in rad although its mimic follower is prismatic.
  EXPECT_TRUE(model->joint_is_prismatic(0));
  EXPECT_FALSE(model->joint_is_prismatic(1));
  const std::vector<std::string> good = {"hinge", "slide"};
  EXPECT_TRUE(model->check_joint_names(good).ok());
  for (const char* bad : {"finger_joint", "ghost"}) {
    const std::vector<std::string> names = {"slide", bad};
    const Status st = model->check_joint_names(names);
    ASSERT_FALSE(st.ok()) << bad;
    EXPECT_EQ(st.error().code, ErrorCode::kNotFound);
    EXPECT_EQ(st.error().message,
              "joint '" + std::string(bad) + "' is not a movable joint of robot 'slider'");
  }

  const JointLimits& slide = model->joint_limits(0);
  EXPECT_TRUE(slide.bounded);
  EXPECT_DOUBLE_EQ(slide.lower, -200.0);  // metres to millimetres
  EXPECT_DOUBLE_EQ(slide.upper, 300.0);
  const Link& carriage = model->link(model->find_link("carriage"));
  EXPECT_EQ(carriage.joint.type, JointType::kPrismatic);
  EXPECT_DOUBLE_EQ(carriage.joint.axis.x(), 1.0);  // normalised
  EXPECT_DOUBLE_EQ(carriage.joint.axis.norm(), 1.0);

  const Link& finger = model->link(model->find_link("finger"));
  EXPECT_EQ(finger.joint.q_index, 1);
  EXPECT_DOUBLE_EQ(finger.joint.mimic_multiplier, 20.0);  // 0.02 m/rad
  EXPECT_DOUBLE_EQ(finger.joint.mimic_offset, 10.0);      // 0.01 m
  const Link& finger2 = model->link(model->find_link("finger2"));
  EXPECT_EQ(finger2.joint.q_index, 1);  // a mimic of a mimic follows the first leader
  EXPECT_DOUBLE_EQ(finger2.joint.mimic_multiplier, 40.0);
  EXPECT_DOUBLE_EQ(finger2.joint.mimic_offset, 21.0);  // 2 * 10 mm + 1 mm

  const double slide_mm = 40.0, hinge = 0.5;
  const std::vector<double> q = {slide_mm, hinge};
  std::vector<Pose> poses(model->link_count());
  ASSERT_TRUE(model->forward_kinematics(q, poses).ok());
  const auto at = [&](const char* name) { return poses[model->find_link(name)]; };

  // Carriage: origin (100, 0, 50) mm turned 90 degrees about z, then 40 mm along its x = world y.
  expect_point_near(at("carriage").translation_mm, 100, 40, 50, "carriage");
  // Arm: 200 mm above the carriage, turned by 90 degrees + hinge about z.
  expect_point_near(at("arm").translation_mm, 100, 40, 250, "arm");
  EXPECT_NEAR(at("arm").rotation(0, 0), std::cos(M_PI / 2 + hinge), 1e-12);
  EXPECT_NEAR(at("arm").rotation(1, 0), std::sin(M_PI / 2 + hinge), 1e-12);
  // Mirror: angle -hinge + 0.1 about z, origin (0, 100, 200) in the carriage = (0, 40, 250).
  expect_point_near(at("arm2").translation_mm, 0, 40, 250, "arm2");
  EXPECT_NEAR(at("arm2").rotation(0, 0), std::cos(M_PI / 2 - hinge + 0.1), 1e-12);
  EXPECT_NEAR(at("arm2").rotation(1, 0), std::sin(M_PI / 2 - hinge + 0.1), 1e-12);
  // Finger: 300 mm + (20 mm/rad * 0.5 + 10 mm) = 320 mm along the arm's x.
  const double c = std::cos(M_PI / 2 + hinge), s = std::sin(M_PI / 2 + hinge);
  expect_point_near(at("finger").translation_mm, 100 + 320 * c, 40 + 320 * s, 250, "finger");
  // Finger 2: 40 mm/rad * 0.5 + 21 mm = 41 mm along the finger's y.
  expect_point_near(at("finger2").translation_mm, 100 + 320 * c - 41 * s, 40 + 320 * s + 41 * c,
                    250, "finger2");
}

constexpr const char* kFloatingWorld = R"(<robot name="floater">
  <link name="world"/>
  <link name="base"><visual><geometry><box size="0.1 0.1 0.1"/></geometry></visual></link>
  <link name="tip"/>
  <joint name="float" type="floating">
    <parent link="world"/><child link="base"/>
    <origin xyz="1 2 3" rpy="0.1 0.2 0.3"/>
  </joint>
  <joint name="bend" type="continuous">
    <parent link="base"/><child link="tip"/>
    <origin xyz="0 0 0.1"/>
    <axis xyz="0 1 0"/>
  </joint>
</robot>)";

TEST(RobotModelTest, WorldLinkAndFloatingJointAboveTheBaseAreDropped) {
  auto model = RobotModel::from_urdf_string(kFloatingWorld);
  ASSERT_TRUE(model.ok()) << model.error().to_string();
  ASSERT_EQ(model->link_count(), 2);
  EXPECT_EQ(model->link(0).name, "base");
  EXPECT_EQ(model->link(0).parent, -1);
  EXPECT_EQ(model->find_link("world"), -1);
  ASSERT_EQ(model->joint_count(), 1);
  EXPECT_EQ(model->joint_name(0), "bend");
  EXPECT_FALSE(model->joint_limits(0).bounded);  // continuous
  EXPECT_EQ(model->joint_limits(0).lower, model->joint_limits(0).upper);

  const std::vector<double> q = {0.25};
  std::vector<Pose> poses(2);
  ASSERT_TRUE(model->forward_kinematics(q, poses).ok());
  expect_point_near(poses[0].translation_mm, 0, 0, 0, "base");  // the float's origin is ignored
  expect_point_near(poses[1].translation_mm, 0, 0, 100, "tip");
  EXPECT_NEAR(poses[1].rotation(0, 2), std::sin(0.25), 1e-12);
}

// Loads `xml` and expects an error of `code` whose message contains every one of `names`.
void expect_refused(const std::string& xml, ErrorCode code, const std::vector<std::string>& names) {
  const auto model = RobotModel::from_urdf_string(xml);
  ASSERT_FALSE(model.ok()) << xml;
  EXPECT_EQ(model.error().code, code) << model.error().to_string();
  for (const std::string& name : names) {
    EXPECT_THAT(model.error().message, HasSubstr(name));
  }
}

std::string robot_with(const std::string& body) {
  return "<robot name=\"bad\"><link name=\"base\"/><link name=\"a\"/>" + body + "</robot>";
}

TEST(RobotModelTest, BadDescriptionsAreRefusedWithClearErrors) {
  // Missing file.
  const auto missing = RobotModel::from_urdf_file("/nonexistent/dir/robot.urdf");
  ASSERT_FALSE(missing.ok());
  EXPECT_EQ(missing.error().code, ErrorCode::kNotFound);
  EXPECT_THAT(missing.error().message, HasSubstr("/nonexistent/dir/robot.urdf"));

  // Not URDF at all, and XML that is not a robot.
  expect_refused("this is not xml <<<", ErrorCode::kParse, {"URDF"});
  expect_refused("<config><value>3</value></config>", ErrorCode::kParse, {"robot"});
  expect_refused("", ErrorCode::kParse, {"URDF"});

  // A planar joint.
  expect_refused(robot_with(R"(<joint name="table_glide" type="planar">
      <parent link="base"/><child link="a"/><axis xyz="0 0 1"/>
      <limit lower="-1" upper="1" effort="1" velocity="1"/></joint>)"),
                 ErrorCode::kUnsupported, {"table_glide", "planar"});

  // A zero axis.
  expect_refused(robot_with(R"(<joint name="limp_joint" type="revolute">
      <parent link="base"/><child link="a"/><axis xyz="0 0 0"/>
      <limit lower="-1" upper="1" effort="1" velocity="1"/></joint>)"),
                 ErrorCode::kInvalidArgument, {"limp_joint", "zero axis"});

  // Two roots: nothing joins base and a.
  expect_refused(robot_with(""), ErrorCode::kParse, {"base", "a", "root"});

  // A floating joint below the root (the root has geometry).
  expect_refused(R"(<robot name="bad"><link name="base"><inertial><mass value="1"/>
      <inertia ixx="1" ixy="0" ixz="0" iyy="1" iyz="0" izz="1"/></inertial></link>
      <link name="a"/><joint name="loose" type="floating"><parent link="base"/>
      <child link="a"/></joint></robot>)",
                 ErrorCode::kUnsupported, {"loose", "floating"});

  // A cycle beside the root.
  expect_refused(robot_with(R"(<link name="b"/>
      <joint name="ab" type="fixed"><parent link="a"/><child link="b"/></joint>
      <joint name="ba" type="fixed"><parent link="b"/><child link="a"/></joint>)"),
                 ErrorCode::kParse, {"cycle"});

  // A mimic of a joint that does not exist.
  expect_refused(robot_with(R"(<joint name="copycat" type="revolute">
      <parent link="base"/><child link="a"/><axis xyz="0 0 1"/>
      <limit lower="-1" upper="1" effort="1" velocity="1"/><mimic joint="ghost"/></joint>)"),
                 ErrorCode::kParse, {"copycat", "ghost"});
}

// Parsing routes urdfdom's messages into the error and leaves console_bridge as it found it.
TEST(RobotModelTest, ConsoleBridgeIsLeftAsFound) {
  struct Counter final : console_bridge::OutputHandler {
    void log(const std::string&, console_bridge::LogLevel, const char*, int) override { ++n; }
    int n = 0;
  };
  static Counter counter;  // console_bridge may keep a pointer to it as its "previous" handler
  const console_bridge::LogLevel level = console_bridge::getLogLevel();
  console_bridge::useOutputHandler(&counter);
  console_bridge::setLogLevel(console_bridge::CONSOLE_BRIDGE_LOG_DEBUG);

  const auto model = RobotModel::from_urdf_string(robot_with(""));  // two roots
  ASSERT_FALSE(model.ok());
  EXPECT_THAT(model.error().message, HasSubstr("Two root links"));  // urdfdom's words
  EXPECT_EQ(counter.n, 0);
  EXPECT_EQ(console_bridge::getOutputHandler(), &counter);
  EXPECT_EQ(console_bridge::getLogLevel(), console_bridge::CONSOLE_BRIDGE_LOG_DEBUG);
  CONSOLE_BRIDGE_logDebug("robot_model_test: a message after parsing");
  EXPECT_EQ(counter.n, 1);

  // The handler the parse used stays valid if console_bridge hands it back.
  console_bridge::restorePreviousOutputHandler();
  EXPECT_NE(console_bridge::getOutputHandler(), nullptr);
  console_bridge::setLogLevel(console_bridge::CONSOLE_BRIDGE_LOG_ERROR);
  CONSOLE_BRIDGE_logError(
      "robot_model_test: this line is expected (printed by the restored handler)");
  console_bridge::useOutputHandler(&counter);
  console_bridge::setLogLevel(level);
}

TEST(RobotModelTest, FileErrorsNameTheFile) {
  const std::string path =
      (std::filesystem::temp_directory_path() / "skinbus_robot_model_test_bad.urdf").string();
  {
    std::ofstream out(path);
    out << "<robot name=\"bad\"><link name=\"x\"/><link name=\"y\"/></robot>";
  }
  const auto model = RobotModel::from_urdf_file(path);
  std::filesystem::remove(path);
  ASSERT_FALSE(model.ok());
  EXPECT_EQ(model.error().code, ErrorCode::kParse);
  EXPECT_THAT(model.error().message, HasSubstr(path));
}

TEST(RobotModelTest, JointTypeNames) {
  EXPECT_STREQ(joint_type_name(JointType::kFixed), "fixed");
  EXPECT_STREQ(joint_type_name(JointType::kRevolute), "revolute");
  EXPECT_STREQ(joint_type_name(JointType::kContinuous), "continuous");
  EXPECT_STREQ(joint_type_name(JointType::kPrismatic), "prismatic");
}

// ---- The project's own robot. ----

class SkinbotTest : public ::testing::Test {
 protected:
  void SetUp() override {
    auto model = RobotModel::from_urdf_file(skinbot_path());
    ASSERT_TRUE(model.ok()) << model.error().to_string();
    model_ = std::move(model).value();
  }
  std::vector<Pose> fk(const std::vector<double>& q) const {
    std::vector<Pose> poses(model_.link_count());
    const Status s = model_.forward_kinematics(q, poses);
    EXPECT_TRUE(s.ok()) << s.error().to_string();
    return poses;
  }
  const Pose& pose_of(const std::vector<Pose>& poses, const char* link) const {
    const int i = model_.find_link(link);
    EXPECT_GE(i, 0) << link;
    return poses[i < 0 ? 0 : i];
  }
  std::vector<double> q_with(std::initializer_list<std::pair<const char*, double>> values) const {
    std::vector<double> q(model_.joint_count(), 0.0);
    for (const auto& [name, value] : values) {
      const int j = model_.find_joint(name);
      EXPECT_GE(j, 0) << name;
      if (j >= 0) q[j] = value;
    }
    return q;
  }

  RobotModel model_;
};

TEST_F(SkinbotTest, NamesAndTree) {
  EXPECT_EQ(model_.name(), "skinbot");
  EXPECT_EQ(model_.link(0).name, "pelvis");
  EXPECT_EQ(model_.link_count(), 13);
  const std::vector<std::string> expected = {"waist_yaw_joint",
                                             "left_shoulder_pitch_joint",
                                             "left_shoulder_roll_joint",
                                             "left_shoulder_yaw_joint",
                                             "left_elbow_joint",
                                             "left_wrist_joint",
                                             "right_shoulder_pitch_joint",
                                             "right_shoulder_roll_joint",
                                             "right_shoulder_yaw_joint",
                                             "right_elbow_joint",
                                             "right_wrist_joint"};
  ASSERT_EQ(model_.joint_count(), static_cast<int>(expected.size()));
  for (int j = 0; j < model_.joint_count(); ++j) EXPECT_EQ(model_.joint_name(j), expected[j]);
  for (const char* side : {"left", "right"}) {
    const std::string s = side;
    EXPECT_EQ(model_.link(model_.find_link(s + "_hand_link")).joint.type, JointType::kContinuous);
    EXPECT_FALSE(model_.joint_limits(model_.find_joint(s + "_wrist_joint")).bounded);
    EXPECT_TRUE(model_.joint_limits(model_.find_joint(s + "_elbow_joint")).bounded);
    EXPECT_EQ(model_.link(model_.link(model_.find_link(s + "_forearm_link")).parent).name,
              s + "_upper_arm_link");
  }
  EXPECT_EQ(model_.link(model_.find_link("head_link")).joint.type, JointType::kFixed);
}

TEST_F(SkinbotTest, DocumentedGeometryAtZero) {
  const std::vector<Pose> p = fk(std::vector<double>(model_.joint_count(), 0.0));
  expect_point_near(pose_of(p, "torso_link").translation_mm, 0, 0, 100, "torso");
  expect_point_near(pose_of(p, "head_link").translation_mm, 0, 0, 600, "head");
  for (const double sign : {1.0, -1.0}) {
    const std::string s = sign > 0 ? "left" : "right";
    const Pose& shoulder = pose_of(p, (s + "_upper_arm_link").c_str());
    expect_point_near(shoulder.translation_mm, 0, sign * 200, 500, s + " shoulder");
    const Pose& forearm = pose_of(p, (s + "_forearm_link").c_str());
    expect_point_near(forearm.translation_mm, 0, sign * 200, 220, s + " elbow");
    EXPECT_NEAR((forearm.rotation - Eigen::Matrix3d::Identity()).norm(), 0.0, 1e-15);
    // The forearm cylinder's end (x = 250 mm) is forward of the elbow.
    expect_point_near(forearm.apply({250, 0, 0}), 250, sign * 200, 220, s + " forearm end");
    expect_point_near(pose_of(p, (s + "_hand_link").c_str()).translation_mm, 260, sign * 200, 220,
                      s + " wrist");
  }
  // The chest centre (x = 110 mm in the torso) is 100 mm higher in the pelvis frame.
  expect_point_near(pose_of(p, "torso_link").apply({110, 0, 240}), 110, 0, 340, "chest");
}

TEST_F(SkinbotTest, DocumentedJointDirections) {
  // Waist yaw by 90 degrees turns the chest to +y.
  std::vector<Pose> p = fk(q_with({{"waist_yaw_joint", M_PI / 2}}));
  expect_point_near(pose_of(p, "torso_link").apply({110, 0, 240}), 0, 110, 340, "chest turned");
  // Elbow at +pi/2: the arm hangs straight, the wrist 260 mm below the elbow.
  p = fk(q_with({{"left_elbow_joint", M_PI / 2}}));
  expect_point_near(pose_of(p, "left_hand_link").translation_mm, 0, 200, -40, "straight arm");
  // Shoulder roll +pi/2 lifts the left arm sideways (outward, +y).
  p = fk(q_with({{"left_shoulder_roll_joint", M_PI / 2}}));
  expect_point_near(pose_of(p, "left_forearm_link").translation_mm, 0, 480, 500, "abducted");
  // Shoulder pitch -pi/2 lifts the arm forward: the elbow 280 mm in front of the shoulder.
  p = fk(q_with({{"right_shoulder_pitch_joint", -M_PI / 2}}));
  expect_point_near(pose_of(p, "right_forearm_link").translation_mm, 280, -200, 500, "raised");
}

// The facts in the file's header comment that the tiling generator relies on, as the file
// states them.
TEST_F(SkinbotTest, FileCarriesTheDocumentedShapes) {
  const std::string text = read_text(skinbot_path());
  EXPECT_THAT(text, HasSubstr("part of skinbus"));
  for (const char* side : {"left", "right"}) {
    const std::string open = "<link name=\"" + std::string(side) + "_forearm_link\">";
    const std::size_t begin = text.find(open);
    ASSERT_NE(begin, std::string::npos) << open;
    const std::string block = text.substr(begin, text.find("</link>", begin) - begin);
    EXPECT_THAT(block, HasSubstr("<origin xyz=\"0.135 0 0\" rpy=\"0 1.5707963267948966 0\"/>"));
    EXPECT_THAT(block, HasSubstr("<cylinder radius=\"0.045\" length=\"0.23\"/>"));
  }
  const std::size_t torso = text.find("<link name=\"torso_link\">");
  ASSERT_NE(torso, std::string::npos);
  const std::string block = text.substr(torso, text.find("</link>", torso) - torso);
  EXPECT_THAT(block, HasSubstr("<origin xyz=\"0 0 0.24\" rpy=\"0 0 0\"/>"));
  EXPECT_THAT(block, HasSubstr("<box size=\"0.22 0.32 0.44\"/>"));
}

}  // namespace
}  // namespace skinbus::body_map
