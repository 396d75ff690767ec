// Reading a URDF with urdfdom into a RobotModel, and forward kinematics.
//
// Link order ("model order"): a depth-first, pre-order walk from the root, visiting the children
// of a link in the order of the names of the joints that hold them (byte-wise, as urdfdom's joint
// map sorts them). The order is therefore a property of the names alone, not of the order of the
// elements in the file. The movable joints (the entries of q) are numbered in that same order: the
// joint above link i comes before the joint above link k whenever i < k (mimic joints have no
// entry). For the Unitree G1 this is also the order of the joints in the vendor's file (left leg,
// right leg, waist, left arm, right arm).
#include "skinbus/body_map/robot_model.h"

#include "skinbus/common/text_file.h"

#include <console_bridge/console.h>
#include <urdf_parser/urdf_parser.h>

#include <atomic>
#include <cmath>
#include <exception>
#include <filesystem>
#include <fstream>
#include <map>
#include <mutex>
#include <sstream>
#include <unordered_map>
#include <utility>

namespace skinbus::body_map {
namespace {

constexpr double kMmPerM = 1000.0;

// Collects what urdfdom reports through console_bridge while a parse runs, so the reason for a
// failure comes back in the Error instead of on stderr. One instance lives for the whole process:
// console_bridge keeps the handler it replaced ("previous") and may install it again later, so it
// must never dangle. When no parse is running it prints like console_bridge's own handler.
class LogCapture final : public console_bridge::OutputHandler {
 public:
  void log(const std::string& text, console_bridge::LogLevel level, const char* filename,
           int line) override {
    if (!armed_.load()) {
      fallback_.log(text, level, filename, line);
      return;
    }
    if (level < console_bridge::CONSOLE_BRIDGE_LOG_ERROR) return;
    if (!text_.empty()) text_ += "; ";
    text_ += text;
  }
  void arm() {
    text_.clear();
    armed_.store(true);
  }
  std::string disarm() {
    armed_.store(false);
    return std::exchange(text_, {});
  }

 private:
  std::atomic<bool> armed_{false};
  std::string text_;
  console_bridge::OutputHandlerSTD fallback_;
};

// Routes console_bridge's output into the LogCapture until release(), then gives the caller's
// handler and log level back. console_bridge is process-wide, so parses are serialised (and an
// error another thread logs meanwhile lands in the parse's error text).
class ScopedLogCapture {
 public:
  ScopedLogCapture() : lock_(mutex()), saved_level_(console_bridge::getLogLevel()) {
    capture().arm();
    console_bridge::useOutputHandler(&capture());
    console_bridge::setLogLevel(console_bridge::CONSOLE_BRIDGE_LOG_ERROR);
  }
  ~ScopedLogCapture() { release(); }
  ScopedLogCapture(const ScopedLogCapture&) = delete;
  ScopedLogCapture& operator=(const ScopedLogCapture&) = delete;

  // Ends the capture (the first call only) and returns the errors logged meanwhile.
  std::string release() {
    if (released_) return {};
    released_ = true;
    console_bridge::setLogLevel(saved_level_);
    console_bridge::restorePreviousOutputHandler();
    return capture().disarm();
  }

