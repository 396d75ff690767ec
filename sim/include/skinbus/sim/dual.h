// skinbus/sim/dual.h: forward-mode automatic differentiation for the physics templates.
//
// The forward model (skinbus/sim/patch_model.h) is written once as a template on its scalar
// type: double for speed, Dual<N> for exact Jacobians (the Cramer-Rao bound, tests), and any
// jet type with the same arithmetic (a Ceres Jet in the estimators) once ScalarTraits knows
// how to read its value part.
#pragma once

#include <array>
#include <cmath>

namespace skinbus::sim {

template <int N>
struct Dual {
  double v = 0;               // value
  std::array<double, N> d{};  // partial derivatives

  Dual() = default;
  Dual(double value) : v(value) {}  // NOLINT: constants promote implicitly
  static Dual variable(double value, int index) {
    Dual x(value);
    x.d[index] = 1;
    return x;
  }
};

template <int N>
Dual<N> operator+(const Dual<N>& a, const Dual<N>& b) {
  Dual<N> r(a.v + b.v);
  for (int i = 0; i < N; ++i) r.d[i] = a.d[i] + b.d[i];
  return r;
}
template <int N>
Dual<N> operator-(const Dual<N>& a, const Dual<N>& b) {
  Dual<N> r(a.v - b.v);
  for (int i = 0; i < N; ++i) r.d[i] = a.d[i] - b.d[i];
  return r;
}
template <int N>
Dual<N> operator-(const Dual<N>& a) {
  Dual<N> r(-a.v);
  for (int i = 0; i < N; ++i) r.d[i] = -a.d[i];
  return r;
}
template <int N>
Dual<N> operator*(const Dual<N>& a, const Dual<N>& b) {
  Dual<N> r(a.v * b.v);
  for (int i = 0; i < N; ++i) r.d[i] = a.d[i] * b.v + a.v * b.d[i];
  return r;
}
template <int N>
Dual<N> operator/(const Dual<N>& a, const Dual<N>& b) {
  const double inv = 1.0 / b.v;
  Dual<N> r(a.v * inv);
  for (int i = 0; i < N; ++i) r.d[i] = (a.d[i] - r.v * b.d[i]) * inv;
  return r;
}
template <int N>
Dual<N> operator+(const Dual<N>& a, double b) {
  return a + Dual<N>(b);
}
template <int N>
Dual<N> operator+(double a, const Dual<N>& b) {
  return Dual<N>(a) + b;
}
template <int N>
Dual<N> operator-(const Dual<N>& a, double b) {
  return a - Dual<N>(b);
}
template <int N>
Dual<N> operator-(double a, const Dual<N>& b) {
  return Dual<N>(a) - b;
}
template <int N>
Dual<N> operator*(const Dual<N>& a, double b) {
  Dual<N> r(a.v * b);
  for (int i = 0; i < N; ++i) r.d[i] = a.d[i] * b;
  return r;
}
template <int N>
Dual<N> operator*(double a, const Dual<N>& b) {
  return b * a;
}
template <int N>
Dual<N> operator/(const Dual<N>& a, double b) {
  return a * (1.0 / b);
}
template <int N>
Dual<N> operator/(double a, const Dual<N>& b) {
  return Dual<N>(a) / b;
}
template <int N>
Dual<N>& operator+=(Dual<N>& a, const Dual<N>& b) {
  return a = a + b;
}
template <int N>
Dual<N>& operator-=(Dual<N>& a, const Dual<N>& b) {
  return a = a - b;
}
template <int N>
Dual<N>& operator*=(Dual<N>& a, const Dual<N>& b) {
  return a = a * b;
}

template <int N>
Dual<N> sqrt(const Dual<N>& a) {
  const double s = std::sqrt(a.v);
  Dual<N> r(s);
  const double k = s > 0 ? 0.5 / s : 0.0;
  for (int i = 0; i < N; ++i) r.d[i] = a.d[i] * k;
  return r;
}
template <int N>
Dual<N> sin(const Dual<N>& a) {
  Dual<N> r(std::sin(a.v));
  const double c = std::cos(a.v);
  for (int i = 0; i < N; ++i) r.d[i] = a.d[i] * c;
  return r;
}
template <int N>
Dual<N> cos(const Dual<N>& a) {
  Dual<N> r(std::cos(a.v));
  const double s = -std::sin(a.v);
  for (int i = 0; i < N; ++i) r.d[i] = a.d[i] * s;
  return r;
}

// How a scalar type exposes its value part. Specialise for other jet types.
template <typename T>
struct ScalarTraits;
// value(): the value part; zero(): value and every derivative exactly 0 (a term that cannot
// change the result or its derivatives, so the model may skip it).
template <>
struct ScalarTraits<double> {
  static double value(double x) { return x; }
  static bool zero(double x) { return x == 0; }
};
template <int N>
struct ScalarTraits<Dual<N>> {
  static double value(const Dual<N>& x) { return x.v; }
  static bool zero(const Dual<N>& x) {
    for (double d : x.d) {
      if (d != 0) return false;
    }
    return x.v == 0;
  }
};
template <typename T>
double value_of(const T& x) {
  return ScalarTraits<T>::value(x);
}
template <typename T>
bool is_zero(const T& x) {
  return ScalarTraits<T>::zero(x);
}

// f(x) for a function known by its value and slope at value_of(x): exact to first order, so
// tabulated functions carry derivatives through any jet type.
template <typename T>
T first_order(const T& x, double f, double df) {
  return T(f) + (x - T(value_of(x))) * df;
}
inline double first_order(double, double f, double) {
  return f;
}

}  // namespace skinbus::sim
