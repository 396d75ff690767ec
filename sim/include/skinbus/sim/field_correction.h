// skinbus/sim/field_correction.h: what a unit's field does that its model class does not: a
// smooth correction added to the modelled field change of a press, learned from the unit's own
// presses (estimators/field_correction_fit.h fits it).
//
// Identification fits a unit's parameters within a model class; a real unit has physics no class
// contains (how the lattice deforms under the tip, how its surface moves in-plane, magnets of
// finite size). What the class misses is systematic: the same for every press at a place and
// depth, and smooth in both. A FieldCorrection holds it as, for each channel c,
//
//   delta_c(u, v, d) = sum_ijk C[c; i, j, k] B_i(u) B_j(v) (d / max_depth_mm)^(k + 1)
//
// B: uniform cubic B-splines, `nu` along u from `u0_mm` and `nv` along v from `v0_mm`, knots
// `step_mm` apart (the grid spans u0_mm .. u0_mm + (nu - 3) step_mm, likewise v); k = 0 ..
// kDepthTerms - 1. Every term vanishes at d = 0: an untouched patch is never corrected. A place
// outside the grid takes the value at the grid's nearest edge (no slope there), a depth beyond
// max_depth_mm the value at max_depth_mm; a contact with depth <= 0 (or NaN) adds nothing.
//
// PatchModel adds it, per pressing contact, to the field change it models (and its derivatives to
// the field's Jacobian): the inversion, the Cramer-Rao bound and simulated training presses then
// all use the corrected model. A unit file carries it (unit_parameters.h).
//
// Cost of one contact: 16 kDepthTerms basis weights, then that many multiply-adds per channel
// (48 x 48 for 16 sensors); with the derivatives, four times the multiply-adds. No allocation.
#pragma once

#include <cstddef>
#include <string>
#include <vector>

#include "skinbus/common/result.h"
#include "skinbus/sim/dual.h"

namespace skinbus::sim {

class FieldCorrection {
 public:
  static constexpr int kDepthTerms = 3;
  static constexpr int kMaxKnots = 256;     // nu, nv at most (and at least 4)
  static constexpr int kMaxChannels = 768;  // 256 sensors (PatchModel's kMaxSensors)
  // Largest coefficient taken (uT): a tesla. Bounds every value and derivative it adds, so no
  // correction can overflow a field.
  static constexpr double kMaxCoefficientUt = 1e6;

  struct Grid {
    double u0_mm = 0, v0_mm = 0, step_mm = 0;
    int nu = 0, nv = 0;
    double max_depth_mm = 0;
    // Basis functions: nu x nv x kDepthTerms.
    std::size_t terms() const {
      return static_cast<std::size_t>(nu) * static_cast<std::size_t>(nv) * kDepthTerms;
    }
  };

  // A correction from its grid and coefficients: `coefficients` has grid.terms() x channels
  // entries, term-major (the term's channels contiguous; term (i, j, k) is (j nu + i)
  // kDepthTerms + k). Errors (kInvalidArgument, naming what): channels outside 1 ..
  // kMaxChannels, nu or nv outside 4 .. kMaxKnots, step or max depth not positive, a grid origin
  // not finite, a coefficient not finite or beyond +-kMaxCoefficientUt, the wrong number of
  // coefficients.
  static Result<FieldCorrection> make(const Grid& grid, int channels,
                                      std::vector<double> coefficients);

  const Grid& grid() const { return grid_; }
  int channels() const { return channels_; }
  const std::vector<double>& coefficients() const { return coef_; }

  // The basis weights of a contact at (u, v, depth): `index[n]` the term and, n < the returned
  // count (0 for depth <= 0 or NaN; at most kSupport), its weight: weight[n] alone, or with
  // `derivatives` weight[4 n .. 4 n + 3], its value and its derivatives by u, v and depth (mm^-1).
  static constexpr int kSupport = 16 * kDepthTerms;
  int basis(double u_mm, double v_mm, double depth_mm, int* index, double* weight,
            bool derivatives = false) const;

  // Adds the correction of a contact at (u, v, depth) to out[0 .. channels()) (uT), its channel
  // loop on field_isa()'s instructions.
  void add_ut(double u_mm, double v_mm, double depth_mm, double* out) const;
  // The same for a jet type: the value at the jets' values and its derivatives by u, v and depth
  // chained to theirs (first order, all a jet carries).
  template <typename T>
  void add_ut(const T& u_mm, const T& v_mm, const T& depth_mm, T* out) const;

  // Adds the correction to `field` (channels() entries) and its derivatives by the contact's u, v
  // and depth to columns col, col + 1, col + 2 of `jacobian` (row-major, `stride` columns a
  // channel). Its channel loop on field_isa()'s instructions.
  void add_with_jacobian(double u_mm, double v_mm, double depth_mm, double* field, double* jacobian,
                         int stride, int col) const;

 private:
  FieldCorrection() = default;
  // The correction at (u, v, depth) into sums[0 .. channels()) and its derivatives by u, v and
  // depth into the next three runs of channels() each; false (sums untouched) for depth <= 0 or
  // NaN.
  bool sums_with_derivatives(double u_mm, double v_mm, double depth_mm, double* sums) const;

  Grid grid_;
  int channels_ = 0;
  std::vector<double> coef_;
};

// ---- implementation of the templates ---------------------------------------------------------

template <typename T>
void FieldCorrection::add_ut(const T& u_mm, const T& v_mm, const T& depth_mm, T* out) const {
  const double u = value_of(u_mm), v = value_of(v_mm), d = value_of(depth_mm);
  double s[4 * kMaxChannels];  // value, d/du, d/dv, d/d depth; the first 4 channels() are used
  if (!sums_with_derivatives(u, v, d, s)) return;
  const T du = u_mm - u, dv = v_mm - v, dd = depth_mm - d;  // the jets' derivative parts alone
  const std::size_t nc = static_cast<std::size_t>(channels_);
  for (std::size_t ch = 0; ch < nc; ++ch) {
    out[ch] = out[ch] + (du * s[nc + ch] + dv * s[2 * nc + ch] + dd * s[3 * nc + ch] + s[ch]);
  }
}

}  // namespace skinbus::sim
