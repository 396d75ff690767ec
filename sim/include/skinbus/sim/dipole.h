// skinbus/sim/dipole.h: the magnetic field of a point dipole, of a magnet (its dipole and its
// cylinder's octupole: magnet_field_ut), and magnet moments.
//
//   B(r) = mu0 / (4 pi) * (3 (m . r^) r^ - m) / |r|^3
// with m in A m^2 and r in mm; B in microtesla. Exact for a uniformly magnetised sphere; for the
// small disc magnets of a patch 0.7 % high at 17.75 mm and 9.6 % at 5 mm, which the octupole
// brings to 0.001 % and 0.23 % (docs/sim/physics.md compares both with the exact field of a
// finite cylinder on its axis).
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

// The octupole of a uniformly (axially) magnetised cylinder of `diameter_mm` and `height_mm`, per
// unit of its dipole moment: q3 / m = (L^2 - 3 a^2) / 4 (mm^2; a the radius, L the height), from
// the magnetic charge +-M on its end faces. Negative for a disc flatter than sqrt(3) a, zero for
// L = sqrt(3) a. Beside the dipole its field is 2 (q3 / m) / r^2 of the dipole's on the axis:
// -0.71 % for the built-in 3 x 1.5 mm disc at 17.75 mm, -9 % at 5 mm.
inline double cylinder_octupole_mm2(double diameter_mm, double height_mm) {
  const double a = 0.5 * diameter_mm;
  return 0.25 * (height_mm * height_mm - 3 * a * a);
}

// Field at `r_mm` of a magnet of moment `m_am2` whose shape adds an axial octupole
// `octupole_mm2` x |m| along m (cylinder_octupole_mm2; 0: a point dipole, the very bits of
// dipole_field_ut()), in uT:
//   B = dipole + K q [(35 g p^3 / r^4 - 15 p / r^2) r + (3 - 15 g p^2 / r^2) m] / r^5,
// p = m.r, g = 1 / |m|^2, q = octupole / 2, K = kDipoleScale: the l = 3 term of the potential
// q3 P3(cos t) / r^4. What the cylinder has beyond (l = 5, ...) falls as (radius / r)^4 of it.
template <typename T>
Vec3<T> magnet_field_ut(const Vec3<T>& m_am2, const Vec3<T>& r_mm, double octupole_mm2) {
  const Vec3<T> dipole = dipole_field_ut(m_am2, r_mm);
  if (octupole_mm2 == 0) return dipole;
  using std::sqrt;
  const T r2 = dot(r_mm, r_mm);
  const T inv_r = T(1.0) / sqrt(r2);
  const T ir2 = inv_r * inv_r;
  const T k = T(0.5 * kDipoleScale * octupole_mm2) * ir2 * ir2 * inv_r;  // K q / r^5
  const T p = dot(m_am2, r_mm);
  const T g = T(1.0) / dot(m_am2, m_am2);
  const T c1 = k * (T(35.0) * g * p * p * p * ir2 * ir2 - T(15.0) * p * ir2);
  const T c2 = k * (T(3.0) - T(15.0) * g * p * p * ir2);
  return {dipole.x + c1 * r_mm.x + c2 * m_am2.x, dipole.y + c1 * r_mm.y + c2 * m_am2.y,
          dipole.z + c1 * r_mm.z + c2 * m_am2.z};
}

// The octupole's coefficients at an offset r from a magnet of moment m, each times
// k = K q / r^5 (`k`), from p = m.r, `ir2` = 1 / r^2 and `inv_m2` = 1 / |m|^2: the field's, of r
// (c1) and of m (c2), and those of its change (magnet_field_gradient_ut()). One set of formulas
// for the closed form below and the vectorised sums (sim/src/dipole_sum.cc).
struct OctupoleCoefficients {
  double c1, c2, a, bd, g1, a2, b2, g2;
};
inline OctupoleCoefficients octupole_coefficients(double k, double p, double ir2, double inv_m2) {
  const double ir4 = ir2 * ir2;
  const double gp = inv_m2 * p, gp2 = gp * p, gp3 = gp2 * p;
  const double u1 = 35.0 * gp3 * ir4 - 15.0 * p * ir2, u2 = 3.0 - 15.0 * gp2 * ir2;
  OctupoleCoefficients o;
  o.c1 = k * u1;
  o.c2 = k * u2;
  o.a = k * (105.0 * gp2 * ir4 - 15.0 * ir2);
  o.bd = k * (-140.0 * gp3 * ir4 * ir2 + 30.0 * p * ir4 - 5.0 * u1 * ir2);
  o.g1 = k * (-70.0 * inv_m2 * gp3 * ir4);
  o.a2 = k * (-30.0 * gp * ir2);
  o.b2 = k * (30.0 * gp2 * ir4 - 5.0 * u2 * ir2);
  o.g2 = k * (30.0 * inv_m2 * gp2 * ir2);
  return o;
}

// magnet_field_ut() and its derivatives in closed form, as dipole_field_gradient_ut() (the same
// bits when `octupole_mm2` is 0). With c1, c2 the coefficients of r and m above (k = K q / r^5
// folded in) and e a change of r, f of m, the octupole's change is
//   k [r (A (m.e + r.f) + (Bd - 5 c1' / r^2) (r.e) + G1 (m.f)) + m (A2 (m.e + r.f) +
//      (B2 - 5 c2' / r^2) (r.e) + G2 (m.f)) + c1' e + c2' f],
// c1' = c1 / k, A = 105 g p^2 / r^4 - 15 / r^2, Bd = -140 g p^3 / r^6 + 30 p / r^4,
// G1 = -70 g^2 p^3 / r^4, A2 = -30 g p / r^2, B2 = 30 g p^2 / r^4, G2 = 30 g^2 p^2 / r^2
// (octupole_coefficients(): a, bd, g1, a2, b2, g2, the 5 c' / r^2 terms in bd and b2).
inline Vec3<double> magnet_field_gradient_ut(const Vec3<double>& m_am2, const Vec3<double>& r_mm,
                                             double octupole_mm2, double d_dr[3][3],
                                             double d_dm[3][3]) {
  const Vec3<double> dipole = dipole_field_gradient_ut(m_am2, r_mm, d_dr, d_dm);
  if (octupole_mm2 == 0) return dipole;
  const double inv_r = 1.0 / std::sqrt(dot(r_mm, r_mm));
  const double ir2 = inv_r * inv_r;
  const OctupoleCoefficients o =
      octupole_coefficients(0.5 * kDipoleScale * octupole_mm2 * ir2 * ir2 * inv_r, dot(m_am2, r_mm),
                            ir2, 1.0 / dot(m_am2, m_am2));
  const double r[3] = {r_mm.x, r_mm.y, r_mm.z}, m[3] = {m_am2.x, m_am2.y, m_am2.z};
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) {
      const double diag = i == j ? 1.0 : 0.0;
      d_dr[i][j] +=
          r[i] * (o.a * m[j] + o.bd * r[j]) + m[i] * (o.a2 * m[j] + o.b2 * r[j]) + o.c1 * diag;
      d_dm[i][j] +=
          r[i] * (o.g1 * m[j] + o.a * r[j]) + m[i] * (o.g2 * m[j] + o.a2 * r[j]) + o.c2 * diag;
    }
  }
  return {dipole.x + o.c1 * r_mm.x + o.c2 * m_am2.x, dipole.y + o.c1 * r_mm.y + o.c2 * m_am2.y,
          dipole.z + o.c1 * r_mm.z + o.c2 * m_am2.z};
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
