#include "skinbus/sim/crlb.h"

#include <cmath>
#include <vector>

namespace skinbus::sim {

bool invert_small(double* a, int n) {
  double inv[64] = {};
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

CrlbPoint crlb_at(const PatchModel& model, const Contact& c, double noise_xy_ut, double noise_z_ut,
                  bool ambient) {
  const int nc = model.channel_count();
  const int np = ambient ? 6 : 3;
  std::vector<double> jac(static_cast<std::size_t>(nc) * 3);
  model.contact_jacobian(c, jac);
  double fisher[36] = {};
  const auto& sensors = model.sensors();
  for (int i = 0; i < nc; ++i) {
    const double sigma = (i % 3 == 2) ? noise_z_ut : noise_xy_ut;
    const double w = 1 / (sigma * sigma);
    double row[6] = {jac[3 * i], jac[3 * i + 1], jac[3 * i + 2], 0, 0, 0};
    if (ambient) {
      // d channel / d ambient: the sensor's axis (row of its frame) times its gain.
      const auto& s = sensors[i / 3];
      const int axis = i % 3;
      const double g = axis == 0 ? s.gain.x : axis == 1 ? s.gain.y : s.gain.z;
      row[3] = s.frame.r[axis].x * g;
      row[4] = s.frame.r[axis].y * g;
      row[5] = s.frame.r[axis].z * g;
    }
    for (int a = 0; a < np; ++a) {
      for (int b = 0; b < np; ++b) fisher[a * np + b] += w * row[a] * row[b];
    }
  }
  CrlbPoint p;
  if (!invert_small(fisher, np) || !(fisher[0] >= 0) || !(fisher[np + 1] >= 0) ||
      !(fisher[2 * np + 2] >= 0)) {
    p.identifiable = false;
    p.sd_u_mm = p.sd_v_mm = p.sd_xy_mm = p.sd_depth_mm = kUnidentifiableMm;
    return p;
  }
  p.sd_u_mm = std::fmin(std::sqrt(fisher[0]), kUnidentifiableMm);
  p.sd_v_mm = std::fmin(std::sqrt(fisher[np + 1]), kUnidentifiableMm);
  p.sd_xy_mm = std::fmin(std::sqrt(fisher[0] + fisher[np + 1]), kUnidentifiableMm);
  p.sd_depth_mm = std::fmin(std::sqrt(fisher[2 * np + 2]), kUnidentifiableMm);
  p.identifiable = p.sd_xy_mm < kUnidentifiableMm && p.sd_depth_mm < kUnidentifiableMm;
  return p;
}

}  // namespace skinbus::sim
