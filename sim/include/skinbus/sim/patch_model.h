// skinbus/sim/patch_model.h: the physics of one skin patch, from a press to the field at its
// 16 Hall sensors.
//
// Chain (docs/sim/physics.md gives every parameter with its source or marks it an assumption):
//   press (u, v, depth) -> surface deflection by the plate-on-foundation kernel
//     (skinbus/sim/plate_kernel.h), superposed over contacts
//   -> each magnet moves down with the surface, in-plane toward the press (the surface layer
//      bends: -lateral * slope) and tilts with the surface normal
//   -> field at every sensor: the sum of each magnet's dipole and octupole (skinbus/sim/dipole.h)
//   -> sensor frame, per-unit sensor rotation and gain.
//
// Coordinates: the patch frame has its origin at the patch centre on the skin surface, u and v
// along the sensor grid, h out of the skin; depth is positive into the skin. For a flat patch
// (u, v, h) is (x, y, z). For a cylinder section (a forearm) u is arc length around the axis at
// the skin surface, v runs along the axis, h is the outward normal; the cylinder's axis is
// parallel to y at z = -radius. Sensor channels are in each sensor's own frame (x along u,
// y along v, z along the outward normal at the sensor).
//
// Costs: a PatchModel precomputes every magnet's rest field at every sensor (magnets x sensors
// x 3 doubles). contact_field() touches only magnets within the kernel's reach of a contact
// (skip what a scene does not need): O(touched magnets x sensors) dipole evaluations.
#pragma once

#include <cmath>
#include <cstdint>
#include <memory>
#include <span>
#include <vector>

#include "skinbus/common/isa.h"
#include "skinbus/common/result.h"
#include "skinbus/sim/dipole.h"
#include "skinbus/sim/dual.h"
#include "skinbus/sim/mlx90393.h"
#include "skinbus/sim/plate_kernel.h"
#include "skinbus/sim/unit_parameters.h"
#include "skinbus/sim/vec3.h"

