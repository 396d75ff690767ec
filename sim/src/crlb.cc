#include "skinbus/sim/crlb.h"

#include <algorithm>
#include <cmath>
#include <vector>

namespace skinbus::sim {

bool invert_small(double* a, int n) {
  if (n < 1 || n > kInvertSmallMax) return false;
  double inv[kInvertSmallMax * kInvertSmallMax] = {};
  for (int i = 0; i < n; ++i) inv[i * n + i] = 1;
  double scale = 0;
  for (int i = 0; i < n * n; ++i) scale = std::fmax(scale, std::fabs(a[i]));
  if (!(scale > 0) || !std::isfinite(scale)) return false;
  for (int c = 0; c < n; ++c) {
    int p = c;
    for (int r = c + 1; r < n; ++r) {
      if (std::fabs(a[r * n + c]) > std::fabs(a[p * n + c])) p = r;
    }
    if (std::fabs(a[p * n + c]) < 1e-13 * scale) return false;
    if (p != c) {
      for (int k = 0; k < n; ++k) {
        std::swap(a[p * n + k], a[c * n + k]);
        std::swap(inv[p * n + k], inv[c * n + k]);
      }
    }
    const double d = 1 / a[c * n + c];
    for (int k = 0; k < n; ++k) {
      a[c * n + k] *= d;
      inv[c * n + k] *= d;
    }
    for (int r = 0; r < n; ++r) {
      if (r == c) continue;
      const double f = a[r * n + c];
      if (f == 0) continue;
      for (int k = 0; k < n; ++k) {
        a[r * n + k] -= f * a[c * n + k];
        inv[r * n + k] -= f * inv[c * n + k];
      }
    }
  }
  for (int i = 0; i < n * n; ++i) a[i] = inv[i];
  return true;
}

namespace {

// The bound of the contact whose (u, v, depth) start at parameter `first` of the inverted
// np x np Fisher matrix `inv` (ok: the inversion succeeded).
CrlbPoint point_from_inverse(const double* inv, int np, int first, bool ok) {
  CrlbPoint p;
  const int u = first * np + first, v = (first + 1) * np + first + 1,
            d = (first + 2) * np + first + 2;
  if (!ok || !(inv[u] >= 0) || !(inv[v] >= 0) || !(inv[d] >= 0)) {
    p.identifiable = false;
    p.sd_u_mm = p.sd_v_mm = p.sd_xy_mm = p.sd_depth_mm = kUnidentifiableMm;
    return p;
  }
  p.sd_u_mm = std::fmin(std::sqrt(inv[u]), kUnidentifiableMm);
  p.sd_v_mm = std::fmin(std::sqrt(inv[v]), kUnidentifiableMm);
  p.sd_xy_mm = std::fmin(std::sqrt(inv[u] + inv[v]), kUnidentifiableMm);
  p.sd_depth_mm = std::fmin(std::sqrt(inv[d]), kUnidentifiableMm);
  p.identifiable = p.sd_xy_mm < kUnidentifiableMm && p.sd_depth_mm < kUnidentifiableMm;
  return p;
}

// The Fisher information (np x np, row-major, into `fisher`) of a contact Jacobian `jac`
// (channels x k, row-major) whitened by the channel noise, with the ambient offset's 3 columns
// appended when `ambient` (np = k + 3, else k).
void fisher_information(const PatchModel& model, const std::vector<double>& jac, int k,
                        double noise_xy_ut, double noise_z_ut, bool ambient, double* fisher) {
  const int nc = model.channel_count();
  const int np = ambient ? k + 3 : k;
  const auto& sensors = model.sensors();
  std::fill(fisher, fisher + np * np, 0.0);
  for (int i = 0; i < nc; ++i) {
    const double sigma = (i % 3 == 2) ? noise_z_ut : noise_xy_ut;
    const double w = 1 / (sigma * sigma);
    double row[kInvertSmallMax] = {};
    for (int c = 0; c < k; ++c) row[c] = jac[static_cast<std::size_t>(k * i + c)];
    if (ambient) {
      // d channel / d ambient: the sensor's axis (row of its frame) times its gain.
      const auto& s = sensors[i / 3];
      const int axis = i % 3;
      const double g = axis == 0 ? s.gain.x : axis == 1 ? s.gain.y : s.gain.z;
      row[k] = s.frame.r[axis].x * g;
      row[k + 1] = s.frame.r[axis].y * g;
      row[k + 2] = s.frame.r[axis].z * g;
    }
    for (int a = 0; a < np; ++a) {
      for (int b = 0; b < np; ++b) fisher[a * np + b] += w * row[a] * row[b];
    }
  }
}

}  // namespace

CrlbPoint crlb_at(const PatchModel& model, const Contact& c, double noise_xy_ut, double noise_z_ut,
                  bool ambient) {
  const int nc = model.channel_count();
  const int np = ambient ? 6 : 3;
  std::vector<double> jac(static_cast<std::size_t>(nc) * 3);
  model.contact_jacobian(c, jac);
  double fisher[36];
  fisher_information(model, jac, 3, noise_xy_ut, noise_z_ut, ambient, fisher);
  return point_from_inverse(fisher, np, 0, invert_small(fisher, np));
}

namespace {

// The bound of a sheared contact whose (u, v, depth, F_u, F_v) start at parameter `first` of the
// inverted np x np Fisher matrix `inv` (ok: the inversion succeeded; inv may be null if not):
// unidentifiable, never NaN, when any of its variances is not a variance.
CrlbShear shear_from_inverse(const double* inv, int np, int first, bool ok) {
  CrlbShear s;
  s.contact = point_from_inverse(inv, np, first, ok);
  const double vu = ok ? inv[(first + 3) * np + first + 3] : -1;
  const double vv = ok ? inv[(first + 4) * np + first + 4] : -1;
  if (!ok || !s.contact.identifiable || !(vu >= 0) || !(vv >= 0)) {
    s.contact = point_from_inverse(nullptr, np, first, false);
    s.sd_shear_u_n = s.sd_shear_v_n = s.sd_shear_n = kUnidentifiableN;
    s.identifiable = false;
    return s;
  }
  s.sd_shear_u_n = std::fmin(std::sqrt(vu), kUnidentifiableN);
  s.sd_shear_v_n = std::fmin(std::sqrt(vv), kUnidentifiableN);
  s.sd_shear_n = std::fmin(std::sqrt(vu + vv), kUnidentifiableN);
  s.identifiable = s.sd_shear_n < kUnidentifiableN;
  return s;
}

// The inverted Fisher information (into `fisher`, np x np with the ambient's 3 when `ambient`)
// of the n contacts `cd`, dual numbers over all their K unknowns; whether it inverted.
template <int K>
bool inverse_fisher_of(const PatchModel& model, const ContactT<Dual<K>>* cd, int n,
                       double noise_xy_ut, double noise_z_ut, bool ambient, double* fisher) {
  const int nc = model.channel_count();
  std::vector<Dual<K>> field(static_cast<std::size_t>(nc));
  model.contact_field_ut<Dual<K>>(
      std::span<const ContactT<Dual<K>>>(cd, static_cast<std::size_t>(n)), field.data());
  std::vector<double> jac(static_cast<std::size_t>(nc) * K);
  for (int i = 0; i < nc; ++i) {
    for (int j = 0; j < K; ++j) jac[static_cast<std::size_t>(K * i + j)] = field[i].d[j];
  }
  fisher_information(model, jac, K, noise_xy_ut, noise_z_ut, ambient, fisher);
  return invert_small(fisher, ambient ? K + 3 : K);
}

}  // namespace

CrlbShear crlb_shear_at(const PatchModel& model, const Contact& c, double noise_xy_ut,
                        double noise_z_ut, bool ambient) {
  constexpr int k = 5;
  const int np = ambient ? k + 3 : k;
  const double inputs[] = {c.u_mm,      c.v_mm,      c.depth_mm,  c.tip_radius_mm,
                           c.shear_u_n, c.shear_v_n, noise_xy_ut, noise_z_ut};
  for (double x : inputs) {
    if (!std::isfinite(x)) return shear_from_inverse(nullptr, np, 0, false);
  }
  using D = Dual<k>;
  const ContactT<D> cd{D::variable(c.u_mm, 0),      D::variable(c.v_mm, 1),
                       D::variable(c.depth_mm, 2),  c.tip_radius_mm,
                       D::variable(c.shear_u_n, 3), D::variable(c.shear_v_n, 4)};
  double fisher[kInvertSmallMax * kInvertSmallMax];
  const bool ok = inverse_fisher_of<k>(model, &cd, 1, noise_xy_ut, noise_z_ut, ambient, fisher);
  return shear_from_inverse(fisher, np, 0, ok);
}

CrlbPairShear crlb_pair_shear_at(const PatchModel& model, const Contact& first,
                                 const Contact& second, double noise_xy_ut, double noise_z_ut,
                                 bool ambient) {
  constexpr int k = 10;
  const int np = ambient ? k + 3 : k;
  CrlbPairShear out;
  const double inputs[] = {
      first.u_mm,       first.v_mm,       first.depth_mm, first.tip_radius_mm, first.shear_u_n,
      first.shear_v_n,  second.u_mm,      second.v_mm,    second.depth_mm,     second.tip_radius_mm,
      second.shear_u_n, second.shear_v_n, noise_xy_ut,    noise_z_ut};
  for (double x : inputs) {
    if (!std::isfinite(x)) {
      out.first = out.second = shear_from_inverse(nullptr, np, 0, false);
      return out;
    }
  }
  using D = Dual<k>;
  const ContactT<D> cd[2] = {
      {D::variable(first.u_mm, 0), D::variable(first.v_mm, 1), D::variable(first.depth_mm, 2),
       first.tip_radius_mm, D::variable(first.shear_u_n, 3), D::variable(first.shear_v_n, 4)},
      {D::variable(second.u_mm, 5), D::variable(second.v_mm, 6), D::variable(second.depth_mm, 7),
       second.tip_radius_mm, D::variable(second.shear_u_n, 8), D::variable(second.shear_v_n, 9)}};
  double fisher[kInvertSmallMax * kInvertSmallMax];
  const bool ok = inverse_fisher_of<k>(model, cd, 2, noise_xy_ut, noise_z_ut, ambient, fisher);
  out.first = shear_from_inverse(fisher, np, 0, ok);
  out.second = shear_from_inverse(fisher, np, 5, ok);
  if (!out.first.identifiable || !out.second.identifiable) {  // one is not there: neither is told
    out.first = out.second = shear_from_inverse(nullptr, np, 0, false);
  }
  return out;
}

namespace {

// crlb_contacts_at() for K / 3 contacts (dual numbers over their K unknowns).
template <int K>
void contacts_bound(const PatchModel& model, std::span<const Contact> contacts, double noise_xy_ut,
                    double noise_z_ut, bool ambient, std::span<CrlbPoint> out) {
  constexpr int n = K / 3;
  const int np = ambient ? K + 3 : K;
  using D = Dual<K>;
  ContactT<D> cd[n];
  for (int j = 0; j < n; ++j) {
    const Contact& c = contacts[static_cast<std::size_t>(j)];
    cd[j] = {D::variable(c.u_mm, 3 * j),
             D::variable(c.v_mm, 3 * j + 1),
             D::variable(c.depth_mm, 3 * j + 2),
             c.tip_radius_mm,
             c.shear_u_n,
             c.shear_v_n};
  }
  double fisher[kInvertSmallMax * kInvertSmallMax];
  const bool ok = inverse_fisher_of<K>(model, cd, n, noise_xy_ut, noise_z_ut, ambient, fisher);
  bool all = true;
  for (int j = 0; j < n; ++j) {
    out[static_cast<std::size_t>(j)] = point_from_inverse(fisher, np, 3 * j, ok);
    all = all && out[static_cast<std::size_t>(j)].identifiable;
  }
  if (!all) {  // one is not there: none is told
    for (int j = 0; j < n; ++j) {
      out[static_cast<std::size_t>(j)] = point_from_inverse(nullptr, np, 0, false);
    }
  }
}

}  // namespace

void crlb_contacts_at(const PatchModel& model, std::span<const Contact> contacts,
                      double noise_xy_ut, double noise_z_ut, bool ambient,
                      std::span<CrlbPoint> out) {
  const std::size_t n = contacts.size();
  bool finite = std::isfinite(noise_xy_ut) && std::isfinite(noise_z_ut);
  for (const Contact& c : contacts) {
    for (double x : {c.u_mm, c.v_mm, c.depth_mm, c.tip_radius_mm, c.shear_u_n, c.shear_v_n}) {
      finite = finite && std::isfinite(x);
    }
  }
  if (n < 1 || n > static_cast<std::size_t>(kCrlbMaxContacts) || out.size() < n || !finite) {
    for (CrlbPoint& p : out.first(std::min(n, out.size()))) {
      p = point_from_inverse(nullptr, 0, 0, false);
    }
    return;
  }
  if (n == 1) contacts_bound<3>(model, contacts, noise_xy_ut, noise_z_ut, ambient, out);
  if (n == 2) contacts_bound<6>(model, contacts, noise_xy_ut, noise_z_ut, ambient, out);
  if (n == 3) contacts_bound<9>(model, contacts, noise_xy_ut, noise_z_ut, ambient, out);
}

CrlbPair crlb_pair_at(const PatchModel& model, const Contact& first, const Contact& second,
                      double noise_xy_ut, double noise_z_ut, bool ambient) {
  const Contact both[2] = {first, second};
  CrlbPoint out[2];
  crlb_contacts_at(model, both, noise_xy_ut, noise_z_ut, ambient, out);
  return {out[0], out[1]};
}

}  // namespace skinbus::sim
