// skinbus/view/scene_json.h: what the web view's server sends that the host does not publish:
// the scene (the robot's URDF address and every patch's surface on its link) and joint states.
// Formats in docs/view.md.
#pragma once

#include <cstdint>
#include <span>
#include <string>

#include "skinbus/body_map/skin_map.h"

namespace skinbus::view {

// Points across each axis of a patch's surface grid in the scene (15 x 15 per patch).
inline constexpr int kSceneGridPoints = 15;

// The scene document (GET /api/scene), one line of JSON: `robot_url` (may be empty) and every
// patch of `map` with its surface sampled on a grid in its link's frame (mm), through the same
// body_map::link_surface_point the host places contacts with.
std::string scene_to_json(const body_map::SkinMap& map, const std::string& robot_url,
                          const std::string& base_frame, bool read_only);

// A joint_state message: names and positions (radians, metres) at `stamp_us`. Non-finite
// positions are sent as null (JSON has no NaN).
std::string joint_state_to_json(uint64_t stamp_us, std::span<const std::string> names,
                                std::span<const double> positions);

// A heartbeat: `host_age_ms` since the host's last message (-1: never).
std::string heartbeat_to_json(uint64_t stamp_us, int64_t host_age_ms);

// The first message of every connection.
std::string hello_to_json(bool read_only);

}  // namespace skinbus::view