namespace skinbus::sim {

enum class SurfaceKind : uint8_t { kFlat, kCylinder };
inline constexpr int kMaxSensors = 256;
// The largest indenter tip radius a design or a tool takes (mm): a palm, not a fingertip.
inline constexpr double kMaxIndenterTipRadiusMm = 50.0;
// A tip's contact radius counts up to 2 spread lengths (beyond, a press is no longer local).
inline constexpr double kMaxTipContact2 = 4.0;
enum class Polarity : uint8_t { kUniform, kCheckerboard };

// One magnet placed by hand (a design whose magnets are not a grid): its rest position and the
// sign of its moment along the surface normal (+1: north pole out of the skin).
struct MagnetPlacement {
  double u_mm = 0, v_mm = 0;
  double centre_height_mm = 0.75;  // above the surface (negative: below it)
  int polarity = +1;               // +1 or -1
};
// One sensor placed by hand: its position and its mounting turn about the surface normal.
struct SensorPlacement {
  double u_mm = 0, v_mm = 0;
  double depth_mm = 17;  // below the surface (>= the lattice's thickness)
  double yaw_deg = 0;    // the chip's x axis turned this far from u, about the normal
};

struct PatchDesign {
  // Geometry of the skin surface.
  SurfaceKind surface = SurfaceKind::kFlat;
  double size_u_mm = 140, size_v_mm = 140;  // extent (arc length along u for a cylinder)
  double radius_mm = 0;                     // cylinder: skin-surface radius (> sensor depth)
  double thickness_mm = 15;                 // lattice: surface, infill and base layers
  // Magnets: a grid on the surface, or (magnet_list non-empty) the listed magnets in that order.
  int magnets_u = 7, magnets_v = 7;
  double magnet_pitch_mm = 20;
  Polarity polarity = Polarity::kCheckerboard;
  double magnet_diameter_mm = 3, magnet_height_mm = 1.5;
  double remanence_t = 1.32;                 // NdFeB N42
  double magnet_centre_height_mm = 0.75;     // magnet centre above the surface
  std::vector<MagnetPlacement> magnet_list;  // non-empty: replaces the grid (up to 4096)
  // Sensors: a grid below the base, or (sensor_list non-empty) the listed sensors: channel
  // 3k..3k+2 is the k-th sensor's x, y, z.
  int sensors_u = 4, sensors_v = 4;
  double sensor_pitch_mm = 30;
  double sensor_depth_mm = 17;  // below the surface: lattice 15 mm + base and package 2 mm
  mlx90393::Config sensor_config;
  std::vector<SensorPlacement> sensor_list;  // non-empty: replaces the grid (up to 256)
  // Lattice mechanics.
  double spread_mm = 10;    // plate-on-foundation length l
  double lateral_mm = 2.0;  // in-plane motion of a magnet = -lateral * surface slope
  // l_u = l (1 + a), l_v = l (1 - a) (a lattice printed stiffer one way); identification
  // starts from it and fits the unit's own (UnitParameters::anisotropy).
  double anisotropy = 0;
  // A lattice whose top layer crushes under the tip: a press d deep bends the plate by
  // d / (1 + d / tip_crush_mm) only, the rest taken up under the tip (0: none). Physics outside
  // the class identification fits (it fits 0): a stand-in for a unit whose deformation law under
  // the tip is not the model's.
  double tip_crush_mm = 0;
  // Another in-plane motion law: the surface layer is dragged toward a press, a magnet moving by
  // inplane_drag x its deflection by that press x its distance to it over the spread length
  // (along u: drag w du / l_u), on top of the class's -lateral x slope (0: none). Outside the
  // class, identification fits 0.
  double inplane_drag = 0;
  // Creep (viscoelastic lag): under a press d(t), the plate bends by (1 - f) d + f q, where q
  // follows d with time constant creep_time_s (dq/dt = (d - q) / tau); f = creep_fraction, 0:
  // none. It acts where the simulator steps time, in the ramps of sim::generate_ramp_dataset
  // (loading bends the plate less than the press is deep, unloading more); a static press is
  // the relaxed state. Not in the static class (class_design: 0); identification fits it from a
  // recording's ramps after the static fit (estimators/creep.h) and a unit file carries it
  // (UnitParameters::creep_fraction, given to the model's design by of_unit_file()).
  double creep_fraction = 0;
  double creep_time_s = 0.3;
  // A second, slower lag of the same law: a further creep_slow_fraction of the bend follows d
  // with creep_slow_time_s, so the plate bends by (1 - f - f_s) d + f q + f_s q_s. A real lattice
  // relaxes over a spectrum of times; this is its simplest such unit. Identification fits one lag
  // or two (estimators/creep.h) and a unit file carries them (UnitParameters). 0: none;
  // f + f_s < 1.
  double creep_slow_fraction = 0;
  double creep_slow_time_s = 3;
  // Shear: a tangential force F at a contact moves the surface layer in-plane, along F, by
  // (F / shear_stiffness) exp(a/l_t - sqrt(r^2 + a^2)/l_t) at distance r from the contact
  // (l_t = shear_spread_mm, a = the tip's contact radius): F / shear_stiffness under the tip,
  // decaying over l_t around it. Both values are assumptions (docs/sim/physics.md).
  double shear_stiffness_n_per_mm = 1.4;
  double shear_spread_mm = 8;
  // Depth -> normal force: F = k d + k3 d^3.
  double stiffness_n_per_mm = 2.0;
  double stiffening_n_per_mm3 = 0.05;
  // Temperature: magnet remanence coefficient (NdFeB), per degC.
  double remanence_tempco_per_c = -0.0012;
  // The indenter: the round tip's radius (mm; 0: a point) of the probe the unit's lab presses
  // are made with, and the tip the host's refinement assumes (a fingertip is about 8 mm). The
  // tools use it where a recording does not say (its `protocol:` header's tip_radius_mm=,
  // sim::recorded_tip_radius_mm) and no --tip-radius is given. Not the patch's physics: the
  // model takes each contact's own tip (Contact::tip_radius_mm).
  double indenter_tip_radius_mm = 5.0;

