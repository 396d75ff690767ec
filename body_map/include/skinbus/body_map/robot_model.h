// skinbus/body_map/robot_model.h: a robot's kinematic tree from URDF, and forward kinematics.
//
// A RobotModel is read once from a URDF file (urdfdom) and is immutable afterwards; forward
// kinematics then allocates nothing and costs one small matrix product per link, so it can run
// every sample period for every link.
//
// Frames and units:
// - The model's frame is its root link's frame ("base"). A floating joint above the root (a
//   "world" link joined by a floating joint) is not part of the model: the root's pose in the
//   world is the caller's (odometry), and the floating link is dropped.
// - Lengths are millimetres (URDF metres x 1000). Joint positions `q` are radians for revolute
//   and continuous joints and millimetres for prismatic ones, one entry per movable joint in the
//   model's joint order (joint_name(j)). Mimic joints follow their leader and have no entry.
// - Links are stored in topological order: index 0 is the root and every link's parent has a
//   smaller index. "Model order" (of links and of the movable joints, i.e. of q) is depth-first
//   from the root, a link's children taken in joint-name order.
#pragma once

#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "skinbus/body_map/pose.h"
#include "skinbus/common/result.h"

namespace skinbus::body_map {

enum class JointType { kFixed, kRevolute, kContinuous, kPrismatic };

// Returns "fixed", "revolute", "continuous" or "prismatic".
const char* joint_type_name(JointType type);

// How a link hangs from its parent: p_parent = origin * motion(q) * p_link.
struct LinkJoint {
  std::string joint_name;  // the URDF joint's name; empty for the root
  JointType type = JointType::kFixed;
  Pose origin;                                      // joint frame in the parent link's frame
  Eigen::Vector3d axis = Eigen::Vector3d::UnitX();  // unit, in the joint frame
  int q_index = -1;  // entry of q that drives it (the leader's for a mimic joint); -1 if fixed
  double mimic_multiplier = 1.0;  // position = multiplier * q[q_index] + offset
  double mimic_offset = 0.0;      // rad or mm
};

struct Link {
  std::string name;
  int parent = -1;  // index of the parent link; -1 for the root
  LinkJoint joint;
};

struct JointLimits {
  double lower = 0, upper = 0;  // rad or mm; equal for continuous joints (no limits)
  bool bounded = false;
};

class RobotModel {
 public:
  // Reads a URDF file or text. Errors: the file is missing or not URDF (kNotFound, kParse),
  // several root links or a cycle (kParse), a planar joint or a floating joint below the root
  // (kUnsupported), a zero joint axis or a non-finite number (kInvalidArgument).
  static Result<RobotModel> from_urdf_file(const std::string& path);
  static Result<RobotModel> from_urdf_string(const std::string& xml);

  const std::string& name() const { return name_; }

  int link_count() const { return static_cast<int>(links_.size()); }
  const Link& link(int i) const { return links_[i]; }
  // Index of the link called `name`, or -1.
  int find_link(std::string_view name) const;

  // Movable joints (the entries of q), in model order.
  int joint_count() const { return static_cast<int>(joint_names_.size()); }
  const std::string& joint_name(int j) const { return joint_names_[j]; }
  const JointLimits& joint_limits(int j) const { return limits_[j]; }
  // Index of the movable joint called `name` in q, or -1 (also -1 for fixed and mimic joints).
  int find_joint(std::string_view name) const;
  // Whether movable joint j is prismatic: its entry of q is in mm (ROS 2 joint states carry
  // metres). Its own type only: a prismatic mimic follower does not make a revolute leader one.
  bool joint_is_prismatic(int j) const { return prismatic_[j]; }
  // OK when every name is a movable joint of this robot, else kNotFound naming the first that is
  // not ("joint 'x' is not a movable joint of robot 'r'": absent, fixed or a mimic follower).
  Status check_joint_names(std::span<const std::string> names) const;

  // The pose of every link in the root frame for joint positions `q` (joint_count() entries):
  // link_poses[i] maps link i's points into the root frame. Errors: wrong sizes
  // (kInvalidArgument), a non-finite q (kInvalidArgument). Limits are not enforced. Allocates
  // nothing.
  Status forward_kinematics(std::span<const double> q, std::span<Pose> link_poses) const;

  // The pose of one link in the root frame: walks only that link's chain (but checks all of q).
  // Errors: as forward_kinematics, and a link index out of range (kInvalidArgument).
  Result<Pose> link_pose(std::span<const double> q, int link) const;

 private:
  std::string name_;
  std::vector<Link> links_;
  std::vector<std::string> joint_names_;
  std::vector<JointLimits> limits_;
  std::vector<bool> prismatic_;  // per movable joint
};

}  // namespace skinbus::body_map
