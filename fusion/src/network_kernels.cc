#include "network_kernels.h"

#include <cpuid.h>
#include <immintrin.h>

#include <cmath>
#include <cstring>
#include <utility>

namespace skinbus::fusion::detail {
namespace {

// ---- portable ----------------------------------------------------------------------------------

template <int R, int V>
void gemm_f32_portable(const float* const* a, const float* const* b, int segments, int k,
                       float* const* c, const float* bias, bool relu) {
  constexpr int kCols = kLanes * V;
  float acc[R][kCols];
  for (int i = 0; i < R; ++i) {
    for (int j = 0; j < kCols; ++j) acc[i][j] = bias != nullptr ? bias[j] : c[i][j];
  }
  for (int seg = 0; seg < segments; ++seg) {
    const float* const* as = a + static_cast<std::ptrdiff_t>(seg) * R;
    for (int kk = 0; kk < k; ++kk) {
      const float* bk = b[seg] + static_cast<std::ptrdiff_t>(kk) * kCols;
      for (int i = 0; i < R; ++i) {
        const float av = as[i][kk];
        for (int j = 0; j < kCols; ++j) acc[i][j] += av * bk[j];
      }
    }
  }
  for (int i = 0; i < R; ++i) {
    for (int j = 0; j < kCols; ++j) c[i][j] = relu && acc[i][j] < 0.0f ? 0.0f : acc[i][j];
  }
}

template <int R, int V>
void gemm_bf16_portable(const uint16_t* const* a, const uint16_t* b, int k_pairs, float* const* c,
                        const float* bias, bool relu) {
  constexpr int kCols = kLanes * V;
  float acc[R][kCols];
  for (int i = 0; i < R; ++i) {
    for (int j = 0; j < kCols; ++j) acc[i][j] = bias != nullptr ? bias[j] : c[i][j];
  }
  for (int kp = 0; kp < k_pairs; ++kp) {
    const uint16_t* bk = b + static_cast<std::ptrdiff_t>(kp) * kCols * 2;
    for (int i = 0; i < R; ++i) {
      const float a0 = from_bf16_bits(a[i][2 * kp]), a1 = from_bf16_bits(a[i][2 * kp + 1]);
      for (int j = 0; j < kCols; ++j) {
        acc[i][j] += a0 * from_bf16_bits(bk[2 * j]) + a1 * from_bf16_bits(bk[2 * j + 1]);
      }
    }
  }
  for (int i = 0; i < R; ++i) {
    for (int j = 0; j < kCols; ++j) c[i][j] = relu && acc[i][j] < 0.0f ? 0.0f : acc[i][j];
  }
}

template <int R, int V>
void gemm_i8_portable(const uint8_t* const* a, const int8_t* b, int k_quads, float* const* c,
                      const float* bias, const float* a_scale, const float* w_scale, bool relu) {
  constexpr int kCols = kLanes * V;
  int32_t acc[R][kCols] = {};
  for (int kq = 0; kq < k_quads; ++kq) {
    const int8_t* bk = b + static_cast<std::ptrdiff_t>(kq) * kCols * 4;
    for (int i = 0; i < R; ++i) {
      const uint8_t* ak = a[i] + 4 * kq;
      for (int j = 0; j < kCols; ++j) {
        int32_t sum = 0;
        for (int e = 0; e < 4; ++e) sum += static_cast<int32_t>(ak[e]) * bk[4 * j + e];
        acc[i][j] += sum;
      }
    }
  }
  for (int i = 0; i < R; ++i) {
    for (int j = 0; j < kCols; ++j) {
      const float y = std::fma(static_cast<float>(acc[i][j]), w_scale[j] * a_scale[i],
                               bias != nullptr ? bias[j] : c[i][j]);
      c[i][j] = relu && y < 0.0f ? 0.0f : y;
    }
  }
}

// The scale of a sample whose largest value is `max_value` (`finite` false when any value is
// not finite), and its inverse for quantising.
float u8_scale(float max_value, bool finite, float* inv) {
  if (!finite) {
    *inv = 0.0f;
    return std::nanf("");
  }
  if (!(max_value > 0.0f)) {
    *inv = 0.0f;
    return 0.0f;
  }
  *inv = 255.0f / max_value;
  return max_value / 255.0f;
}

float quantise_u8_portable(const float* x, int n, uint8_t* out) {
  float mx = 0.0f;
  bool finite = true;
  for (int i = 0; i < n; ++i) {
    finite = finite && std::isfinite(x[i]);
    mx = x[i] > mx ? x[i] : mx;
  }
  float inv = 0.0f;
  const float scale = u8_scale(mx, finite, &inv);
  if (!finite) {  // the row's outputs become NaN through the scale; no NaN is converted
    std::memset(out, 0, static_cast<std::size_t>(n));
    return scale;
  }
  for (int i = 0; i < n; ++i) {
    const float q = std::nearbyint((x[i] > 0.0f ? x[i] : 0.0f) * inv);
    out[i] = static_cast<uint8_t>(q > 255.0f ? 255.0f : q);
  }
  return scale;
}

void to_bf16_portable(const float* in, uint16_t* out, int n, bool relu) {
  for (int i = 0; i < n; ++i) out[i] = to_bf16_bits(relu && in[i] < 0.0f ? 0.0f : in[i]);
}

void relu_portable(float* x, int n) {
  for (int i = 0; i < n; ++i) x[i] = x[i] < 0.0f ? 0.0f : x[i];
}

void pool_portable(const float* x, int cells, int ld, int c, float* out) {
  float* avg = out;
  float* mx = out + c;
  for (int j = 0; j < c; ++j) avg[j] = mx[j] = x[j];
  for (int cell = 1; cell < cells; ++cell) {
    const float* row = x + static_cast<std::ptrdiff_t>(cell) * ld;
    for (int j = 0; j < c; ++j) {
      avg[j] += row[j];
      mx[j] = mx[j] < row[j] ? row[j] : mx[j];
    }
  }
  const float inv = 1.0f / static_cast<float>(cells);
  for (int j = 0; j < c; ++j) avg[j] *= inv;
}

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

void winograd_input_portable(const float* const* d, float* const* v, int c) {
  for (int j = 0; j < c; ++j) {
    float x[16], y[16];
    for (int p = 0; p < 16; ++p) x[p] = d[p][j];
    winograd_input_tile(x, y);
    for (int p = 0; p < 16; ++p) v[p][j] = y[p];
  }
}

void winograd_output_portable(const float* const* m, float* const* y, int c, const float* bias,
                              bool relu) {
  for (int j = 0; j < c; ++j) {
    float x[16], out[4];
    for (int p = 0; p < 16; ++p) x[p] = m[p][j];
    winograd_output_tile(x, out);
    for (int q = 0; q < 4; ++q) {
      const float r = out[q] + bias[j];
      y[q][j] = relu && r < 0.0f ? 0.0f : r;
    }
  }
}

// ---- AVX-512 -----------------------------------------------------------------------------------

// The compiler's max and conversion intrinsics start from an "undefined" vector it then reports
// as (maybe) uninitialised.
#pragma GCC diagnostic push
#if !defined(__clang__)
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
#endif
#pragma GCC diagnostic ignored "-Wuninitialized"

#define SKINBUS_AVX512 __attribute__((target("avx512f,avx512vl,avx512bw,avx512dq,fma")))
#define SKINBUS_AVX512_BF16 \
  __attribute__((target("avx512f,avx512vl,avx512bw,avx512dq,fma,avx512bf16")))
#define SKINBUS_AVX512_VNNI \
  __attribute__((target("avx512f,avx512vl,avx512bw,avx512dq,fma,avx512vnni")))

template <int R, int V>
SKINBUS_AVX512 void gemm_f32_avx512(const float* const* a, const float* const* b, int segments,
                                    int k, float* const* c, const float* bias, bool relu) {
  __m512 acc[R][V];
#pragma GCC unroll 8
  for (int i = 0; i < R; ++i) {
#pragma GCC unroll 4
    for (int v = 0; v < V; ++v) {
      acc[i][v] = _mm512_loadu_ps((bias != nullptr ? bias : c[i]) + kLanes * v);
    }
  }
  for (int seg = 0; seg < segments; ++seg) {
    const float* ap[R];
#pragma GCC unroll 8
    for (int i = 0; i < R; ++i) ap[i] = a[seg * R + i];
    const float* bp = b[seg];
    for (int kk = 0; kk < k; ++kk) {
      __m512 bv[V];
#pragma GCC unroll 4
      for (int v = 0; v < V; ++v) bv[v] = _mm512_loadu_ps(bp + kLanes * v);
      bp += kLanes * V;
#pragma GCC unroll 8
      for (int i = 0; i < R; ++i) {
        const __m512 av = _mm512_set1_ps(ap[i][kk]);
#pragma GCC unroll 4
        for (int v = 0; v < V; ++v) acc[i][v] = _mm512_fmadd_ps(av, bv[v], acc[i][v]);
      }
    }
  }
  const __m512 zero = _mm512_setzero_ps();
#pragma GCC unroll 8
  for (int i = 0; i < R; ++i) {
#pragma GCC unroll 4
    for (int v = 0; v < V; ++v) {
      _mm512_storeu_ps(c[i] + kLanes * v, relu ? _mm512_max_ps(acc[i][v], zero) : acc[i][v]);
    }
  }
}

template <int R, int V>
SKINBUS_AVX512_BF16 void gemm_bf16_avx512(const uint16_t* const* a, const uint16_t* b, int k_pairs,
                                          float* const* c, const float* bias, bool relu) {
  __m512 acc[R][V];
  const uint16_t* ap[R];
#pragma GCC unroll 8
  for (int i = 0; i < R; ++i) {
    ap[i] = a[i];
#pragma GCC unroll 4
    for (int v = 0; v < V; ++v) {
      acc[i][v] = _mm512_loadu_ps((bias != nullptr ? bias : c[i]) + kLanes * v);
    }
  }
  for (int kp = 0; kp < k_pairs; ++kp) {
    __m512bh bv[V];
#pragma GCC unroll 4
    for (int v = 0; v < V; ++v) {
      bv[v] = (__m512bh)(_mm512_loadu_si512(b + 2 * kLanes * v));
    }
    b += 2 * kLanes * V;
#pragma GCC unroll 8
    for (int i = 0; i < R; ++i) {
      int32_t pair;
      std::memcpy(&pair, ap[i] + 2 * kp, sizeof pair);
      const __m512bh av = (__m512bh)(_mm512_set1_epi32(pair));
#pragma GCC unroll 4
      for (int v = 0; v < V; ++v) acc[i][v] = _mm512_dpbf16_ps(acc[i][v], av, bv[v]);
    }
  }
  const __m512 zero = _mm512_setzero_ps();
#pragma GCC unroll 8
  for (int i = 0; i < R; ++i) {
#pragma GCC unroll 4
    for (int v = 0; v < V; ++v) {
      _mm512_storeu_ps(c[i] + kLanes * v, relu ? _mm512_max_ps(acc[i][v], zero) : acc[i][v]);
    }
  }
}

// The int32 sums of an int8 block, stored to `c`. Kept apart from the float epilogue (and out
// of line): with both in one function the compiler shuffles the accumulators through extra
// registers and the stack on every K step, at half the speed.
template <int R, int V>
__attribute__((noinline)) SKINBUS_AVX512_VNNI void sums_i8_avx512(const uint8_t* const* a,
                                                                  const int8_t* b, int k_quads,
                                                                  int32_t (*c)[kLanes * V],
                                                                  bool init) {
  __m512i acc[R][V];
  const uint8_t* ap[R];
#pragma GCC unroll 8
  for (int i = 0; i < R; ++i) {
    ap[i] = a[i];
#pragma GCC unroll 4
    for (int v = 0; v < V; ++v) {
      acc[i][v] = init ? _mm512_setzero_si512() : _mm512_loadu_si512(c[i] + kLanes * v);
    }
  }
  for (int kq = 0; kq < k_quads; ++kq) {
    __m512i bv[V];
#pragma GCC unroll 4
    for (int v = 0; v < V; ++v) bv[v] = _mm512_loadu_si512(b + 4 * kLanes * v);
    b += 4 * kLanes * V;
#pragma GCC unroll 8
    for (int i = 0; i < R; ++i) {
      int32_t quad;
      std::memcpy(&quad, ap[i] + 4 * kq, sizeof quad);
      const __m512i av = _mm512_set1_epi32(quad);
#pragma GCC unroll 4
      for (int v = 0; v < V; ++v) acc[i][v] = _mm512_dpbusd_epi32(acc[i][v], av, bv[v]);
    }
  }
#pragma GCC unroll 8
  for (int i = 0; i < R; ++i) {
#pragma GCC unroll 4
    for (int v = 0; v < V; ++v) _mm512_storeu_si512(c[i] + kLanes * v, acc[i][v]);
  }
}

template <int R, int V>
SKINBUS_AVX512_VNNI void gemm_i8_avx512(const uint8_t* const* a, const int8_t* b, int k_quads,
                                        float* const* c, const float* bias, const float* a_scale,
                                        const float* w_scale, bool relu) {
  alignas(64) int32_t sums[R][kLanes * V];
  sums_i8_avx512<R, V>(a, b, k_quads, sums, true);
  __m512 ws[V];
#pragma GCC unroll 4
  for (int v = 0; v < V; ++v) ws[v] = _mm512_loadu_ps(w_scale + kLanes * v);
  const __m512 zero = _mm512_setzero_ps();
#pragma GCC unroll 8
  for (int i = 0; i < R; ++i) {
    const __m512 as = _mm512_set1_ps(a_scale[i]);
#pragma GCC unroll 4
    for (int v = 0; v < V; ++v) {
      const __m512 start = _mm512_loadu_ps((bias != nullptr ? bias : c[i]) + kLanes * v);
      const __m512 sum = _mm512_cvtepi32_ps(_mm512_load_si512(sums[i] + kLanes * v));
      __m512 y = _mm512_fmadd_ps(sum, _mm512_mul_ps(ws[v], as), start);
      if (relu) y = _mm512_max_ps(y, zero);
      _mm512_storeu_ps(c[i] + kLanes * v, y);
    }
  }
}

SKINBUS_AVX512 float quantise_u8_avx512(const float* x, int n, uint8_t* out) {
  const __m512 zero = _mm512_setzero_ps();
  __m512 mx = zero;
  __mmask16 bad = 0;
  int i = 0;
  for (; i + kLanes <= n; i += kLanes) {
    const __m512 v = _mm512_loadu_ps(x + i);
    // Quiet or signalling NaN, +Inf, -Inf.
    bad = static_cast<__mmask16>(bad | _mm512_fpclass_ps_mask(v, 0x99));
    mx = _mm512_max_ps(mx, v);
  }
  alignas(64) float lanes[kLanes];
  _mm512_store_ps(lanes, mx);
  float m = 0.0f;
  for (const float v : lanes) m = v > m ? v : m;
  bool finite = bad == 0;
  for (int j = i; j < n; ++j) {
    finite = finite && std::isfinite(x[j]);
    m = x[j] > m ? x[j] : m;
  }
  float inv = 0.0f;
  const float scale = u8_scale(m, finite, &inv);
  if (!finite) {  // the row's outputs become NaN through the scale; no NaN is converted
    std::memset(out, 0, static_cast<std::size_t>(n));
    return scale;
  }
  const __m512 vinv = _mm512_set1_ps(inv);
  for (i = 0; i + kLanes <= n; i += kLanes) {
    // Round to nearest even (the default mode), then saturate to 0..255.
    const __m512 v = _mm512_mul_ps(_mm512_max_ps(_mm512_loadu_ps(x + i), zero), vinv);
    _mm_storeu_si128(reinterpret_cast<__m128i*>(out + i),
                     _mm512_cvtusepi32_epi8(_mm512_cvtps_epi32(v)));
  }
  for (; i < n; ++i) {
    const float q = std::nearbyint((x[i] > 0.0f ? x[i] : 0.0f) * inv);
    out[i] = static_cast<uint8_t>(q > 255.0f ? 255.0f : q);
  }
  return scale;
}

SKINBUS_AVX512 void relu_avx512(float* x, int n) {
  const __m512 zero = _mm512_setzero_ps();
  int i = 0;
  for (; i + kLanes <= n; i += kLanes)
    _mm512_storeu_ps(x + i, _mm512_max_ps(_mm512_loadu_ps(x + i), zero));
  relu_portable(x + i, n - i);
}

SKINBUS_AVX512 void pool_avx512(const float* x, int cells, int ld, int c, float* out) {
  const __m512 inv = _mm512_set1_ps(1.0f / static_cast<float>(cells));
  for (int j = 0; j < c; j += kLanes) {
    __m512 sum = _mm512_loadu_ps(x + j), mx = sum;
    for (int cell = 1; cell < cells; ++cell) {
      const __m512 v = _mm512_loadu_ps(x + static_cast<std::ptrdiff_t>(cell) * ld + j);
      sum = _mm512_add_ps(sum, v);
      mx = _mm512_max_ps(mx, v);
    }
    const int left = c - j < kLanes ? c - j : kLanes;
    const __mmask16 m = static_cast<__mmask16>((1u << left) - 1u);
    _mm512_mask_storeu_ps(out + j, m, _mm512_mul_ps(sum, inv));
    _mm512_mask_storeu_ps(out + c + j, m, mx);
  }
}

SKINBUS_AVX512 void winograd_input_avx512(const float* const* d, float* const* v, int c) {
  for (int j = 0; j < c; j += kLanes) {
    __m512 x[16], y[16];
#pragma GCC unroll 16
    for (int p = 0; p < 16; ++p) x[p] = _mm512_loadu_ps(d[p] + j);
    winograd_input_tile(x, y);
#pragma GCC unroll 16
    for (int p = 0; p < 16; ++p) _mm512_storeu_ps(v[p] + j, y[p]);
  }
}

SKINBUS_AVX512 void winograd_output_avx512(const float* const* m, float* const* y, int c,
                                           const float* bias, bool relu) {
  const __m512 zero = _mm512_setzero_ps();
  for (int j = 0; j < c; j += kLanes) {
    __m512 x[16], out[4];
#pragma GCC unroll 16
    for (int p = 0; p < 16; ++p) x[p] = _mm512_loadu_ps(m[p] + j);
    winograd_output_tile(x, out);
    const __m512 b = _mm512_loadu_ps(bias + j);
#pragma GCC unroll 4
    for (int q = 0; q < 4; ++q) {
      const __m512 r = _mm512_add_ps(out[q], b);
      _mm512_storeu_ps(y[q] + j, relu ? _mm512_max_ps(r, zero) : r);
    }
  }
}

SKINBUS_AVX512_BF16 void to_bf16_avx512(const float* in, uint16_t* out, int n, bool relu) {
  const __m512 zero = _mm512_setzero_ps();
  int i = 0;
  for (; i + kLanes <= n; i += kLanes) {
    __m512 x = _mm512_loadu_ps(in + i);
    if (relu) x = _mm512_max_ps(x, zero);
    _mm256_storeu_si256(reinterpret_cast<__m256i*>(out + i), (__m256i)(_mm512_cvtneps_pbh(x)));
  }
  to_bf16_portable(in + i, out + i, n - i, relu);
}

#pragma GCC diagnostic pop

// ---- tables ------------------------------------------------------------------------------------

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

template <int R, int V>
struct F32Portable {
  static GemmF32 get() { return &gemm_f32_portable<R, V>; }
};
template <int R, int V>
struct Bf16Portable {
  static GemmBf16 get() { return &gemm_bf16_portable<R, V>; }
};
template <int R, int V>
struct I8Portable {
  static GemmI8 get() { return &gemm_i8_portable<R, V>; }
};
template <int R, int V>
struct I8Avx512 {
  static GemmI8 get() { return &gemm_i8_avx512<R, V>; }
};
template <int R, int V>
struct F32Avx512 {
  static GemmF32 get() { return &gemm_f32_avx512<R, V>; }
};
template <int R, int V>
struct Bf16Avx512 {
  static GemmBf16 get() { return &gemm_bf16_avx512<R, V>; }
};

using RowSeq = std::make_integer_sequence<int, kMaxRows>;

KernelSet make_portable() {
  KernelSet k;
  k.name = "portable";
  fill<F32Portable>(k.f32, RowSeq{});
  fill<Bf16Portable>(k.bf16, RowSeq{});
  k.to_bf16 = &to_bf16_portable;
  fill<I8Portable>(k.i8, RowSeq{});
  k.quantise_u8 = &quantise_u8_portable;
  k.relu = &relu_portable;
  k.pool = &pool_portable;
  k.winograd_input = &winograd_input_portable;
  k.winograd_output = &winograd_output_portable;
  return k;
}

bool has_avx512() {
  __builtin_cpu_init();
  return __builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512vl") &&
         __builtin_cpu_supports("avx512bw") && __builtin_cpu_supports("avx512dq") &&
         __builtin_cpu_supports("fma");
}

bool has_avx512_bf16() {
  // __builtin_cpu_supports has no name for AVX512_BF16 in every compiler: ask CPUID leaf 7
  // sub-leaf 1, EAX bit 5.
  unsigned eax = 0, ebx = 0, ecx = 0, edx = 0;
  if (__get_cpuid_count(7, 1, &eax, &ebx, &ecx, &edx) == 0) return false;
  return (eax & (1u << 5)) != 0;
}

bool has_avx512_vnni() {
  // CPUID leaf 7 sub-leaf 0, ECX bit 11.
  unsigned eax = 0, ebx = 0, ecx = 0, edx = 0;
  if (__get_cpuid_count(7, 0, &eax, &ebx, &ecx, &edx) == 0) return false;
  return (ecx & (1u << 11)) != 0;
}

}  // namespace

const KernelSet& portable_kernels() {
  static const KernelSet k = make_portable();
  return k;
}

const KernelSet* avx512_kernels() {
  static const KernelSet k = [] {
    KernelSet s;
    if (!has_avx512()) return s;
    s.name = "avx512";
    fill<F32Avx512>(s.f32, RowSeq{});
    s.relu = &relu_avx512;
    s.pool = &pool_avx512;
    s.winograd_input = &winograd_input_avx512;
    s.winograd_output = &winograd_output_avx512;
    if (has_avx512_bf16()) {
      fill<Bf16Avx512>(s.bf16, RowSeq{});
      s.to_bf16 = &to_bf16_avx512;
    }
    if (has_avx512_vnni()) {
      fill<I8Avx512>(s.i8, RowSeq{});
      s.quantise_u8 = &quantise_u8_avx512;
    }
    return s;
  }();
  return k.f32[0][0] != nullptr ? &k : nullptr;
}

}  // namespace skinbus::fusion::detail
