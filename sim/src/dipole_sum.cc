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

#define SKINBUS_DIPOLE_SUM_PARAMS                                                               \
  std::size_t ns, double px, double py, double pz, double mx, double my, double mz,             \
      const double *sx, const double *sy, const double *sz, const double *rx, const double *ry, \
      const double *rz, double *ax, double *ay, double *az
#define SKINBUS_DIPOLE_SUM_ARGS ns, px, py, pz, mx, my, mz, sx, sy, sz, rx, ry, rz, ax, ay, az

void dipole_sum_baseline(SKINBUS_DIPOLE_SUM_PARAMS) {
  dipole_sum_body(SKINBUS_DIPOLE_SUM_ARGS);
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
#endif

#undef SKINBUS_DIPOLE_SUM_PARAMS
#undef SKINBUS_DIPOLE_SUM_ARGS

struct Chosen {
  DipoleSum fn;
  Isa isa;
};

const Chosen& chosen() {
  static const Chosen c = [] {
    for (Isa isa : {Isa::kAvx512, Isa::kAvx2}) {
      DipoleSum f = isa_allowed(isa, env_isa_cap()) ? dipole_sum_for(isa) : nullptr;
      if (f != nullptr) return Chosen{f, isa};
    }
    return Chosen{&dipole_sum_baseline, Isa::kPortable};
  }();
  return c;
}

}  // namespace

DipoleSum dipole_sum_for(Isa isa) {
#if defined(__x86_64__) && defined(__GNUC__)
  __builtin_cpu_init();  // may run before libgcc's constructor (a static initialiser's call)
#endif
  switch (isa) {
    case Isa::kPortable:
      return &dipole_sum_baseline;
#if defined(__x86_64__) && defined(__GNUC__)
    case Isa::kAvx512:
      return __builtin_cpu_supports("avx512f") ? &dipole_sum_avx512 : nullptr;
    case Isa::kAvx2:
      return __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma") ? &dipole_sum_avx2
                                                                             : nullptr;
#endif
    default:
      return nullptr;
  }
}

DipoleSum dipole_sum() {
  return chosen().fn;
}

}  // namespace skinbus::sim::detail

namespace skinbus::sim {

Isa field_isa() {
  return detail::chosen().isa;
}

}  // namespace skinbus::sim
