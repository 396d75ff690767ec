// skinbus/sim/unit_parameters.h: the explicit physical parameters of one patch unit.
//
// A PatchModel is its design (skinbus/sim/patch_model.h: PatchDesign) plus these numbers: where
// every magnet sits and how it is magnetised, where every sensor sits, how it is turned and how
// sensitive each of its axes is, and how the lattice spreads a press. PatchModel::parameters()
// reads them from a model; PatchModel::from_parameters() builds a model from them (the round
// trip is exact). Per-unit identification (fusion/unit_identification.h) fits them from a
// unit's own presses.
//
// The model class: one isotropic spread length. A design's `anisotropy` (different spread along
// u and v) is applied on top of `spread_mm` by from_parameters(), exactly as PatchModel builds a
// fabricated unit, but identification never fits it: a unit with anisotropy carries physics the
// identified class does not contain.
//
// Plain data; copying costs (magnets + sensors) small structs.
#pragma once

#include <vector>

#include "skinbus/sim/vec3.h"

namespace skinbus::sim {

struct MagnetParameters {
  // Rest position in surface coordinates (mm): u, v along the patch, h above the skin surface.
  double u_mm = 0, v_mm = 0, h_mm = 0;
  // Moment in the local surface frame (t_u, t_v, normal), A m^2; tilt and strength included.
  Vec3<double> moment_am2{};
};

struct SensorParameters {
  // Position in surface coordinates (mm); h < 0: below the surface.
  double u_mm = 0, v_mm = 0, h_mm = 0;
  // Mounting rotation relative to the local surface frame: row r of the sensor's frame is
  // sum_k mounting.r[r][k] * (t_u, t_v, normal)[k]. Identity for a perfectly mounted chip.
  Mat3 mounting;
  // Per-axis gain (1 nominal): channel = gain * (field along the axis).
  Vec3<double> gain{1, 1, 1};
};

struct UnitParameters {
  double spread_mm = 10;  // isotropic plate-on-foundation length l (mm), > 0
  double lateral_mm = 2;  // in-plane motion of a magnet = -lateral * surface slope (mm), >= 0
  std::vector<MagnetParameters> magnets;  // design order: u index fastest
  std::vector<SensorParameters> sensors;  // design order: u index fastest
};

}  // namespace skinbus::sim
