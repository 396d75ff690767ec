// skinbus/body_map/calibration_sim.h: simulated calibration sessions with known true poses.
//
// A humanoid is tiled with patches (cylinder sections around the forearms, flat patches on the
// chest), a simulated probe presses each patch at chosen points, and each touch is logged the
// way a real session logs it: the probe's position (noisy; in the link frame or, with random
// joint positions, in the base frame) and the patch's own estimate (noisy; a fraction of them
// wrong, as outliers). The starting skin map is the true one with every pose disturbed.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "skinbus/body_map/robot_model.h"
#include "skinbus/body_map/skin_map.h"
#include "skinbus/body_map/touch_log.h"
#include "skinbus/common/result.h"

namespace skinbus::body_map {

// Where patches go. The defaults fit the project's robot, body_map/robots/skinbot.urdf: each
// forearm is a cylinder around its link's x axis; the chest is the plane x = chest_x_mm of the
// torso link, spanning chest_y_mm x chest_z_mm.
struct HumanoidLayout {
  std::vector<std::string> forearm_links = {"left_forearm_link", "right_forearm_link"};
  double forearm_radius_mm = 45;
  double forearm_start_mm = 20, forearm_end_mm = 250;  // along the link's x axis
  int patches_around = 2;                              // per forearm, evenly spaced
  // Upper arms (none by default): cylinders around the link's -z axis (the arm hanging down),
  // from upper_arm_start_mm to upper_arm_end_mm below the shoulder, patches facing forward (+x)
  // first, then evenly around.
  std::vector<std::string> upper_arm_links;
  double upper_arm_radius_mm = 40;
  double upper_arm_start_mm = 40, upper_arm_end_mm = 250;
  int upper_arm_patches_around = 1;
  std::string torso_link = "torso_link";
  double chest_x_mm = 110;
  double chest_y_mm[2] = {-160, 160};
  double chest_z_mm[2] = {20, 460};
  int first_node = 1;
  uint64_t first_uid = 0x5B00000000000001ull;
  std::string model = "models/nominal.skinmodel";
};

// The skin map of a humanoid tiled per `layout`: as many 140 x 140 mm patches as fit on each
// forearm (around x along), on each upper arm (around -z) and on the chest. Node IDs and UIDs
// count up in that order. Errors name a missing link.
Result<SkinMap> tile_humanoid(const RobotModel& robot, const HumanoidLayout& layout = {});

struct SessionOptions {
  int touches_per_patch = 30;
  double probe_noise_mm = 0.5;           // 1 sd per axis
  double estimate_noise_mm = 0.5;        // patch estimate error, 1 sd in u and v
  double estimate_depth_noise_mm = 0.1;  // and in depth
  double outlier_fraction = 0.1;  // touches whose estimate is elsewhere on the patch (>= 10 mm)
  double depth_min_mm = 1.0, depth_max_mm = 3.0;  // press depths
  double edge_margin_mm = 10;                     // presses stay this far inside the patch edge
  double initial_position_error_mm = 10;          // the starting map's poses are off by this ...
  double initial_rotation_error_deg = 10;         // ... and this, in random directions
  double initial_radius_error_mm = 0;             // cylinder radius off by this
  bool base_frame = false;  // log probe positions in the base frame, at random joint positions
  uint64_t seed = 1;
};

struct SimulatedSession {
  SkinMap truth;
  SkinMap initial;  // the truth, disturbed: what the calibrator starts from
  TouchLog log;
  std::vector<bool> outlier;  // per log row: its estimate is an outlier
};

// Simulates one session over every patch of `truth`. Errors: a link not in `robot`, bad options.
Result<SimulatedSession> simulate_calibration_session(const RobotModel& robot, const SkinMap& truth,
                                                      const SessionOptions& options);

}  // namespace skinbus::body_map