  int magnet_count() const {
    return magnet_list.empty() ? magnets_u * magnets_v : static_cast<int>(magnet_list.size());
  }
  int sensor_count() const {
    return sensor_list.empty() ? sensors_u * sensors_v : static_cast<int>(sensor_list.size());
  }
  int channel_count() const { return 3 * sensor_count(); }
  // Deepest press the lattice takes (densified beyond): 60 % of its thickness. The model holds
  // deeper presses at this depth.
  double max_depth_mm() const { return 0.6 * thickness_mm; }
  // The deepest press the tools make and fit: 10 % short of that stop, where a fitted depth zero
  // of a few tenths of a millimetre does not take the model onto it (a fingertip's unit pressed
  // to its stop, its zero fitted 0.01 mm off, was left at 1.3 noise units rather than 1.07).
  double deepest_press_mm() const { return 0.9 * max_depth_mm(); }
};

// The static model class identification fits (estimators/unit_identification.h) and unit files
// belong to: `design` without the physics no fit takes up (a crushing top, in-plane drag: 0),
// its anisotropy 0 (a unit's own is in its parameters, UnitParameters::anisotropy) and without
// creep, which identification fits apart and a unit file carries
// (PatchModel::of_unit_file). A simulated unit may have them (the design's values, applied by
// PatchModel::from_parameters()); the model of an identified unit does not.
PatchDesign class_design(const PatchDesign& design);

// Checks a design: positive sizes, sensors inside the patch, a cylinder radius larger than the
// sensor depth, a valid sensor configuration. The error names the parameter.
Status validate(const PatchDesign& design);

// Per-unit spread of a fabricated patch (1 standard deviation). Assumptions for a hand-
// assembled, 3D-printed patch; see docs/sim/physics.md.
struct FabricationVariation {
  double magnet_position_sd_mm = 0.15;
  double magnet_height_sd_mm = 0.1;
  double magnet_moment_rel_sd = 0.02;
  double magnet_tilt_sd_rad = 0.026;  // 1.5 degrees
  double sensor_position_sd_mm = 0.1;
  double sensor_rotation_sd_rad = 0.0087;  // 0.5 degrees
  double sensor_gain_rel_sd = 0.01;
  double spread_rel_sd = 0.03;
  double lateral_rel_sd = 0.05;
  static FabricationVariation none() { return {0, 0, 0, 0, 0, 0, 0, 0, 0}; }
};

template <typename T>
struct ContactT {
  T u_mm{}, v_mm{}, depth_mm{};
  // Radius of the round indenter tip (a finger, a robot's probe); 0: a point. The bowl is the
  // plate's point-load shape seen from sqrt(r^2 + a^2), a = the tip's contact radius at this
  // depth (the sphere's chord), scaled so the deflection under the tip is depth_mm: a blunter
  // tip at the same depth spreads wider.
  double tip_radius_mm = 0;
  // Tangential (shear) force the indenter applies to the skin, along u and v (N): it moves the
  // surface in-plane (PatchDesign::shear_stiffness_n_per_mm, shear_spread_mm). Acts only while
  // the contact presses (depth > 0). 0: a pure normal press (the model skips the term).
  T shear_u_n{}, shear_v_n{};
};
using Contact = ContactT<double>;

class PatchModel {
 public:
  struct Magnet {
    double u, v, h;      // rest position, surface coordinates (mm)
    Vec3<double> m_loc;  // moment in the local surface frame (A m^2), tilt included
  };
  struct Sensor {
    double u, v, h;     // position, surface coordinates (h < 0: below the surface)
    Vec3<double> pos;   // 3D position (mm)
    Mat3 frame;         // rows: the sensor's x, y, z axes in patch 3D coordinates
    Vec3<double> gain;  // per-axis gain (1 nominal)
    Mat3 mounting;      // mounting rotation relative to the local surface frame (see
                        // SensorParameters); `frame` is built from it
  };

  // The nominal unit of a design (no fabrication variation).
  static Result<PatchModel> nominal(const PatchDesign& design);
  // A fabricated unit: variation drawn from a generator seeded by the board's hardware UID,
  // so the same UID always gives the same unit.
  static Result<PatchModel> fabricated(const PatchDesign& design, uint64_t hardware_uid,
                                       const FabricationVariation& variation);
  // A unit from its explicit parameters (skinbus/sim/unit_parameters.h): `params` must have
  // design.magnet_count() magnets and design.sensor_count() sensors, finite values, spread > 0,
  // lateral >= 0, finite non-zero gains and orthonormal mounting rotations; the error names the
  // entry that is not. The design's anisotropy is added to the parameters' own (their sum within
  // (-0.5, 0.5)).
  // from_parameters(m.design(), m.parameters()) rebuilds m exactly (bit for bit; not a
  // with_disc_magnets() model, whose points would gain the octupole). Cost: the rest
  // field table, magnets x sensors dipole evaluations.
  static Result<PatchModel> from_parameters(const PatchDesign& design,
                                            const UnitParameters& params);
  // A unit file's model: from_parameters() on class_design(design), the model class identification
  // fits, which a unit file's parameters belong to (a design's physics outside the class are not
  // added to them), with the unit's identified creep (UnitParameters::creep_fraction,
  // creep_time_s) as its design's. Errors: as from_parameters().
  static Result<PatchModel> of_unit_file(const PatchDesign& design, const UnitParameters& params);

