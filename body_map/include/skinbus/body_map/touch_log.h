// skinbus/body_map/touch_log.h: the calibration touch log (CSV), documented in docs/body_map.md.
//
//   # comment lines start with '#'
//   node,frame,probe_x_mm,probe_y_mm,probe_z_mm,u_mm,v_mm,depth_mm[,q:<joint>...]
//   3,link,101.2,-4.5,47.9,12.1,-30.4,2.05
//   5,base,312.0,140.2,655.1,-8.0,22.3,1.80,0.12,-0.40,...
//
// One row per touch: which patch (node), the frame the probe position is given in (`link`: the
// patch's parent link; `base`: the robot's root link, with the joint positions of that moment in
// the q:<joint> columns, radians or mm for prismatic joints), the probe tip's position, and the
// patch's own estimate of the touch (u, v, depth; mm).
#pragma once

#include <istream>
#include <string>
#include <vector>

#include "skinbus/body_map/calibration.h"
#include "skinbus/body_map/robot_model.h"
#include "skinbus/body_map/skin_map.h"
#include "skinbus/common/result.h"

namespace skinbus::body_map {

enum class ProbeFrame { kLink, kBase };

struct TouchRecord {
  int node_id = 0;
  ProbeFrame frame = ProbeFrame::kLink;
  Eigen::Vector3d probe_mm = Eigen::Vector3d::Zero();
  double u_mm = 0, v_mm = 0, depth_mm = 0;
  std::vector<double> joint_positions;  // one per TouchLog::joint_names (base-frame rows)
  int line = 0;                         // line in the file, for messages
};

struct TouchLog {
  std::vector<std::string> joint_names;  // the q:<joint> columns, in file order
  std::vector<TouchRecord> touches;
};

// Bounds of a touch log: a line, and the touches.
inline constexpr std::size_t kMaxTouchLogLineBytes = 64 * 1024;
inline constexpr std::size_t kMaxTouches = 1'000'000;

// Reads a touch log. Errors (kParse) name the line and column; a row with a non-finite number,
// a node outside 1..125 or an unknown frame is refused; `base` rows need every joint column. A
// row that repeats an earlier one exactly (every value, bit for bit) is refused: counted twice,
// it would shrink the calibration's reported uncertainty. A line or a log beyond the bounds
// above, and a directory, are refused.
Result<TouchLog> read_touch_log(std::istream& in);
Result<TouchLog> load_touch_log_file(const std::string& path);

// Writes a touch log that read_touch_log reads back exactly (numbers with 17 digits).
std::string touch_log_to_csv(const TouchLog& log);

// The touches of one patch in its parent link's frame. Base-frame rows are moved into the link
// frame with forward kinematics (needs `robot`; joints of the model missing from the log are
// an error when they move the link, and ignored otherwise).
Result<std::vector<CalibrationTouch>> link_frame_touches(const TouchLog& log,
                                                         const PatchPlacement& patch,
                                                         const RobotModel* robot);

}  // namespace skinbus::body_map
