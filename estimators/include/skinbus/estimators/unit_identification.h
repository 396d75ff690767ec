// skinbus/estimators/unit_identification.h: fits one unit's physical parameters from its own
// presses, and measures how well a model explains a dataset.
//
// Input: a dataset of presses at known (u, v, depth) with the tared field they gave (an
// indentation robot's ramp protocol: sim::generate_ramp_dataset or a lab recording), and the
// unit's design as the nominal start. A few samples per press are kept (depths_per_press, the
// samples nearest to evenly spaced fractions of the press's deepest sample; those below the
// deepest in turn from before and after it in the dataset's order, the way down and the way up
// of a ramp, the turn alternating from press to press, so each depth is fitted on both ways).
//
// Unknowns (sim::UnitParameters): per magnet its rest position (u, v, h) and moment vector
// (strength and tilt); per sensor its position, a small mounting rotation and per-axis gain;
// the lattice's spread length, its anisotropy (spread along u and along v: l (1 + a), l (1 - a))
// and its lateral coupling: 6 x 49 + 9 x 16 + 3 = 441 for the standard patch (the anisotropy is
// fitted in stage 1 and held in stage 2: freed there, it moved the fit of an isotropic unit).
// Physics outside the class (a crushing top, another in-plane law, discs rather than dipoles) is
// left in the residual, which fit quality reports.
//
// Method, in two stages, both least squares with Ceres (Levenberg-Marquardt), residuals whitened
// by the sensor noise:
// 1. The globals (GlobalPhysics: spread length, lateral coupling, one height offset for every
//    magnet, one for every sensor, one scale of every moment, the anisotropy, and the presses'
//    frame against the design's: a shift and a turn, and the depth the presses read at the
//    surface), 10 unknowns over every fitting row and each press's onset (the sample nearest
//    half the first fraction, where the depth zero shows), from several spread lengths (the lowest
//    cost wins), under broad priors about the design (GlobalPriors). A design file is a drawing,
//    not the unit: a lattice printed softer or magnets set deeper is off by more than fabrication
//    scatter, and the per-part parameters, held to that scatter, then settle in a poor minimum. A
//    global that runs to its bound is refused, naming it.
// 2. Every parameter (maximum a posteriori, sparse normal Cholesky): a Gaussian prior per
//    parameter, centred on the design with stage 1's globals and as wide as the fabrication
//    spread (sim::FabricationVariation), fixes the directions the data cannot see (e.g. all
//    moments up and all gains down together). A fit that leaves more than max_residual noise
//    units is refused with its residual per depth bin.
// One residual block per (sample, sensor) touches that sensor, the two lattice parameters and
// only the magnets within derivative_reach spread lengths of the press, so the Jacobian stays
// sparse. Derivatives are exact: forward-mode jets through sim's own templates
// (PatchModel::magnet_pose, sim::magnet_field_ut), the field of a pressed magnet's pose in closed
// form (sim::magnet_field_gradient_ut); magnets beyond derivative_reach (moved by at
// most ~1 % of the depth) enter with their value, refreshed between outer iterations. What does
// not depend on a block's own sensor or sample is made once an evaluation and shared: a sample's
// magnet poses by its sensors' blocks, the magnets' rest fields by every sample's.
//
// Quality: residual RMS in noise units (1.0: the model explains the data down to the sensor
// noise; clearly above 1: the model class misses something), overall and per depth bin, on the
// fitting rows and on held-out rows.
//
// Cost: stage 1, a dense 10-unknown fit per spread start, each evaluation moving every magnet a
// press reaches for every row; stage 2, a sparse Levenberg-Marquardt over every sample's
// residuals, a few iterations. For the seed's 361 presses on one core: 5-11 s on units of the
// model class (16 sensors, 49-81 magnets), about a minute where 57 iterations cannot explain a
// unit outside it; memory growing with the samples (figures: docs/physics_estimator.md,
// docs/benchmarks/designs.md). Single-threaded (Eigen's sparse Cholesky; no BLAS threads).
#pragma once

#include <cstdint>
#include <functional>
#include <span>
#include <string>
#include <vector>

