// skinbus/sim/plate_kernel.h: how a press spreads through the lattice.
//
// Model: the printed surface layer is a thin elastic plate (bending stiffness D) resting on the
// diamond-strut infill, which acts as an elastic (Winkler) foundation of stiffness k per unit
// area over a rigid base. A point load P then deflects the surface by
//     w(r) = -(P l^2 / (2 pi D)) kei(r / l),   l = (D / k)^(1/4)
// (Hetenyi, "Beams on Elastic Foundation", 1946; kei is the Kelvin function). Normalised to the
// deflection under the load, the shape is g(s) = kei(s) / kei(0) = -(4/pi) kei(s), s = r / l:
// g(0) = 1, g'(0) = 0, a wide smooth bowl with a small uplift ring (g < 0) beyond s ~ 3.9.
// The only length is l (docs/sim/physics.md: why ~10 mm). Beyond s = 5 the shape is faded to
// exactly 0 at s = 6.5 by a smooth (C1) window, so presses touch only nearby magnets.
#pragma once

#include <cmath>

namespace skinbus::sim {

inline constexpr double kPlateKernelFadeStart = 5.0;
inline constexpr double kPlateKernelCutoff = 6.5;  // g(s) = g'(s) = 0 for s >= this

// g(s), dg/ds and d2g/ds2 for s >= 0 (negative s is treated as |s|). Tabulated from the
// Kelvin-function series at first use (step 0.001), then cubic Hermite: |g error| < 1e-9;
// the second derivative is that of the interpolant (piecewise, for first-order jets). Inline:
// every field evaluation calls it once a moved magnet; about 20 floating-point operations.
inline void plate_kernel(double s, double* g, double* dg_ds, double* d2g_ds2 = nullptr);

// The Kelvin function kei(x) and its derivative by their power series (Abramowitz & Stegun
// 9.9.12), accurate for 0 <= x <= 10. Used to build the table and by tests.
void kelvin_kei(double x, double* kei, double* dkei_dx);

namespace detail {

inline constexpr int kPlateTableSize = 6501;  // points 0, 0.001, ..., 6.5
inline constexpr double kPlateTableStep = kPlateKernelCutoff / (kPlateTableSize - 1);
inline constexpr double kPlateTablePerUnit = (kPlateTableSize - 1) / kPlateKernelCutoff;  // 1000

// g and dg/ds at the table's points, interleaved (g, dg) a point: a lookup reads one or two
// cache lines. Built once, at first use (thread-safe), from kelvin_kei().
struct PlateTable {
  PlateTable();
  double gd[2 * kPlateTableSize];
};
inline const PlateTable& plate_table() {
  static const PlateTable table;
  return table;
}

// The table interval of s >= 0 (g and dg at points j and j + 1: gd[2 j .. 2 j + 3]), its index
// held to the last (also for NaN and s past the cutoff), and the offset f in it, in steps.
struct PlateInterval {
  int j;
  double f;
};
[[gnu::always_inline]] inline PlateInterval plate_interval(double s) {
  constexpr int kLast = kPlateTableSize - 2;
  const double u = s * kPlateTablePerUnit;
  const int j = u < kLast ? static_cast<int>(u) : kLast;
  return {j, u - j};
}

// The cubic Hermite between the interval's two points (g0, dg0 and g1, dg1 as the table holds
// them): g and dg/ds at offset f. No branch: the vectorised poses inline it too.
struct PlateValue {
  double g, dg;
};
[[gnu::always_inline]] inline PlateValue plate_hermite(double f, double g0, double dg0, double g1,
                                                       double dg1) {
  constexpr double h = kPlateTableStep;
  const double d0 = dg0 * h, d1 = dg1 * h;
  const double h00 = (1 + 2 * f) * (1 - f) * (1 - f), h10 = f * (1 - f) * (1 - f);
  const double h01 = f * f * (3 - 2 * f), h11 = f * f * (f - 1);
  const double dh00 = 6 * f * f - 6 * f, dh10 = 3 * f * f - 4 * f + 1, dh01 = -dh00,
               dh11 = 3 * f * f - 2 * f;
  return {h00 * g0 + h10 * d0 + h01 * g1 + h11 * d1,
          (dh00 * g0 + dh10 * d0 + dh01 * g1 + dh11 * d1) * kPlateTablePerUnit};
}

}  // namespace detail

inline void plate_kernel(double s, double* g, double* dg_ds, double* d2g_ds2) {
  s = std::fabs(s);
  if (!(s < kPlateKernelCutoff)) {  // also catches NaN
    *g = 0;
    *dg_ds = 0;
    if (d2g_ds2) *d2g_ds2 = 0;
    return;
  }
  const double* t = detail::plate_table().gd;
  const detail::PlateInterval at = detail::plate_interval(s);
  const int i = at.j;
  const double f = at.f;
  const double g0 = t[2 * i], g1 = t[2 * i + 2];
  const double d0 = t[2 * i + 1] * detail::kPlateTableStep,
               d1 = t[2 * i + 3] * detail::kPlateTableStep;
  const detail::PlateValue v = detail::plate_hermite(f, g0, t[2 * i + 1], g1, t[2 * i + 3]);
  *g = v.g;
  *dg_ds = v.dg;
  if (d2g_ds2) {
    const double e00 = 12 * f - 6, e10 = 6 * f - 4, e11 = 6 * f - 2;
    *d2g_ds2 = (e00 * g0 + e10 * d0 - e00 * g1 + e11 * d1) *
               (detail::kPlateTablePerUnit * detail::kPlateTablePerUnit);
  }
}

}  // namespace skinbus::sim
