#include "skinbus/body_map/touch_log.h"

#include <algorithm>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <set>
#include <sstream>
#include <unordered_map>

#include "skinbus/body_map/joint_map.h"
#include "skinbus/common/csv.h"
#include "skinbus/common/line_reader.h"
#include "skinbus/common/text_file.h"

namespace skinbus::body_map {

namespace {

constexpr const char* kColumns[] = {"node",       "frame", "probe_x_mm", "probe_y_mm",
                                    "probe_z_mm", "u_mm",  "v_mm",       "depth_mm"};
constexpr int kFixedColumns = 8;

Error parse_error(int line, const std::string& what) {
  return make_error(ErrorCode::kParse, "touch log line " + std::to_string(line) + ": " + what);
}

}  // namespace

Result<TouchLog> read_touch_log(std::istream& in) {
  TouchLog log;
  std::string line;
  int line_no = 0;
  bool have_header = false;
  std::set<std::string> seen_joints;
  // Each touch's values (bit for bit) -> its line: a row given twice is refused, since the
  // calibration would count it as two measurements and claim more certainty than it has.
  std::unordered_map<std::string, int> line_of_touch;
  for (BoundedLine got;
       (got = getline_bounded(in, line, kMaxTouchLogLineBytes)) != BoundedLine::kEof;) {
    ++line_no;
    if (got == BoundedLine::kTooLong) {
      return parse_error(line_no,
                         "longer than " + std::to_string(kMaxTouchLogLineBytes) + " bytes");
    }
    if (is_csv_comment_or_blank(line)) continue;
    const std::vector<std::string_view> f = split_csv_fields(line);
    if (!have_header) {
      if (static_cast<int>(f.size()) < kFixedColumns) {
        return parse_error(line_no,
                           "the header needs the columns node,frame,probe_x_mm,"
                           "probe_y_mm,probe_z_mm,u_mm,v_mm,depth_mm");
      }
      for (int c = 0; c < kFixedColumns; ++c) {
        if (f[c] != kColumns[c]) {
          return parse_error(line_no, "column " + std::to_string(c + 1) + " is '" +
                                          std::string(f[c]) + "', expected '" + kColumns[c] + "'");
        }
      }
      for (std::size_t c = kFixedColumns; c < f.size(); ++c) {
        if (f[c].substr(0, 2) != "q:" || f[c].size() < 3) {
          return parse_error(line_no, "column " + std::to_string(c + 1) + " '" + std::string(f[c]) +
                                          "': joint columns are q:<joint>");
        }
        std::string name(f[c].substr(2));
        if (!seen_joints.insert(name).second) {
          return parse_error(line_no, "joint column q:" + name + " appears twice");
        }
        log.joint_names.push_back(std::move(name));
      }
      have_header = true;
      continue;
    }
    const std::size_t want = kFixedColumns + log.joint_names.size();
    if (f.size() != want && f.size() != kFixedColumns) {
      return parse_error(line_no, std::to_string(f.size()) + " fields, expected " +
                                      std::to_string(kFixedColumns) + " or " +
                                      std::to_string(want));
    }
    TouchRecord r;
    r.line = line_no;
    long long node = 0;
    if (!parse_csv_int(f[0], 1, 125, &node)) {
      return parse_error(line_no, "node '" + std::string(f[0]) + "' is not a patch node ID 1..125");
    }
    r.node_id = static_cast<int>(node);
    if (f[1] == "link") {
      r.frame = ProbeFrame::kLink;
    } else if (f[1] == "base") {
      r.frame = ProbeFrame::kBase;
    } else {
      return parse_error(line_no, "frame '" + std::string(f[1]) + "' is not link or base");
    }
    double v[6];
    for (int c = 0; c < 6; ++c) {
      if (!parse_csv_number(f[2 + c], &v[c])) {
        return parse_error(line_no, std::string(kColumns[2 + c]) + " '" + std::string(f[2 + c]) +
                                        "' is not a finite number");
      }
    }
    r.probe_mm = {v[0], v[1], v[2]};
    r.u_mm = v[3];
    r.v_mm = v[4];
    r.depth_mm = v[5];
    // A link-frame row whose joint fields are all empty gives no joint positions, as a row of
    // the fixed columns alone does (touch_log_to_csv writes such a row that way).
    bool joints_given = f.size() == want && !log.joint_names.empty();
    if (joints_given && r.frame == ProbeFrame::kLink) {
      joints_given = false;
      for (std::size_t c = kFixedColumns; c < want; ++c)
        joints_given = joints_given || !f[c].empty();
    }
    if (joints_given) {
      r.joint_positions.resize(log.joint_names.size());
      for (std::size_t j = 0; j < log.joint_names.size(); ++j) {
        const std::string_view field = f[kFixedColumns + j];
        if (field.empty() && r.frame == ProbeFrame::kLink) continue;  // not needed
        if (!parse_csv_number(field, &r.joint_positions[j])) {
          return parse_error(line_no, "q:" + log.joint_names[j] + " '" + std::string(field) +
                                          "' is not a finite number");
        }
      }
    }
    if (r.frame == ProbeFrame::kBase && r.joint_positions.empty()) {
      return parse_error(line_no,
                         "a base-frame touch needs the joint positions (q:<joint> "
                         "columns) of that moment");
    }
    std::string key(reinterpret_cast<const char*>(&r.node_id), sizeof r.node_id);
    key.push_back(r.frame == ProbeFrame::kLink ? 'l' : 'b');
    for (double x : {r.probe_mm.x(), r.probe_mm.y(), r.probe_mm.z(), r.u_mm, r.v_mm, r.depth_mm}) {
      key.append(reinterpret_cast<const char*>(&x), sizeof x);
    }
    for (double q : r.joint_positions) key.append(reinterpret_cast<const char*>(&q), sizeof q);
    if (auto [it, fresh] = line_of_touch.emplace(std::move(key), line_no); !fresh) {
      return parse_error(line_no, "repeats the touch of line " + std::to_string(it->second) +
                                      " exactly: a touch counted twice would shrink the "
                                      "calibration's uncertainty; give each touch once");
    }
    if (log.touches.size() >= kMaxTouches) {
      return parse_error(line_no, "more than " + std::to_string(kMaxTouches) + " touches");
    }
    log.touches.push_back(std::move(r));
  }
  if (!have_header) return make_error(ErrorCode::kParse, "touch log: no header line");
  return log;
}

Result<TouchLog> load_touch_log_file(const std::string& path) {
  Result<std::string> text = read_text_file(path, "touch log", 256u << 20);
  if (!text.ok()) return text.error();
  std::istringstream in(std::move(text).value());
  Result<TouchLog> log = read_touch_log(in);
  if (!log.ok()) return make_error(log.error().code, path + ": " + log.error().message);
  return log;
}

std::string touch_log_to_csv(const TouchLog& log) {
  std::ostringstream o;
  for (const char* c : kColumns) o << (c == kColumns[0] ? "" : ",") << c;
  for (const std::string& j : log.joint_names) o << ",q:" << j;
  o << "\n";
  char buf[40];
  auto num = [&](double x) {
    std::snprintf(buf, sizeof buf, "%.17g", x);
    o << "," << buf;
  };
  for (const TouchRecord& r : log.touches) {
    o << r.node_id << "," << (r.frame == ProbeFrame::kLink ? "link" : "base");
    for (double x : {r.probe_mm.x(), r.probe_mm.y(), r.probe_mm.z(), r.u_mm, r.v_mm, r.depth_mm})
      num(x);
    if (!log.joint_names.empty()) {
      if (r.joint_positions.size() == log.joint_names.size()) {
        for (double q : r.joint_positions) num(q);
      } else {
        for (std::size_t j = 0; j < log.joint_names.size(); ++j) o << ",";
      }
    }
    o << "\n";
  }
  return o.str();
}

Result<std::vector<CalibrationTouch>> link_frame_touches(const TouchLog& log,
                                                         const PatchPlacement& patch,
                                                         const RobotModel* robot) {
  std::vector<CalibrationTouch> out;
  int link = -1;
  JointMap columns;  // the log's q:<joint> columns onto the robot's q (mm and rad)
  std::vector<double> q;
  for (const TouchRecord& r : log.touches) {
    if (r.node_id != patch.node_id) continue;
    CalibrationTouch t{r.probe_mm, r.u_mm, r.v_mm, r.depth_mm};
    if (r.frame == ProbeFrame::kBase) {
      if (!robot) {
        return make_error(ErrorCode::kInvalidArgument,
                          "touch log line " + std::to_string(r.line) +
                              ": a base-frame touch needs the robot model (URDF)");
      }
      if (link < 0) {
        link = robot->find_link(patch.link);
        if (link < 0) {
          return make_error(ErrorCode::kNotFound, "node " + std::to_string(patch.node_id) +
                                                      ": link '" + patch.link +
                                                      "' is not in robot '" + robot->name() + "'");
        }
        columns = JointMap(*robot, log.joint_names, PrismaticUnit::kMillimetres);
        // Joints that move the link must be in the log.
        for (int l = link; l > 0; l = robot->link(l).parent) {
          const int j = robot->link(l).joint.q_index;
          if (j >= 0 && !columns.covers(j)) {
            return make_error(ErrorCode::kInvalidArgument,
                              "touch log: base-frame touches of node " +
                                  std::to_string(patch.node_id) +
                                  " need a q:" + robot->joint_name(j) +
                                  " column (the joint moves link " + patch.link + ")");
          }
        }
        q.assign(robot->joint_count(), 0.0);
      }
      std::fill(q.begin(), q.end(), 0.0);
      columns.apply(r.joint_positions, q);
      Result<Pose> pose = robot->link_pose(q, link);
      if (!pose.ok()) {
        return make_error(pose.error().code,
                          "touch log line " + std::to_string(r.line) + ": " + pose.error().message);
      }
      t.probe_mm = pose.value().inverse().apply(r.probe_mm);
    }
    out.push_back(t);
  }
  return out;
}

}  // namespace skinbus::body_map
