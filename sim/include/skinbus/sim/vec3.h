// skinbus/sim/vec3.h: a 3-vector over any scalar type (double or a jet).
#pragma once

#include <cmath>

namespace skinbus::sim {

template <typename T>
struct Vec3 {
  T x{}, y{}, z{};
};

template <typename T>
Vec3<T> operator+(const Vec3<T>& a, const Vec3<T>& b) {
  return {a.x + b.x, a.y + b.y, a.z + b.z};
}
template <typename T>
Vec3<T> operator-(const Vec3<T>& a, const Vec3<T>& b) {
  return {a.x - b.x, a.y - b.y, a.z - b.z};
}
template <typename T, typename S>
Vec3<T> operator*(const Vec3<T>& a, const S& s) {
  return {a.x * s, a.y * s, a.z * s};
}
template <typename T>
T dot(const Vec3<T>& a, const Vec3<T>& b) {
  return a.x * b.x + a.y * b.y + a.z * b.z;
}
template <typename T>
Vec3<T> cross(const Vec3<T>& a, const Vec3<T>& b) {
  return {a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x};
}
template <typename T>
Vec3<T> lift(const Vec3<double>& v) {
  return {T(v.x), T(v.y), T(v.z)};
}

// A rotation as a 3x3 matrix, rows r[0..2]: apply(v) = R v.
struct Mat3 {
  Vec3<double> r[3] = {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
  template <typename T>
  Vec3<T> apply(const Vec3<T>& v) const {
    return {v.x * r[0].x + v.y * r[0].y + v.z * r[0].z, v.x * r[1].x + v.y * r[1].y + v.z * r[1].z,
            v.x * r[2].x + v.y * r[2].y + v.z * r[2].z};
  }
  template <typename T>
  Vec3<T> apply_transposed(const Vec3<T>& v) const {
    return {v.x * r[0].x + v.y * r[1].x + v.z * r[2].x, v.x * r[0].y + v.y * r[1].y + v.z * r[2].y,
            v.x * r[0].z + v.y * r[1].z + v.z * r[2].z};
  }
};

// Rotation by a small-or-large angle vector (axis * angle, radians), Rodrigues' formula.
inline Mat3 rotation_from_vector(const Vec3<double>& w) {
  const double a = std::sqrt(dot(w, w));
  Mat3 m;
  if (a < 1e-15) return m;
  const Vec3<double> k = w * (1.0 / a);
  const double c = std::cos(a), s = std::sin(a), t = 1 - c;
  m.r[0] = {t * k.x * k.x + c, t * k.x * k.y - s * k.z, t * k.x * k.z + s * k.y};
  m.r[1] = {t * k.x * k.y + s * k.z, t * k.y * k.y + c, t * k.y * k.z - s * k.x};
  m.r[2] = {t * k.x * k.z - s * k.y, t * k.y * k.z + s * k.x, t * k.z * k.z + c};
  return m;
}

}  // namespace skinbus::sim
