// skinbus/body_map/joint_map.h: a source's joint names (a joint-state message, a trajectory's or a
// touch log's columns) mapped onto a robot model's joint positions q.
//
// Every place that turns "name = value" pairs into the q of RobotModel::forward_kinematics uses
// this one mapping, so that all of them agree on the rules:
// - A name that is a movable joint with an entry of q (RobotModel::find_joint) sets that entry.
// - A mimic joint (URDF <mimic>) has no entry of q: its position is always
//   multiplier * leader + offset (RobotModel's LinkJoint), for prismatic and revolute joints
//   alike. A mimic joint's name is known (not counted as unknown) but its value is not used; the
//   leader's value moves it. Joint-state publishers often send mimic joints too, and they then
//   agree with the leader anyway.
// - Any other name (absent from the robot, or a fixed joint) is unknown: its value is ignored and
//   counted (unknown_count()).
// - Continuous joints take their value as given (any finite angle, not wrapped).
// - Units: q is radians for revolute and continuous joints and millimetres for prismatic ones.
//   The source gives prismatic joints in millimetres (skinbus files) or metres (ROS 2
//   JointState), PrismaticUnit; everything else in radians.
// - A name given twice: its first value counts.
// - The result depends on the names and values only, not on their order.
#pragma once

#include <cstddef>
#include <span>
#include <string>
#include <vector>

#include "skinbus/body_map/robot_model.h"
#include "skinbus/common/result.h"

namespace skinbus::body_map {

enum class PrismaticUnit { kMillimetres, kMetres };

class JointMap {
 public:
  enum class Kind { kJoint, kMimic, kUnknown };

  JointMap() = default;
  // Maps `names` (in the source's order) onto `robot`'s q. `robot` must outlive the map.
  JointMap(const RobotModel& robot, std::span<const std::string> names, PrismaticUnit unit);

  std::size_t size() const { return names_.size(); }
  const std::vector<std::string>& names() const { return names_; }
  PrismaticUnit unit() const { return unit_; }
  // Whether this map was made for exactly these names (in this order) and unit: a caller that
  // receives the same names again and again keeps its map.
  bool same_source(std::span<const std::string> names, PrismaticUnit unit) const;

  Kind kind(std::size_t i) const { return entries_[i].kind; }
  // The entry of q that source name i sets, or -1 (a mimic joint, an unknown name, a repeat).
  int q_index(std::size_t i) const { return entries_[i].q_index; }
  // The factor from source name i's unit to the model's: 1000 for a prismatic joint (its own
  // type, also for a mimic follower) given in metres, else 1.
  double to_model(std::size_t i) const { return entries_[i].to_model; }
  // How many names are neither a joint nor a mimic joint of the robot.
  int unknown_count() const { return unknown_; }
  // Whether some source name sets entry j of q.
  bool covers(int j) const {
    return j >= 0 && j < static_cast<int>(covered_.size()) && covered_[j];
  }
  // OK when every name sets an entry of q; else kNotFound naming the first that does not
  // ("joint 'x' is not a movable joint of robot 'r'": absent, fixed or a mimic follower), for
  // sources that must drive the robot completely (trajectory files).
  Status check_all_joints() const;

  // q[q_index(i)] = positions[i] * to_model(i) for every name that has an entry of q and whose
  // value is finite in model units (NaN, Inf or an overflow leaves the entry as it was); the
  // other entries of q keep their values. Pairs beyond the shorter of names and positions are
  // ignored; q must have robot.joint_count() entries. Returns how many entries were set.
  int apply(std::span<const double> positions, std::span<double> q) const;

 private:
  struct Entry {
    Kind kind = Kind::kUnknown;
    int q_index = -1;
    double to_model = 1.0;
  };
  const RobotModel* robot_ = nullptr;
  std::vector<std::string> names_;
  PrismaticUnit unit_ = PrismaticUnit::kMillimetres;
  std::vector<Entry> entries_;
  std::vector<bool> covered_;  // per entry of q
  int unknown_ = 0;
};

}  // namespace skinbus::body_map
