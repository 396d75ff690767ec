// skinbus-touchsim: a simulated calibration session on a humanoid, with the true poses known.
//
//   skinbus-touchsim --robot body_map/robots/skinbot.urdf --out-dir session/
//   skinbus-calibrate --map session/initial.yaml --touches session/touches.csv
//       --truth session/truth.yaml --out session/calibrated.yaml
#include <CLI/CLI.hpp>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>

#include "skinbus/body_map/calibration_sim.h"
#include "skinbus/common/atomic_file.h"
#include "tool_util.h"

int main(int argc, char** argv) {
  using namespace skinbus::body_map;
  CLI::App app{
      "skinbus-touchsim: simulates a patch pose calibration session. Tiles a humanoid with\n"
      "patches (cylinder sections around each forearm, flat patches on the chest), presses each\n"
      "patch with a simulated probe, and writes what a real session would record plus the truth:\n"
      "  truth.yaml     the skin map with the true poses\n"
      "  initial.yaml   the same map with every pose disturbed (the calibrator's start)\n"
      "  touches.csv    the touch log (docs/body_map.md): probe positions and the patches' own\n"
      "                 estimates, with noise and a fraction of outliers\n\n"
      "The default layout fits the project's robot (body_map/robots/skinbot.urdf); for another\n"
      "humanoid name its links and give the forearm and chest geometry.\n\n"
      "Example:\n"
      "  skinbus-touchsim --robot body_map/robots/skinbot.urdf --out-dir session --base-frame\n"};
  std::string robot_path, out_dir = ".";
  HumanoidLayout layout;
  SessionOptions o;
  app.add_option("--robot", robot_path, "robot description (URDF)")->required();
  app.add_option("--out-dir", out_dir, "folder for truth.yaml, initial.yaml, touches.csv")
      ->capture_default_str();
  app.add_option("--forearm-links", layout.forearm_links, "links that are forearms (cylinders)")
      ->delimiter(',')
      ->capture_default_str();
  app.add_option("--forearm-radius", layout.forearm_radius_mm, "forearm radius, mm")
      ->capture_default_str()
      ->check(CLI::Range(5.0, 1000.0));
  app.add_option("--forearm-start", layout.forearm_start_mm,
                 "forearm covered from this x (mm, link frame) ...")
      ->capture_default_str();
  app.add_option("--forearm-end", layout.forearm_end_mm, "... to this x (mm)")
      ->capture_default_str();
  app.add_option("--upper-arm-links", layout.upper_arm_links,
                 "links that are upper arms (cylinders around -z; none by default)")
      ->delimiter(',');
  app.add_option("--upper-arm-radius", layout.upper_arm_radius_mm, "upper arm radius, mm")
      ->capture_default_str()
      ->check(CLI::Range(5.0, 1000.0));
  app.add_option("--model", layout.model, "model file every patch names in the maps")
      ->capture_default_str();
  app.add_option("--torso-link", layout.torso_link, "link that carries the chest")
      ->capture_default_str();
  app.add_option("--chest-x", layout.chest_x_mm, "chest plane x in the torso link's frame, mm")
      ->capture_default_str();
  app.add_option("--touches", o.touches_per_patch, "touches per patch")
      ->capture_default_str()
      ->check(CLI::Range(1, 100000));
  app.add_option("--probe-noise", o.probe_noise_mm, "probe position noise, mm (1 sd per axis)")
      ->capture_default_str()
      ->check(CLI::Range(0.0, 100.0));
  app.add_option("--estimate-noise", o.estimate_noise_mm,
                 "error of the patches' own u, v estimates, mm (1 sd)")
      ->capture_default_str()
      ->check(CLI::Range(0.0, 100.0));
  app.add_option("--depth-noise", o.estimate_depth_noise_mm,
                 "error of the patches' own depth estimates, mm (1 sd)")
      ->capture_default_str()
      ->check(CLI::Range(0.0, 100.0));
  app.add_option("--outliers", o.outlier_fraction,
                 "fraction of touches whose estimate is elsewhere on the patch")
      ->capture_default_str()
      ->check(CLI::Range(0.0, 1.0));
  app.add_option("--position-error", o.initial_position_error_mm,
                 "the starting map's poses are this far off, mm")
      ->capture_default_str();
  app.add_option("--rotation-error", o.initial_rotation_error_deg,
                 "... and turned by this much, degrees")
      ->capture_default_str();
  app.add_flag("--base-frame", o.base_frame,
               "log probe positions in the robot's base frame at random joint positions "
               "(q:<joint> columns), as an external tracker would");
  app.add_option("--seed", o.seed, "random seed")->capture_default_str();
  CLI11_PARSE(app, argc, argv);

  auto fail = [](const std::string& m) { return skinbus::tools::fail("skinbus-touchsim", m, 1); };
  skinbus::Result<RobotModel> robot = RobotModel::from_urdf_file(robot_path);
  if (!robot.ok()) return fail(robot.error().to_string());
  skinbus::Result<SkinMap> truth = tile_humanoid(robot.value(), layout);
  if (!truth.ok()) return fail(truth.error().to_string());
  // The maps name the robot relative to themselves.
  std::error_code ec;
  std::filesystem::create_directories(out_dir, ec);
  const std::filesystem::path abs_robot = std::filesystem::absolute(robot_path);
  truth.value().robot =
      std::filesystem::relative(abs_robot, std::filesystem::absolute(out_dir)).string();
  skinbus::Result<SimulatedSession> s =
      simulate_calibration_session(robot.value(), truth.value(), o);
  if (!s.ok()) return fail(s.error().to_string());
  const std::string dir = out_dir + "/";
  for (auto [map, name] :
       {std::pair{&s.value().truth, "truth.yaml"}, std::pair{&s.value().initial, "initial.yaml"}}) {
    if (skinbus::Status st = save_skin_map_file(*map, dir + name); !st.ok()) {
      return fail(st.error().to_string());
    }
  }
  std::ostringstream csv;
  csv << "# skinbus touch log: simulated session, seed " << o.seed << ", " << o.touches_per_patch
      << " touches per patch, probe noise " << o.probe_noise_mm << " mm, estimate noise "
      << o.estimate_noise_mm << " mm, outliers " << o.outlier_fraction << "\n"
      << touch_log_to_csv(s.value().log);
  if (skinbus::Status st = skinbus::write_file_atomic(dir + "touches.csv", csv.str(), "touch log");
      !st.ok()) {
    return fail(st.error().message);
  }
  int outliers = 0;
  for (bool b : s.value().outlier) outliers += b;
  std::printf(
      "skinbus-touchsim: %zu patches on %s, %zu touches (%d outliers) -> %s{truth,initial}"
      ".yaml, %stouches.csv\n",
      s.value().truth.patches.size(), robot.value().name().c_str(), s.value().log.touches.size(),
      outliers, dir.c_str(), dir.c_str());
  return 0;
}
