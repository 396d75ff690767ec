#include "skinbus/body_map/skin_map.h"

#include <cinttypes>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>
#include <numbers>
#include <sstream>

#include "skinbus/common/atomic_file.h"
#include "skinbus/common/yaml_reader.h"

namespace skinbus::body_map {

namespace {

constexpr int kNodeMin = 1, kNodeMax = 125;  // patch node IDs (docs/protocol.md)
constexpr double kDeg = std::numbers::pi / 180.0;

bool finite(const Eigen::Vector3d& v) {
  return v.allFinite();
}

// A list of exactly N numbers, e.g. [1, 2, 3].
template <int N>
bool get_vector(YamlReader& r, const YAML::Node& map, const char* key, const std::string& path,
                Eigen::Matrix<double, N, 1>* out) {
  const YAML::Node n = map[key];
  if (r.error || !n) return false;
  if (!n.IsSequence() || n.size() != N) {
    r.fail(path + key, n, "expected a list of " + std::to_string(N) + " numbers");
    return false;
  }
  for (int i = 0; i < N; ++i)
    if (!r.number(n[i], path + key, &(*out)(i))) return false;
  return true;
}

void parse_geometry(YamlReader& r, const YAML::Node& g, const std::string& path,
                    PatchGeometry* out) {
  r.only(g, path, {"type", "size_mm", "radius_mm", "axis", "arc_deg"});
  if (r.error) return;
  std::string type = "flat";
  r.get_string(g, "type", path + ".", &type);
  if (type == "flat") {
    out->kind = SurfaceKind::kFlat;
  } else if (type == "cylinder") {
    out->kind = SurfaceKind::kCylinder;
  } else {
    r.fail(path + ".type", g["type"], "'" + type + "' is not flat or cylinder");
    return;
  }
  Eigen::Vector2d size(out->size_u_mm, out->size_v_mm);
  get_vector<2>(r, g, "size_mm", path + ".", &size);
  out->size_u_mm = size.x();
  out->size_v_mm = size.y();
  if (out->kind == SurfaceKind::kFlat) {
    for (const char* k : {"radius_mm", "axis", "arc_deg"})
      if (g[k]) r.fail(path + "." + k, g[k], "only a cylinder has this");
    return;
  }
  if (!g["radius_mm"]) {
    r.fail(path + ".radius_mm", g, "missing: a cylinder needs its radius");
    return;
  }
  r.get_double(g, "radius_mm", path + ".", 5, 5000, &out->radius_mm);
  std::string axis = "v";
  r.get_string(g, "axis", path + ".", &axis);
  if (axis == "u" || axis == "v") {
    out->axis = axis == "u" ? CylinderAxis::kU : CylinderAxis::kV;
  } else {
    r.fail(path + ".axis", g["axis"], "'" + axis + "' is not u or v");
  }
  if (g["arc_deg"] && !r.error) {
    double arc = 0;
    r.get_double(g, "arc_deg", path + ".", 0.1, 360, &arc);
    if (r.error) return;
    double& across = out->axis == CylinderAxis::kV ? out->size_u_mm : out->size_v_mm;
    const double from_arc = arc * kDeg * out->radius_mm;
    if (g["size_mm"] && std::abs(from_arc - across) > 0.5) {
      char buf[160];
      std::snprintf(buf, sizeof buf,
                    "%.6g degrees on radius %.6g mm is %.6g mm of skin, but size_mm says %.6g; "
                    "give one of them",
                    arc, out->radius_mm, from_arc, across);
      r.fail(path + ".arc_deg", g["arc_deg"], buf);
      return;
    }
    across = from_arc;
  }
}

void parse_calibration(YamlReader& r, const YAML::Node& c, const std::string& path,
                       PoseUncertainty* out) {
  r.only(c, path,
         {"touches", "inliers", "rms_residual_mm", "position_sd_mm", "rotation_sd_deg",
          "radius_sd_mm"});
  r.get_int(c, "touches", path + ".", 0, 1000000, &out->touches);
  r.get_int(c, "inliers", path + ".", 0, 1000000, &out->inliers);
  r.get_double(c, "rms_residual_mm", path + ".", 0, 1e9, &out->rms_residual_mm);
  get_vector<3>(r, c, "position_sd_mm", path + ".", &out->position_sd_mm);
  get_vector<3>(r, c, "rotation_sd_deg", path + ".", &out->rotation_sd_deg);
  r.get_double(c, "radius_sd_mm", path + ".", 0, 1e9, &out->radius_sd_mm);
}

void parse_patch(YamlReader& r, const YAML::Node& p, const std::string& path, PatchPlacement* out) {
  r.only(
      p, path,
      {"node", "uid", "link", "position_mm", "rpy_deg", "quaternion_wxyz", "geometry", "model",
       "unit", "design", "correction", "refine_shear", "max_contacts", "proposer", "calibration"});
  if (r.error) return;
  for (const char* k : {"node", "link", "position_mm"})
    if (!p[k]) r.fail(path + "." + k, p, "missing");
  r.get_int(p, "node", path + ".", kNodeMin, kNodeMax, &out->node_id);
  unsigned long long uid = 0;
  r.get_uint64(p, "uid", path + ".", &uid);
  out->hardware_uid = uid;
  r.get_string(p, "link", path + ".", &out->link);
  if (get_vector<3>(r, p, "position_mm", path + ".", &out->pose_on_link.translation_mm) &&
      !(out->pose_on_link.translation_mm.norm() <= kMaxPatchOffsetMm)) {
    r.fail(path + ".position_mm", p["position_mm"],
           "the patch is " + std::to_string(out->pose_on_link.translation_mm.norm() * 1e-3) +
               " m from its link's origin, more than the " +
               std::to_string(static_cast<int>(kMaxPatchOffsetMm * 1e-3)) +
               " m any robot link spans (mm expected)");
  }
  if (p["rpy_deg"] && p["quaternion_wxyz"]) {
    r.fail(path + ".quaternion_wxyz", p["quaternion_wxyz"], "give rpy_deg or quaternion_wxyz");
  }
  Eigen::Vector3d rpy = Eigen::Vector3d::Zero();
  if (get_vector<3>(r, p, "rpy_deg", path + ".", &rpy)) {
    out->pose_on_link.rotation = rotation_from_rpy(rpy.x() * kDeg, rpy.y() * kDeg, rpy.z() * kDeg);
  }
  Eigen::Vector4d q;
  if (get_vector<4>(r, p, "quaternion_wxyz", path + ".", &q)) {
    const double n = q.norm();
    if (std::abs(n - 1.0) > 1e-3) {
      r.fail(path + ".quaternion_wxyz", p["quaternion_wxyz"],
             "not a unit quaternion (norm " + std::to_string(n) + ")");
    } else {
      out->pose_on_link.rotation =
          Eigen::Quaterniond(q(0), q(1), q(2), q(3)).normalized().toRotationMatrix();
    }
  }
  if (const YAML::Node g = p["geometry"]) parse_geometry(r, g, path + ".geometry", &out->geometry);
  r.get_string(p, "model", path + ".", &out->model);
  r.get_string(p, "unit", path + ".", &out->unit);
  r.get_string(p, "design", path + ".", &out->design);
  r.get_string(p, "correction", path + ".", &out->correction);
  r.get_bool(p, "refine_shear", path + ".", &out->refine_shear);
  r.get_int(p, "max_contacts", path + ".", 1, 3, &out->max_contacts);
  r.get_string(p, "proposer", path + ".", &out->proposer);
  if (const YAML::Node c = p["calibration"]) {
    out->calibration.emplace();
    parse_calibration(r, c, path + ".calibration", &*out->calibration);
  }
}

Result<SkinMap> parse(const YAML::Node& root, const RobotModel* robot) {
  YamlReader r;
  SkinMap map;
  if (!root || root.IsNull()) return make_error(ErrorCode::kParse, "empty skin map");
  r.only(root, "", {"skin_map_version", "robot", "patches"});
  int version = 1;
  r.get_int(root, "skin_map_version", "", 1, 1, &version);
  r.get_string(root, "robot", "", &map.robot);
  const YAML::Node patches = root["patches"];
  if (!r.error && (!patches || !patches.IsSequence())) {
    r.fail("patches", patches ? patches : root, "expected a list of patches");
  }
  std::map<int, int> node_line;
  std::map<uint64_t, int> uid_node;
  for (std::size_t i = 0; !r.error && i < patches.size(); ++i) {
    const std::string path = "patches[" + std::to_string(i) + "]";
    PatchPlacement p;
    parse_patch(r, patches[i], path, &p);
    if (r.error) break;
    const int line = patches[i].Mark().line + 1;
    if (auto [it, fresh] = node_line.emplace(p.node_id, line); !fresh) {
      r.fail(path + ".node", patches[i]["node"],
             "node " + std::to_string(p.node_id) + " is already placed (line " +
                 std::to_string(it->second) + ")");
      break;
    }
    if (p.hardware_uid != 0) {
      if (auto [it, fresh] = uid_node.emplace(p.hardware_uid, p.node_id); !fresh) {
        char buf[40];
        std::snprintf(buf, sizeof buf, "0x%016" PRIx64, p.hardware_uid);
        r.fail(
            path + ".uid", patches[i]["uid"],
            std::string("hardware UID ") + buf + " is already node " + std::to_string(it->second));
        break;
      }
    }
    if (Status st = validate_geometry(p.geometry); !st.ok()) {
      r.fail(path + ".geometry", patches[i]["geometry"] ? patches[i]["geometry"] : patches[i],
             st.error().message);
      break;
    }
    if (robot && robot->find_link(p.link) < 0) {
      r.fail(path + ".link", patches[i]["link"],
             "'" + p.link + "' is not a link of robot '" + robot->name() + "'");
      break;
    }
    map.patches.push_back(std::move(p));
  }
  if (r.error) return *r.error;
  return map;
}

void print_vector(std::ostream& o, const double* v, int n) {
  o << "[";
  for (int i = 0; i < n; ++i) o << (i ? ", " : "") << yaml_number(v[i]);
  o << "]";
}

}  // namespace

double PatchGeometry::arc_deg() const {
  if (kind == SurfaceKind::kFlat || radius_mm <= 0) return 0;
  return (axis == CylinderAxis::kV ? size_u_mm : size_v_mm) / radius_mm / kDeg;
}

const PatchPlacement* SkinMap::find_node(int node_id) const {
  for (const PatchPlacement& p : patches)
    if (p.node_id == node_id) return &p;
  return nullptr;
}
PatchPlacement* SkinMap::find_node(int node_id) {
  for (PatchPlacement& p : patches)
    if (p.node_id == node_id) return &p;
  return nullptr;
}

SurfacePoint patch_surface_point(const PatchGeometry& g, double u_mm, double v_mm,
                                 double depth_mm) {
  SurfacePoint s;
  s.point_mm = patch_point<double>(g, g.radius_mm, u_mm, v_mm, depth_mm);
  if (g.kind == SurfaceKind::kFlat) {
    s.normal = Eigen::Vector3d::UnitZ();
  } else if (g.axis == CylinderAxis::kV) {
    const double theta = u_mm / g.radius_mm;
    s.normal = {std::sin(theta), 0, std::cos(theta)};
    s.tangent_u = {std::cos(theta), 0, -std::sin(theta)};
  } else {
    const double theta = v_mm / g.radius_mm;
    s.normal = {0, std::sin(theta), std::cos(theta)};
    s.tangent_v = {0, std::cos(theta), -std::sin(theta)};
  }
  return s;
}

SurfacePoint link_surface_point(const PatchPlacement& p, double u_mm, double v_mm,
                                double depth_mm) {
  const SurfacePoint s = patch_surface_point(p.geometry, u_mm, v_mm, depth_mm);
  return {p.pose_on_link.apply(s.point_mm), p.pose_on_link.rotation * s.normal,
          p.pose_on_link.rotation * s.tangent_u, p.pose_on_link.rotation * s.tangent_v};
}

Result<PatchCoordinates> patch_coordinates(const PatchGeometry& g, const Eigen::Vector3d& p) {
  if (!finite(p)) return make_error(ErrorCode::kInvalidArgument, "point is not finite");
  PatchCoordinates c;
  if (g.kind == SurfaceKind::kFlat) {
    c = {p.x(), p.y(), -p.z(), false};
  } else {
    const double along = g.axis == CylinderAxis::kV ? p.y() : p.x();
    const double across = g.axis == CylinderAxis::kV ? p.x() : p.y();
    const double up = p.z() + g.radius_mm;
    const double r = std::hypot(across, up);
    if (r < 1e-9 * g.radius_mm) {
      return make_error(ErrorCode::kDegenerate,
                        "point lies on the cylinder's axis: its patch coordinates are undefined");
    }
    const double arc = g.radius_mm * std::atan2(across, up);
    c.depth_mm = g.radius_mm - r;
    c.u_mm = g.axis == CylinderAxis::kV ? arc : along;
    c.v_mm = g.axis == CylinderAxis::kV ? along : arc;
  }
  c.inside = std::abs(c.u_mm) <= 0.5 * g.size_u_mm && std::abs(c.v_mm) <= 0.5 * g.size_v_mm &&
             c.depth_mm >= -0.5 && c.depth_mm <= 10.0;
  return c;
}

Result<PatchCoordinates> link_to_patch_coordinates(const PatchPlacement& p,
                                                   const Eigen::Vector3d& p_link_mm) {
  return patch_coordinates(p.geometry, p.pose_on_link.inverse().apply(p_link_mm));
}

Status validate_geometry(const PatchGeometry& g) {
  auto bad = [](const std::string& m) { return Status(make_error(ErrorCode::kOutOfRange, m)); };
  for (double s : {g.size_u_mm, g.size_v_mm}) {
    if (!std::isfinite(s) || s <= 0 || s > 1000) {
      return bad("patch size " + std::to_string(s) + " mm is outside (0, 1000] mm");
    }
  }
  if (g.kind == SurfaceKind::kCylinder) {
    if (!std::isfinite(g.radius_mm) || g.radius_mm < 5 || g.radius_mm > 5000) {
      return bad("cylinder radius " + std::to_string(g.radius_mm) + " mm is outside [5, 5000] mm");
    }
    if (g.arc_deg() > 360.0 + 1e-9) {
      return bad("the patch wraps " + std::to_string(g.arc_deg()) +
                 " degrees around its cylinder: more than a full turn");
    }
  }
  return Status::Ok();
}

Status validate_skin_map(const SkinMap& map, const RobotModel* robot) {
  for (const PatchPlacement& p : map.patches) {
    const Eigen::Matrix3d& r = p.pose_on_link.rotation;
    if (!r.allFinite() || !p.pose_on_link.translation_mm.allFinite() ||
        (r.transpose() * r - Eigen::Matrix3d::Identity()).norm() > 1e-6 || r.determinant() < 0) {
      return make_error(ErrorCode::kInvalidArgument,
                        "node " + std::to_string(p.node_id) +
                            ": pose_on_link is not a finite proper rigid transform");
    }
  }
  // The loader checks everything else as it reads: round-trip through it so the rules live once.
  Result<SkinMap> again = load_skin_map_text(skin_map_to_yaml(map), robot);
  if (!again.ok()) return again.error();
  return Status::Ok();
}

Result<SkinMap> load_skin_map_text(const std::string& yaml, const RobotModel* robot) {
  Result<YAML::Node> root = parse_yaml_text(yaml);
  if (!root.ok()) return root.error();
  try {
    return parse(root.value(), robot);
  } catch (const YAML::Exception& e) {
    return make_error(ErrorCode::kParse, "line " + std::to_string(e.mark.line + 1) + ": " + e.msg);
  }
}

Result<SkinMap> load_skin_map_file(const std::string& path, const RobotModel* robot) {
  Result<std::string> text = read_text_file(path, "skin map");
  if (!text.ok()) return text.error();
  Result<SkinMap> map = load_skin_map_text(text.value(), robot);
  if (!map.ok()) return make_error(map.error().code, path + ": " + map.error().message);
  return map;
}

std::string skin_map_to_yaml(const SkinMap& map) {
  std::ostringstream o;
  o << "# skinbus skin map (docs/body_map.md): where each patch sits on the robot.\n"
    << "skin_map_version: 1\n";
  if (!map.robot.empty()) o << "robot: " << yaml_string(map.robot) << "\n";
  o << (map.patches.empty() ? "patches: []\n" : "patches:\n");
  char buf[64];
  for (const PatchPlacement& p : map.patches) {
    std::snprintf(buf, sizeof buf, "0x%016" PRIx64, p.hardware_uid);
    o << "  - node: " << p.node_id << "\n    uid: " << buf << "\n    link: " << yaml_string(p.link)
      << "\n    position_mm: ";
    print_vector(o, p.pose_on_link.translation_mm.data(), 3);
    const Eigen::Quaterniond q(p.pose_on_link.rotation);
    const double wxyz[4] = {q.w(), q.x(), q.y(), q.z()};
    o << "\n    quaternion_wxyz: ";
    print_vector(o, wxyz, 4);
    const Eigen::Vector3d rpy = rpy_from_rotation(p.pose_on_link.rotation) / kDeg;
    std::snprintf(buf, sizeof buf, "  # rpy_deg: [%.3f, %.3f, %.3f]", rpy.x(), rpy.y(), rpy.z());
    o << buf << "\n    geometry:\n      type: "
      << (p.geometry.kind == SurfaceKind::kFlat ? "flat" : "cylinder") << "\n      size_mm: ";
    const double size[2] = {p.geometry.size_u_mm, p.geometry.size_v_mm};
    print_vector(o, size, 2);
    o << "\n";
    if (p.geometry.kind == SurfaceKind::kCylinder) {
      std::snprintf(buf, sizeof buf, "%.15g", p.geometry.radius_mm);
      o << "      radius_mm: " << buf
        << "\n      axis: " << (p.geometry.axis == CylinderAxis::kU ? "u" : "v") << "\n";
      std::snprintf(buf, sizeof buf, "%.3f", p.geometry.arc_deg());
      o << "      # arc_deg: " << buf << "\n";
    }
    if (!p.model.empty()) o << "    model: " << yaml_string(p.model) << "\n";
    if (!p.unit.empty()) o << "    unit: " << yaml_string(p.unit) << "\n";
    if (!p.design.empty()) o << "    design: " << yaml_string(p.design) << "\n";
    if (!p.correction.empty()) o << "    correction: " << yaml_string(p.correction) << "\n";
    if (p.refine_shear) o << "    refine_shear: true\n";
    if (p.max_contacts != 1) o << "    max_contacts: " << p.max_contacts << "\n";
    if (!p.proposer.empty()) o << "    proposer: " << yaml_string(p.proposer) << "\n";
    if (p.calibration) {
      const PoseUncertainty& c = *p.calibration;
      std::snprintf(buf, sizeof buf, "%.6g", c.rms_residual_mm);
      o << "    calibration:\n      touches: " << c.touches << "\n      inliers: " << c.inliers
        << "\n      rms_residual_mm: " << buf << "\n      position_sd_mm: ";
      print_vector(o, c.position_sd_mm.data(), 3);
      o << "\n      rotation_sd_deg: ";
      print_vector(o, c.rotation_sd_deg.data(), 3);
      std::snprintf(buf, sizeof buf, "%.6g", c.radius_sd_mm);
      o << "\n      radius_sd_mm: " << buf << "\n";
    }
  }
  return o.str();
}

Status save_skin_map_file(const SkinMap& map, const std::string& path) {
  return write_file_atomic(path, skin_map_to_yaml(map), "skin map");  // never a torn map
}

std::string path_beside(const std::string& map_path, const std::string& path) {
  if (path.empty() || std::filesystem::path(path).is_absolute()) return path;
  return (std::filesystem::path(map_path).parent_path() / path).lexically_normal().string();
}

}  // namespace skinbus::body_map
