// The NEON kernels (aarch64: every such CPU has NEON and FMA). int8 runs SDOT (the Armv8.2
// dot-product instructions, compiled with a target attribute, no -march flags) where the CPU has
// them, else widening multiplies; the choice is made at run time from the kernel's HWCAP_ASIMDDP.
//
// A 16-column vector of the packed layout is four q registers here (4 columns each, a "quarter").
// A kernel of R rows x 16V columns runs as passes over column groups of Q quarters, Q chosen so
// that the accumulators (R Q registers; 2 R Q on the widening int8 path) and the operands fit the
// 32 q registers; every pass covers all of K, so each column's float32 sum is formed in the same
// order as the portable kernel's (bias or C, then segment by segment, K in order, with FMA).
#if defined(__aarch64__)
#include <arm_neon.h>
#include <asm/hwcap.h>
#include <sys/auxv.h>

#include <cmath>
#include <cstring>

#include "network_kernels.h"
#include "network_kernels_impl.h"

namespace skinbus::estimators::detail {
namespace {

// The dot-product instructions are an Armv8.2 extension (FEAT_DotProd): every CPU that has them
// implements Armv8.2, and GCC's arm_neon.h declares their intrinsics for that architecture. (The
// aarch64 build is made with GCC, Debian's g++-aarch64-linux-gnu; clang 14's arm_neon.h declares
// them only when the whole file is compiled with +dotprod, which this attribute cannot replace.)
#define SKINBUS_DOTPROD __attribute__((target("arch=armv8.2-a+dotprod")))

constexpr int kQuarter = 4;  // floats (or int32 sums) per q register

// Quarters per pass for R rows, from the register budget `budget(R)`, spread evenly over the
// passes the 4V quarters need (e.g. 16 quarters with a budget of 12: two passes of 8).
template <int kQuarters, int kBudget>
constexpr int balanced_group() {
  constexpr int passes = (kQuarters + kBudget - 1) / kBudget;
  return (kQuarters + passes - 1) / passes;
}
// float32 and the dot-product int8 path: R Q accumulators, R A values, one B quarter
// (R = 1: 16 + 2, 2: 24 + 3, 3: 24 + 4, 4: 24 + 5, 5: 25 + 6, 6: 24 + 7).
template <int R>
constexpr int f32_budget() {
  return R == 1 ? 16 : R == 2 ? 12 : R == 3 ? 8 : R == 4 ? 6 : R == 5 ? 5 : 4;
}
// The widening int8 path: two accumulators per quarter and two product temporaries, rows in
// passes of at most 3 (R = 1: 24 + 4, 2: 24 + 5, 3: 24 + 6).
template <int R>
constexpr int widen_budget() {
  return R == 1 ? 12 : R == 2 ? 6 : 4;
}
// bfloat16: two A values per row and three B temporaries, rows in passes of at most 4
// (R = 1: 16 + 5, 2: 24 + 7, 3: 21 + 9, 4: 20 + 11).
template <int R>
constexpr int bf16_budget() {
  return R == 1 ? 16 : R == 2 ? 12 : R == 3 ? 7 : 5;
}

// max(0, .) exactly as the portable kernels (x < 0 ? 0 : x: -0 and NaN kept).
[[gnu::always_inline]] inline float32x4_t relu_q(float32x4_t x) {
  return vbslq_f32(vcltzq_f32(x), vdupq_n_f32(0.0f), x);
}

// Calls fn.template operator()<Q>(quarter0) for every pass of `kQuarters` quarters in groups of
// at most `kGroup`.
template <int kQuarters, int kGroup, typename Fn>
[[gnu::always_inline]] inline void for_passes(Fn&& fn) {
  constexpr int Q = balanced_group<kQuarters, kGroup>();
  constexpr int kFull = kQuarters / Q, kRest = kQuarters % Q;
#pragma GCC unroll 4
  for (int g = 0; g < kFull; ++g) fn.template operator()<Q>(Q * g);
  if constexpr (kRest > 0) fn.template operator()<kRest>(Q * kFull);
}

// ---- float32 ------------------------------------------------------------------------------------

// R rows x Q quarters starting at column `col` of a panel `ldb` floats wide.
template <int R, int Q>
[[gnu::always_inline]] inline void f32_pass(const float* const* a, const float* const* b,
                                            int segments, int k, float* const* c, const float* bias,
                                            bool relu, int col, int ldb) {
  float32x4_t acc[R][Q];
#pragma GCC unroll 8
  for (int i = 0; i < R; ++i) {
#pragma GCC unroll 16
    for (int q = 0; q < Q; ++q)
      acc[i][q] = vld1q_f32((bias != nullptr ? bias : c[i]) + col + 4 * q);
  }
  for (int seg = 0; seg < segments; ++seg) {
    const float* ap[R];
#pragma GCC unroll 8
    for (int i = 0; i < R; ++i) ap[i] = a[seg * R + i];
    const float* bp = b[seg] + col;
    for (int kk = 0; kk < k; ++kk) {
      float av[R];
#pragma GCC unroll 8
      for (int i = 0; i < R; ++i) av[i] = ap[i][kk];
#pragma GCC unroll 16
      for (int q = 0; q < Q; ++q) {
        const float32x4_t bv = vld1q_f32(bp + kQuarter * q);
#pragma GCC unroll 8
        for (int i = 0; i < R; ++i) acc[i][q] = vfmaq_n_f32(acc[i][q], bv, av[i]);
      }
      bp += ldb;
    }
  }
#pragma GCC unroll 8
  for (int i = 0; i < R; ++i) {
#pragma GCC unroll 16
    for (int q = 0; q < Q; ++q) {
      vst1q_f32(c[i] + col + kQuarter * q, relu ? relu_q(acc[i][q]) : acc[i][q]);
    }
  }
}

template <int R, int V>
void gemm_f32_neon(const float* const* a, const float* const* b, int segments, int k,
                   float* const* c, const float* bias, bool relu) {
  for_passes<4 * V, f32_budget<R>()>([&]<int Q>(int quarter0) {
    f32_pass<R, Q>(a, b, segments, k, c, bias, relu, kQuarter * quarter0, kLanes * V);
  });
}

// ---- int8: exact int32 sums of u8 (0..kActMax) x s8 quads ---------------------------------------

// The dot-product path: SDOT adds the four products of a quad into each int32 lane. Activations
// are at most 127, so they are the same numbers read as signed bytes. Four quads of an A row are
// loaded at once and used lane by lane (SDOT by element); a tail of fewer than four quads
// broadcasts each quad. R rows x Q quarters starting at column `col` of a panel `ldb` bytes per
// quad; sums[i * ldc + col ...] receive them.
template <int L, int R, int Q>
[[gnu::always_inline]] SKINBUS_DOTPROD inline void sdot_lane(int32x4_t (&acc)[R][Q],
                                                             const int8x16_t (&av)[R],
                                                             const int8_t* bp) {
#pragma GCC unroll 16
  for (int q = 0; q < Q; ++q) {
    const int8x16_t bv = vld1q_s8(bp + 16 * q);
#pragma GCC unroll 8
    for (int i = 0; i < R; ++i) acc[i][q] = vdotq_laneq_s32(acc[i][q], bv, av[i], L);
  }
}

template <int R, int Q>
[[gnu::always_inline]] SKINBUS_DOTPROD inline void i8_pass_sdot(const uint8_t* const* a,
                                                                const int8_t* b, int k_quads,
                                                                int32_t* sums, int ldc, int col,
                                                                int ldb) {
  int32x4_t acc[R][Q];
#pragma GCC unroll 8
  for (int i = 0; i < R; ++i) {
#pragma GCC unroll 16
    for (int q = 0; q < Q; ++q) acc[i][q] = vdupq_n_s32(0);
  }
  const int8_t* bp = b + 4 * col;
  int kq = 0;
  for (; kq + 4 <= k_quads; kq += 4) {
    int8x16_t av[R];
#pragma GCC unroll 8
    for (int i = 0; i < R; ++i) av[i] = vreinterpretq_s8_u8(vld1q_u8(a[i] + 4 * kq));
    sdot_lane<0>(acc, av, bp);
    sdot_lane<1>(acc, av, bp + ldb);
    sdot_lane<2>(acc, av, bp + 2 * ldb);
    sdot_lane<3>(acc, av, bp + 3 * ldb);
    bp += 4 * ldb;
  }
  for (; kq < k_quads; ++kq) {
    int8x16_t av[R];
#pragma GCC unroll 8
    for (int i = 0; i < R; ++i) {
      int32_t quad;
      std::memcpy(&quad, a[i] + 4 * kq, sizeof quad);
      av[i] = vreinterpretq_s8_s32(vdupq_n_s32(quad));
    }
    sdot_lane<0>(acc, av, bp);
    bp += ldb;
  }
#pragma GCC unroll 8
  for (int i = 0; i < R; ++i) {
#pragma GCC unroll 16
    for (int q = 0; q < Q; ++q) vst1q_s32(sums + i * ldc + col + kQuarter * q, acc[i][q]);
  }
}

// The widening path (any Armv8-A): SMULL multiplies two columns' quads by the broadcast A quad
// into eight 16-bit products (exact: |a b| <= 127 x 127), SADALP adds adjacent pairs into int32
// lanes (column c's two half sums in lanes 2c and 2c + 1 of a pair of registers), and ADDP joins
// the halves at the end.
template <int R, int Q>
[[gnu::always_inline]] inline void i8_pass_widen(const uint8_t* const* a, const int8_t* b,
                                                 int k_quads, int32_t* sums, int ldc, int col,
                                                 int ldb) {
  int32x4_t lo[R][Q], hi[R][Q];
#pragma GCC unroll 8
  for (int i = 0; i < R; ++i) {
#pragma GCC unroll 16
    for (int q = 0; q < Q; ++q) lo[i][q] = hi[i][q] = vdupq_n_s32(0);
  }
  const int8_t* bp = b + 4 * col;
  for (int kq = 0; kq < k_quads; ++kq) {
    int8x16_t av[R];
#pragma GCC unroll 8
    for (int i = 0; i < R; ++i) {
      int32_t quad;
      std::memcpy(&quad, a[i] + 4 * kq, sizeof quad);
      av[i] = vreinterpretq_s8_s32(vdupq_n_s32(quad));
    }
#pragma GCC unroll 16
    for (int q = 0; q < Q; ++q) {
      const int8x16_t bv = vld1q_s8(bp + 16 * q);
#pragma GCC unroll 8
      for (int i = 0; i < R; ++i) {
        lo[i][q] = vpadalq_s16(lo[i][q], vmull_s8(vget_low_s8(bv), vget_low_s8(av[i])));
        hi[i][q] = vpadalq_s16(hi[i][q], vmull_high_s8(bv, av[i]));
      }
    }
    bp += ldb;
  }
#pragma GCC unroll 8
  for (int i = 0; i < R; ++i) {
#pragma GCC unroll 16
    for (int q = 0; q < Q; ++q) {
      vst1q_s32(sums + i * ldc + col + kQuarter * q, vpaddq_s32(lo[i][q], hi[i][q]));
    }
  }
}

// The int32 sums of R rows x 16V columns into sums[R][16V]. Kept out of line, apart from the
// float epilogue, as the x86 sets do (the accumulators stay in registers across K).
template <int R, int V>
[[gnu::noinline]] SKINBUS_DOTPROD void sums_i8_sdot(const uint8_t* const* a, const int8_t* b,
                                                    int k_quads, int32_t* sums) {
  for_passes<4 * V, f32_budget<R>()>([&]<int Q>(int quarter0) SKINBUS_DOTPROD {
    i8_pass_sdot<R, Q>(a, b, k_quads, sums, kLanes * V, kQuarter * quarter0, 4 * kLanes * V);
  });
}

template <int R, int V>
[[gnu::always_inline]] inline void i8_rows_widen(const uint8_t* const* a, const int8_t* b,
                                                 int k_quads, int32_t* sums) {
  for_passes<4 * V, widen_budget<R>()>([&]<int Q>(int quarter0) {
    i8_pass_widen<R, Q>(a, b, k_quads, sums, kLanes * V, kQuarter * quarter0, 4 * kLanes * V);
  });
}

template <int R, int V>
[[gnu::noinline]] void sums_i8_widen(const uint8_t* const* a, const int8_t* b, int k_quads,
                                     int32_t* sums) {
  constexpr int kFirst = R > 3 ? 3 : R;
  i8_rows_widen<kFirst, V>(a, b, k_quads, sums);
  if constexpr (R > kFirst) {
    i8_rows_widen<R - kFirst, V>(a + kFirst, b, k_quads, sums + kFirst * kLanes * V);
  }
}

// The portable kernels' epilogue: y = fma(sum, w_scale * a_scale, start), then ReLU.
template <int R, int V, bool kDot>
void gemm_i8_neon(const uint8_t* const* a, const int8_t* b, int k_quads, float* const* c,
                  const float* bias, const float* a_scale, const float* w_scale, bool relu) {
  constexpr int kCols = kLanes * V;
  alignas(16) int32_t sums[R * kCols];
  if constexpr (kDot) {
    sums_i8_sdot<R, V>(a, b, k_quads, sums);
  } else {
    sums_i8_widen<R, V>(a, b, k_quads, sums);
  }
#pragma GCC unroll 8
  for (int i = 0; i < R; ++i) {
    const float32x4_t as = vdupq_n_f32(a_scale[i]);
#pragma GCC unroll 16
    for (int q = 0; q < 4 * V; ++q) {
      const float32x4_t start = vld1q_f32((bias != nullptr ? bias : c[i]) + kQuarter * q);
      const float32x4_t sum = vcvtq_f32_s32(vld1q_s32(sums + i * kCols + kQuarter * q));
      const float32x4_t ws = vld1q_f32(w_scale + kQuarter * q);
      const float32x4_t y = vfmaq_f32(start, sum, vmulq_f32(ws, as));
      vst1q_f32(c[i] + kQuarter * q, relu ? relu_q(y) : y);
    }
  }
}

// ---- bfloat16: pairs widened to float32, summed with FMA ----------------------------------------

template <int R, int Q>
[[gnu::always_inline]] inline void bf16_pass(const uint16_t* const* a, const uint16_t* b,
                                             int k_pairs, float* const* c, const float* bias,
                                             bool relu, int col, int ldb) {
  float32x4_t acc[R][Q];
#pragma GCC unroll 8
  for (int i = 0; i < R; ++i) {
#pragma GCC unroll 16
    for (int q = 0; q < Q; ++q)
      acc[i][q] = vld1q_f32((bias != nullptr ? bias : c[i]) + col + 4 * q);
  }
  const uint32x4_t high = vdupq_n_u32(0xffff0000u);
  const uint16_t* bp = b + 2 * col;
  for (int kp = 0; kp < k_pairs; ++kp) {
    float a0[R], a1[R];
#pragma GCC unroll 8
    for (int i = 0; i < R; ++i) {
      a0[i] = from_bf16_bits(a[i][2 * kp]);
      a1[i] = from_bf16_bits(a[i][2 * kp + 1]);
    }
#pragma GCC unroll 16
    for (int q = 0; q < Q; ++q) {
      // 4 columns' (even, odd) pairs: the even element is the low half of each 32-bit lane.
      const uint32x4_t x = vreinterpretq_u32_u16(vld1q_u16(bp + 2 * kQuarter * q));
      const float32x4_t even = vreinterpretq_f32_u32(vshlq_n_u32(x, 16));
      const float32x4_t odd = vreinterpretq_f32_u32(vandq_u32(x, high));
#pragma GCC unroll 8
      for (int i = 0; i < R; ++i) {
        acc[i][q] = vfmaq_n_f32(acc[i][q], even, a0[i]);
        acc[i][q] = vfmaq_n_f32(acc[i][q], odd, a1[i]);
      }
    }
    bp += ldb;
  }
#pragma GCC unroll 8
  for (int i = 0; i < R; ++i) {
#pragma GCC unroll 16
    for (int q = 0; q < Q; ++q) {
      vst1q_f32(c[i] + col + kQuarter * q, relu ? relu_q(acc[i][q]) : acc[i][q]);
    }
  }
}

template <int R, int V>
[[gnu::always_inline]] inline void bf16_rows(const uint16_t* const* a, const uint16_t* b,
                                             int k_pairs, float* const* c, const float* bias,
                                             bool relu) {
  for_passes<4 * V, bf16_budget<R>()>([&]<int Q>(int quarter0) {
    bf16_pass<R, Q>(a, b, k_pairs, c, bias, relu, kQuarter * quarter0, 2 * kLanes * V);
  });
}

template <int R, int V>
void gemm_bf16_neon(const uint16_t* const* a, const uint16_t* b, int k_pairs, float* const* c,
                    const float* bias, bool relu) {
  constexpr int kFirst = R > 4 ? 3 : R;
  bf16_rows<kFirst, V>(a, b, k_pairs, c, bias, relu);
  if constexpr (R > kFirst) {
    bf16_rows<R - kFirst, V>(a + kFirst, b, k_pairs, c + kFirst, bias, relu);
  }
}

// ---- element-wise -------------------------------------------------------------------------------

float quantise_u8_neon(const float* x, int n, uint8_t* out) {
  const float32x4_t zero = vdupq_n_f32(0.0f);
  float32x4_t mx = zero;
  uint32x4_t all_finite = vdupq_n_u32(~0u);
  int i = 0;
  for (; i + kQuarter <= n; i += kQuarter) {
    const float32x4_t v = vld1q_f32(x + i);
    // x - x is 0 only for finite x.
    all_finite = vandq_u32(all_finite, vceqzq_f32(vsubq_f32(v, v)));
    mx = vmaxq_f32(mx, v);
  }
  float m = vmaxvq_f32(mx);
  bool finite = vminvq_u32(all_finite) != 0;
  for (int j = i; j < n; ++j) {
    finite = finite && std::isfinite(x[j]);
    m = x[j] > m ? x[j] : m;
  }
  float inv = 0.0f;
  const float scale = act_scale(m, finite, &inv);
  if (!finite) {  // the row's outputs become NaN through the scale; no NaN is converted
    std::memset(out, 0, static_cast<std::size_t>(n));
    return scale;
  }
  const float32x4_t vinv = vdupq_n_f32(inv);
  const uint32x4_t top = vdupq_n_u32(kActMax);
  for (i = 0; i + 2 * kQuarter <= n; i += 2 * kQuarter) {
    // Round to nearest even (FCVTNU), then saturate to 0..kActMax.
    const uint32x4_t q0 =
        vminq_u32(vcvtnq_u32_f32(vmulq_f32(vmaxq_f32(vld1q_f32(x + i), zero), vinv)), top);
    const uint32x4_t q1 = vminq_u32(
        vcvtnq_u32_f32(vmulq_f32(vmaxq_f32(vld1q_f32(x + i + kQuarter), zero), vinv)), top);
    vst1_u8(out + i, vmovn_u16(vcombine_u16(vmovn_u32(q0), vmovn_u32(q1))));
  }
  for (; i < n; ++i) {
    const float q = std::nearbyint((x[i] > 0.0f ? x[i] : 0.0f) * inv);
    out[i] = static_cast<uint8_t>(q > kActMaxF ? kActMaxF : q);
  }
  return scale;
}

void to_bf16_neon(const float* in, uint16_t* out, int n, bool relu) {
  const uint32x4_t one = vdupq_n_u32(1), bias = vdupq_n_u32(0x7fff);
  int i = 0;
  for (; i + 2 * kQuarter <= n; i += 2 * kQuarter) {
    uint16x4_t half[2];
#pragma GCC unroll 2
    for (int h = 0; h < 2; ++h) {
      float32x4_t x = vld1q_f32(in + i + kQuarter * h);
      if (relu) x = relu_q(x);
      // Round to nearest even, as to_bf16_bits: u + 0x7fff + ((u >> 16) & 1), then the top half.
      const uint32x4_t u = vreinterpretq_u32_f32(x);
      const uint32x4_t lsb = vandq_u32(vshrq_n_u32(u, 16), one);
      half[h] = vshrn_n_u32(vaddq_u32(u, vaddq_u32(bias, lsb)), 16);
    }
    vst1q_u16(out + i, vcombine_u16(half[0], half[1]));
  }
  to_bf16_portable(in + i, out + i, n - i, relu);
}

void relu_neon(float* x, int n) {
  int i = 0;
  for (; i + kQuarter <= n; i += kQuarter) vst1q_f32(x + i, relu_q(vld1q_f32(x + i)));
  relu_portable(x + i, n - i);
}

void pool_neon(const float* x, int cells, int ld, int c, float* out) {
  const float inv = 1.0f / static_cast<float>(cells);
  int j = 0;
  for (; j + kQuarter <= c; j += kQuarter) {
    float32x4_t sum = vld1q_f32(x + j), mx = sum;
    for (int cell = 1; cell < cells; ++cell) {
      const float32x4_t v = vld1q_f32(x + static_cast<std::ptrdiff_t>(cell) * ld + j);
      sum = vaddq_f32(sum, v);
      mx = vbslq_f32(vcltq_f32(mx, v), v, mx);  // the portable kernel's mx < v ? v : mx
    }
    vst1q_f32(out + j, vmulq_n_f32(sum, inv));
    vst1q_f32(out + c + j, mx);
  }
  // The last c % 4 channels as the portable kernel does them.
  for (; j < c; ++j) {
    float sum = x[j], mx = sum;
    for (int cell = 1; cell < cells; ++cell) {
      const float v = x[static_cast<std::ptrdiff_t>(cell) * ld + j];
      sum += v;
      mx = mx < v ? v : mx;
    }
    out[j] = sum * inv;
    out[c + j] = mx;
  }
}

void winograd_input_neon(const float* const* d, float* const* v, int c) {
  for (int j = 0; j < c; j += kQuarter) {
    float32x4_t x[16], y[16];
#pragma GCC unroll 16
    for (int p = 0; p < 16; ++p) x[p] = vld1q_f32(d[p] + j);
    winograd_input_tile(x, y);
#pragma GCC unroll 16
    for (int p = 0; p < 16; ++p) vst1q_f32(v[p] + j, y[p]);
  }
}

void winograd_output_neon(const float* const* m, float* const* y, int c, const float* bias,
                          bool relu) {
  for (int j = 0; j < c; j += kQuarter) {
    float32x4_t x[16], out[4];
#pragma GCC unroll 16
    for (int p = 0; p < 16; ++p) x[p] = vld1q_f32(m[p] + j);
    winograd_output_tile(x, out);
    const float32x4_t b = vld1q_f32(bias + j);
#pragma GCC unroll 4
    for (int q = 0; q < 4; ++q) {
      const float32x4_t r = vaddq_f32(out[q], b);
      vst1q_f32(y[q] + j, relu ? relu_q(r) : r);
    }
  }
}

template <int R, int V>
struct F32Neon {
  static GemmF32 get() { return &gemm_f32_neon<R, V>; }
};
template <int R, int V>
struct Bf16Neon {
  static GemmBf16 get() { return &gemm_bf16_neon<R, V>; }
};
template <int R, int V>
struct I8NeonDot {
  static GemmI8 get() { return &gemm_i8_neon<R, V, true>; }
};
template <int R, int V>
struct I8NeonWiden {
  static GemmI8 get() { return &gemm_i8_neon<R, V, false>; }
};

bool has_dotprod() {
  return (getauxval(AT_HWCAP) & HWCAP_ASIMDDP) != 0;
}

// The set with the dot-product int8 kernels (`dot`) or the widening ones.
KernelSet make_neon(bool dot) {
  KernelSet s;
  s.name = "neon";
  fill<F32Neon>(s.f32, RowSeq{});
  fill<Bf16Neon>(s.bf16, RowSeq{});
  if (dot) {
    fill<I8NeonDot>(s.i8, RowSeq{});
    s.i8_name = "neon-dotprod";
  } else {
    fill<I8NeonWiden>(s.i8, RowSeq{});
    s.i8_name = "neon";
  }
  s.quantise_u8 = &quantise_u8_neon;
  s.to_bf16 = &to_bf16_neon;
  s.relu = &relu_neon;
  s.pool = &pool_neon;
  s.winograd_input = &winograd_input_neon;
  s.winograd_output = &winograd_output_neon;
  return s;
}

}  // namespace

const KernelSet* neon_kernels() {
  static const KernelSet k = make_neon(has_dotprod());
  return &k;
}

const KernelSet* neon_widening_kernels() {
  if (!has_dotprod()) return neon_kernels();
  static const KernelSet k = make_neon(false);
  return &k;
}

}  // namespace skinbus::estimators::detail
#endif  // __aarch64__
