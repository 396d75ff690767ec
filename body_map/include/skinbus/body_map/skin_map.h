// skinbus/body_map/skin_map.h: where each patch sits on the robot, its shape, and the mapping
// between a patch's own coordinates (u, v, depth) and points of its parent link.
//
// The patch frame (as everywhere in skinbus): origin at the patch centre on the skin surface,
// x along u, y along v (the sensor grid), z out of the skin; depth is positive into the skin.
// `pose_on_link` maps patch-frame points into the parent link's frame (millimetres).
//
// Geometry:
// - flat: the surface is the patch frame's z = 0 plane; (u, v, depth) -> (u, v, -depth).
// - cylinder: the patch is wrapped around a cylinder of radius `radius_mm` (the outer skin
//   surface) whose axis is parallel to the patch's v axis (`axis = kV`) or u axis (`kU`) and
//   passes through (0, 0, -radius_mm) of the patch frame. The coordinate across the axis is arc
//   length on the outer surface: for kV, theta = u / radius and the point at depth d is
//   ((R - d) sin theta, v, (R - d) cos theta - R), its outward normal (sin theta, 0, cos theta).
//   The arc the patch covers is its size across the axis divided by the radius.
//
// The skin map file is YAML; docs/body_map.md documents every key. Reading checks everything a
// later stage relies on and names the key and line of what is wrong.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "skinbus/body_map/pose.h"
#include "skinbus/body_map/robot_model.h"
#include "skinbus/common/result.h"

namespace skinbus::body_map {

enum class SurfaceKind { kFlat, kCylinder };
enum class CylinderAxis { kU, kV };  // the patch direction that runs along the cylinder's axis

struct PatchGeometry {
  SurfaceKind kind = SurfaceKind::kFlat;
  double size_u_mm = 140, size_v_mm = 140;  // extent on the surface (arc length across an axis)
  double radius_mm = 0;                     // cylinder only: radius of the outer surface
  CylinderAxis axis = CylinderAxis::kV;     // cylinder only

  // Angle the patch covers around a cylinder (degrees); 0 for a flat patch.
  double arc_deg() const;
};

// What the calibrator learnt about a patch's pose (kept in the skin map for the record).
struct PoseUncertainty {
  int touches = 0, inliers = 0;
  double rms_residual_mm = 0;
  Eigen::Vector3d position_sd_mm = Eigen::Vector3d::Zero();   // along the link's axes
  Eigen::Vector3d rotation_sd_deg = Eigen::Vector3d::Zero();  // about the link's axes
  double radius_sd_mm = 0;                                    // 0 when the radius was not fitted
};

// A patch sits at most this far from its link's origin (a skin map that places one farther is
// refused: mm mistaken for something else, or a damaged file). Contacts placed beyond a
// kilometre are not contacts on a robot.
inline constexpr double kMaxPatchOffsetMm = 10'000;

struct PatchPlacement {
  int node_id = 0;            // CAN node ID, 1..125
  uint64_t hardware_uid = 0;  // the node's 64-bit hardware UID
  std::string link;           // parent link (URDF link name)
  Pose pose_on_link;          // patch frame -> link frame
  PatchGeometry geometry;
  std::string model;  // the patch's model file (relative paths are relative to the map file)
  // The unit's calibration, for the host's physics refinement (docs/aggregator.md): its unit file
  // (sim/unit_parameters.h, written by skinbus-identify) and design file (docs/design_file.md;
  // empty: the built-in design). Relative paths are relative to the map file. Empty unit: none.
  std::string unit;
  std::string design;
  // The unit's learned correction of the refined estimate (a correction file,
  // estimators/bias_correction.h, as scripts/calibrate_unit.sh writes it when the unit's own
  // presses show one pays off); relative to the map file. Empty: none. Used only with a unit.
  std::string correction;
  // The refinement also fits each contact's shear force (published as its shear and in its
  // wrench). It costs the position precision (about 2.3x the bound without it:
  // docs/benchmarks/shear.md), so it is for patches where shear matters.
  bool refine_shear = false;
  // How many presses the refinement looks for on this patch: 1, 2 (two fingers) or 3 (a grasp;
  // each published with its own track). A search for another press costs a few milliseconds
  // (tens with three; made when a press's fit leaves more than noise, rate-limited), held
  // presses about 0.5 ms a sample for two, a few for three (docs/aggregator.md).
  int max_contacts = 1;
  // With max_contacts 2 or 3: a proposer network (docs/models.md, "The proposer"; model path
  // stem, relative to the map file) the count starts from when it proposes several presses,
  // instead of searching from nothing (about 1-3 ms for three presses instead of 8-22). Empty:
  // none.
  std::string proposer;
  std::optional<PoseUncertainty> calibration;
};

struct SkinMap {
  std::string robot;  // URDF file (relative paths are relative to the map file); may be empty
  std::vector<PatchPlacement> patches;

