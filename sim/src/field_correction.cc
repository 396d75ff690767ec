// FieldCorrection: a unit's learned field correction, evaluated (skinbus/sim/field_correction.h).
#include "skinbus/sim/field_correction.h"

#include <algorithm>
#include <cmath>

#include "dipole_sum.h"

namespace skinbus::sim {

Result<FieldCorrection> FieldCorrection::make(const Grid& grid, int channels,
                                              std::vector<double> coefficients) {
  auto bad = [](const std::string& what) {
    return make_error(ErrorCode::kInvalidArgument, "field correction: " + what);
  };
  if (channels < 1 || channels > kMaxChannels) {
    return bad("channels must be 1 .. " + std::to_string(kMaxChannels));
  }
  if (grid.nu < 4 || grid.nu > kMaxKnots || grid.nv < 4 || grid.nv > kMaxKnots) {
    return bad("nu and nv must be 4 .. " + std::to_string(kMaxKnots));
  }
  if (!std::isfinite(grid.step_mm) || !(grid.step_mm > 0)) return bad("step_mm must be > 0");
  if (!std::isfinite(grid.max_depth_mm) || !(grid.max_depth_mm > 0)) {
    return bad("max_depth_mm must be > 0");
  }
  if (!std::isfinite(grid.u0_mm) || !std::isfinite(grid.v0_mm)) {
    return bad("u0_mm and v0_mm must be finite");
  }
  const std::size_t want = grid.terms() * static_cast<std::size_t>(channels);
  if (coefficients.size() != want) {
    return bad(std::to_string(coefficients.size()) + " coefficients, " + std::to_string(want) +
               " expected (" + std::to_string(grid.nu) + " x " + std::to_string(grid.nv) + " x " +
               std::to_string(kDepthTerms) + " terms x " + std::to_string(channels) + " channels)");
  }
  for (std::size_t i = 0; i < coefficients.size(); ++i) {
    if (!(std::fabs(coefficients[i]) <= kMaxCoefficientUt)) {
      return bad("coefficient " + std::to_string(i) + " is not finite or beyond 1e6 uT");
    }
  }
  FieldCorrection f;
  f.grid_ = grid;
  f.channels_ = channels;
  f.coef_ = std::move(coefficients);
  return f;
}

namespace {

// The interval index along an axis of n basis functions and the fraction in it; false (index and
// fraction at the nearest edge) when x lies outside the grid.
bool interval(double x, int n, int* s, double* t) {
  const double top = n - 3;  // the grid spans x in [0, n - 3]
  if (!(x > 0)) {            // below, or NaN: the lower edge
    *s = 0;
    *t = 0;
    return x == 0;
  }
  if (x >= top) {
    *s = n - 4;
    *t = 1;
    return x == top;
  }
  *s = std::min(static_cast<int>(x), n - 4);
  *t = x - *s;
  return true;
}

// The four cubic B-spline weights at fraction t of an interval, and their slopes by t.
void cubic(double t, double* w) {
  const double t2 = t * t, t3 = t2 * t, s = 1 - t;
  w[0] = s * s * s / 6;
  w[1] = (3 * t3 - 6 * t2 + 4) / 6;
  w[2] = (-3 * t3 + 3 * t2 + 3 * t + 1) / 6;
  w[3] = t3 / 6;
}
void cubic_slope(double t, double* dw) {
  const double s = 1 - t;
  dw[0] = -0.5 * s * s;
  dw[1] = 1.5 * t * t - 2 * t;
  dw[2] = -1.5 * t * t + t + 0.5;
  dw[3] = 0.5 * t * t;
}

}  // namespace

int FieldCorrection::basis(double u_mm, double v_mm, double depth_mm, int* index, double* weight,
                           bool derivatives) const {
  if (!(depth_mm > 0)) return 0;
  const double h = grid_.step_mm;
  int su = 0, sv = 0;
  double tu = 0, tv = 0;
  const bool in_u = interval((u_mm - grid_.u0_mm) / h, grid_.nu, &su, &tu);
  const bool in_v = interval((v_mm - grid_.v0_mm) / h, grid_.nv, &sv, &tv);
  double wu[4], wv[4], du[4] = {}, dv[4] = {};
  cubic(tu, wu);
  cubic(tv, wv);
  if (in_u) cubic_slope(tu, du);
  if (in_v) cubic_slope(tv, dv);
  const bool in_d = depth_mm < grid_.max_depth_mm;
  const double x = in_d ? depth_mm / grid_.max_depth_mm : 1.0;
  double g[kDepthTerms], dg[kDepthTerms];
  double xk = 1;  // x^k
  for (int k = 0; k < kDepthTerms; ++k) {
    dg[k] = in_d ? (k + 1) * xk / grid_.max_depth_mm : 0.0;
    xk *= x;
    g[k] = xk;
  }
  int n = 0;
  for (int b = 0; b < 4; ++b) {
    for (int a = 0; a < 4; ++a) {
      const int cell = (sv + b) * grid_.nu + su + a;
      for (int k = 0; k < kDepthTerms; ++k) {
        index[n] = cell * kDepthTerms + k;
        if (derivatives) {
          double* w = weight + 4 * n;
          w[0] = wu[a] * wv[b] * g[k];
          w[1] = du[a] / h * wv[b] * g[k];
          w[2] = wu[a] * dv[b] / h * g[k];
          w[3] = wu[a] * wv[b] * dg[k];
        } else {
          weight[n] = wu[a] * wv[b] * g[k];
        }
        ++n;
      }
    }
  }
  return n;
}

void FieldCorrection::add_ut(double u_mm, double v_mm, double depth_mm, double* out) const {
  int index[kSupport];
  double w[kSupport];
  const int n = basis(u_mm, v_mm, depth_mm, index, w);
  if (n == 0) return;
  detail::row_sums()(static_cast<std::size_t>(n), index, w, 1, coef_.data(),
                     static_cast<std::size_t>(channels_), out);
}

bool FieldCorrection::sums_with_derivatives(double u_mm, double v_mm, double depth_mm,
                                            double* sums) const {
  int index[kSupport];
  double w[4 * kSupport];
  const int n = basis(u_mm, v_mm, depth_mm, index, w, true);
  if (n == 0) return false;
  const std::size_t nc = static_cast<std::size_t>(channels_);
  std::fill_n(sums, 4 * nc, 0.0);
  detail::row_sums()(static_cast<std::size_t>(n), index, w, 4, coef_.data(), nc, sums);
  return true;
}

void FieldCorrection::add_with_jacobian(double u_mm, double v_mm, double depth_mm, double* field,
                                        double* jacobian, int stride, int col) const {
  double sums[4 * kMaxChannels];  // value, d/du, d/dv, d/d depth; the first 4 channels() are used
  if (!sums_with_derivatives(u_mm, v_mm, depth_mm, sums)) return;
  const std::size_t nc = static_cast<std::size_t>(channels_);
  const std::size_t s = static_cast<std::size_t>(stride), o = static_cast<std::size_t>(col);
  for (std::size_t ch = 0; ch < nc; ++ch) {
    field[ch] += sums[ch];
    jacobian[ch * s + o] += sums[nc + ch];
    jacobian[ch * s + o + 1] += sums[2 * nc + ch];
    jacobian[ch * s + o + 2] += sums[3 * nc + ch];
  }
}

}  // namespace skinbus::sim
