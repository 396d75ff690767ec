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

#include <algorithm>
#include <cmath>
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

  // The basis weights of a contact at (u, v, depth): `index[n]` the term, `weight[n]` its value,
  // n < the returned count (0 for depth <= 0; at most kSupport). With `d_weight` not null, also
  // each weight's derivatives by u, v and depth (mm^-1), three a term.
  static constexpr int kSupport = 16 * kDepthTerms;
  int basis(double u_mm, double v_mm, double depth_mm, int* index, double* weight,
            double* d_weight = nullptr) const;

  // Adds the correction of a contact at (u, v, depth) to out[0 .. channels()) (uT). T = double or
  // a jet type: derivatives by u, v and depth follow the jets.
  template <typename T>
  void add_ut(const T& u_mm, const T& v_mm, const T& depth_mm, T* out) const;
  // The same for double, its channel loop on field_isa()'s instructions (equal to the template
  // to rounding: the vector builds fuse multiplies and adds).
  void add_ut(double u_mm, double v_mm, double depth_mm, double* out) const;

  // Adds the correction to `field` (channels() entries) and its derivatives by the contact's u, v
  // and depth to columns col, col + 1, col + 2 of `jacobian` (row-major, `stride` columns a
  // channel). Its channel loop on field_isa()'s instructions.
  void add_with_jacobian(double u_mm, double v_mm, double depth_mm, double* field, double* jacobian,
                         int stride, int col) const;

 private:
  FieldCorrection() = default;
  // The four cubic B-spline weights at fraction t of an interval, and their slopes by t.
  template <typename T>
  static void cubic(const T& t, T* w);
  static void cubic_slope(double t, double* dw);
  // The interval index along an axis of n basis functions and the fraction in it; false (index
  // and fraction at the nearest edge) when x lies outside the grid.
  static bool interval(double x, int n, int* s, double* t);

  Grid grid_;
  int channels_ = 0;
  std::vector<double> coef_;
};

// ---- implementation of the templates ---------------------------------------------------------

template <typename T>
void FieldCorrection::cubic(const T& t, T* w) {
  const T t2 = t * t, t3 = t2 * t, s = T(1.0) - t;
  w[0] = s * s * s * (1.0 / 6);
  w[1] = (t3 * 3.0 - t2 * 6.0 + 4.0) * (1.0 / 6);
  w[2] = (t3 * -3.0 + t2 * 3.0 + t * 3.0 + 1.0) * (1.0 / 6);
  w[3] = t3 * (1.0 / 6);
}

template <typename T>
void FieldCorrection::add_ut(const T& u_mm, const T& v_mm, const T& depth_mm, T* out) const {
  const double d0 = value_of(depth_mm);
  if (!(d0 > 0)) return;
  int su = 0, sv = 0;
  double tu0 = 0, tv0 = 0;
  const bool in_u = interval((value_of(u_mm) - grid_.u0_mm) / grid_.step_mm, grid_.nu, &su, &tu0);
  const bool in_v = interval((value_of(v_mm) - grid_.v0_mm) / grid_.step_mm, grid_.nv, &sv, &tv0);
  // Inside the grid the fraction carries the jets' derivatives; outside, the edge's value.
  const T tu = in_u ? (u_mm - grid_.u0_mm) / grid_.step_mm - double(su) : T(tu0);
  const T tv = in_v ? (v_mm - grid_.v0_mm) / grid_.step_mm - double(sv) : T(tv0);
  T wu[4], wv[4];
  cubic(tu, wu);
  cubic(tv, wv);
  const T x = d0 < grid_.max_depth_mm ? depth_mm / grid_.max_depth_mm : T(1.0);
  T g[kDepthTerms];
  g[0] = x;
  for (int k = 1; k < kDepthTerms; ++k) g[k] = g[k - 1] * x;
  const std::size_t nc = static_cast<std::size_t>(channels_);
  for (int b = 0; b < 4; ++b) {
    for (int a = 0; a < 4; ++a) {
      const T wab = wu[a] * wv[b];
      const std::size_t cell = static_cast<std::size_t>((sv + b) * grid_.nu + su + a);
      for (int k = 0; k < kDepthTerms; ++k) {
        const T w = wab * g[k];
        const double* c = coef_.data() + (cell * kDepthTerms + static_cast<std::size_t>(k)) * nc;
        for (std::size_t ch = 0; ch < nc; ++ch) out[ch] = out[ch] + w * c[ch];
      }
    }
  }
}

}  // namespace skinbus::sim