 private:
  static std::mutex& mutex() {
    static std::mutex m;
    return m;
  }
  static LogCapture& capture() {
    static LogCapture& c = *new LogCapture;  // never destroyed: see LogCapture
    return c;
  }
  std::lock_guard<std::mutex> lock_;
  console_bridge::LogLevel saved_level_;
  bool released_ = false;
};

// Parses `xml` with urdfdom without printing. Returns the model, or an error carrying urdfdom's
// messages.
Result<urdf::ModelInterfaceSharedPtr> parse_urdf(const std::string& xml) {
  ScopedLogCapture capture;
  urdf::ModelInterfaceSharedPtr model;
  std::string thrown;
  try {
    model = urdf::parseURDF(xml);
  } catch (const std::exception& e) {
    thrown = e.what();
  } catch (...) {
    thrown = "unknown exception from urdfdom";
  }
  std::string why = capture.release();
  if (model && model->getRoot()) return model;
  if (!thrown.empty()) why += (why.empty() ? "" : "; ") + thrown;
  if (why.empty()) why = "urdfdom gave no reason";
  return make_error(ErrorCode::kParse, "not a valid URDF robot description: " + why);
}

bool is_finite(const Eigen::Vector3d& v) {
  return v.allFinite();
}

// The joint frame in the parent link's frame, in millimetres. The rotation is built from urdfdom's
// quaternion (which it computed from the URDF's rpy with R = Rz(yaw) Ry(pitch) Rx(roll), the same
// convention as rotation_from_rpy): going back through rpy would lose accuracy near pitch = +-pi/2,
// where urdfdom's getRPY snaps the pitch.
Pose to_pose(const urdf::Pose& p) {
  Pose out;
  const urdf::Rotation& r = p.rotation;
  out.rotation = Eigen::Quaterniond(r.w, r.x, r.y, r.z).normalized().toRotationMatrix();
  out.translation_mm = Eigen::Vector3d(p.position.x, p.position.y, p.position.z) * kMmPerM;
  return out;
}

bool is_movable(JointType type) {
  return type != JointType::kFixed;
}

// Millimetres per URDF unit of a joint's position: 1000 for prismatic (metres), 1 for angles.
double position_scale(JointType type) {
  return type == JointType::kPrismatic ? kMmPerM : 1.0;
}

// The link's pose in its parent's frame with the joint at `position` (rad or mm).
Pose joint_transform(const LinkJoint& joint, double position) {
  switch (joint.type) {
    case JointType::kRevolute:
    case JointType::kContinuous:
      return {joint.origin.rotation * Eigen::AngleAxisd(position, joint.axis).toRotationMatrix(),
              joint.origin.translation_mm};
    case JointType::kPrismatic:
      return {joint.origin.rotation,
              joint.origin.translation_mm + joint.origin.rotation * (joint.axis * position)};
    case JointType::kFixed:
      break;
  }
  return joint.origin;
}

double joint_position(const LinkJoint& joint, std::span<const double> q) {
  if (joint.q_index < 0) return 0.0;
  return joint.mimic_multiplier * q[joint.q_index] + joint.mimic_offset;
}

// A mimic relation as written in the URDF, converted to model units, before it is resolved to a
// joint that has an entry in q.
struct PendingMimic {
  int link = -1;
  std::string leader;
  double multiplier = 1.0;
  double offset = 0.0;
};

}  // namespace

const char* joint_type_name(JointType type) {
  switch (type) {
    case JointType::kFixed:
      return "fixed";
    case JointType::kRevolute:
      return "revolute";
    case JointType::kContinuous:
      return "continuous";
    case JointType::kPrismatic:
      return "prismatic";
  }
  return "unknown";
}

Result<RobotModel> RobotModel::from_urdf_file(const std::string& path) {
  std::error_code ec;
  if (!std::filesystem::exists(path, ec)) {
    return make_error(ErrorCode::kNotFound, "URDF file '" + path + "' does not exist");
  }
  if (!std::filesystem::is_regular_file(path, ec)) {
    return make_error(ErrorCode::kNotFound, "URDF file '" + path + "' is not a regular file");
  }
  Result<std::string> text = read_text_file(path, "URDF file");  // bounded (64 MiB)
  if (!text.ok()) return text.error();
  Result<RobotModel> model = from_urdf_string(text.value());
  if (!model.ok()) {
    return make_error(model.error().code, "URDF file '" + path + "': " + model.error().message);
  }
  return model;
}

Result<RobotModel> RobotModel::from_urdf_string(const std::string& xml) {
  Result<urdf::ModelInterfaceSharedPtr> parsed = parse_urdf(xml);
  if (!parsed.ok()) return parsed.error();
  const urdf::ModelInterface& urdf_model = **parsed;
  const std::string robot = "robot '" + urdf_model.name_ + "'";

  // A bare root (no geometry, no inertia) whose only joint is floating is a "world" link: drop it
  // and its joint, and root the model at the floating joint's child.
  urdf::LinkConstSharedPtr root = urdf_model.getRoot();
  const urdf::Joint* dropped_joint = nullptr;
  if (!root->visual && root->visual_array.empty() && !root->collision &&
      root->collision_array.empty() && !root->inertial && root->child_joints.size() == 1 &&
      root->child_joints[0]->type == urdf::Joint::FLOATING) {
    dropped_joint = root->child_joints[0].get();
  }
  const std::string root_name = dropped_joint ? dropped_joint->child_link_name : root->name;

  // The children of every link, in joint-name order (urdfdom's joint map is sorted by name).
  std::map<std::string, std::vector<const urdf::Joint*>> children;
  std::unordered_map<std::string, const urdf::Joint*> parent_joint;
  for (const auto& [joint_name, joint] : urdf_model.joints_) {
    switch (joint->type) {
      case urdf::Joint::REVOLUTE:
      case urdf::Joint::CONTINUOUS:
      case urdf::Joint::PRISMATIC:
      case urdf::Joint::FIXED:
        break;
      case urdf::Joint::PLANAR:
        return make_error(
            ErrorCode::kUnsupported,
            robot + ": joint '" + joint_name + "' is planar; planar joints are not supported");
      case urdf::Joint::FLOATING:
        if (joint.get() == dropped_joint) continue;
        return make_error(ErrorCode::kUnsupported,
                          robot + ": joint '" + joint_name + "' is floating and joins '" +
                              joint->parent_link_name + "' to '" + joint->child_link_name +
                              "'; a floating joint is supported only above the root, from a "
                              "world link with no geometry and no other joint");
      default:
        return make_error(ErrorCode::kParse,
                          robot + ": joint '" + joint_name + "' has an unknown type");
    }
    const auto [it, inserted] = parent_joint.emplace(joint->child_link_name, joint.get());
    if (!inserted) {
      return make_error(ErrorCode::kParse, robot + ": link '" + joint->child_link_name +
                                               "' is the child of two joints, '" +
                                               it->second->name + "' and '" + joint_name + "'");
    }
    children[joint->parent_link_name].push_back(joint.get());
  }

  RobotModel model;
  model.name_ = urdf_model.name_;
  std::vector<PendingMimic> mimics;
  std::unordered_map<std::string, int> link_of_joint;

  // Depth-first, pre-order: a link is numbered when it is popped, after its parent.
  struct Visit {
    const urdf::Joint* joint;  // nullptr for the root
    const std::string* link;
    int parent;
  };
  std::vector<Visit> stack{{nullptr, &root_name, -1}};
  while (!stack.empty()) {
    const Visit visit = stack.back();
    stack.pop_back();
    const int index = static_cast<int>(model.links_.size());
    Link link;
    link.name = *visit.link;
    link.parent = visit.parent;
    if (const urdf::Joint* j = visit.joint) {
      const std::string where = robot + ": joint '" + j->name + "'";
      LinkJoint& lj = link.joint;
      lj.joint_name = j->name;
      lj.type = j->type == urdf::Joint::REVOLUTE     ? JointType::kRevolute
                : j->type == urdf::Joint::CONTINUOUS ? JointType::kContinuous
                : j->type == urdf::Joint::PRISMATIC  ? JointType::kPrismatic
                                                     : JointType::kFixed;
      lj.origin = to_pose(j->parent_to_joint_origin_transform);
      if (!is_finite(lj.origin.translation_mm) || !lj.origin.rotation.allFinite()) {
        return make_error(ErrorCode::kInvalidArgument,
                          where + " has a non-finite origin (in millimetres)");
      }
      if (is_movable(lj.type)) {
        const Eigen::Vector3d axis(j->axis.x, j->axis.y, j->axis.z);
        const double norm = axis.norm();
        if (!std::isfinite(norm)) {
          return make_error(ErrorCode::kInvalidArgument, where + " has a non-finite axis");
        }
        if (!(norm > 1e-12)) {
          return make_error(ErrorCode::kInvalidArgument, where + " has a zero axis");
        }
        lj.axis = axis / norm;
        if (j->mimic && !j->mimic->joint_name.empty()) {
          // URDF: position = multiplier * leader + offset, each in its own joint's unit.
          const double multiplier = j->mimic->multiplier, offset = j->mimic->offset;
          if (!std::isfinite(multiplier) || !std::isfinite(offset)) {
            return make_error(ErrorCode::kInvalidArgument,
                              where + " has a non-finite mimic multiplier or offset");
          }
          mimics.push_back({index, j->mimic->joint_name, multiplier, offset});
        }
      }
      link_of_joint.emplace(j->name, index);
    }
    model.links_.push_back(std::move(link));
    const auto kids = children.find(*visit.link);
    if (kids == children.end()) continue;
    for (auto it = kids->second.rbegin(); it != kids->second.rend(); ++it) {
      stack.push_back({*it, &(*it)->child_link_name, index});
    }
  }

  // urdfdom has checked that exactly one link has no parent, so a link the walk did not reach
  // hangs in a cycle of joints.
  const std::size_t expected = urdf_model.links_.size() - (dropped_joint ? 1 : 0);
  if (model.links_.size() != expected) {
    for (const auto& [link_name, link] : urdf_model.links_) {
      if (link.get() == root.get() && dropped_joint) continue;
      if (model.find_link(link_name) < 0) {
        return make_error(ErrorCode::kParse, robot + ": link '" + link_name +
                                                 "' cannot be reached from the root '" + root_name +
                                                 "' (its joints form a cycle)");
      }
    }
    return make_error(ErrorCode::kInternal, robot + ": link count mismatch after the tree walk");
  }

  // Movable joints that are not mimics get entries of q, in link order.
  std::vector<bool> is_mimic(model.links_.size(), false);
  for (const PendingMimic& m : mimics) is_mimic[m.link] = true;
  for (std::size_t i = 1; i < model.links_.size(); ++i) {
    LinkJoint& lj = model.links_[i].joint;
    if (!is_movable(lj.type) || is_mimic[i]) continue;
    const urdf::JointConstSharedPtr j = urdf_model.getJoint(lj.joint_name);
    JointLimits limits;
    if (lj.type != JointType::kContinuous && j->limits) {
      const double scale = position_scale(lj.type);
      limits.lower = j->limits->lower * scale;
      limits.upper = j->limits->upper * scale;
      limits.bounded = true;
      if (!std::isfinite(limits.lower) || !std::isfinite(limits.upper)) {
        return make_error(ErrorCode::kInvalidArgument,
                          robot + ": joint '" + lj.joint_name + "' has non-finite limits");
      }
    }
    lj.q_index = model.joint_count();
    model.joint_names_.push_back(lj.joint_name);
    model.limits_.push_back(limits);
    model.prismatic_.push_back(lj.type == JointType::kPrismatic);
  }

  // Mimic joints: follow the chain of leaders to a joint with an entry in q, composing
  // position = multiplier * leader + offset in model units (rad or mm) along the way.
  for (const PendingMimic& m : mimics) {
    LinkJoint& follower = model.links_[m.link].joint;
    const std::string where = robot + ": mimic joint '" + follower.joint_name + "'";
    double multiplier = 1.0, offset = 0.0;  // follower = multiplier * current + offset
    int current = m.link;
    for (int hops = 0;; ++hops) {
      if (hops > model.link_count()) {
        return make_error(ErrorCode::kParse, where + " is part of a cycle of mimic joints");
      }
      const PendingMimic* step = nullptr;
      for (const PendingMimic& candidate : mimics) {
        if (candidate.link == current) step = &candidate;
      }
      if (!step) break;  // `current` has an entry in q
      const auto leader = link_of_joint.find(step->leader);
      if (leader == link_of_joint.end()) {
        return make_error(ErrorCode::kParse, where + " follows '" + step->leader +
                                                 "', which is not a joint of the model");
      }
      const LinkJoint& from = model.links_[current].joint;
      const LinkJoint& to = model.links_[leader->second].joint;
      if (!is_movable(to.type)) {
        return make_error(ErrorCode::kParse,
                          where + " follows '" + step->leader + "', which is fixed");
      }
      const double scale = position_scale(from.type);
      offset += multiplier * step->offset * scale;
      multiplier *= step->multiplier * scale / position_scale(to.type);
      current = leader->second;
    }
    if (!std::isfinite(multiplier) || !std::isfinite(offset)) {
      return make_error(ErrorCode::kInvalidArgument,
                        where + " has a non-finite multiplier or offset in model units");
    }
    follower.q_index = model.links_[current].joint.q_index;
    follower.mimic_multiplier = multiplier;
    follower.mimic_offset = offset;
  }
  return model;
}

int RobotModel::find_link(std::string_view name) const {
  for (std::size_t i = 0; i < links_.size(); ++i) {
    if (links_[i].name == name) return static_cast<int>(i);
  }
  return -1;
}

int RobotModel::find_joint(std::string_view name) const {
  for (std::size_t j = 0; j < joint_names_.size(); ++j) {
    if (joint_names_[j] == name) return static_cast<int>(j);
  }
  return -1;
}

Status RobotModel::check_joint_names(std::span<const std::string> names) const {
  for (const std::string& n : names) {
    if (find_joint(n) < 0) {
      return make_error(ErrorCode::kNotFound,
                        "joint '" + n + "' is not a movable joint of robot '" + name_ + "'");
    }
  }
  return Status::Ok();
}

namespace {

Status check_q(std::span<const double> q, const std::vector<std::string>& joint_names,
               const std::string& robot_name) {
  if (q.size() != joint_names.size()) {
    return make_error(ErrorCode::kInvalidArgument,
                      "q has " + std::to_string(q.size()) + " entries but robot '" + robot_name +
                          "' has " + std::to_string(joint_names.size()) + " movable joints");
  }
  for (std::size_t j = 0; j < q.size(); ++j) {
    if (!std::isfinite(q[j])) {
      return make_error(ErrorCode::kInvalidArgument, "q[" + std::to_string(j) + "] for joint '" +
                                                         joint_names[j] + "' is not finite");
    }
  }
  return Status::Ok();
}

}  // namespace

Status RobotModel::forward_kinematics(std::span<const double> q, std::span<Pose> link_poses) const {
  if (Status s = check_q(q, joint_names_, name_); !s.ok()) return s;
  if (link_poses.size() != links_.size()) {
    return make_error(ErrorCode::kInvalidArgument, "link_poses has " +
                                                       std::to_string(link_poses.size()) +
                                                       " entries but robot '" + name_ + "' has " +
                                                       std::to_string(links_.size()) + " links");
  }
  if (links_.empty()) return Status::Ok();
  link_poses[0] = Pose{};
  for (std::size_t i = 1; i < links_.size(); ++i) {
    const Link& link = links_[i];
    link_poses[i] =
        link_poses[link.parent] * joint_transform(link.joint, joint_position(link.joint, q));
  }
  return Status::Ok();
}

Result<Pose> RobotModel::link_pose(std::span<const double> q, int link) const {
  if (Status s = check_q(q, joint_names_, name_); !s.ok()) return s.error();
  if (link < 0 || link >= link_count()) {
    return make_error(ErrorCode::kInvalidArgument, "link index " + std::to_string(link) +
                                                       " is outside robot '" + name_ + "' (" +
                                                       std::to_string(links_.size()) + " links)");
  }
  Pose pose;
  for (int i = link; i > 0; i = links_[i].parent) {
    const LinkJoint& joint = links_[i].joint;
    pose = joint_transform(joint, joint_position(joint, q)) * pose;
  }
  return pose;
}

}  // namespace skinbus::body_map
