#include "dipole_sum.h"

#include <cmath>
#include <cstring>

#include "skinbus/sim/patch_model.h"

namespace skinbus::sim::detail {

namespace {

// The loop, inlined into one function per instruction set and vectorised by the compiler for
// that set.
// The octupole's coefficients at a sensor offset (x, y, z) from a magnet of moment m
// (sim::octupole_coefficients(), k = K q / r^5 with K q = `kq`), the offset kept beside them.
struct OctupoleTerms {
  double x, y, z;
  OctupoleCoefficients o;
};
__attribute__((always_inline)) inline OctupoleTerms octupole_terms(double x, double y, double z,
                                                                   const double m[3], double kq,
                                                                   double inv_m2) {
  const double inv_r = 1.0 / std::sqrt(x * x + y * y + z * z);
  const double ir2 = inv_r * inv_r;
  return {
      x, y, z,
      octupole_coefficients(kq * ir2 * ir2 * inv_r, m[0] * x + m[1] * y + m[2] * z, ir2, inv_m2)};
}

// Adds the octupole of a magnet's shape (K q = `kq`, not 0) to a field sum and, for `unknowns`
// > 0, to its jets (e = -dp, f = dm of each unknown):
//   B' = k [d (A (m.e + d.f) + Bd (d.e) + G1 (m.f)) + m (A2 (m.e + d.f) + B2 (d.e) + G2 (m.f))
//        + c1 e + c2 f].
__attribute__((always_inline)) inline void octupole_sum(
    std::size_t ns, const double p[3], const double m[3], double kq, int unknowns,
    const double (*dp)[3], const double (*dm)[3], const double* __restrict sx,
    const double* __restrict sy, const double* __restrict sz, double* __restrict ax,
    double* __restrict ay, double* __restrict az, double* __restrict jx, double* __restrict jy,
    double* __restrict jz) {
  const double inv_m2 = 1.0 / (m[0] * m[0] + m[1] * m[1] + m[2] * m[2]);
  for (std::size_t si = 0; si < ns; ++si) {
    const OctupoleTerms t =
        octupole_terms(sx[si] - p[0], sy[si] - p[1], sz[si] - p[2], m, kq, inv_m2);
    const OctupoleCoefficients& o = t.o;
    ax[si] += o.c1 * t.x + o.c2 * m[0];
    ay[si] += o.c1 * t.y + o.c2 * m[1];
    az[si] += o.c1 * t.z + o.c2 * m[2];
    for (int k = 0; k < unknowns; ++k) {
      const double ex = -dp[k][0], ey = -dp[k][1], ez = -dp[k][2];
      const double fx = dm[k][0], fy = dm[k][1], fz = dm[k][2];
      const double me = m[0] * ex + m[1] * ey + m[2] * ez, mf = m[0] * fx + m[1] * fy + m[2] * fz;
      const double de = t.x * ex + t.y * ey + t.z * ez, df = t.x * fx + t.y * fy + t.z * fz;
      const double cd = o.a * (me + df) + o.bd * de + o.g1 * mf;
      const double cm = o.a2 * (me + df) + o.b2 * de + o.g2 * mf;
      const std::size_t at = static_cast<std::size_t>(k) * ns + si;
      jx[at] += cd * t.x + cm * m[0] + o.c1 * ex + o.c2 * fx;
      jy[at] += cd * t.y + cm * m[1] + o.c1 * ey + o.c2 * fy;
      jz[at] += cd * t.z + cm * m[2] + o.c1 * ez + o.c2 * fz;
    }
  }
}

// The loop with or without the octupole (kOctupole: `octupole` is not 0), fused into one pass a
// sensor: the offset and distance made once for both.
template <bool kOctupole>
__attribute__((always_inline)) inline void dipole_sum_pass(
    std::size_t ns, double px, double py, double pz, double mx, double my, double mz,
    double octupole, const double* __restrict sx, const double* __restrict sy,
    const double* __restrict sz, const double* __restrict rx, const double* __restrict ry,
    const double* __restrict rz, double* __restrict ax, double* __restrict ay,
    double* __restrict az) {
  const double inv_m2 = kOctupole ? 1.0 / (mx * mx + my * my + mz * mz) : 0.0;
  for (std::size_t si = 0; si < ns; ++si) {
    const double dx = sx[si] - px, dy = sy[si] - py, dz = sz[si] - pz;
    const double r2 = dx * dx + dy * dy + dz * dz;
    const double inv_r = 1.0 / std::sqrt(r2);
    const double inv_r3 = inv_r * inv_r * inv_r;
    const double md = mx * dx + my * dy + mz * dz;
    double a = 3.0 * kDipoleScale * md * inv_r3 * inv_r * inv_r;
    double b = kDipoleScale * inv_r3;
    if constexpr (kOctupole) {  // B += c1 d + c2 m (sim::magnet_field_ut())
      const double ir2 = inv_r * inv_r;
      const OctupoleCoefficients o =
          octupole_coefficients(octupole * ir2 * ir2 * inv_r, md, ir2, inv_m2);
      a += o.c1;
      b -= o.c2;
    }
    ax[si] += a * dx - b * mx - rx[si];
    ay[si] += a * dy - b * my - ry[si];
    az[si] += a * dz - b * mz - rz[si];
  }
}

__attribute__((always_inline)) inline void dipole_sum_body(
    std::size_t ns, double px, double py, double pz, double mx, double my, double mz,
    double octupole, const double* __restrict sx, const double* __restrict sy,
    const double* __restrict sz, const double* __restrict rx, const double* __restrict ry,
    const double* __restrict rz, double* __restrict ax, double* __restrict ay,
    double* __restrict az) {
  if (octupole != 0) {
    dipole_sum_pass<true>(ns, px, py, pz, mx, my, mz, octupole, sx, sy, sz, rx, ry, rz, ax, ay, az);
  } else {
    dipole_sum_pass<false>(ns, px, py, pz, mx, my, mz, octupole, sx, sy, sz, rx, ry, rz, ax, ay,
                           az);
  }
}

// A jet's terms at a sensor (sx, sy, sz) of a magnet at p with moment m: the sensor's offset
// d = (x, y, z) from it, 1 / r^2, q = 3 K / r^5, a = q (m.d) and b = K / r^3 (B = a d - b m).
struct JetTerms {
  double x, y, z, ir2, q, a, b;
};
__attribute__((always_inline)) inline JetTerms jet_terms(double sx, double sy, double sz,
                                                         const double p[3], const double m[3]) {
  JetTerms t;
  t.x = sx - p[0], t.y = sy - p[1], t.z = sz - p[2];
  const double r2 = t.x * t.x + t.y * t.y + t.z * t.z;
  const double inv_r = 1.0 / std::sqrt(r2);
  const double inv_r3 = inv_r * inv_r * inv_r;
  t.ir2 = inv_r * inv_r;
  t.q = 3.0 * kDipoleScale * inv_r3 * inv_r * inv_r;
  t.a = t.q * (m[0] * t.x + m[1] * t.y + m[2] * t.z);
  t.b = kDipoleScale * inv_r3;
  return t;
}

// The jet: the field as above, each sensor's offset and powers of its distance kept, then per
// unknown k (offset derivative e = -dp[k], moment derivative dm[k]), with B = a d - b m,
// a = 3 K (m.d) / r^5, b = K / r^3:
//   a' = 3 K (dm.d + m.e) / r^5 - 5 a (d.e) / r^2,  b' = -3 b (d.e) / r^2,
//   B' = a' d + a e - b' m - b dm.
__attribute__((always_inline)) inline void dipole_sum_jet_body(
    std::size_t ns, const MagnetJet& g, const double* __restrict sx, const double* __restrict sy,
    const double* __restrict sz, const double* __restrict rx, const double* __restrict ry,
    const double* __restrict rz, double* __restrict ax, double* __restrict ay,
    double* __restrict az, double* __restrict jx, double* __restrict jy, double* __restrict jz) {
  constexpr std::size_t kBlock = 64;  // sensors a pass: the kept terms stay on the stack
  const double p[3] = {g.p[0], g.p[1], g.p[2]};
  const double mx = g.m[0], my = g.m[1], mz = g.m[2];
  for (std::size_t s0 = 0; s0 < ns; s0 += kBlock) {
    const std::size_t n = ns - s0 < kBlock ? ns - s0 : kBlock;
    double dx[kBlock], dy[kBlock], dz[kBlock], a[kBlock], b[kBlock], inv_r2[kBlock], k5[kBlock];
    for (std::size_t i = 0; i < n; ++i) {
      const std::size_t si = s0 + i;
      const JetTerms t = jet_terms(sx[si], sy[si], sz[si], p, g.m);
      ax[si] += t.a * t.x - t.b * mx - rx[si];
      ay[si] += t.a * t.y - t.b * my - ry[si];
      az[si] += t.a * t.z - t.b * mz - rz[si];
      dx[i] = t.x;
      dy[i] = t.y;
      dz[i] = t.z;
      a[i] = t.a;
      b[i] = t.b;
      inv_r2[i] = t.ir2;
      k5[i] = t.q;
    }
    for (int k = 0; k < g.unknowns; ++k) {
      const double ex = -g.dp[k][0], ey = -g.dp[k][1], ez = -g.dp[k][2];
      const double fx = g.dm[k][0], fy = g.dm[k][1], fz = g.dm[k][2];
      const double me = mx * ex + my * ey + mz * ez;
      double* __restrict ox = jx + static_cast<std::size_t>(k) * ns + s0;
      double* __restrict oy = jy + static_cast<std::size_t>(k) * ns + s0;
      double* __restrict oz = jz + static_cast<std::size_t>(k) * ns + s0;
      for (std::size_t i = 0; i < n; ++i) {
        const double de = dx[i] * ex + dy[i] * ey + dz[i] * ez;
        const double fd = fx * dx[i] + fy * dy[i] + fz * dz[i];
        const double da = k5[i] * (fd + me) - 5.0 * a[i] * de * inv_r2[i];
        const double db = -3.0 * b[i] * de * inv_r2[i];
        ox[i] += da * dx[i] + a[i] * ex - db * mx - b[i] * fx;
        oy[i] += da * dy[i] + a[i] * ey - db * my - b[i] * fy;
        oz[i] += da * dz[i] + a[i] * ez - db * mz - b[i] * fz;
      }
    }
  }
}

// The jet for exactly three unknowns (one press's u, v and depth: every Jacobian of a
// single-contact fit), the same formulas fused into one pass a sensor: the three derivatives are
// made while the sensor's offset and distance are in registers, not kept and read back per
// unknown.
template <bool kOctupole>
__attribute__((always_inline)) inline void dipole_sum_jet3_pass(
    std::size_t ns, const MagnetJet& g, const double* __restrict sx, const double* __restrict sy,
    const double* __restrict sz, const double* __restrict rx, const double* __restrict ry,
    const double* __restrict rz, double* __restrict ax, double* __restrict ay,
    double* __restrict az, double* __restrict jx, double* __restrict jy, double* __restrict jz) {
  const double p[3] = {g.p[0], g.p[1], g.p[2]};
  const double mx = g.m[0], my = g.m[1], mz = g.m[2];
  double ex[3], ey[3], ez[3], fx[3], fy[3], fz[3], me[3], mf[3];
  double* __restrict ox[3];
  double* __restrict oy[3];
  double* __restrict oz[3];
  for (int k = 0; k < 3; ++k) {
    ex[k] = -g.dp[k][0], ey[k] = -g.dp[k][1], ez[k] = -g.dp[k][2];
    fx[k] = g.dm[k][0], fy[k] = g.dm[k][1], fz[k] = g.dm[k][2];
    me[k] = mx * ex[k] + my * ey[k] + mz * ez[k];
    mf[k] = mx * fx[k] + my * fy[k] + mz * fz[k];
    ox[k] = jx + static_cast<std::size_t>(k) * ns;
    oy[k] = jy + static_cast<std::size_t>(k) * ns;
    oz[k] = jz + static_cast<std::size_t>(k) * ns;
  }
  const double inv_m2 = kOctupole ? 1.0 / (mx * mx + my * my + mz * mz) : 0.0;
  const double oq = kOctupole ? g.octupole / (3.0 * kDipoleScale) : 0.0;  // k = oq q (q: 3K/r^5)
  for (std::size_t si = 0; si < ns; ++si) {
    const JetTerms t = jet_terms(sx[si], sy[si], sz[si], p, g.m);
    const double x = t.x, y = t.y, z = t.z, q = t.q, a = t.a, b = t.b;
    const double a5 = 5.0 * a * t.ir2, b3 = 3.0 * b * t.ir2;  // a' = q (dm.d + m.e) - a5 (d.e)
    // The octupole's coefficients (sim::octupole_coefficients()), 0 without one: B gains
    // c1 d + c2 m.
    OctupoleCoefficients o{};
    if constexpr (kOctupole) {
      o = octupole_coefficients(oq * q, mx * x + my * y + mz * z, t.ir2, inv_m2);
    }
    const double ac = a + o.c1, bc = b - o.c2;  // B = ac d - bc m
    ax[si] += ac * x - bc * mx - rx[si];
    ay[si] += ac * y - bc * my - ry[si];
    az[si] += ac * z - bc * mz - rz[si];
#pragma GCC unroll 3
    for (int k = 0; k < 3; ++k) {
      const double de = x * ex[k] + y * ey[k] + z * ez[k];
      const double fd = fx[k] * x + fy[k] * y + fz[k] * z;
      double da = q * (fd + me[k]) - a5 * de;
      double ndb = b3 * de;  // -b'
      if constexpr (kOctupole) {
        da += o.a * (me[k] + fd) + o.bd * de + o.g1 * mf[k];
        ndb += o.a2 * (me[k] + fd) + o.b2 * de + o.g2 * mf[k];
      }
      ox[k][si] += da * x + ac * ex[k] + ndb * mx - bc * fx[k];
      oy[k][si] += da * y + ac * ey[k] + ndb * my - bc * fy[k];
      oz[k][si] += da * z + ac * ez[k] + ndb * mz - bc * fz[k];
    }
  }
}

__attribute__((always_inline)) inline void dipole_sum_jet3_body(
    std::size_t ns, const MagnetJet& g, const double* __restrict sx, const double* __restrict sy,
    const double* __restrict sz, const double* __restrict rx, const double* __restrict ry,
    const double* __restrict rz, double* __restrict ax, double* __restrict ay,
    double* __restrict az, double* __restrict jx, double* __restrict jy, double* __restrict jz) {
  if (g.octupole != 0) {
    dipole_sum_jet3_pass<true>(ns, g, sx, sy, sz, rx, ry, rz, ax, ay, az, jx, jy, jz);
  } else {
    dipole_sum_jet3_pass<false>(ns, g, sx, sy, sz, rx, ry, rz, ax, ay, az, jx, jy, jz);
  }
}

// Three unknowns take the fused pass, any other count the kept-terms one.
__attribute__((always_inline)) inline void dipole_sum_jet_any(std::size_t ns, const MagnetJet& g,
                                                              const double* sx, const double* sy,
                                                              const double* sz, const double* rx,
                                                              const double* ry, const double* rz,
                                                              double* ax, double* ay, double* az,
                                                              double* jx, double* jy, double* jz) {
  if (g.unknowns == 3) {
    dipole_sum_jet3_body(ns, g, sx, sy, sz, rx, ry, rz, ax, ay, az, jx, jy, jz);
  } else {
    if (g.octupole != 0) {  // a pass of its own beside the kept terms' (several contacts)
      octupole_sum(ns, g.p, g.m, g.octupole, g.unknowns, g.dp, g.dm, sx, sy, sz, ax, ay, az, jx, jy,
                   jz);
    }
    dipole_sum_jet_body(ns, g, sx, sy, sz, rx, ry, rz, ax, ay, az, jx, jy, jz);
  }
}

// The poses of a press's magnets (PressPoses): PatchModel::contact_field_ut()'s formulas for one
// press term by term, without a branch (every term computed, then chosen), so that the compiler
// puts magnets in the vector lanes.
__attribute__((always_inline)) inline void press_poses_body(
    const PressPose& p, std::size_t n, const MagnetArrays& m, const double* __restrict gd,
    double* __restrict s2_out, double* __restrict uu_out, double* __restrict vv_out,
    double* __restrict hh_out, double* __restrict bu_out, double* __restrict bv_out,
    double* __restrict bz_out) {
  const double* __restrict mu = m.u;
  const double* __restrict mv = m.v;
  const double* __restrict mh = m.h;
  const double* __restrict mx = m.mx;
  const double* __restrict my = m.my;
  const double* __restrict mz = m.mz;
  const double pu0 = p.u_mm, pv0 = p.v_mm, inv_lu2 = p.inv_lu2, inv_lv2 = p.inv_lv2;
  const double a2 = p.a2, amp = p.amp_mm, lateral = p.lateral_mm, drag = p.drag;
  const double lu = p.spread_u_mm, lv = p.spread_v_mm;
  for (std::size_t i = 0; i < n; ++i) {
    const double du = mu[i] - pu0, dv = mv[i] - pv0;
    const double s2 = du * du * inv_lu2 + dv * dv * inv_lv2;
    const double s = std::sqrt(s2 + a2);
    // plate_kernel(s) without its branch: the table's values read here, through the restrict
    // pointer (read in a helper, the compiler would no longer know they are not the outputs),
    // the interpolant zeroed past the cutoff.
    const PlateInterval at = plate_interval(s);
    const PlateValue v =
        plate_hermite(at.f, gd[2 * at.j], gd[2 * at.j + 1], gd[2 * at.j + 2], gd[2 * at.j + 3]);
    const bool inside = s < kPlateKernelCutoff;
    const double g = inside ? v.g : 0.0, dg = inside ? v.dg : 0.0;
    const bool off_centre = s > 1e-6;
    const double q_off = dg / (off_centre ? s : 1.0);
    const double q = off_centre ? q_off : 0.0;
    const double w = 0.0 + amp * g;
    const double pu = 0.0 - amp * q * du * inv_lu2, pv = 0.0 - amp * q * dv * inv_lv2;
    // PatchModel::drag_toward() (zero when there is no drag: the sum's bits as without it).
    const double su = 0.0 - drag * amp * g * du / lu, sv = 0.0 - drag * amp * g * dv / lv;
    const double ml2 = mx[i] * mx[i] + my[i] * my[i] + mz[i] * mz[i];
    const double bu = mx[i] - pu * mz[i], bv = my[i] - pv * mz[i], bz = mz[i];
    const double k = std::sqrt(ml2 / (bu * bu + bv * bv + bz * bz));
    s2_out[i] = s2;
    uu_out[i] = mu[i] - lateral * pu + su;
    vv_out[i] = mv[i] - lateral * pv + sv;
    hh_out[i] = mh[i] - w;
    bu_out[i] = bu * k;
    bv_out[i] = bv * k;
    bz_out[i] = bz * k;
  }
}

// The row sums, a block of kLanes x kVectors channels a pass: the block's sums stay in registers
// over every term (kOuts x kVectors vectors of kLanes doubles), each term's row read once. Each
// build takes vectors of its own width (one 512-bit vector a block for AVX-512, two 256-bit ones
// for AVX2, two 128-bit ones for the baseline): a vector wider than the build's registers is
// split by the compiler through the stack, at a fraction of the speed.
template <int kLanes, int kVectors, int kOuts>
__attribute__((always_inline)) inline void row_sums_outs(std::size_t n, const int* index,
                                                         const double* weight,
                                                         const double* __restrict rows,
                                                         std::size_t nc, double* __restrict out) {
  typedef double Vec __attribute__((vector_size(kLanes * sizeof(double))));
  constexpr std::size_t kBlock = static_cast<std::size_t>(kLanes) * kVectors;
  std::size_t c0 = 0;
  for (; c0 + kBlock <= nc; c0 += kBlock) {
    Vec acc[kOuts][kVectors] = {};
    for (std::size_t t = 0; t < n; ++t) {
      const double* row = rows + static_cast<std::size_t>(index[t]) * nc + c0;
      Vec r[kVectors];
      for (int v = 0; v < kVectors; ++v) std::memcpy(&r[v], row + v * kLanes, sizeof(Vec));
      for (int k = 0; k < kOuts; ++k) {
        const double w = weight[t * kOuts + static_cast<std::size_t>(k)];
        for (int v = 0; v < kVectors; ++v) acc[k][v] += w * r[v];
      }
    }
    for (int k = 0; k < kOuts; ++k) {
      for (int v = 0; v < kVectors; ++v) {
        Vec o;
        double* at = out + static_cast<std::size_t>(k) * nc + c0 + v * kLanes;
        std::memcpy(&o, at, sizeof o);
        o += acc[k][v];
        std::memcpy(at, &o, sizeof o);
      }
    }
  }
  for (std::size_t t = 0; c0 < nc && t < n; ++t) {  // the last channels, fewer than a block
    const double* __restrict r = rows + static_cast<std::size_t>(index[t]) * nc;
    for (int k = 0; k < kOuts; ++k) {
      const double w = weight[t * kOuts + static_cast<std::size_t>(k)];
      for (std::size_t ch = c0; ch < nc; ++ch)
        out[static_cast<std::size_t>(k) * nc + ch] += w * r[ch];
    }
  }
}

template <int kLanes, int kVectors>
__attribute__((always_inline)) inline void row_sums_body(std::size_t n, const int* index,
                                                         const double* weight, int outs,
                                                         const double* __restrict rows,
                                                         std::size_t nc, double* __restrict out) {
  if (outs == 1) {
    row_sums_outs<kLanes, kVectors, 1>(n, index, weight, rows, nc, out);
  } else {
    row_sums_outs<kLanes, kVectors, 4>(n, index, weight, rows, nc, out);
  }
}

#define SKINBUS_DIPOLE_SUM_PARAMS                                                              \
  std::size_t ns, double px, double py, double pz, double mx, double my, double mz,            \
      double octupole, const double *sx, const double *sy, const double *sz, const double *rx, \
      const double *ry, const double *rz, double *ax, double *ay, double *az
#define SKINBUS_DIPOLE_SUM_ARGS \
  ns, px, py, pz, mx, my, mz, octupole, sx, sy, sz, rx, ry, rz, ax, ay, az
#define SKINBUS_DIPOLE_SUM_JET_PARAMS                                                           \
  std::size_t ns, const MagnetJet &g, const double *sx, const double *sy, const double *sz,     \
      const double *rx, const double *ry, const double *rz, double *ax, double *ay, double *az, \
      double *jx, double *jy, double *jz
#define SKINBUS_DIPOLE_SUM_JET_ARGS ns, g, sx, sy, sz, rx, ry, rz, ax, ay, az, jx, jy, jz
#define SKINBUS_PRESS_POSES_PARAMS                                                                \
  const PressPose &p, std::size_t n, const MagnetArrays &m, const double *__restrict gd,          \
      double *__restrict s2, double *__restrict uu, double *__restrict vv, double *__restrict hh, \
      double *__restrict bu, double *__restrict bv, double *__restrict bz
#define SKINBUS_PRESS_POSES_ARGS p, n, m, gd, s2, uu, vv, hh, bu, bv, bz
#define SKINBUS_ROW_SUMS_PARAMS                                                        \
  std::size_t n, const int *index, const double *weight, int outs, const double *rows, \
      std::size_t nc, double *out
#define SKINBUS_ROW_SUMS_ARGS n, index, weight, outs, rows, nc, out

void dipole_sum_baseline(SKINBUS_DIPOLE_SUM_PARAMS) {
  dipole_sum_body(SKINBUS_DIPOLE_SUM_ARGS);
}
void dipole_sum_jet_baseline(SKINBUS_DIPOLE_SUM_JET_PARAMS) {
  dipole_sum_jet_any(SKINBUS_DIPOLE_SUM_JET_ARGS);
}
void press_poses_baseline(SKINBUS_PRESS_POSES_PARAMS) {
  press_poses_body(SKINBUS_PRESS_POSES_ARGS);
}
void row_sums_baseline(SKINBUS_ROW_SUMS_PARAMS) {
  row_sums_body<2, 2>(SKINBUS_ROW_SUMS_ARGS);
}

#if defined(__x86_64__) && defined(__GNUC__)
// AVX2 with FMA (every AVX2 CPU robots carry has both) and AVX-512F (whose EVEX encoding has
// FMA): the compiler may fuse a multiply and an add, so these differ from the baseline in the
// last bits.
__attribute__((target("avx2,fma"))) void dipole_sum_avx2(SKINBUS_DIPOLE_SUM_PARAMS) {
  dipole_sum_body(SKINBUS_DIPOLE_SUM_ARGS);
}
__attribute__((target("avx512f"))) void dipole_sum_avx512(SKINBUS_DIPOLE_SUM_PARAMS) {
  dipole_sum_body(SKINBUS_DIPOLE_SUM_ARGS);
}
__attribute__((target("avx2,fma"))) void dipole_sum_jet_avx2(SKINBUS_DIPOLE_SUM_JET_PARAMS) {
  dipole_sum_jet_any(SKINBUS_DIPOLE_SUM_JET_ARGS);
}
__attribute__((target("avx512f"))) void dipole_sum_jet_avx512(SKINBUS_DIPOLE_SUM_JET_PARAMS) {
  dipole_sum_jet_any(SKINBUS_DIPOLE_SUM_JET_ARGS);
}
__attribute__((target("avx2,fma"))) void press_poses_avx2(SKINBUS_PRESS_POSES_PARAMS) {
  press_poses_body(SKINBUS_PRESS_POSES_ARGS);
}
__attribute__((target("avx512f"))) void press_poses_avx512(SKINBUS_PRESS_POSES_PARAMS) {
  press_poses_body(SKINBUS_PRESS_POSES_ARGS);
}
__attribute__((target("avx2,fma"))) void row_sums_avx2(SKINBUS_ROW_SUMS_PARAMS) {
  row_sums_body<4, 2>(SKINBUS_ROW_SUMS_ARGS);
}
__attribute__((target("avx512f"))) void row_sums_avx512(SKINBUS_ROW_SUMS_PARAMS) {
  row_sums_body<8, 1>(SKINBUS_ROW_SUMS_ARGS);
}
#endif

#undef SKINBUS_DIPOLE_SUM_PARAMS
#undef SKINBUS_DIPOLE_SUM_ARGS
#undef SKINBUS_DIPOLE_SUM_JET_PARAMS
#undef SKINBUS_DIPOLE_SUM_JET_ARGS
#undef SKINBUS_PRESS_POSES_PARAMS
#undef SKINBUS_PRESS_POSES_ARGS
#undef SKINBUS_ROW_SUMS_PARAMS
#undef SKINBUS_ROW_SUMS_ARGS

// One instruction set's builds of the loops.
struct Builds {
  DipoleSum fn;
  DipoleSumJet jet;
  PressPoses poses;
  RowSums rows;
};
constexpr Builds kBaselineBuilds{&dipole_sum_baseline, &dipole_sum_jet_baseline,
                                 &press_poses_baseline, &row_sums_baseline};
#if defined(__x86_64__) && defined(__GNUC__)
constexpr Builds kAvx2Builds{&dipole_sum_avx2, &dipole_sum_jet_avx2, &press_poses_avx2,
                             &row_sums_avx2};
constexpr Builds kAvx512Builds{&dipole_sum_avx512, &dipole_sum_jet_avx512, &press_poses_avx512,
                               &row_sums_avx512};
#endif

// Whether this CPU and build have `isa`'s builds.
bool have(Isa isa) {
#if defined(__x86_64__) && defined(__GNUC__)
  __builtin_cpu_init();  // may run before libgcc's constructor (a static initialiser's call)
  switch (isa) {
    case Isa::kPortable:
      return true;
    case Isa::kAvx512:
      return __builtin_cpu_supports("avx512f");
    case Isa::kAvx2:
      return __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma");
    default:
      return false;
  }
#else
  return isa == Isa::kPortable;
#endif
}

// `isa`'s builds, or null when this CPU or build lacks them.
const Builds* builds_for(Isa isa) {
  if (!have(isa)) return nullptr;
  switch (isa) {
    case Isa::kPortable:
      return &kBaselineBuilds;
#if defined(__x86_64__) && defined(__GNUC__)
    case Isa::kAvx512:
      return &kAvx512Builds;
    case Isa::kAvx2:
      return &kAvx2Builds;
#endif
    default:
      return nullptr;
  }
}

struct Chosen {
  Builds builds;
  Isa isa;
};

const Chosen& chosen() {
  static const Chosen c = [] {
    for (Isa isa : {Isa::kAvx512, Isa::kAvx2}) {
      if (isa_allowed(isa, env_isa_cap()) && have(isa)) return Chosen{*builds_for(isa), isa};
    }
    return Chosen{kBaselineBuilds, Isa::kPortable};
  }();
  return c;
}

}  // namespace

DipoleSum dipole_sum_for(Isa isa) {
  const Builds* b = builds_for(isa);
  return b != nullptr ? b->fn : nullptr;
}

DipoleSumJet dipole_sum_jet_for(Isa isa) {
  const Builds* b = builds_for(isa);
  return b != nullptr ? b->jet : nullptr;
}

PressPoses press_poses_for(Isa isa) {
  const Builds* b = builds_for(isa);
  return b != nullptr ? b->poses : nullptr;
}

RowSums row_sums_for(Isa isa) {
  const Builds* b = builds_for(isa);
  return b != nullptr ? b->rows : nullptr;
}

DipoleSum dipole_sum() {
  return chosen().builds.fn;
}

DipoleSumJet dipole_sum_jet() {
  return chosen().builds.jet;
}

PressPoses press_poses() {
  return chosen().builds.poses;
}

RowSums row_sums() {
  return chosen().builds.rows;
}

}  // namespace skinbus::sim::detail

namespace skinbus::sim {

Isa field_isa() {
  return detail::chosen().isa;
}

}  // namespace skinbus::sim
