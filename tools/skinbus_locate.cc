// skinbus-locate: where a patch-local point (node, u, v) lies on the robot, in the base frame.
//
//   skinbus-locate --map skin.yaml 3 12.5 -20
//   echo "3 12.5 -20" | skinbus-locate --map skin.yaml --joints traj.csv --time 1.5 -
#include <CLI/CLI.hpp>

#include <cstdio>
#include <iostream>
#include <optional>
#include <sstream>
#include <string>
#include <vector>

#include "skinbus/body_map/joint_map.h"
#include "skinbus/body_map/joint_trajectory.h"
#include "skinbus/body_map/robot_model.h"
#include "skinbus/body_map/skin_map.h"
#include "skinbus/common/line_reader.h"
#include "tool_util.h"

using namespace skinbus;

int main(int argc, char** argv) {
  CLI::App app{
      "skinbus-locate: maps patch-local coordinates to the robot's base frame, as the host\n"
      "aggregator places contacts: the point (u, v) on the patch's surface (its geometry in the\n"
      "skin map), through the patch's pose on its link, through forward kinematics at the joint\n"
      "positions of a trajectory file at --time (or the zero pose). Prints one line a point:\n"
      "  node link x_mm y_mm z_mm nx ny nz\n"
      "Give the point as arguments (NODE U_MM V_MM) or '-' to read such lines from stdin; a\n"
      "stdin line of four numbers, T_S NODE U_MM V_MM, is placed at the trajectory's time T_S\n"
      "instead of --time (for contacts of a moving robot).\n\n"
      "Example:\n"
      "  skinbus-locate --map skin.yaml --joints arms.csv --time 2.0 3 12.5 -20"};
  std::string map_path, robot_path, joints_path;
  double time_s = 0;
  std::vector<std::string> point;
  app.add_option("--map", map_path, "skin map (YAML)")->required();
  app.add_option("--robot", robot_path, "robot (URDF); default: the map's");
  app.add_option("--joints", joints_path, "joint trajectory (CSV: time_s,<joint>,...)");
  app.add_option("--time", time_s, "time into the trajectory, s")->capture_default_str();
  app.add_option("point", point, "NODE U_MM V_MM, or '-' for stdin");
  CLI11_PARSE(app, argc, argv);
  auto map = body_map::load_skin_map_file(map_path);
  if (!map) {
    return skinbus::tools::fail("skinbus-locate", map.error().to_string(), 1);
  }
  if (robot_path.empty()) robot_path = body_map::path_beside(map_path, map->robot);
  std::unique_ptr<body_map::RobotModel> robot;
  std::vector<body_map::Pose> poses;
  if (!robot_path.empty()) {
    auto r = body_map::RobotModel::from_urdf_file(robot_path);
    if (!r) {
      return skinbus::tools::fail("skinbus-locate", r.error().to_string(), 1);
    }
    robot = std::make_unique<body_map::RobotModel>(std::move(*r));
  }
  std::optional<body_map::JointTrajectory> traj;
  body_map::JointMap columns;  // the trajectory's columns onto the robot's q
  if (!joints_path.empty()) {
    if (!robot) {
      return skinbus::tools::fail("skinbus-locate", "--joints needs a robot (the map's or --robot)",
                                  2);
    }
    auto t = body_map::load_joint_trajectory(joints_path);
    if (!t) {
      return skinbus::tools::fail("skinbus-locate", t.error().to_string(), 1);
    }
    columns = body_map::JointMap(*robot, t->names, body_map::PrismaticUnit::kMillimetres);
    if (Status st = columns.check_all_joints(); !st.ok()) {
      return skinbus::tools::fail("skinbus-locate", st.error().message, 2);
    }
    traj = std::move(*t);
  }
  // Forward kinematics at trajectory time `t_s` (the zero pose without a trajectory).
  auto pose_at = [&](double t_s) -> bool {
    if (!robot) return true;
    std::vector<double> q(static_cast<std::size_t>(robot->joint_count()), 0.0);
    if (traj) {
      std::vector<double> v(traj->names.size());
      traj->sample(t_s, v);
      columns.apply(v, q);
    }
    poses.resize(static_cast<std::size_t>(robot->link_count()));
    if (Status st = robot->forward_kinematics(q, poses); !st.ok()) {
      return skinbus::tools::fail("skinbus-locate", st.error().to_string(), false);
    }
    return true;
  };
  if (!pose_at(time_s)) return 1;
  auto locate = [&](int node, double u, double v) {
    const body_map::PatchPlacement* p = map->find_node(node);
    if (p == nullptr) {
      std::fprintf(stderr, "skinbus-locate: node %d is not in the map\n", node);
      return false;
    }
    body_map::SurfacePoint s = body_map::link_surface_point(*p, u, v, 0.0);
    if (robot) {
      const int l = robot->find_link(p->link);
      if (l >= 0) {
        s.point_mm = poses[static_cast<std::size_t>(l)].apply(s.point_mm);
        s.normal = poses[static_cast<std::size_t>(l)].rotation * s.normal;
      }
    }
    std::printf("%d %s %.3f %.3f %.3f %.6f %.6f %.6f\n", node, p->link.c_str(), s.point_mm.x(),
                s.point_mm.y(), s.point_mm.z(), s.normal.x(), s.normal.y(), s.normal.z());
    return true;
  };
  bool ok = true;
  if (point.size() == 1 && point[0] == "-") {
    std::string line;
    for (BoundedLine got; (got = getline_bounded(std::cin, line, 4096)) != BoundedLine::kEof;) {
      if (got == BoundedLine::kTooLong) {
        std::fprintf(stderr,
                     "skinbus-locate: a line of standard input is longer than 4096 "
                     "bytes: skipped\n");
        ok = false;
        continue;
      }
      std::istringstream in(line);
      std::vector<double> f;
      double x;
      while (in >> x) f.push_back(x);
      if (f.size() == 4) {  // T_S NODE U V
        if (!pose_at(f[0])) return 1;
        ok = locate(static_cast<int>(f[1]), f[2], f[3]) && ok;
      } else if (f.size() == 3) {
        ok = locate(static_cast<int>(f[0]), f[1], f[2]) && ok;
      } else {
        std::fprintf(
            stderr, "skinbus-locate: expected 'NODE U_MM V_MM' or 'T_S NODE U_MM V_MM', got '%s'\n",
            line.c_str());
        ok = false;
      }
    }
  } else if (point.size() == 3) {
    try {
      ok = locate(std::stoi(point[0]), std::stod(point[1]), std::stod(point[2]));
    } catch (const std::exception&) {
      return skinbus::tools::fail("skinbus-locate", "NODE U_MM V_MM must be numbers", 2);
    }
  } else {
    return skinbus::tools::fail("skinbus-locate", "give NODE U_MM V_MM or '-' (see --help)", 2);
  }
  return ok ? 0 : 1;
}
