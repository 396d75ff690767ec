// skinbus/sim/crlb.h: the Cramer-Rao lower bound: the best position and depth error any
// unbiased estimator can reach at a point of a patch, from the forward model's Jacobian.
//
// With channel noise sigma_i (independent, Gaussian), the Fisher information of the contact
// parameters theta = (u, v, depth) is F = J^T diag(1/sigma^2) J, J = d field / d theta, and the
// covariance of any unbiased estimate is at least F^-1. Optionally a uniform ambient field
// (3 more unknowns, as the physics estimator fits) is a nuisance parameter: F grows to 6 x 6 and
// the bound on (u, v, depth) is read from its inverse. This is the physical limit every
// estimator in this project is judged against.
#pragma once

#include "skinbus/sim/patch_model.h"

namespace skinbus::sim {

inline constexpr double kUnidentifiableMm = 1e3;  // reported bound where F is singular

struct CrlbPoint {
  double sd_u_mm = 0, sd_v_mm = 0;
  double sd_xy_mm = 0;  // sqrt(var_u + var_v): the RMS in-plane error bound
  double sd_depth_mm = 0;
  bool identifiable =
      true;  // false: no information (e.g. far off the patch); sd = kUnidentifiableMm
};

CrlbPoint crlb_at(const PatchModel& model, const Contact& c, double noise_xy_ut, double noise_z_ut,
                  bool ambient_nuisance = false);

// The bound for two simultaneous contacts (each with its own u, v, depth: 6 unknowns, 9 with the
// ambient nuisance): what the second press costs the first, as a function of where both are.
// The Jacobian is exact (crlb_contacts_at() with two contacts). Two contacts that the field cannot
// tell apart (coincident, or one out of reach) give identifiable = false and kUnidentifiableMm for
// both, never NaN; so do non-finite inputs.
struct CrlbPair {
  CrlbPoint first, second;
};
CrlbPair crlb_pair_at(const PatchModel& model, const Contact& first, const Contact& second,
                      double noise_xy_ut, double noise_z_ut, bool ambient_nuisance = false);

// The bound for n simultaneous contacts, 1 <= n <= kCrlbMaxContacts (each its own u, v, depth:
// 3n unknowns, 3n + 3 with the ambient nuisance), into out[0..n): crlb_pair_at() for any count
// (the shear is not an unknown here; each contact's is taken as given). Exact Jacobian (dual
// numbers through the superposed field). When any contact cannot be told from the others
// (coincident, out of reach), n is out of range, `out` is shorter than n, or an input is not
// finite: every written point is unidentifiable (kUnidentifiableMm), never NaN.
inline constexpr int kCrlbMaxContacts = 3;
void crlb_contacts_at(const PatchModel& model, std::span<const Contact> contacts,
                      double noise_xy_ut, double noise_z_ut, bool ambient_nuisance,
                      std::span<CrlbPoint> out);

// The bound for a contact with a tangential (shear) force: its (u, v, depth) and the force's
// (F_u, F_v) all unknown (5 unknowns, 8 with the ambient nuisance), at the contact `c` with its
// shear (ContactT::shear_u_n, shear_v_n; the bound barely depends on it, the field being nearly
// linear in the shear). `contact` is what the unknown shear costs the position (compare
// crlb_at(), which knows the shear is 0); sd_shear_* bound the force's error, N. The Jacobian is
// exact (forward-mode dual numbers through the model). Unidentifiable or non-finite input:
// identifiable = false, kUnidentifiableMm / kUnidentifiableN, never NaN.
inline constexpr double kUnidentifiableN = 1e3;  // reported shear bound where F is singular
struct CrlbShear {
  CrlbPoint contact;
  double sd_shear_u_n = 0, sd_shear_v_n = 0;
  double sd_shear_n = 0;  // sqrt(var F_u + var F_v): the RMS error bound of the force vector
  bool identifiable = true;
};
CrlbShear crlb_shear_at(const PatchModel& model, const Contact& c, double noise_xy_ut,
                        double noise_z_ut, bool ambient_nuisance = false);

// The bound for two contacts each with its own tangential force: both contacts' (u, v, depth) and
// (F_u, F_v) unknown (10 unknowns, 13 with the ambient nuisance). Exact Jacobian (dual numbers
// through the superposed field). Coincident, unreachable or non-finite: both unidentifiable,
// never NaN.
struct CrlbPairShear {
  CrlbShear first, second;
};
CrlbPairShear crlb_pair_shear_at(const PatchModel& model, const Contact& first,
                                 const Contact& second, double noise_xy_ut, double noise_z_ut,
                                 bool ambient_nuisance = false);

// Inverts a symmetric positive-definite n x n matrix in place (n <= 13) by Gauss-Jordan with
// partial pivoting; false if it is singular to working precision.
inline constexpr int kInvertSmallMax = 13;
bool invert_small(double* a, int n);

}  // namespace skinbus::sim
