#include "skinbus/view/foxglove_json.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <nlohmann/json.hpp>

#include "skinbus/common/uid.h"

namespace skinbus::view {
namespace {

using Json = nlohmann::json;

constexpr double kMetresPerMm = 0.001;
constexpr double kPatchLiftMm = 1.5;    // patches are drawn this far out of the skin (as the page)
constexpr int kCylinderArcPoints = 13;  // points across a cylinder patch's curved direction
constexpr double kForceMaxN = 8;        // the force colour ramp's top

std::string dump(const Json& j) {
  return j.dump(-1, ' ', false, Json::error_handler_t::replace);
}

Json time_json(uint64_t stamp_us) {
  return {{"sec", stamp_us / 1'000'000}, {"nsec", (stamp_us % 1'000'000) * 1000}};
}

Json vec3(double x, double y, double z) {
  return {{"x", x}, {"y", y}, {"z", z}};
}

Json point_m(const Eigen::Vector3d& p_mm) {
  return vec3(p_mm.x() * kMetresPerMm, p_mm.y() * kMetresPerMm, p_mm.z() * kMetresPerMm);
}

Json quaternion(const Eigen::Matrix3d& r) {
  Eigen::Quaterniond q(r);
  q.normalize();
  if (q.w() < 0) q.coeffs() *= -1;  // one of the two: w >= 0
  return {{"x", q.x()}, {"y", q.y()}, {"z", q.z()}, {"w", q.w()}};
}

Json identity_pose() {
  return {{"position", vec3(0, 0, 0)}, {"orientation", {{"x", 0}, {"y", 0}, {"z", 0}, {"w", 1}}}};
}

Json colour(double r, double g, double b, double a) {
  return {{"r", r}, {"g", g}, {"b", b}, {"a", a}};
}

Json hex_colour(uint32_t rgb, double a) {
  return colour(((rgb >> 16) & 0xff) / 255.0, ((rgb >> 8) & 0xff) / 255.0, (rgb & 0xff) / 255.0, a);
}

// The page's force ramp (view/web): nine stops, the top one at kForceMaxN and above.
Json force_colour(double force_n) {
  static constexpr std::array<uint32_t, 9> kStops = {
      0x2c7bb6, 0x00a6ca, 0x00ccbc, 0x90eb9d, 0xffff8c, 0xf9d057, 0xf29e2e, 0xe76818, 0xd7191c};
  const double t = std::clamp(std::isfinite(force_n) ? force_n / kForceMaxN : 0.0, 0.0, 1.0) *
                   (kStops.size() - 1);
  const auto i = std::min<std::size_t>(static_cast<std::size_t>(t), kStops.size() - 2);
  const double f = t - static_cast<double>(i);
  auto channel = [&](int shift) {
    const double a = ((kStops[i] >> shift) & 0xff) / 255.0;
    const double b = ((kStops[i + 1] >> shift) & 0xff) / 255.0;
    return a + (b - a) * f;
  };
  return colour(channel(16), channel(8), channel(0), 0.9);
}

// The page's state colours (view/web).
Json state_colour(const std::string& state) {
  constexpr double kAlpha = 0.55;
  if (state == "online") return hex_colour(0x2ecc40, kAlpha);
  if (state == "degraded") return hex_colour(0xff851b, kAlpha);
  if (state == "stale") return hex_colour(0xffdc00, kAlpha);
  if (state == "offline") return hex_colour(0x8a8a8a, kAlpha);
  if (state == "discovering") return hex_colour(0x3d8bfd, kAlpha);
  return hex_colour(0xd8d8e8, kAlpha);
}

Json key_values(const std::vector<std::pair<std::string, std::string>>& pairs) {
  Json out = Json::array();
  for (const auto& [k, v] : pairs) out.push_back({{"key", k}, {"value", v}});
  return out;
}

std::string number_text(double v) {
  return Json(v).dump();
}

Json entity(uint64_t stamp_us, const std::string& frame_id, const std::string& id,
            bool frame_locked) {
  return {{"timestamp", time_json(stamp_us)},
          {"frame_id", frame_id},
          {"id", id},
          {"lifetime", {{"sec", 0}, {"nsec", 0}}},
          {"frame_locked", frame_locked},
          {"metadata", Json::array()},
          {"arrows", Json::array()},
          {"cubes", Json::array()},
          {"spheres", Json::array()},
          {"cylinders", Json::array()},
          {"lines", Json::array()},
          {"triangles", Json::array()},
          {"texts", Json::array()},
          {"models", Json::array()}};
}

// -- JSON Schema pieces --------------------------------------------------------------------------

Json number_schema() {
  return {{"type", "number"}};
}

Json object_schema(const std::string& title, Json properties) {
  Json required = Json::array();
  for (const auto& [k, v] : properties.items()) required.push_back(k);
  return {{"title", title},
          {"type", "object"},
          {"properties", std::move(properties)},
          {"required", std::move(required)}};
}

Json time_schema() {
  return object_schema("time",
                       {{"sec", {{"type", "integer"}, {"minimum", 0}}},
                        {"nsec", {{"type", "integer"}, {"minimum", 0}, {"maximum", 999'999'999}}}});
}

Json vector3_schema(const std::string& title) {
  return object_schema(title,
                       {{"x", number_schema()}, {"y", number_schema()}, {"z", number_schema()}});
}

Json quaternion_schema() {
  return object_schema("foxglove.Quaternion", {{"x", number_schema()},
                                               {"y", number_schema()},
                                               {"z", number_schema()},
                                               {"w", number_schema()}});
}

Json pose_schema() {
  return object_schema("foxglove.Pose", {{"position", vector3_schema("foxglove.Vector3")},
                                         {"orientation", quaternion_schema()}});
}

Json colour_schema() {
  return object_schema("foxglove.Color", {{"r", number_schema()},
                                          {"g", number_schema()},
                                          {"b", number_schema()},
                                          {"a", number_schema()}});
}

Json array_of(Json items) {
  return {{"type", "array"}, {"items", std::move(items)}};
}

}  // namespace

std::string foxglove_scene_update_schema() {
  const Json sphere =
      object_schema("foxglove.SpherePrimitive", {{"pose", pose_schema()},
                                                 {"size", vector3_schema("foxglove.Vector3")},
                                                 {"color", colour_schema()}});
  const Json cube =
      object_schema("foxglove.CubePrimitive", {{"pose", pose_schema()},
                                               {"size", vector3_schema("foxglove.Vector3")},
                                               {"color", colour_schema()}});
  const Json triangles =
      object_schema("foxglove.TriangleListPrimitive",
                    {{"pose", pose_schema()},
                     {"points", array_of(vector3_schema("foxglove.Point3"))},
                     {"color", colour_schema()},
                     {"colors", array_of(colour_schema())},
                     {"indices", array_of({{"type", "integer"}, {"minimum", 0}})}});
  const Json arrow = object_schema("foxglove.ArrowPrimitive", {{"pose", pose_schema()},
                                                               {"shaft_length", number_schema()},
                                                               {"shaft_diameter", number_schema()},
                                                               {"head_length", number_schema()},
                                                               {"head_diameter", number_schema()},
                                                               {"color", colour_schema()}});
  const Json key_value = object_schema(
      "foxglove.KeyValuePair", {{"key", {{"type", "string"}}}, {"value", {{"type", "string"}}}});
  Json entity_properties = {
      {"timestamp", time_schema()},
      {"frame_id", {{"type", "string"}}},
      {"id", {{"type", "string"}}},
      {"lifetime", time_schema()},
      {"frame_locked", {{"type", "boolean"}}},
      {"metadata", array_of(key_value)},
      {"spheres", array_of(sphere)},
      {"cubes", array_of(cube)},
      {"triangles", array_of(triangles)},
      {"arrows", array_of(arrow)},
      // Primitives these messages leave empty (see Foxglove's schema for their fields).
      {"cylinders", array_of({{"type", "object"}})},
      {"lines", array_of({{"type", "object"}})},
      {"texts", array_of({{"type", "object"}})},
      {"models", array_of({{"type", "object"}})},
  };
  const Json deletion =
      object_schema("foxglove.SceneEntityDeletion",
                    {{"timestamp", time_schema()},
                     {"type",
                      {{"title", "foxglove.SceneEntityDeletionType"},
                       {"oneOf", Json::array({{{"title", "MATCHING_ID"}, {"const", 0}},
                                              {{"title", "ALL"}, {"const", 1}}})}}},
                     {"id", {{"type", "string"}}}});
  Json schema = object_schema(
      "foxglove.SceneUpdate",
      {{"deletions", array_of(deletion)},
       {"entities",
        array_of(object_schema("foxglove.SceneEntity", std::move(entity_properties)))}});
  schema["description"] = "skinbus contacts (spheres in the base frame) and patches (on links)";
  return dump(schema);
}

std::string foxglove_frame_transforms_schema() {
  const Json transform =
      object_schema("foxglove.FrameTransform", {{"timestamp", time_schema()},
                                                {"parent_frame_id", {{"type", "string"}}},
                                                {"child_frame_id", {{"type", "string"}}},
                                                {"translation", vector3_schema("foxglove.Vector3")},
                                                {"rotation", quaternion_schema()}});
  Json schema = object_schema("foxglove.FrameTransforms", {{"transforms", array_of(transform)}});
  schema["description"] = "every robot link from its parent (the URDF posed by the joint states)";
  return dump(schema);
}

std::string skinbus_patch_status_schema() {
  const Json string_schema = {{"type", "string"}};
  const Json integer = {{"type", "integer"}};
  Json patch = object_schema("skinbus.PatchStatus", {{"node", integer},
                                                     {"hardware_uid", string_schema},
                                                     {"interface", string_schema},
                                                     {"link", string_schema},
                                                     {"state", string_schema},
                                                     {"node_state", integer},
                                                     {"node_mode", integer},
                                                     {"fault_mask", integer},
                                                     {"uptime_s", integer},
                                                     {"reboots", integer},
                                                     {"samples", integer},
                                                     {"samples_lost", integer},
                                                     {"contacts", integer},
                                                     {"clock_offset_us", number_schema()},
                                                     {"clock_drift_ppm", number_schema()},
                                                     {"last_heard_us", integer},
                                                     {"duplicate_id", {{"type", "boolean"}}},
                                                     {"detail", string_schema}});
  Json event = object_schema("skinbus.PatchEvent", {{"time_us", integer},
                                                    {"event", string_schema},
                                                    {"node", integer},
                                                    {"hardware_uid", string_schema},
                                                    {"detail", string_schema}});
  Json schema = object_schema("skinbus.PatchStatusArray", {{"type", {{"const", "patch_status"}}},
                                                           {"stamp_us", integer},
                                                           {"patches", array_of(std::move(patch))},
                                                           {"events", array_of(std::move(event))}});
  schema["description"] =
      "rt/skin/patch_status as skinbus-host --json writes it (docs/aggregator.md)";
  return dump(schema);
}

double shear_arrow_length_mm(double shear_n) {
  return std::isfinite(shear_n) ? std::max(12.0 * shear_n, 4.0) : 4.0;
}

double contact_sphere_diameter_mm(double depth_mm) {
  const double d = std::isfinite(depth_mm) ? std::clamp(depth_mm, 0.0, 5.0) : 0.0;
  return 2 * (5 + 3 * d);
}

std::string ContactSceneEncoder::encode(uint64_t stamp_us, const std::string& base_frame,
                                        std::span<const SceneContact> contacts) {
  Json entities = Json::array(), deletions = Json::array();
  std::vector<uint32_t> now;
  now.reserve(contacts.size());
  for (const auto& c : contacts) {
    now.push_back(c.track_id);
    Json e = entity(stamp_us, base_frame, "contact/" + std::to_string(c.track_id), false);
    const double d_m = contact_sphere_diameter_mm(c.depth_mm) * kMetresPerMm;
    e["spheres"].push_back(
        {{"pose",
          {{"position",
            point_m(Eigen::Vector3d(c.position_mm[0], c.position_mm[1], c.position_mm[2]))},
           {"orientation", {{"x", 0}, {"y", 0}, {"z", 0}, {"w", 1}}}}},
         {"size", vec3(d_m, d_m, d_m)},
         {"color", force_colour(c.force_n)}});
    std::vector<std::pair<std::string, std::string>> meta = {
        {"track_id", std::to_string(c.track_id)},
        {"node", std::to_string(c.node)},
        {"link", c.link},
        {"depth_mm", number_text(c.depth_mm)},
        {"force_n", number_text(c.force_n)}};
    const Eigen::Vector3d shear(c.shear_n[0], c.shear_n[1], c.shear_n[2]);
    const double newtons = shear.norm();
    if (c.has_shear && newtons > 0 && std::isfinite(newtons)) {
      // From the sphere's surface along the force; the arrow points along its pose's x axis.
      const Eigen::Vector3d dir = shear / newtons;
      const Eigen::Vector3d from =
          Eigen::Vector3d(c.position_mm[0], c.position_mm[1], c.position_mm[2]) +
          dir * (contact_sphere_diameter_mm(c.depth_mm) / 2);
      const Eigen::Quaterniond q =
          Eigen::Quaterniond::FromTwoVectors(Eigen::Vector3d::UnitX(), dir);
      const double length_m = shear_arrow_length_mm(newtons) * kMetresPerMm;
      e["arrows"].push_back(
          {{"pose",
            {{"position", point_m(from)},
             {"orientation", {{"x", q.x()}, {"y", q.y()}, {"z", q.z()}, {"w", q.w()}}}}},
           {"shaft_length", 0.7 * length_m},
           {"shaft_diameter", 1.5 * kMetresPerMm},
           {"head_length", 0.3 * length_m},
           {"head_diameter", 4 * kMetresPerMm},
           {"color", {{"r", 1.0}, {"g", 0.82}, {"b", 0.25}, {"a", 1.0}}}});
      meta.push_back({"shear_n", number_text(shear.x()) + " " + number_text(shear.y()) + " " +
                                     number_text(shear.z())});
    }
    e["metadata"] = key_values(meta);
    entities.push_back(std::move(e));
  }
  // Foxglove deletes entities stamped earlier than the deletion: the host publishes a stamp again
  // when only a track ended, so the deletion is stamped 1 ns after the publication.
  Json deletion_time = time_json(stamp_us);
  deletion_time["nsec"] = deletion_time["nsec"].get<uint64_t>() + 1;
  for (uint32_t id : previous_) {
    if (std::find(now.begin(), now.end(), id) == now.end()) {
      deletions.push_back(
          {{"timestamp", deletion_time}, {"type", 0}, {"id", "contact/" + std::to_string(id)}});
    }
  }
  previous_ = std::move(now);
  return dump({{"deletions", std::move(deletions)}, {"entities", std::move(entities)}});
}

std::string patches_scene_update_json(uint64_t stamp_us, const body_map::SkinMap& map,
                                      std::span<const std::string> states) {
  Json entities = Json::array();
  for (std::size_t k = 0; k < map.patches.size(); ++k) {
    const auto& p = map.patches[k];
    const auto& g = p.geometry;
    const std::string state = k < states.size() && !states[k].empty() ? states[k] : "unknown";
    // A grid over the surface: 2 x 2 for a flat patch, kCylinderArcPoints across a cylinder's
    // curved direction.
    const bool cylinder = g.kind == body_map::SurfaceKind::kCylinder;
    const int nu = cylinder && g.axis == body_map::CylinderAxis::kV ? kCylinderArcPoints : 2;
    const int nv = cylinder && g.axis == body_map::CylinderAxis::kU ? kCylinderArcPoints : 2;
    Json points = Json::array(), indices = Json::array();
    for (int i = 0; i < nu; ++i) {
      const double u = -g.size_u_mm / 2 + i * g.size_u_mm / (nu - 1);
      for (int j = 0; j < nv; ++j) {
        const double v = -g.size_v_mm / 2 + j * g.size_v_mm / (nv - 1);
        points.push_back(point_m(body_map::link_surface_point(p, u, v, -kPatchLiftMm).point_mm));
      }
    }
    for (int i = 0; i + 1 < nu; ++i) {
      for (int j = 0; j + 1 < nv; ++j) {
        const int a = i * nv + j, b = (i + 1) * nv + j, c = (i + 1) * nv + j + 1,
                  d = i * nv + j + 1;
        for (int n : {a, b, c, a, c, d}) indices.push_back(n);
      }
    }
    Json e = entity(stamp_us, p.link, "patch/" + std::to_string(p.node_id), true);
    e["triangles"].push_back({{"pose", identity_pose()},
                              {"points", std::move(points)},
                              {"color", state_colour(state)},
                              {"colors", Json::array()},
                              {"indices", std::move(indices)}});
    e["metadata"] = key_values({{"node", std::to_string(p.node_id)},
                                {"hardware_uid", format_uid(p.hardware_uid)},
                                {"link", p.link},
                                {"state", state},
                                {"kind", cylinder ? "cylinder" : "flat"}});
    entities.push_back(std::move(e));
  }
  return dump({{"deletions", Json::array()}, {"entities", std::move(entities)}});
}

std::string frame_transforms_json(uint64_t stamp_us, const body_map::RobotModel& robot,
                                  std::span<const body_map::Pose> link_poses) {
  Json transforms = Json::array();
  const int n = std::min<int>(robot.link_count(), static_cast<int>(link_poses.size()));
  for (int i = 0; i < n; ++i) {
    const auto& link = robot.link(i);
    if (link.parent < 0 || link.parent >= n) continue;
    const body_map::Pose rel = link_poses[link.parent].inverse() * link_poses[i];
    transforms.push_back({{"timestamp", time_json(stamp_us)},
                          {"parent_frame_id", robot.link(link.parent).name},
                          {"child_frame_id", link.name},
                          {"translation", point_m(rel.translation_mm)},
                          {"rotation", quaternion(rel.rotation)}});
  }
  return dump({{"transforms", std::move(transforms)}});
}

}  // namespace skinbus::view