  // The same unit with every magnet a uniformly magnetised disc of the design's diameter and
  // height, its field summed over its volume rather than the model's dipole and octupole
  // (magnet_field_ut()): each magnet becomes kDiscPoints point dipoles at a cubature exact for
  // every polynomial of degree 7 across the disc and 5 along its height (2 radii, Gauss in the
  // squared radius, times 8 angles; 3 Gauss points over the height), so its multipoles are the
  // cylinder's to l = 5; placed in the local surface frame about the magnet's rest position, each
  // moving with the lattice where it sits. Physics outside the class of every estimator and of
  // identification (what the cylinder has beyond the octupole: about 1 % of the field 5 mm from a
  // 3 x 1.5 mm disc, 0.01 % at 17.75 mm). Before 2026-11-29 a degree-3 cubature of 14 points, the
  // model a point dipole. The result's design lists the cubature points as its magnets, its
  // octupole 0. Errors: more than 4096 points (kInvalidArgument). Cost: kDiscPoints x the field
  // work of `unit`.
  static constexpr int kDiscPoints = 48;
  static Result<PatchModel> with_disc_magnets(const PatchModel& unit);

  // The unit's explicit parameters (what from_parameters() takes).
  UnitParameters parameters() const;

  const PatchDesign& design() const { return design_; }
  const std::vector<Magnet>& magnets() const { return magnets_; }
  const std::vector<Sensor>& sensors() const { return sensors_; }
  int channel_count() const { return 3 * static_cast<int>(sensors_.size()); }
  double spread_mm() const { return spread_; }  // isotropic spread, before anisotropy
  double spread_u_mm() const { return spread_u_; }
  // The octupole every magnet has beyond its dipole (sim::magnet_field_ut()): the design's
  // cylinder's (sim::cylinder_octupole_mm2(magnet_diameter_mm, magnet_height_mm)), mm^2; 0 for
  // with_disc_magnets()' cubature points.
  double octupole_mm2() const { return octupole_mm2_; }
  double spread_v_mm() const { return spread_v_; }
  double lateral_mm() const { return lateral_; }
  // The depth a contact reads when its tip meets the surface (UnitParameters::depth_zero_mm; 0
  // for a design's units): a contact presses depth_mm - depth_zero_mm() into the lattice.
  double depth_zero_mm() const { return depth_zero_; }
  // True when contact `c` presses the lattice: deeper than depth_zero_mm() (false for NaN).
  template <typename T>
  bool presses(const ContactT<T>& c) const {
    return value_of(c.depth_mm) > depth_zero_;
  }
  // The unit's learned field correction (UnitParameters::field_correction), added to every
  // pressing contact's field change by contact_field_ut() and contact_field_jacobian_ut(); null:
  // none.
  const FieldCorrection* field_correction() const { return correction_.get(); }

  // Field at every channel with nothing touching, uT (what a tare removes).
  void rest_field_ut(std::span<double> out) const;

  // Change of the field at every channel caused by `contacts` (superposed deflections), uT,
  // noise-free, no ambient field, at reference temperature. `out` has channel_count() entries.
  // T = double, or a jet type for derivatives with respect to contact parameters.
  template <typename T>
  void contact_field_ut(std::span<const ContactT<T>> contacts, T* out) const;
  // The same for double, with the sensor loop laid out for SIMD (patch_model.cc) and, for one
  // press without shear (a single-contact fit's every evaluation), the magnets' poses too; equal
  // to the template to rounding (tested). Its inner loops run on field_isa()'s instructions.
  void contact_field_ut(std::span<const Contact> contacts, std::span<double> out) const;

  // Jacobian of the field change of one contact with respect to (u, v, depth): row-major,
  // channel_count() x 3. Also returns the field change itself in `field` when not empty. The
  // contact's shear is not applied (contact_field_jacobian_ut() below, which this calls).
  void contact_jacobian(const Contact& c, std::span<double> jacobian,
                        std::span<double> field = {}) const;

