// skinbus/estimators/unit_identification.h: fits one unit's physical parameters from its own
// presses, and measures how well a model explains a dataset.
//
// Input: a dataset of presses at known (u, v, depth) with the tared field they gave (an
// indentation robot's ramp protocol: sim::generate_ramp_dataset or a lab recording), and the
// unit's design as the nominal start. A few samples per press are kept (depths_per_press, the
// samples nearest to evenly spaced fractions of the press's deepest sample).
//
// Unknowns (sim::UnitParameters): per magnet its rest position (u, v, h) and moment vector
// (strength and tilt); per sensor its position, a small mounting rotation and per-axis gain;
// the lattice's isotropic spread length and lateral coupling: 6 x 49 + 9 x 16 + 2 = 440 for
// the standard patch. The design's anisotropy is NOT fitted (the identified model has
// anisotropy 0): the model class is the nominal one, so a unit whose lattice spreads unequally
// along u and v is left with a residual above the noise, which fit quality reports.
//
// Method: maximum a posteriori least squares with Ceres (Levenberg-Marquardt, sparse normal
// Cholesky). Data residuals are whitened by the sensor noise; a Gaussian prior per parameter,
// centred on the nominal design with the fabrication spread (sim::FabricationVariation), fixes
// the directions the data cannot see (e.g. all moments up and all gains down together).
// One residual block per (sample, sensor) touches that sensor, the two lattice parameters and
// only the magnets within derivative_reach spread lengths of the press, so the Jacobian stays
// sparse. Derivatives are exact forward-mode jets through sim's own templates
// (PatchModel::magnet_pose, sim::dipole_field_ut); magnets beyond derivative_reach (moved by at
// most ~1 % of the depth) enter with their value, refreshed between outer iterations.
//
// Quality: residual RMS in noise units (1.0: the model explains the data down to the sensor
// noise; clearly above 1: the model class misses something), overall and per depth bin, on the
// fitting rows and on held-out rows.
//
// Cost: a sparse Levenberg-Marquardt over every sample's residuals, a few iterations; seconds for
// the seed's 361 presses on one core, memory growing with the samples (figures:
// docs/physics_estimator.md). Single-threaded (Eigen's sparse Cholesky; no BLAS threads).
#pragma once

#include <span>
#include <vector>

#include "skinbus/common/result.h"
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

// Residual of `model` against every row of `data` with depth > 0 and finite positions (or only
// the rows listed in `rows`, when not empty): (data - model) / sigma per channel, channels
// without a finite value left out. Cost: one forward evaluation per row.
FitQuality fit_quality(const sim::PatchModel& model, const sim::Dataset& data, double tip_radius_mm,
                       const ChannelNoise& noise, std::span<const double> depth_bin_edges_mm,
                       std::span<const std::size_t> rows = {});

struct IdentificationOptions {
  double tip_radius_mm = 5.0;  // the indenter's round tip (sim::RampProtocol's default)
  int depths_per_press = 4;    // samples kept per press
  double min_depth_mm = 0.3;   // shallower samples are not used
  ChannelNoise noise{0, 0};    // 0: the design's sensor noise
  // Prior: 1 sd of every parameter about the nominal design (the expected fabrication spread).
  sim::FabricationVariation prior{};
  int max_iterations = 40;   // Levenberg-Marquardt iterations per outer iteration
  int outer_iterations = 2;  // refreshes of the far magnets' frozen contribution
  double function_tolerance = 1e-6;
  double derivative_reach = 4.0;  // spread lengths: magnets nearer a press get derivatives
  // Degenerate input: fewer presses, or a magnet with fewer presses than
  // min_presses_per_magnet within coverage_radius_mm, gives kDegenerate.
  int min_presses = 20;
  int min_presses_per_magnet = 2;
  double coverage_radius_mm = 15;
  std::vector<double> depth_bin_edges_mm = {0, 1, 2, 3, 4, 9};
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
};

// Fits the unit that produced `presses`. Errors: kInvalidArgument (design invalid, channel
// count differs), kDegenerate (too few presses, a magnet without presses near it; the message
// says which), kNotConverged (the solver failed or hit its iteration limit without
// converging). Single-threaded; allocates.
Result<IdentifiedUnit> identify_unit(const sim::PatchDesign& design, const sim::Dataset& presses,
                                     const IdentificationOptions& options = {},
                                     const sim::Dataset* held_out = nullptr);

}  // namespace skinbus::estimators
