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

namespace skinbus::sim {

inline constexpr double kPlateKernelFadeStart = 5.0;
inline constexpr double kPlateKernelCutoff = 6.5;  // g(s) = g'(s) = 0 for s >= this

// g(s), dg/ds and d2g/ds2 for s >= 0 (negative s is treated as |s|). Tabulated from the
// Kelvin-function series at start-up (step 0.001), then cubic Hermite: |g error| < 1e-9;
// the second derivative is that of the interpolant (piecewise, for first-order jets).
void plate_kernel(double s, double* g, double* dg_ds, double* d2g_ds2 = nullptr);

// The Kelvin function kei(x) and its derivative by their power series (Abramowitz & Stegun
// 9.9.12), accurate for 0 <= x <= 10. Used to build the table and by tests.
void kelvin_kei(double x, double* kei, double* dkei_dx);

}  // namespace skinbus::sim