#include "skinbus/common/result.h"
#include "skinbus/estimators/creep.h"
#include "skinbus/estimators/lookup_estimator.h"
#include "skinbus/sim/dataset.h"
#include "skinbus/sim/patch_model.h"
#include "skinbus/sim/unit_parameters.h"

namespace skinbus::estimators {

// Identification residual (RMS, noise units, on the unit's own presses) above which the model is
// taken to miss physics the unit has, and a learned correction on top pays off: a correct model
// leaves ~1.01 (the tare's own noise adds ~1.6 %), an anisotropic lattice 1.24
// (docs/benchmarks/models.md, the 361-press budget).
inline constexpr double kModelMissesResidual = 1.1;

struct DepthBinResidual {
  double depth_lo_mm = 0, depth_hi_mm = 0;  // [lo, hi)
  int rows = 0;
  double rms = 0;  // residual RMS over the bin's channels, noise units
};

struct FitQuality {
  int rows = 0;
  double rms = 0;  // residual RMS over every channel of every row, noise units
  std::vector<DepthBinResidual> bins;
};

// The chips' noise as a recording of ramps shows it, whatever their settings say: from the sixth
// differences of each press's consecutive samples (weights 1 -6 15 -20 15 -6 1, of variance
// 924 sigma^2 for noise alone). Lower differences carry the field's curvature along the ramp
// too: on a patch whose sensors sit 8 mm under its magnets, second differences read the z noise
// 1.76x the chips' and fourth 1.10x, sixth 1.02x. Only seven samples over which the depth moves
// one way count (the turn and holds are left out), RMS over the sensors, per kind of axis.
// `windows`: how many such runs of seven it rests on (0: none, and the noise returned is 0).
// Cost: one pass over the rows.
struct RecordedNoise {
  ChannelNoise noise{0, 0};
  int64_t windows = 0;
  // How much larger than `design` (per kind of axis), and the RMS of that over the channels
  // (x, y and z alike): the residual in `design`'s noise units that noise alone leaves.
  double xy_ratio(const ChannelNoise& design) const { return noise.xy_ut / design.xy_ut; }
  double z_ratio(const ChannelNoise& design) const { return noise.z_ut / design.z_ut; }
  double residual(const ChannelNoise& design) const;
};
RecordedNoise recorded_noise(const sim::Dataset& d);

// Residual of `model` against every row of `data` with depth > 0 and finite positions (or only
// the rows listed in `rows`, when not empty): (data - model) / sigma per channel, channels
// without a finite value left out. Cost: one forward evaluation per row.
FitQuality fit_quality(const sim::PatchModel& model, const sim::Dataset& data, double tip_radius_mm,
                       const ChannelNoise& noise, std::span<const double> depth_bin_edges_mm,
                       std::span<const std::size_t> rows = {});

// The design's global physics as identification's first stage finds them: what a design file
// may have wrong for a whole unit (a lattice printed softer, magnets set deeper, sensors on a
// thicker board, stronger magnets), applied to every magnet and sensor of the design.
struct GlobalPhysics {
  double spread_mm = 0;                // the lattice's spread length
  double lateral_mm = 0;               // its lateral coupling
  double magnet_height_offset_mm = 0;  // added to every magnet's height
  double sensor_height_offset_mm = 0;  // added to every sensor's height (negative: deeper)
  double moment_scale = 1;             // every magnet's moment times this
  double anisotropy = 0;               // the lattice's (sim::UnitParameters::anisotropy)
  // The presses' frame against the design's (an indentation robot's origin and axes off the
  // patch's): every part's (u, v) turned by frame_yaw_deg about the design's origin (u toward v),
  // then moved by (frame_du_mm, frame_dv_mm); the chips and the moments turn with them. The unit
  // file's parts are in the presses' frame, as the contacts refined on it are.
  double frame_du_mm = 0, frame_dv_mm = 0, frame_yaw_deg = 0;
  // The depth the presses read when the tip met the surface (an indenter whose zero is off the
  // surface: positive, it read deep): sim::UnitParameters::depth_zero_mm. The unit reads depth as
  // the presses did, as it reads (u, v) in their frame.
  double depth_zero_mm = 0;
  double rms = 0;  // residual with these globals alone, noise units
  int starts = 0;  // starts tried
};

// Broad priors and hard bounds of the first stage, about the design's values: wide enough for a
// design off by +-30 % in spread, +-1 mm in the depths and +-10 % in the moments (tested), and
// keeping the nearly interchangeable magnet and sensor heights from drifting apart.
struct GlobalPriors {
  double spread_rel_sd = 0.5;
  double spread_min_rel = 0.3, spread_max_rel = 3.0;
  double lateral_sd_mm = 2.0, lateral_max_mm = 10.0;
  double height_sd_mm = 2.0, height_max_mm = 5.0;  // each offset
  double moment_rel_sd = 0.3, moment_min = 0.3, moment_max = 3.0;
  double anisotropy_sd = 0.2, anisotropy_max = 0.45;      // about the design's, absolute
  double frame_shift_sd_mm = 3, frame_shift_max_mm = 15;  // the presses' frame, each axis
  double frame_yaw_sd_deg = 3, frame_yaw_max_deg = 20;
  double depth_zero_sd_mm = 0.5, depth_zero_max_mm = 2;  // the presses' depth zero; sd 0 holds it
};

// A chip whose readings the design's nominal model explains far better turned from the design
// file's mounting by a quarter turn or more about the surface normal, or upside down: an assembly
// error, or a design file whose sensors' yaw_deg follows another convention. Identification fits
// the chip so turned (its unit file's mounting) and says so.
struct ChipTurn {
  int sensor = 0;
  double yaw_deg = 0;        // turned this far about the normal from the design (90, 180, 270)
  bool upside_down = false;  // and turned over about the surface's u axis
  // RMS residual per channel (noise units) of the nominal model's readings, each at its best
  // scale (the design's globals may be off): turned so, and as the design file mounts it.
  double rms = 0, rms_as_drawn = 0;
  std::string text() const;  // "sensor 3: ... turned 90 degrees ..." for reports
};

struct IdentificationOptions {
  double tip_radius_mm = 5.0;  // the indenter's round tip (sim::RampProtocol's default)
  int depths_per_press = 4;    // samples kept per press
  double min_depth_mm = 0.3;   // shallower samples are not used
  ChannelNoise noise{0, 0};    // 0: the design's sensor noise
  // Prior: 1 sd of every parameter about the nominal design (the expected fabrication spread).
  sim::FabricationVariation prior{};
  // Levenberg-Marquardt iterations per outer iteration, at most; a pass also ends at
  // function_tolerance, or stalled (cost down less than 0.01 % of itself over 5 iterations).
  int max_iterations = 40;
  int outer_iterations = 2;  // refreshes of the far magnets' frozen contribution
  double function_tolerance = 1e-6;
  double derivative_reach = 4.0;  // spread lengths: magnets nearer a press get derivatives
  // Degenerate input: fewer presses than min_presses gives kDegenerate. A magnet with fewer
  // presses than min_presses_per_magnet within coverage_radius_mm (a hole in a random plan, a
  // corner not reached) is not fitted: it is held at the design with the globals found
  // (IdentifiedUnit::uncovered_magnets). More than max_uncovered_share of the magnets so gives
  // kDegenerate: the presses do not cover the patch.
  int min_presses = 20;
  int min_presses_per_magnet = 2;
  double coverage_radius_mm = 15;
  double max_uncovered_share = 0.25;
  std::vector<double> depth_bin_edges_mm = {0, 1, 2, 3, 4, 9};
  // Stage 1 (fit_globals): the globals from each of these spread starts (x the design's); the
  // lowest cost wins. false: start stage 2 from the design as it is.
  bool fit_globals = true;
  std::vector<double> spread_starts = {1.0, 0.7, 1.4};
  // For a later fit of a unit already fitted (a spread of `spread_mm` found on `design`): one
  // start, from that spread (the first fit's other starts found the same globals or worse).
  // Nothing changes without a spread or without fit_globals.
  void start_from_spread(const sim::PatchDesign& design, double spread_mm) {
    if (fit_globals && spread_mm > 0 && design.spread_mm > 0) {
      spread_starts = {spread_mm / design.spread_mm};
    }
  }
  GlobalPriors global_priors{};
  // A fit leaving more than this (RMS, noise units, on the fitting rows) is refused: the model
  // class does not explain the unit (above kModelMissesResidual it is kept, with physics missed).
  double max_residual = 4.0;
  // Called with a line on each step (stage 1 per start, stage 2 at the start of each outer
  // iteration and every 5 of its iterations); may be empty.
  std::function<void(const std::string&)> progress;
  // After the fit, a creep law (creep.h, fit_creep) from the presses' ramps; when one lowers the
  // held-out presses' depth residual, the whole fit is made again on the bends it gives
  // (creep_bend_mm), its globals from the first fit's spread alone (not every spread start),
  // and the law kept in the parameters (about 1.7 times the time). A fit refused for
  // its residual gets the law fitted on it, in the refused parameters, without a second fit.
  bool fit_creep = true;
  // Before the fit, every chip's mounting is tried turned about the normal by 0, 90, 180 and 270
  // degrees, upright and upside down, against the nominal model's readings at the fitting rows;
  // a turn is taken (IdentifiedUnit::chip_turns) when it leaves under a quarter of the residual
  // as drawn and that residual is clearly above the noise (2 noise units RMS).
  bool find_chip_turns = true;
};

struct IdentifiedUnit {
  sim::PatchModel model;           // built from `parameters` with the design (anisotropy 0)
  sim::UnitParameters parameters;  // the fitted unit
  FitQuality fit;                  // on the fitting rows
  FitQuality nominal_fit;          // the nominal model on the same rows, for comparison
  FitQuality held_out;             // on the held-out rows (rows == 0 when none were given)
  FitQuality nominal_held_out;     // the nominal model on the held-out rows
  int presses = 0;                 // distinct presses used
  int rows_used = 0;               // samples fitted
  int iterations = 0;              // Levenberg-Marquardt iterations, all outer iterations
  double solve_seconds = 0;        // wall time of the fit (measured, for reports)
  // Field values left out of the fit for not being finite (a dead channel in a recording; the
  // dataset format allows NaN), counted over the rows considered. A row needs half its channels.
  int masked_values = 0;
  GlobalPhysics globals;  // stage 1's result (the design's own values when not fitted)
  // The creep fit (fit_creep, on the first fit's model). When kept, the parameters carry its law
  // (sim::UnitParameters::creep_fraction), the model's design too, and every other field above
  // is the second fit's, on the bends (fit, held_out: residuals about the bends; iterations and
  // solve_seconds: both fits and the creep's).
  CreepFit creep;
  // The chips fitted turned from the design file's mounting (find_chip_turns), by sensor.
  std::vector<ChipTurn> chip_turns;
  // The magnets too few presses reached to fit (min_presses_per_magnet): held at the design with
  // the globals found. Contacts near them rest on the design's drawing, not on the unit.
  std::vector<int> uncovered_magnets;
};

// Fits the unit that produced `presses`. Errors: kInvalidArgument (design invalid, channel
// count differs), kDegenerate (too few presses, or too many magnets without presses near them;
// the message says which), kNotConverged (the solver failed or hit its iteration limit without
// converging, or the fit leaves more than options.max_residual: refused). When the fit is
// refused for its residual and `refused` is not null, the refused fit is stored there: the
// class's nearest model of the unit, for simulating training presses (never to refine on).
// Single-threaded; allocates.
Result<IdentifiedUnit> identify_unit(const sim::PatchDesign& design, const sim::Dataset& presses,
                                     const IdentificationOptions& options = {},
                                     const sim::Dataset* held_out = nullptr,
                                     sim::UnitParameters* refused = nullptr);

// The creep fit's options for a unit identified with `options` (its tip, noise and shallowest
// depth): what identify_unit fits the creep with.
CreepFitOptions creep_fit_options(const IdentificationOptions& options);

}  // namespace skinbus::estimators