  // contact_field_ut() into `field` (channel_count() entries) and its exact Jacobian into
  // `jacobian`, row-major, channel_count() x unknowns: the unknowns are each contact's
  // (u_mm, v_mm, depth_mm) in turn, each followed by its (shear_u_n, shear_v_n) when `shear`
  // (3 or 5 a contact; at most kMaxJetContacts contacts). The deformation's derivatives per
  // moved magnet by hand for one press without shear (a single-contact fit's Jacobian), by jets
  // otherwise; the dipole's gradient in closed form in the vectorised loop: for one press about
  // two field evaluations' time (sim_benchmark's BM_FieldJacobian/0), a sixth of the template's
  // jets. Equal to the template's jets to rounding (tested). No allocation, but
  // up to 92 KB of stack with three contacts and their shear on 256 sensors. False, the outputs
  // untouched, with more contacts than that or spans too short.
  static constexpr int kMaxJetContacts = 3;
  bool contact_field_jacobian_ut(std::span<const Contact> contacts, bool shear,
                                 std::span<double> field, std::span<double> jacobian) const;

  // Magnets within reach of a contact at (u, v): the others do not move.
  bool magnet_in_reach(const Magnet& m, double u, double v) const {
    const double du = (m.u - u) / spread_u_, dv = (m.v - v) / spread_v_;
    return du * du + dv * dv < kPlateKernelCutoff * kPlateKernelCutoff;
  }

  // In-plane shift of the surface per newton of shear (mm/N) at squared distance `r2` (mm^2)
  // from a contact whose tip touches over squared radius `ac2` (mm^2): PatchDesign's shear law.
  template <typename T>
  T shear_shape(const T& r2, const T& ac2) const;

  // How far a press `depth_mm` deep bends the plate under the tip: the depth, less what the
  // lattice's top crushes (PatchDesign::tip_crush_mm).
  template <typename T>
  T plate_depth(const T& depth_mm) const {
    const double c = design_.tip_crush_mm;
    return c > 0 ? depth_mm / (T(1.0) + depth_mm / c) : depth_mm;
  }
  // How far a magnet is dragged toward a press along one axis (PatchDesign::inplane_drag): its
  // deflection by the press (amp x shape), its offset from the press and the spread along that
  // axis. Subtract it from the magnet's position.
  template <typename T, typename S>
  T drag_toward(const T& amp, const S& shape, const T& offset_mm, const T& spread_mm) const {
    return design_.inplane_drag * amp * shape * offset_mm / spread_mm;
  }

  // Normal force for a press of `depth_mm` (N; the contact's depth, depth_zero_mm() at the
  // surface); 0 for a contact that does not press.
  double force_n(double depth_mm) const;
  // Deepest press the lattice takes (PatchDesign::max_depth_mm). Deeper presses act as this
  // depth.
  double max_depth_mm() const { return design_.max_depth_mm(); }

  // 3D position and local frame (rows: t_u, t_v, normal) of surface point (u, v, h).
  template <typename T>
  Vec3<T> surface_point(const T& u, const T& v, const T& h, Vec3<T>* t_u, Vec3<T>* t_v,
                        Vec3<T>* n) const;

  // Pose of one magnet under `contacts`: its 3D position (mm) and moment (A m^2) in patch
  // coordinates, from its rest parameters (surface coordinates u, v, h; moment `m_loc` in the
  // local surface frame) and the lattice's spread lengths and lateral coupling. Returns false,
  // with the rest pose, when no contact reaches it. The one formula of the deformation for every
  // scalar type: contact_field_ut() calls it with the model's own parameters, per-unit
  // identification with jets over the parameters (estimators/unit_identification.h). Only the
  // design's surface and max_depth_mm() are read from the model.
  template <typename T>
  bool magnet_pose(const T& u, const T& v, const T& h, const Vec3<T>& m_loc, const T& spread_u,
                   const T& spread_v, const T& lateral, std::span<const ContactT<T>> contacts,
                   Vec3<T>* pos, Vec3<T>* moment) const {
    return magnet_pose(u, v, h, m_loc, spread_u, spread_v, lateral, contacts,
                       static_cast<const PressTerms<T>*>(nullptr), pos, moment);
  }

