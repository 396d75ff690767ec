// skinbus/view/foxglove_json.h: the messages skinbus-view sends on its Foxglove channels
// (docs/foxglove.md), JSON in Foxglove's schemas, and the JSON Schemas it advertises for them:
//
//   /skin/contacts       foxglove.SceneUpdate     the contacts (a sphere each) and the patches
//                                                 (a surface each, on its link, by state)
//   /tf                  foxglove.FrameTransforms every link from its parent (the URDF, posed)
//   /skin/patch_status   skinbus.PatchStatusArray the host's patch status, as skinbus-host --json
//
// Units are Foxglove's: metres, quaternions (x, y, z, w), times {sec, nsec}; the inputs are the
// project's (millimetres, microseconds). Every function returns one line of JSON and allocates
// for it; none fails (text that is not UTF-8, a link name from a file, is replaced).
#pragma once

#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include "skinbus/body_map/pose.h"
#include "skinbus/body_map/robot_model.h"
#include "skinbus/body_map/skin_map.h"

namespace skinbus::view {

// The JSON Schemas advertised (schemaEncoding "jsonschema"): the fields these messages carry.
std::string foxglove_scene_update_schema();
std::string foxglove_frame_transforms_schema();
std::string skinbus_patch_status_schema();

// Schema names.
inline constexpr char kSceneUpdateSchemaName[] = "foxglove.SceneUpdate";
inline constexpr char kFrameTransformsSchemaName[] = "foxglove.FrameTransforms";
inline constexpr char kPatchStatusSchemaName[] = "skinbus.PatchStatusArray";

// One contact as the scene shows it (host::BodyContact's fields the scene needs; view does not
// depend on host).
struct SceneContact {
  uint32_t track_id = 0;
  double position_mm[3] = {0, 0, 0};  // in the base frame
  double depth_mm = 0;
  double force_n = 0;
  int node = 0;
  std::string link;
  // The contact's shear force (N, base frame) when it has one (host's kContactShear): drawn as an
  // arrow. `has_shear` false: none.
  bool has_shear = false;
  double shear_n[3] = {0, 0, 0};
};

// A shear arrow's length (mm) for a force (N), as the web page draws it: 12 mm a newton, at least
// 4 mm.
double shear_arrow_length_mm(double shear_n);

// The contact sphere's diameter (mm) for a depth (mm), as the web page draws it: 2 * (5 + 3 *
// depth), depth clamped to [0, 5] mm.
double contact_sphere_diameter_mm(double depth_mm);

// The contacts of one publication as a SceneUpdate: entity "contact/<track_id>" per contact in
// `base_frame` (a sphere at its position, sized by depth, coloured by force; with a shear force,
// an arrow from the sphere's surface along it, its pose's x axis the force's direction, its
// length shear_arrow_length_mm(); metadata track_id, node, link, depth_mm, force_n, and shear_n
// with a shear), and a MATCHING_ID deletion for every track of the previous
// publication that has ended, stamped 1 ns after `stamp_us` (Foxglove deletes entities stamped
// earlier than the deletion, and the host publishes a stamp again when only a track ends). Keeps
// the track IDs it sent last (at most one publication's).
class ContactSceneEncoder {
 public:
  std::string encode(uint64_t stamp_us, const std::string& base_frame,
                     std::span<const SceneContact> contacts);

 private:
  std::vector<uint32_t> previous_;
};

// The patches of `map` as a SceneUpdate: entity "patch/<node>" per patch, in its link's frame
// (frame_locked: it moves with the link), a triangle list of its surface 1.5 mm out of the skin
// (through body_map::link_surface_point, as the host places contacts), coloured by `states[i]`,
// the host's state name of map.patches[i] ("online", "degraded", "stale", "offline",
// "discovering"; "" or anything else: unknown, grey-white); metadata node, hardware_uid, link,
// state, kind. `states` has one entry per patch (missing entries count as "").
std::string patches_scene_update_json(uint64_t stamp_us, const body_map::SkinMap& map,
                                      std::span<const std::string> states);

// Every link of `robot` but the root as a FrameTransform from its parent link (parent_frame_id
// the parent's name, child_frame_id the link's), from `link_poses` (RobotModel::
// forward_kinematics: each link in the root frame, mm): parent^-1 * link. `link_poses` has
// robot.link_count() entries.
std::string frame_transforms_json(uint64_t stamp_us, const body_map::RobotModel& robot,
                                  std::span<const body_map::Pose> link_poses);

}  // namespace skinbus::view
