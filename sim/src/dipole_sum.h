// sim/src/dipole_sum.h (internal): the hot loop of the field evaluation, built for AVX-512, AVX2
// with FMA and baseline x86-64 (elsewhere: baseline only), the widest the CPU has within
// SKINBUS_MAX_ISA chosen once. The builds compute the same element-wise operations, but the
// vector ones may fuse multiplies and adds: they agree with the baseline to a few units in the
// last place of the terms summed (dipole_sum_test.cc).
#pragma once

#include <cstddef>

#include "skinbus/common/isa.h"

namespace skinbus::sim::detail {

// Adds, at each of `ns` sensors (positions sx/sy/sz, mm), the field of one displaced magnet
// (position px/py/pz, moment mx/my/mz) minus its rest field (rx/ry/rz) to ax/ay/az, uT. No
// allocation.
using DipoleSum = void (*)(std::size_t ns, double px, double py, double pz, double mx, double my,
                           double mz, const double* sx, const double* sy, const double* sz,
                           const double* rx, const double* ry, const double* rz, double* ax,
                           double* ay, double* az);

// The build for `isa` (kPortable: baseline), or null when this CPU or build lacks it.
DipoleSum dipole_sum_for(Isa isa);
// The build the field evaluation uses (its set: sim::field_isa()).
DipoleSum dipole_sum();

}  // namespace skinbus::sim::detail
