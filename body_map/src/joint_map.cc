#include "skinbus/body_map/joint_map.h"

#include <algorithm>
#include <cmath>

namespace skinbus::body_map {

JointMap::JointMap(const RobotModel& robot, std::span<const std::string> names, PrismaticUnit unit)
    : robot_(&robot), names_(names.begin(), names.end()), unit_(unit) {
  entries_.resize(names_.size());
  covered_.assign(static_cast<std::size_t>(robot.joint_count()), false);
  const double metres = unit == PrismaticUnit::kMetres ? 1000.0 : 1.0;
  for (std::size_t i = 0; i < names_.size(); ++i) {
    Entry& e = entries_[i];
    for (int l = 1; l < robot.link_count(); ++l) {
      const LinkJoint& lj = robot.link(l).joint;
      if (lj.joint_name != names_[i] || lj.type == JointType::kFixed) continue;
      // A joint's own entry of q is the one named after it; a mimic follower shares its
      // leader's.
      const bool own = lj.q_index >= 0 && robot.joint_name(lj.q_index) == names_[i];
      e.kind = own ? Kind::kJoint : Kind::kMimic;
      e.q_index = own ? lj.q_index : -1;
      e.to_model = lj.type == JointType::kPrismatic ? metres : 1.0;
      break;
    }
    if (e.kind == Kind::kUnknown) ++unknown_;
    if (e.q_index < 0) continue;
    if (covered_[static_cast<std::size_t>(e.q_index)]) {
      e.q_index = -1;  // a name given twice: its first value counts
    } else {
      covered_[static_cast<std::size_t>(e.q_index)] = true;
    }
  }
}

bool JointMap::same_source(std::span<const std::string> names, PrismaticUnit unit) const {
  return robot_ != nullptr && unit == unit_ &&
         std::equal(names.begin(), names.end(), names_.begin(), names_.end());
}

Status JointMap::check_all_joints() const {
  if (robot_ == nullptr) return Status::Ok();
  return robot_->check_joint_names(names_);
}

int JointMap::apply(std::span<const double> positions, std::span<double> q) const {
  const std::size_t n = std::min(entries_.size(), positions.size());
  int set = 0;
  for (std::size_t i = 0; i < n; ++i) {
    const Entry& e = entries_[i];
    if (e.q_index < 0 || static_cast<std::size_t>(e.q_index) >= q.size()) continue;
    const double v = positions[i] * e.to_model;
    if (!std::isfinite(v)) continue;
    q[static_cast<std::size_t>(e.q_index)] = v;
    ++set;
  }
  return set;
}

}  // namespace skinbus::body_map
