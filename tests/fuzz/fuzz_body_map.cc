// Fuzzes the body map's text inputs: the skin map (YAML) and the calibration touch log (CSV).
// The input is split at its first NUL byte: the text before it is read as a skin map, the text
// after it as a touch log (no NUL: a skin map alone).
// Invariants beyond "does not crash":
// - a skin map that loads holds only finite numbers, validates, and its YAML loads again to the
//   same map (node IDs, UIDs, links, files, geometry; sizes and radius to 1e-9 relative, poses
//   to 1e-9 mm and 1e-9 rad);
// - a touch log that reads holds only finite numbers, no touch twice, and its CSV reads back
//   exactly (every number bit for bit, joint names, frames, node IDs);
// - with both, every patch's link-frame touches (no robot model) map to patch coordinates
//   without NaN.
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <sstream>
#include <string>

#include "skinbus/body_map/skin_map.h"
#include "skinbus/body_map/touch_log.h"

using namespace skinbus;
using namespace skinbus::body_map;

namespace {

[[noreturn]] void fail(const char* what, const std::string& text) {
  std::fprintf(stderr, "fuzz_body_map: %s\n%s\n", what, text.c_str());
  std::abort();
}

bool same_bits(double a, double b) {
  return std::memcmp(&a, &b, sizeof a) == 0;
}

bool near_rel(double a, double b) {
  return std::abs(a - b) <= 1e-9 * std::max(std::abs(a), std::abs(b));
}

bool all_finite(const PatchPlacement& p) {
  const PatchGeometry& g = p.geometry;
  bool ok = p.pose_on_link.rotation.allFinite() && p.pose_on_link.translation_mm.allFinite() &&
            std::isfinite(g.size_u_mm) && std::isfinite(g.size_v_mm) &&
            std::isfinite(g.radius_mm) && std::isfinite(g.arc_deg());
  if (p.calibration) {
    const PoseUncertainty& c = *p.calibration;
    ok = ok && std::isfinite(c.rms_residual_mm) && c.position_sd_mm.allFinite() &&
         c.rotation_sd_deg.allFinite() && std::isfinite(c.radius_sd_mm);
  }
  return ok;
}

bool same_placement(const PatchPlacement& a, const PatchPlacement& b) {
  const PatchGeometry &ga = a.geometry, &gb = b.geometry;
  if (a.node_id != b.node_id || a.hardware_uid != b.hardware_uid || a.link != b.link ||
      a.model != b.model || ga.kind != gb.kind || !near_rel(ga.size_u_mm, gb.size_u_mm) ||
      !near_rel(ga.size_v_mm, gb.size_v_mm) || !near_rel(ga.radius_mm, gb.radius_mm)) {
    return false;
  }
  if (ga.kind == SurfaceKind::kCylinder && ga.axis != gb.axis) return false;
  if ((a.pose_on_link.translation_mm - b.pose_on_link.translation_mm).norm() > 1e-9) return false;
  if (!(rotation_angle_between(a.pose_on_link.rotation, b.pose_on_link.rotation) <= 1e-9)) {
    return false;
  }
  if (a.calibration.has_value() != b.calibration.has_value()) return false;
  if (a.calibration && (a.calibration->touches != b.calibration->touches ||
                        a.calibration->inliers != b.calibration->inliers)) {
    return false;
  }
  return true;
}

void check_skin_map(const SkinMap& map) {
  for (const PatchPlacement& p : map.patches)
    if (!all_finite(p)) fail("a loaded skin map holds a non-finite number", skin_map_to_yaml(map));
  if (Status st = validate_skin_map(map); !st.ok()) {
    fail(("a loaded skin map does not validate: " + st.error().message).c_str(),
         skin_map_to_yaml(map));
  }
  const std::string printed = skin_map_to_yaml(map);
  Result<SkinMap> again = load_skin_map_text(printed);
  if (!again.ok())
    fail(("printed skin map does not load: " + again.error().message).c_str(), printed);
  const SkinMap& b = again.value();
  if (b.robot != map.robot || b.patches.size() != map.patches.size()) {
    fail("printed skin map loads to another map", printed);
  }
  for (std::size_t i = 0; i < map.patches.size(); ++i) {
    if (!same_placement(map.patches[i], b.patches[i])) {
      fail(("printed skin map loads to another placement of node " +
            std::to_string(map.patches[i].node_id) + "; reprinted:\n" + skin_map_to_yaml(b))
               .c_str(),
           printed);
    }
  }
}

bool all_finite(const TouchRecord& r) {
  bool ok = r.probe_mm.allFinite() && std::isfinite(r.u_mm) && std::isfinite(r.v_mm) &&
            std::isfinite(r.depth_mm);
  for (double q : r.joint_positions) ok = ok && std::isfinite(q);
  return ok;
}

bool same_record(const TouchRecord& a, const TouchRecord& b) {
  if (a.node_id != b.node_id || a.frame != b.frame ||
      a.joint_positions.size() != b.joint_positions.size()) {
    return false;
  }
  for (int i = 0; i < 3; ++i)
    if (!same_bits(a.probe_mm(i), b.probe_mm(i))) return false;
  if (!same_bits(a.u_mm, b.u_mm) || !same_bits(a.v_mm, b.v_mm) ||
      !same_bits(a.depth_mm, b.depth_mm)) {
    return false;
  }
  for (std::size_t j = 0; j < a.joint_positions.size(); ++j)
    if (!same_bits(a.joint_positions[j], b.joint_positions[j])) return false;
  return true;
}

void check_touch_log(const TouchLog& log) {
  for (const TouchRecord& r : log.touches)
    if (!all_finite(r)) fail("a read touch log holds a non-finite number", touch_log_to_csv(log));
  // No touch twice (a repeated row would shrink the calibration's uncertainty): a small log is
  // compared pair by pair.
  if (log.touches.size() <= 256) {
    for (std::size_t i = 0; i < log.touches.size(); ++i) {
      for (std::size_t j = i + 1; j < log.touches.size(); ++j) {
        if (same_record(log.touches[i], log.touches[j])) {
          fail("a read touch log holds one touch twice", touch_log_to_csv(log));
        }
      }
    }
  }
  const std::string printed = touch_log_to_csv(log);
  std::istringstream in(printed);
  Result<TouchLog> again = read_touch_log(in);
  if (!again.ok())
    fail(("printed touch log does not read: " + again.error().message).c_str(), printed);
  const TouchLog& b = again.value();
  if (b.joint_names != log.joint_names || b.touches.size() != log.touches.size()) {
    fail("printed touch log reads to another log", printed);
  }
  for (std::size_t i = 0; i < log.touches.size(); ++i) {
    if (!same_record(log.touches[i], b.touches[i])) {
      fail(("printed touch log reads to another touch " + std::to_string(i) + "; reprinted:\n" +
            touch_log_to_csv(b))
               .c_str(),
           printed);
    }
  }
}

void check_touches_on_patches(const SkinMap& map, const TouchLog& log) {
  for (const PatchPlacement& p : map.patches) {
    Result<std::vector<CalibrationTouch>> touches = link_frame_touches(log, p, nullptr);
    if (!touches.ok()) continue;
    for (const CalibrationTouch& t : touches.value()) {
      Result<PatchCoordinates> c = link_to_patch_coordinates(p, t.probe_mm);
      if (c.ok() && (std::isnan(c.value().u_mm) || std::isnan(c.value().v_mm) ||
                     std::isnan(c.value().depth_mm))) {
        char buf[160];
        std::snprintf(buf, sizeof buf,
                      "NaN patch coordinates of node %d for probe (%.17g, %.17g, %.17g)", p.node_id,
                      t.probe_mm.x(), t.probe_mm.y(), t.probe_mm.z());
        fail(buf, skin_map_to_yaml(map));
      }
    }
  }
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string input(reinterpret_cast<const char*>(data), size);
  const std::size_t nul = input.find('\0');
  const std::string map_text = input.substr(0, nul);
  const bool have_log = nul != std::string::npos;

  Result<SkinMap> map = load_skin_map_text(map_text);
  if (map.ok()) check_skin_map(map.value());
  if (!have_log) return 0;

  std::istringstream in(input.substr(nul + 1));
  Result<TouchLog> touch_log = read_touch_log(in);
  if (!touch_log.ok()) return 0;
  check_touch_log(touch_log.value());
  if (map.ok()) check_touches_on_patches(map.value(), touch_log.value());
  return 0;
}
