// sim/src/dipole_sum.h (internal): the hot loops of the field evaluation, built for AVX-512, AVX2
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
// `octupole`: K q of the magnet's shape (kDipoleScale x octupole_mm2 / 2, sim::magnet_field_ut();
// 0: a point dipole, the very bits of the dipole's loop).
using DipoleSum = void (*)(std::size_t ns, double px, double py, double pz, double mx, double my,
                           double mz, double octupole, const double* sx, const double* sy,
                           const double* sz, const double* rx, const double* ry, const double* rz,
                           double* ax, double* ay, double* az);

// At most this many unknowns move a magnet in one jet (three contacts with their shear).
inline constexpr int kMaxJetUnknowns = 15;

// One displaced magnet with the derivatives of its pose with respect to `unknowns` unknowns:
// position p (mm) and moment m (A m^2) in patch coordinates, dp[k] and dm[k] their derivatives
// by unknown k.
struct MagnetJet {
  double p[3], m[3];
  double octupole = 0;  // K q of its shape, as DipoleSum's (0: a point dipole)
  int unknowns = 0;
  double dp[kMaxJetUnknowns][3], dm[kMaxJetUnknowns][3];
};

// Adds, like DipoleSum, the magnet's field minus its rest field at each of `ns` sensors to
// ax/ay/az (uT), and the field's derivative by each unknown k to jx/jy/jz[k * ns + sensor]
// (uT per unit of the unknown): the dipole's field and gradient in closed form, no allocation.
using DipoleSumJet = void (*)(std::size_t ns, const MagnetJet& magnet, const double* sx,
                              const double* sy, const double* sz, const double* rx,
                              const double* ry, const double* rz, double* ax, double* ay,
                              double* az, double* jx, double* jy, double* jz);

// One press without shear as every magnet's pose under it reads it (PatchModel::contact_field_ut()
// of a single press): its place, its PatchModel::PressTerms, the model's spreads and lateral
// coupling, PatchDesign::inplane_drag.
struct PressPose {
  double u_mm = 0, v_mm = 0;
  double a2 = 0, amp_mm = 0;                                          // PressTerms' a2 and amp_mm
  double spread_u_mm = 1, spread_v_mm = 1, inv_lu2 = 1, inv_lv2 = 1;  // inv_l*2: 1 / spread^2
  double lateral_mm = 0, drag = 0;
};

// Magnets [0, n) as structure-of-arrays: rest position in surface coordinates (u, v, h; mm) and
// moment in the local surface frame (mx, my, mz; A m^2).
struct MagnetArrays {
  const double *u, *v, *h, *mx, *my, *mz;
};

// The poses of magnets [0, n) under `press`, by the formulas of PatchModel::magnet_pose() (the
// plate kernel by plate_kernel()'s table, `plate_gd`: detail::plate_table().gd), the magnets in
// the vector lanes: each one's squared scaled distance from the press into s2[i] (it moves when
// s2[i] < kPlateKernelCutoff^2), its moved position in surface coordinates into uu/vv/hh[i] and
// its moment in the local frame into bu/bv/bz[i] (meaningful where it moves). No allocation.
using PressPoses = void (*)(const PressPose& press, std::size_t n, const MagnetArrays& magnets,
                            const double* plate_gd, double* s2, double* uu, double* vv, double* hh,
                            double* bu, double* bv, double* bz);

// Adds, for each of `outs` outputs k (1 or 4), the sum over terms t < n of weight[t outs + k] x
// rows[index[t] nc + ch] to out[k nc + ch], for every ch < nc: a field correction's terms at its
// channels (sim::FieldCorrection; 4 outputs: the value and its derivatives by u, v and depth).
// No allocation.
using RowSums = void (*)(std::size_t n, const int* index, const double* weight, int outs,
                         const double* rows, std::size_t nc, double* out);

// The builds for `isa` (kPortable: baseline), or null when this CPU or build lacks it.
DipoleSum dipole_sum_for(Isa isa);
DipoleSumJet dipole_sum_jet_for(Isa isa);
PressPoses press_poses_for(Isa isa);
RowSums row_sums_for(Isa isa);
// The builds the field evaluation uses (their set: sim::field_isa()).
DipoleSum dipole_sum();
DipoleSumJet dipole_sum_jet();
PressPoses press_poses();
RowSums row_sums();

}  // namespace skinbus::sim::detail
