#include "skinbus/view/scene_json.h"

#include <cmath>
#include <nlohmann/json.hpp>

#include "skinbus/common/uid.h"

namespace skinbus::view {
namespace {

nlohmann::json vec(const Eigen::Vector3d& v) {
  return nlohmann::json::array({v.x(), v.y(), v.z()});
}

// One line; bytes that are not UTF-8 (a link name from a file) are replaced, never thrown on.
std::string dump(const nlohmann::json& j) {
  return j.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace);
}

}  // namespace

std::string scene_to_json(const body_map::SkinMap& map, const std::string& robot_url,
                          const std::string& base_frame, bool read_only) {
  nlohmann::json patches = nlohmann::json::array();
  for (const auto& p : map.patches) {
    const auto& g = p.geometry;
    const auto centre = body_map::link_surface_point(p, 0, 0, 0);
    nlohmann::json points = nlohmann::json::array();
    for (int i = 0; i < kSceneGridPoints; ++i) {
      const double u = -g.size_u_mm / 2 + i * g.size_u_mm / (kSceneGridPoints - 1);
      for (int j = 0; j < kSceneGridPoints; ++j) {
        const double v = -g.size_v_mm / 2 + j * g.size_v_mm / (kSceneGridPoints - 1);
        points.push_back(vec(body_map::link_surface_point(p, u, v, 0).point_mm));
      }
    }
    patches.push_back({
        {"node", p.node_id},
        {"hardware_uid", format_uid(p.hardware_uid)},
        {"link", p.link},
        {"kind", g.kind == body_map::SurfaceKind::kFlat ? "flat" : "cylinder"},
        {"size_u_mm", g.size_u_mm},
        {"size_v_mm", g.size_v_mm},
        {"radius_mm", g.kind == body_map::SurfaceKind::kFlat ? 0.0 : g.radius_mm},
        {"centre_mm", vec(centre.point_mm)},
        {"normal", vec(centre.normal)},
        {"grid", {{"nu", kSceneGridPoints}, {"nv", kSceneGridPoints}, {"points_mm", points}}},
    });
  }
  return dump({{"type", "scene"},
               {"robot_url", robot_url},
               {"base_frame", base_frame},
               {"read_only", read_only},
               {"patches", patches}});
}

std::string joint_state_to_json(uint64_t stamp_us, std::span<const std::string> names,
                                std::span<const double> positions) {
  nlohmann::json n = nlohmann::json::array(), q = nlohmann::json::array();
  for (const auto& name : names) n.push_back(name);
  for (double x : positions) q.push_back(std::isfinite(x) ? nlohmann::json(x) : nlohmann::json());
  return dump({{"type", "joint_state"}, {"stamp_us", stamp_us}, {"names", n}, {"positions", q}});
}

std::string heartbeat_to_json(uint64_t stamp_us, int64_t host_age_ms) {
  return dump({{"type", "heartbeat"}, {"stamp_us", stamp_us}, {"host_age_ms", host_age_ms}});
}

std::string hello_to_json(bool read_only) {
  return dump({{"type", "hello"}, {"read_only", read_only}});
}

}  // namespace skinbus::view
