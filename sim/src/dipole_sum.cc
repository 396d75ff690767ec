#include "dipole_sum.h"

#include <cmath>

#include "skinbus/sim/patch_model.h"

namespace skinbus::sim::detail {

namespace {

// The loop, inlined into one function per instruction set and vectorised by the compiler for
// that set.
__attribute__((always_inline)) inline void dipole_sum_body(
    std::size_t ns, double px, double py, double pz, double mx, double my, double mz,
    const double* __restrict sx, const double* __restrict sy, const double* __restrict sz,
    const double* __restrict rx, const double* __restrict ry, const double* __restrict rz,
    double* __restrict ax, double* __restrict ay, double* __restrict az) {
  for (std::size_t si = 0; si < ns; ++si) {
    const double dx = sx[si] - px, dy = sy[si] - py, dz = sz[si] - pz;
    const double r2 = dx * dx + dy * dy + dz * dz;
    const double inv_r = 1.0 / std::sqrt(r2);
    const double inv_r3 = inv_r * inv_r * inv_r;
    const double a = 3.0 * kDipoleScale * (mx * dx + my * dy + mz * dz) * inv_r3 * inv_r * inv_r;
    const double b = kDipoleScale * inv_r3;
    ax[si] += a * dx - b * mx - rx[si];
    ay[si] += a * dy - b * my - ry[si];
    az[si] += a * dz - b * mz - rz[si];
  }
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
  const double px = g.p[0], py = g.p[1], pz = g.p[2];
  const double mx = g.m[0], my = g.m[1], mz = g.m[2];
  for (std::size_t s0 = 0; s0 < ns; s0 += kBlock) {
    const std::size_t n = ns - s0 < kBlock ? ns - s0 : kBlock;
    double dx[kBlock], dy[kBlock], dz[kBlock], a[kBlock], b[kBlock], inv_r2[kBlock], k5[kBlock];
    for (std::size_t i = 0; i < n; ++i) {
      const std::size_t si = s0 + i;
      const double x = sx[si] - px, y = sy[si] - py, z = sz[si] - pz;
      const double r2 = x * x + y * y + z * z;
      const double inv_r = 1.0 / std::sqrt(r2);
      const double inv_r3 = inv_r * inv_r * inv_r;
      const double q = 3.0 * kDipoleScale * inv_r3 * inv_r * inv_r;  // 3 K / r^5
      const double ai = q * (mx * x + my * y + mz * z);
      const double bi = kDipoleScale * inv_r3;
      ax[si] += ai * x - bi * mx - rx[si];
      ay[si] += ai * y - bi * my - ry[si];
      az[si] += ai * z - bi * mz - rz[si];
      dx[i] = x;
      dy[i] = y;
      dz[i] = z;
      a[i] = ai;
      b[i] = bi;
      inv_r2[i] = inv_r * inv_r;
      k5[i] = q;
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

#define SKINBUS_DIPOLE_SUM_PARAMS                                                               \
  std::size_t ns, double px, double py, double pz, double mx, double my, double mz,             \
      const double *sx, const double *sy, const double *sz, const double *rx, const double *ry, \
      const double *rz, double *ax, double *ay, double *az
#define SKINBUS_DIPOLE_SUM_ARGS ns, px, py, pz, mx, my, mz, sx, sy, sz, rx, ry, rz, ax, ay, az
#define SKINBUS_DIPOLE_SUM_JET_PARAMS                                                           \
  std::size_t ns, const MagnetJet &g, const double *sx, const double *sy, const double *sz,     \
      const double *rx, const double *ry, const double *rz, double *ax, double *ay, double *az, \
      double *jx, double *jy, double *jz
#define SKINBUS_DIPOLE_SUM_JET_ARGS ns, g, sx, sy, sz, rx, ry, rz, ax, ay, az, jx, jy, jz

void dipole_sum_baseline(SKINBUS_DIPOLE_SUM_PARAMS) {
  dipole_sum_body(SKINBUS_DIPOLE_SUM_ARGS);
}
void dipole_sum_jet_baseline(SKINBUS_DIPOLE_SUM_JET_PARAMS) {
  dipole_sum_jet_body(SKINBUS_DIPOLE_SUM_JET_ARGS);
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
  dipole_sum_jet_body(SKINBUS_DIPOLE_SUM_JET_ARGS);
}
__attribute__((target("avx512f"))) void dipole_sum_jet_avx512(SKINBUS_DIPOLE_SUM_JET_PARAMS) {
  dipole_sum_jet_body(SKINBUS_DIPOLE_SUM_JET_ARGS);
}
#endif

#undef SKINBUS_DIPOLE_SUM_PARAMS
#undef SKINBUS_DIPOLE_SUM_ARGS
#undef SKINBUS_DIPOLE_SUM_JET_PARAMS
#undef SKINBUS_DIPOLE_SUM_JET_ARGS

struct Chosen {
  DipoleSum fn;
  DipoleSumJet jet;
  Isa isa;
};

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

const Chosen& chosen() {
  static const Chosen c = [] {
    for (Isa isa : {Isa::kAvx512, Isa::kAvx2}) {
      if (isa_allowed(isa, env_isa_cap()) && have(isa)) {
        return Chosen{dipole_sum_for(isa), dipole_sum_jet_for(isa), isa};
      }
    }
    return Chosen{&dipole_sum_baseline, &dipole_sum_jet_baseline, Isa::kPortable};
  }();
  return c;
}

}  // namespace

DipoleSum dipole_sum_for(Isa isa) {
  if (!have(isa)) return nullptr;
  switch (isa) {
    case Isa::kPortable:
      return &dipole_sum_baseline;
#if defined(__x86_64__) && defined(__GNUC__)
    case Isa::kAvx512:
      return &dipole_sum_avx512;
    case Isa::kAvx2:
      return &dipole_sum_avx2;
#endif
    default:
      return nullptr;
  }
}

DipoleSumJet dipole_sum_jet_for(Isa isa) {
  if (!have(isa)) return nullptr;
  switch (isa) {
    case Isa::kPortable:
      return &dipole_sum_jet_baseline;
#if defined(__x86_64__) && defined(__GNUC__)
    case Isa::kAvx512:
      return &dipole_sum_jet_avx512;
    case Isa::kAvx2:
      return &dipole_sum_jet_avx2;
#endif
    default:
      return nullptr;
  }
}

DipoleSum dipole_sum() {
  return chosen().fn;
}

DipoleSumJet dipole_sum_jet() {
  return chosen().jet;
}

}  // namespace skinbus::sim::detail

namespace skinbus::sim {

Isa field_isa() {
  return detail::chosen().isa;
}

}  // namespace skinbus::sim
