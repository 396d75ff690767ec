// skinbus/sim/dipole.h: the magnetic field of a point dipole, and magnet moments.
//
//   B(r) = mu0 / (4 pi) * (3 (m . r^) r^ - m) / |r|^3
// with m in A m^2 and r in mm; B in microtesla. Exact for a uniformly magnetised sphere and,
// outside a few diameters, for the small disc magnets of a patch (docs/sim/physics.md compares
// it with the exact field of a finite cylinder on its axis).
#pragma once

#include <cmath>

#include "skinbus/sim/vec3.h"

namespace skinbus::sim {

inline constexpr double kMu0 = 4e-7 * M_PI;  // T m / A
// mu0/(4 pi) with m in A m^2, r in mm, B in uT: 1e-7 T m/A * 1e9 mm^3/m^3 * 1e6 uT/T.
inline constexpr double kDipoleScale = 1e-7 * 1e9 * 1e6;

// Field at `r_mm` (from the dipole to the point) of a dipole of moment `m_am2`, in uT.
template <typename T>
Vec3<T> dipole_field_ut(const Vec3<T>& m_am2, const Vec3<T>& r_mm) {
  using std::sqrt;  // double: std::sqrt; jets: their own sqrt, found by argument lookup
  const T r2 = dot(r_mm, r_mm);
  const T inv_r = T(1.0) / sqrt(r2);
  const T inv_r3 = inv_r * inv_r * inv_r;
  const T inv_r5 = inv_r3 * inv_r * inv_r;
  const T mr = dot(m_am2, r_mm);
  const T a = T(3.0 * kDipoleScale) * mr * inv_r5;
  const T b = T(kDipoleScale) * inv_r3;
  return {a * r_mm.x - b * m_am2.x, a * r_mm.y - b * m_am2.y, a * r_mm.z - b * m_am2.z};
}

// dipole_field_ut() and its derivatives in closed form: d_dr[i][j] = dB_i / dr_j (uT/mm) and
// d_dm[i][j] = dB_i / dm_j (uT per A m^2; symmetric). About 60 operations, where jets over r
// and m carry every derivative through each of the field's. No allocation.
inline Vec3<double> dipole_field_gradient_ut(const Vec3<double>& m_am2, const Vec3<double>& r_mm,
                                             double d_dr[3][3], double d_dm[3][3]) {
  // The field as dipole_field_ut<double>() computes it, to the bit.
  const double r2 = dot(r_mm, r_mm);
  const double inv_r = 1.0 / std::sqrt(r2);
  const double inv_r3 = inv_r * inv_r * inv_r;
  const double inv_r5 = inv_r3 * inv_r * inv_r;
  const double mr = dot(m_am2, r_mm);
  const double a = 3.0 * kDipoleScale * mr * inv_r5;  // B = a r - b m
  const double b = kDipoleScale * inv_r3;
  const double inv_r2 = inv_r * inv_r;
  const double c = 3.0 * kDipoleScale * inv_r5;
  const double e = 5.0 * a * inv_r2;  // 15 k (m . r) / |r|^7
  const double r[3] = {r_mm.x, r_mm.y, r_mm.z}, m[3] = {m_am2.x, m_am2.y, m_am2.z};
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) {
      const double diag = i == j ? 1.0 : 0.0;
      d_dm[i][j] = c * r[i] * r[j] - b * diag;
      d_dr[i][j] = a * diag + c * (r[i] * m[j] + m[i] * r[j]) - e * r[i] * r[j];
    }
  }
  return {a * r_mm.x - b * m_am2.x, a * r_mm.y - b * m_am2.y, a * r_mm.z - b * m_am2.z};
}

// Dipole moment of a uniformly magnetised cylinder: |m| = Br V / mu0 (A m^2).
inline double cylinder_moment_am2(double remanence_t, double diameter_mm, double height_mm) {
  const double volume_m3 = M_PI * 0.25 * diameter_mm * diameter_mm * height_mm * 1e-9;
  return remanence_t * volume_m3 / kMu0;
}

// Exact on-axis field of a uniformly magnetised cylinder (axial magnetisation), at distance
// `z_mm` from its centre along the axis (|z| > height/2), in uT. For the finite-size check.
inline double cylinder_axial_field_ut(double remanence_t, double diameter_mm, double height_mm,
                                      double z_mm) {
  const double r = diameter_mm / 2, h = height_mm / 2;
  const double a = z_mm + h, b = z_mm - h;
  return remanence_t / 2 * (a / std::sqrt(a * a + r * r) - b / std::sqrt(b * b + r * r)) * 1e6;
}

}  // namespace skinbus::sim
