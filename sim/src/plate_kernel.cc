#include "skinbus/sim/plate_kernel.h"

#include <array>
#include <cmath>
#include <vector>

namespace skinbus::sim {

void kelvin_kei(double x, double* kei, double* dkei_dx) {
  constexpr double kEulerGamma = 0.57721566490153286061;
  if (x <= 0) {
    *kei = -M_PI / 4;
    *dkei_dx = 0;
    return;
  }
  const double z = x / 2;
  const double z4 = z * z * z * z;
  // Terms: ber = sum (-1)^k z^{4k} / ((2k)!)^2 ; bei = sum (-1)^k z^{4k+2} / ((2k+1)!)^2 ;
  // extra = sum (-1)^k psi(2k+2) z^{4k+2} / ((2k+1)!)^2, psi the digamma function.
  double ber = 0, bei = 0, extra = 0, dber = 0, dbei = 0, dextra = 0;
  double zpow = 1;        // z^{4k}
  double fact_even = 1;   // (2k)!
  double fact_odd = 1;    // (2k+1)!
  double harmonic = 1.0;  // H_{2k+1} = sum_{j=1}^{2k+1} 1/j, so psi(2k+2) = H_{2k+1} - gamma
  for (int k = 0; k < 40; ++k) {
    const double sign = (k % 2) ? -1.0 : 1.0;
    const double te = sign * zpow / (fact_even * fact_even);
    const double to = sign * zpow * z * z / (fact_odd * fact_odd);
    const double psi = harmonic - kEulerGamma;
    ber += te;
    bei += to;
    extra += psi * to;
    // d/dx of z^n = n z^{n-1} / 2
    if (k > 0) dber += te * (4.0 * k) / z / 2;
    dbei += to * (4.0 * k + 2) / z / 2;
    dextra += psi * to * (4.0 * k + 2) / z / 2;
    if (std::fabs(te) + std::fabs(to) < 1e-300 ||
        (k > 3 && std::fabs(to) < 1e-18 && std::fabs(te) < 1e-18))
      break;
    zpow *= z4;
    fact_even *= (2.0 * k + 1) * (2.0 * k + 2);
    fact_odd *= (2.0 * k + 2) * (2.0 * k + 3);
    harmonic += 1.0 / (2.0 * k + 2) + 1.0 / (2.0 * k + 3);
  }
  const double lnz = std::log(z);
  *kei = -lnz * bei - (M_PI / 4) * ber + extra;
  *dkei_dx = -bei / x - lnz * dbei - (M_PI / 4) * dber + dextra;
}

namespace {

constexpr int kTableSize = 6501;  // step 0.001 over [0, 6.5]
constexpr double kStep = kPlateKernelCutoff / (kTableSize - 1);

struct Table {
  std::vector<double> g, dg;
  Table() : g(kTableSize), dg(kTableSize) {
    for (int i = 0; i < kTableSize; ++i) {
      const double s = i * kStep;
      double kei, dkei;
      kelvin_kei(s, &kei, &dkei);
      double gs = -(4 / M_PI) * kei, dgs = -(4 / M_PI) * dkei;
      // C1 fade to zero over [fade start, cutoff]: w(t) = 1 - 3t^2 + 2t^3.
      if (s > kPlateKernelFadeStart) {
        const double t = (s - kPlateKernelFadeStart) / (kPlateKernelCutoff - kPlateKernelFadeStart);
        const double w = 1 - 3 * t * t + 2 * t * t * t;
        const double dw = (-6 * t + 6 * t * t) / (kPlateKernelCutoff - kPlateKernelFadeStart);
        dgs = dgs * w + gs * dw;
        gs *= w;
      }
      g[i] = gs;
      dg[i] = dgs;
    }
    g.back() = 0;
    dg.back() = 0;
  }
};

const Table& table() {
  static const Table t;
  return t;
}

}  // namespace

void plate_kernel(double s, double* g, double* dg_ds, double* d2g_ds2) {
  s = std::fabs(s);
  if (!(s < kPlateKernelCutoff)) {  // also catches NaN
    *g = 0;
    *dg_ds = 0;
    if (d2g_ds2) *d2g_ds2 = 0;
    return;
  }
  const Table& t = table();
  const double u = s / kStep;
  const int i = static_cast<int>(u);
  const double f = u - i;
  // Cubic Hermite on (g, dg) at the two table points.
  const double h00 = (1 + 2 * f) * (1 - f) * (1 - f), h10 = f * (1 - f) * (1 - f);
  const double h01 = f * f * (3 - 2 * f), h11 = f * f * (f - 1);
  const double g0 = t.g[i], g1 = t.g[i + 1], d0 = t.dg[i] * kStep, d1 = t.dg[i + 1] * kStep;
  *g = h00 * g0 + h10 * d0 + h01 * g1 + h11 * d1;
  const double dh00 = 6 * f * f - 6 * f, dh10 = 3 * f * f - 4 * f + 1, dh01 = -dh00,
               dh11 = 3 * f * f - 2 * f;
  *dg_ds = (dh00 * g0 + dh10 * d0 + dh01 * g1 + dh11 * d1) / kStep;
  if (d2g_ds2) {
    const double e00 = 12 * f - 6, e10 = 6 * f - 4, e11 = 6 * f - 2;
    *d2g_ds2 = (e00 * g0 + e10 * d0 - e00 * g1 + e11 * d1) / (kStep * kStep);
  }
}

}  // namespace skinbus::sim