  // The placement of node `node_id`, or nullptr.
  const PatchPlacement* find_node(int node_id) const;
  PatchPlacement* find_node(int node_id);
};

// A point on (or under) the skin, in some frame.
struct SurfacePoint {
  Eigen::Vector3d point_mm;
  Eigen::Vector3d normal;  // unit, outward
  // Unit tangents along increasing u and v at the point (u, v, normal: right-handed; a shear
  // force's patch components become a vector along them).
  Eigen::Vector3d tangent_u = Eigen::Vector3d::UnitX(), tangent_v = Eigen::Vector3d::UnitY();
};

// The patch-frame point at (u, v, depth) for a geometry, over any scalar (double or a Ceres jet)
// so that calibration can differentiate through the radius. `radius_mm` is used for cylinders.
template <typename T>
Eigen::Matrix<T, 3, 1> patch_point(const PatchGeometry& g, const T& radius_mm, const T& u_mm,
                                   const T& v_mm, const T& depth_mm) {
  using std::cos;
  using std::sin;
  if (g.kind == SurfaceKind::kFlat) return {u_mm, v_mm, -depth_mm};
  const T r = radius_mm - depth_mm;
  if (g.axis == CylinderAxis::kV) {
    const T theta = u_mm / radius_mm;
    return {r * sin(theta), v_mm, r * cos(theta) - radius_mm};
  }
  const T theta = v_mm / radius_mm;
  return {u_mm, r * sin(theta), r * cos(theta) - radius_mm};
}

// The point and outward normal at (u, v, depth) in the patch frame.
SurfacePoint patch_surface_point(const PatchGeometry& g, double u_mm, double v_mm, double depth_mm);

// The point and outward normal at (u, v, depth) in the parent link's frame.
SurfacePoint link_surface_point(const PatchPlacement& p, double u_mm, double v_mm, double depth_mm);

// Patch coordinates of a point.
struct PatchCoordinates {
  double u_mm = 0, v_mm = 0, depth_mm = 0;
  bool inside = false;  // (u, v) within the patch's extent and depth within [-0.5, 10] mm
};

// The inverse of patch_surface_point / link_surface_point. Error (kDegenerate) for a point on a
// cylinder's axis, where the coordinates are undefined; kInvalidArgument for a non-finite point.
Result<PatchCoordinates> patch_coordinates(const PatchGeometry& g, const Eigen::Vector3d& p_mm);
Result<PatchCoordinates> link_to_patch_coordinates(const PatchPlacement& p,
                                                   const Eigen::Vector3d& p_link_mm);

// Checks one geometry: finite sizes in (0, 1000] mm; a cylinder's radius in [5, 5000] mm and an
// arc of at most 360 degrees. The error names what is wrong.
Status validate_geometry(const PatchGeometry& g);

// Reads a skin map (YAML). Errors name the key and line. Checks each entry (node 1..125, unique
// node IDs and hardware UIDs, a link name, a proper rotation, a valid geometry); when `robot` is
// given, every link must exist in it.
Result<SkinMap> load_skin_map_text(const std::string& yaml, const RobotModel* robot = nullptr);
Result<SkinMap> load_skin_map_file(const std::string& path, const RobotModel* robot = nullptr);

// A path named in the map file `map_path` (its robot, a model), as the tools open it: relative
// paths are relative to the map file's folder; absolute and empty ones are returned as they are.
std::string path_beside(const std::string& map_path, const std::string& path);

// Checks a map built in code the same way the loader checks a file.
Status validate_skin_map(const SkinMap& map, const RobotModel* robot = nullptr);

// Writes a map as YAML that load_skin_map_text reads back to the same map (poses to 1e-9 mm and
// 1e-9 degrees).
std::string skin_map_to_yaml(const SkinMap& map);
Status save_skin_map_file(const SkinMap& map, const std::string& path);

}  // namespace skinbus::body_map
