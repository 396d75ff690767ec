#include "skinbus/sim/plate_kernel.h"

#include <cmath>

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

namespace detail {

PlateTable::PlateTable() {
  for (int i = 0; i < kPlateTableSize; ++i) {
    const double s = i * kPlateTableStep;
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
    gd[2 * i] = gs;
    gd[2 * i + 1] = dgs;
  }
  gd[2 * (kPlateTableSize - 1)] = 0;
  gd[2 * (kPlateTableSize - 1) + 1] = 0;
}

}  // namespace detail

}  // namespace skinbus::sim