  // What of one press is the same at every magnet: how far it presses into the lattice (its depth
  // less depth_zero_mm()) held to [0, max_depth_mm()], the
  // tip's squared contact radius (mm^2), that over spread_u x spread_v (capped at
  // kMaxTipContact2) and the deflection's amplitude under the tip (mm: the plate depth over the
  // kernel's value at the tip's edge). For depth <= 0 or NaN (no press) only depth_mm is set.
  template <typename T>
  struct PressTerms {
    T depth_mm, ac2_mm2, a2, amp_mm;
  };
  template <typename T>
  PressTerms<T> press_terms(const ContactT<T>& c, const T& spread_u, const T& spread_v) const;
  // magnet_pose() with `terms[j]` the press_terms() of contacts[j] at these spreads, computed
  // once for every magnet of an evaluation (nullptr: computed here, per magnet). A plate
  // kernel lookup, a square root and a division less per magnet and contact.
  template <typename T>
  bool magnet_pose(const T& u, const T& v, const T& h, const Vec3<T>& m_loc, const T& spread_u,
                   const T& spread_v, const T& lateral, std::span<const ContactT<T>> contacts,
                   const PressTerms<T>* terms, Vec3<T>* pos, Vec3<T>* moment) const;

 private:
  PatchModel() = default;
  static Result<PatchModel> build(const PatchDesign& design, uint64_t seed,
                                  const FabricationVariation& var);
  // `point_magnets`: every magnet a point dipole (with_disc_magnets()' cubature points), else each
  // with the octupole of the design's cylinder.
  static Result<PatchModel> assemble(const PatchDesign& design, const UnitParameters& params,
                                     bool point_magnets = false);
  // contact_field_jacobian_ut() with K unknowns (contacts x per_contact).
  template <int K>
  void field_jacobian(std::span<const Contact> contacts, int per_contact, double* field,
                      double* jacobian) const;

