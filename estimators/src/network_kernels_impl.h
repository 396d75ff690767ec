// network_kernels_impl.h (internal to the kernel files): what the portable kernels and every
// instruction set's kernels share: the Winograd transforms on any element type, the int8
// activation scale, the table filler, and the portable tails the vector kernels finish with.
#pragma once

#include <cmath>
#include <utility>

#include "network_kernels.h"

namespace skinbus::estimators::detail {

// The scale of a sample whose largest value is `max_value` (`finite` false when any value is
// not finite), and its inverse for quantising to 0..kActMax.
inline float act_scale(float max_value, bool finite, float* inv) {
  if (!finite) {
    *inv = 0.0f;
    return std::nanf("");
  }
  if (!(max_value > 0.0f)) {
    *inv = 0.0f;
    return 0.0f;
  }
  *inv = static_cast<float>(kActMax) / max_value;
  return max_value / static_cast<float>(kActMax);
}

// Portable kernels the vector kernels use for the tail of a row.
float quantise_u8_portable(const float* x, int n, uint8_t* out);
void to_bf16_portable(const float* in, uint16_t* out, int n, bool relu);
void relu_portable(float* x, int n);

// The Winograd F(2x2, 3x3) transforms on any element type with + and - (a float, or a vector of
// 16 floats): the 1-D steps, then the 2-D ones as a 1-D step over the columns and over the rows.
template <typename T>
[[gnu::always_inline]] inline void winograd_bt(const T& x0, const T& x1, const T& x2, const T& x3,
                                               T* out, int stride) {
  out[0] = x0 - x2;
  out[stride] = x1 + x2;
  out[2 * stride] = x2 - x1;
  out[3 * stride] = x1 - x3;
}

// in: 4x4 row-major tile d; out: B^T d B, row-major.
template <typename T>
[[gnu::always_inline]] inline void winograd_input_tile(const T (&d)[16], T (&v)[16]) {
  T t[16];  // B^T d
  for (int col = 0; col < 4; ++col)
    winograd_bt(d[col], d[4 + col], d[8 + col], d[12 + col], t + col, 4);
  for (int row = 0; row < 4; ++row) {
    const T* r = t + 4 * row;
    winograd_bt(r[0], r[1], r[2], r[3], v + 4 * row, 1);
  }
}

// in: 4x4 row-major products m; out: A^T m A, 2x2 row-major.
template <typename T>
[[gnu::always_inline]] inline void winograd_output_tile(const T (&m)[16], T (&y)[4]) {
  T t[8];  // A^T m, 2x4
  for (int col = 0; col < 4; ++col) {
    t[col] = m[col] + m[4 + col] + m[8 + col];
    t[4 + col] = m[4 + col] - m[8 + col] - m[12 + col];
  }
  for (int row = 0; row < 2; ++row) {
    const T* r = t + 4 * row;
    y[2 * row] = r[0] + r[1] + r[2];
    y[2 * row + 1] = r[1] - r[2] - r[3];
  }
}

// Fills a [kMaxRows][kMaxVectors] kernel table from Fn<R, V>::get().
template <template <int, int> class Fn, typename T, int... Rs>
void fill(T (&table)[kMaxRows][kMaxVectors], std::integer_sequence<int, Rs...>) {
  auto row = [&]<int R>() {
    table[R - 1][0] = Fn<R, 1>::get();
    table[R - 1][1] = Fn<R, 2>::get();
    table[R - 1][2] = Fn<R, 3>::get();
    table[R - 1][3] = Fn<R, 4>::get();
  };
  (row.template operator()<Rs + 1>(), ...);
}
using RowSeq = std::make_integer_sequence<int, kMaxRows>;

}  // namespace skinbus::estimators::detail
