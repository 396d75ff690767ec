// skinbus/sim/unit_parameters.h: the explicit physical parameters of one patch unit.
//
// A PatchModel is its design (skinbus/sim/patch_model.h: PatchDesign) plus these numbers: where
// every magnet sits and how it is magnetised, where every sensor sits, how it is turned and how
// sensitive each of its axes is, and how the lattice spreads a press. PatchModel::parameters()
// reads them from a model; PatchModel::from_parameters() builds a model from them (the round
// trip is exact). Per-unit identification (estimators/unit_identification.h) fits them from a
// unit's own presses.
//
// The model class: a spread length along u and one along v (`spread_mm` and `anisotropy`: l_u =
// l (1 + a), l_v = l (1 - a)), which identification fits. A design's `anisotropy` is added to the
// unit's by from_parameters(): PatchModel builds a fabricated unit so (its parameters carry 0, the
// design the lattice's), and a simulation may put an identified unit on another lattice so.
//
// Plain data; copying costs (magnets + sensors) small structs.
#pragma once

#include <memory>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "skinbus/common/result.h"
#include "skinbus/sim/field_correction.h"
#include "skinbus/sim/pressed_area.h"
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
  double spread_mm = 10;  // plate-on-foundation length l (mm), > 0: the mean of u's and v's
  double anisotropy = 0;  // l_u = l (1 + a), l_v = l (1 - a); with the design's, |sum| < 0.5
  double lateral_mm = 2;  // in-plane motion of a magnet = -lateral * surface slope (mm), >= 0
  // The depth the presses read when the tip meets the surface (mm; an indenter whose zero is not
  // the surface's: positive, it reads deep): a contact's depth_mm presses depth_mm - depth_zero_mm
  // into the lattice. Identification finds the zero of the presses it was given, and the unit
  // then reads depth as they did: its contacts, simulated presses and force are in the presses'
  // depth, as its (u, v) are in their frame. |depth_zero_mm| <= 0.2 x the lattice's thickness.
  double depth_zero_mm = 0;
  std::vector<MagnetParameters> magnets;  // design order: u index fastest
  std::vector<SensorParameters> sensors;  // design order: u index fastest
  // What the unit's field does beyond the class (skinbus/sim/field_correction.h), learned from its
  // own presses; null: none. Its channels are the design's. Shared, never changed once made.
  std::shared_ptr<const FieldCorrection> field_correction;
  // The creep the unit's ramps showed (estimators::fit_creep): under a press d(t) the plate bends
  // by (1 - f) d + f q, q following d with time constant creep_time_s (PatchDesign::creep_fraction,
  // the same law); f = creep_fraction, 0: none. PatchModel::of_unit_file() gives the model's
  // design these values; the inversion fits the bend, estimators::CreepCompensator undoes it.
  double creep_fraction = 0;
  double creep_time_s = 0.3;
  // A second, slower lag the ramps showed (PatchDesign::creep_slow_fraction, the same law): the
  // plate bends by (1 - f - f_s) d + f q + f_s q_s; f_s = creep_slow_fraction, 0: none.
  double creep_slow_fraction = 0;
  double creep_slow_time_s = 3;
};

// ---- Unit files ------------------------------------------------------------------------------
// A unit's parameters as JSON (format "skinbus-unit 1", docs/physics_estimator.md "Unit files"):
// lengths in mm, moments in A m^2, and a note of what the file is. Numbers carry 17 significant
// digits: reading back what was written gives the same bits.

// What a unit file says of itself besides the parameters.
struct UnitFileNote {
  std::string source;  // where the numbers came from: a free note
  // Non-empty: identification refused this fit, and why (skinbus-identify --refused-out). Such a
  // file is the class's nearest model of a unit it does not explain: it may be simulated (to
  // train a network from), never refined on (estimators::make_physics_refiner refuses it).
  std::string refused;
  // The area the presses it was fitted on covered (sim::pressed_area, skinbus-identify writes
  // it): its parameters and field correction were fitted there; a press outside it is placed by
  // what the fit extrapolates (the class's physics carry over, a field correction only as its
  // edge's value), so errors there may be far larger. None: not known (a file written before the
  // field, or by hand).
  std::optional<PressedArea> pressed_area;
};

// What a refused fit's source says before the reason, for readers that know no `refused` field.
// A file whose source says it but that has no `refused` field (written before the field existed)
// reads as refused all the same, the source's text after it the reason.
inline constexpr std::string_view kRefusedInSource = ": REFUSED, not for refinement: ";

// The file's text. Allocates.
std::string unit_parameters_json(const UnitParameters& params, const UnitFileNote& note = {});
// Writes unit_parameters_json() to `path`. Errors: kIo (cannot write, the message names the path).
Status write_unit_parameters(const UnitParameters& params, const std::string& path,
                             const UnitFileNote& note = {});
// Parses a unit file's text. Errors: kParse (not JSON, another format or major version, a field
// missing or of the wrong type or size: the message names it). Counts against a design and
// physical sanity (finite, spread > 0, rotations) are checked by PatchModel::from_parameters().
// `note`, when not null, receives the file's note (an absent `source` or `refused`: empty).
// Allocates.
Result<UnitParameters> parse_unit_parameters(std::string_view text, UnitFileNote* note = nullptr);
// Reads and parses `path`. Errors: kNotFound (no file), else as parse_unit_parameters() with the
// path in the message.
Result<UnitParameters> read_unit_parameters(const std::string& path, UnitFileNote* note = nullptr);

}  // namespace skinbus::sim