  PatchDesign design_;
  double spread_ = 10, spread_u_ = 10, spread_v_ = 10, lateral_ = 2;
  double depth_zero_ = 0;    // UnitParameters::depth_zero_mm
  double octupole_mm2_ = 0;  // each magnet's shape: cylinder_octupole_mm2() of the design's
  double anisotropy_ = 0;  // the parameters' own (UnitParameters::anisotropy), without the design's
  std::vector<Magnet> magnets_;
  std::vector<Sensor> sensors_;
  std::vector<Vec3<double>> rest_;  // [magnet * sensors + sensor]: rest field in 3D, uT
  // The same data as structure-of-arrays for the double path.
  std::vector<double> sx_, sy_, sz_, rx_, ry_, rz_;
  // magnets_ likewise, one row of magnets_.size() each: u, v, h, then the local moment's x, y, z.
  std::vector<double> magnet_rows_;
  std::shared_ptr<const FieldCorrection> correction_;  // UnitParameters::field_correction
};

// ---- implementation of the templates ---------------------------------------------------------

template <typename T>
Vec3<T> PatchModel::surface_point(const T& u, const T& v, const T& h, Vec3<T>* t_u, Vec3<T>* t_v,
                                  Vec3<T>* n) const {
  if (design_.surface == SurfaceKind::kFlat) {
    if (t_u) *t_u = {T(1.0), T(0.0), T(0.0)};
    if (t_v) *t_v = {T(0.0), T(1.0), T(0.0)};
    if (n) *n = {T(0.0), T(0.0), T(1.0)};
    return {u, v, h};
  }
  using std::cos;
  using std::sin;
  const double r = design_.radius_mm;
  const T theta = u / r;
  const T s = sin(theta), c = cos(theta);
  if (t_u) *t_u = {c, T(0.0), -s};
  if (t_v) *t_v = {T(0.0), T(1.0), T(0.0)};
  if (n) *n = {s, T(0.0), c};
  const T rr = T(r) + h;
  return {rr * s, v, rr * c - T(r)};
}

template <typename T>
T PatchModel::shear_shape(const T& r2, const T& ac2) const {
  using std::sqrt;
  const double lt2 = design_.shear_spread_mm * design_.shear_spread_mm;
  T at2 = ac2 / lt2;
  if (value_of(at2) > kMaxTipContact2) at2 = T(kMaxTipContact2);
  const T st2 = r2 / lt2 + at2;
  // No derivative through the square root at 0 (a point tip right under the press).
  const T st = value_of(st2) > 0 ? sqrt(st2) : T(0.0);
  const T st0 = value_of(at2) > 0 ? sqrt(at2) : T(0.0);
  const T x = st0 - st;
  const double ex = std::exp(value_of(x));
  return first_order(x, ex, ex) / design_.shear_stiffness_n_per_mm;
}

template <typename T>
PatchModel::PressTerms<T> PatchModel::press_terms(const ContactT<T>& c, const T& spread_u,
                                                  const T& spread_v) const {
  using std::sqrt;
  PressTerms<T> t;
  // A lattice compresses so far and no further: depth is held to [0, max_depth_mm()].
  t.depth_mm = c.depth_mm - T(depth_zero_);
  if (!(value_of(t.depth_mm) > 0)) return t;  // no press (or NaN): nothing moves
  if (value_of(t.depth_mm) > max_depth_mm()) t.depth_mm = T(max_depth_mm());
  const T& depth = t.depth_mm;
  t.ac2_mm2 = T(0.0);  // squared contact radius of the tip, mm^2
  if (c.tip_radius_mm > 0) {
    const double r = c.tip_radius_mm;
    t.ac2_mm2 = value_of(depth) < r ? T(2 * r) * depth - depth * depth : T(r * r);
  }
  t.a2 = t.ac2_mm2 / (spread_u * spread_v);  // over l_u l_v
  if (value_of(t.a2) > kMaxTipContact2) t.a2 = T(kMaxTipContact2);
  // Deflection under the tip is the depth (less what the top crushes): divide by the shape
  // there.
  t.amp_mm = plate_depth(depth);
  if (c.tip_radius_mm > 0) {
    const T s0 = sqrt(t.a2);
    double g0, dg0;
    plate_kernel(value_of(s0), &g0, &dg0);
    t.amp_mm = t.amp_mm / first_order(s0, g0, dg0);
  }
  return t;
}

template <typename T>
bool PatchModel::magnet_pose(const T& u, const T& v, const T& h, const Vec3<T>& m_loc,
                             const T& spread_u, const T& spread_v, const T& lateral,
                             std::span<const ContactT<T>> contacts, const PressTerms<T>* terms,
                             Vec3<T>* pos, Vec3<T>* moment) const {
  using std::sqrt;
  const double lu = value_of(spread_u), lv = value_of(spread_v);
  const T lu2 = spread_u * spread_u, lv2 = spread_v * spread_v;
  // Surface deflection and slope at the magnet, summed over contacts (the plate is linear), and
  // its in-plane shift by shear.
  T w(0.0), pu(0.0), pv(0.0), shift_u(0.0), shift_v(0.0);
  bool moved = false;
  PressTerms<T> here;
  for (std::size_t j = 0; j < contacts.size(); ++j) {
    const ContactT<T>& c = contacts[j];
    // Pressing or not is the contact's depth alone: test it before computing the terms.
    if (!presses(c)) continue;
    const T du = u - c.u_mm, dv = v - c.v_mm;
    const double sdu = value_of(du) / lu, sdv = value_of(dv) / lv;
    const double s2 = sdu * sdu + sdv * sdv;
    if (!(s2 < kPlateKernelCutoff * kPlateKernelCutoff)) continue;
    moved = true;
    if (terms == nullptr) here = press_terms(c, spread_u, spread_v);
    const PressTerms<T>& t = terms != nullptr ? terms[j] : here;
    const T& a2 = t.a2;
    const T& ac2 = t.ac2_mm2;
    // At the very point of a point load (s = 0) the kernel is flat (g'(0) = 0): no derivative
    // through the square root there, which would be 0/0 for jets.
    const T s_sq = du * du / lu2 + dv * dv / lv2 + a2;
    const T s = value_of(s_sq) > 0 ? sqrt(s_sq) : T(0.0);
    const double sv = value_of(s);
    double g, dg, d2g;
    plate_kernel(sv, &g, &dg, &d2g);
    const T gs = first_order(s, g, dg);
    // The slope needs g'(s)/s, finite for s > 0 (it grows like log s at the press itself,
    // where the slope is 0 anyway).
    const double q = sv > 1e-6 ? dg / sv : 0.0;
    const double dq = sv > 1e-6 ? (d2g * sv - dg) / (sv * sv) : 0.0;
    const T dgs = first_order(s, q, dq);
    const T& amp = t.amp_mm;
    w = w + amp * gs;                // deflection into the skin
    pu = pu - amp * dgs * du / lu2;  // slope of the surface height h = -w
    pv = pv - amp * dgs * dv / lv2;
    if (design_.inplane_drag != 0) {  // dragged toward the press (PatchDesign::inplane_drag)
      shift_u = shift_u - drag_toward(amp, gs, du, spread_u);
      shift_v = shift_v - drag_toward(amp, gs, dv, spread_v);
    }
    if (!is_zero(c.shear_u_n) || !is_zero(c.shear_v_n)) {
      const T shape = shear_shape(du * du + dv * dv, ac2);
      shift_u = shift_u + c.shear_u_n * shape;
      shift_v = shift_v + c.shear_v_n * shape;
    }
  }
  Vec3<T> tu, tv, nn;
  if (!moved) {
    *pos = surface_point(u, v, h, &tu, &tv, &nn);
    *moment = tu * m_loc.x + tv * m_loc.y + nn * m_loc.z;
    return false;
  }
  // New magnet pose in surface coordinates.
  *pos =
      surface_point(u - lateral * pu + shift_u, v - lateral * pv + shift_v, h - w, &tu, &tv, &nn);
  // Moment follows the surface normal: local direction (m_u - slope_u |m_z|, ...), its
  // magnitude kept.
  const T mu = m_loc.x - pu * m_loc.z;
  const T mv = m_loc.y - pv * m_loc.z;
  const T mz = m_loc.z;
  const T k = sqrt(dot(m_loc, m_loc) / (mu * mu + mv * mv + mz * mz));
  *moment = (tu * (mu * k)) + (tv * (mv * k)) + (nn * (mz * k));
  return true;
}

template <typename T>
void PatchModel::contact_field_ut(std::span<const ContactT<T>> contacts, T* out) const {
  const std::size_t ns = sensors_.size();
  Vec3<T> acc[kMaxSensors];  // on the stack: no allocation per call
  for (std::size_t si = 0; si < ns; ++si) acc[si] = Vec3<T>{T(0.0), T(0.0), T(0.0)};
  const T lu(spread_u_), lv(spread_v_), lat(lateral_);
  // Each press's terms once for every magnet, for as many contacts as fit here.
  constexpr std::size_t kTermsHeld = 4;
  PressTerms<T> terms[kTermsHeld];
  const bool held = contacts.size() <= kTermsHeld;
  for (std::size_t j = 0; held && j < contacts.size(); ++j)
    terms[j] = press_terms(contacts[j], lu, lv);
  for (std::size_t mi = 0; mi < magnets_.size(); ++mi) {
    const Magnet& m = magnets_[mi];
    Vec3<T> pos, moment;
    if (!magnet_pose(T(m.u), T(m.v), T(m.h), lift<T>(m.m_loc), lu, lv, lat, contacts,
                     held ? terms : static_cast<const PressTerms<T>*>(nullptr), &pos, &moment)) {
      continue;
    }
    for (std::size_t si = 0; si < ns; ++si) {
      const Vec3<T> b = magnet_field_ut(moment, lift<T>(sensors_[si].pos) - pos, octupole_mm2_);
      const Vec3<double>& r = rest_[mi * ns + si];
      acc[si] = acc[si] + b - lift<T>(r);
    }
  }
  for (std::size_t si = 0; si < ns; ++si) {
    const Vec3<T> local = sensors_[si].frame.apply(acc[si]);
    out[3 * si + 0] = local.x * sensors_[si].gain.x;
    out[3 * si + 1] = local.y * sensors_[si].gain.y;
    out[3 * si + 2] = local.z * sensors_[si].gain.z;
  }
  if (correction_ != nullptr) {
    for (const ContactT<T>& c : contacts) correction_->add_ut(c.u_mm, c.v_mm, c.depth_mm, out);
  }
}

// The instruction set of contact_field_ut()'s inner loop: the widest of AVX-512 and AVX2 this CPU
// has within SKINBUS_MAX_ISA (skinbus/common/isa.h), else baseline (kPortable); chosen once. The
// sets agree to rounding (the vector ones fuse multiplies and adds).
Isa field_isa();

}  // namespace skinbus::sim
