// The AVX2 + FMA kernels (x86-64-v3: most robot computers' x86 CPUs), compiled with target
// attributes (no -march flags) and chosen at run time.
//
// A 16-column vector of the packed layout is two ymm registers here. A kernel of R rows x 16V
// columns runs as passes over column groups of W vectors, W chosen so that the accumulators
// (2 R W registers) and the operands fit the 16 ymm registers; every pass covers all of K, so
// each column's sum is formed in the same order as the AVX-512 kernels' (bit-identical float32).
#if defined(__x86_64__)
#include <cpuid.h>
#include <immintrin.h>

#include <cmath>
#include <cstring>

#include "network_kernels.h"
#include "network_kernels_impl.h"

namespace skinbus::estimators::detail {
namespace {

// The compiler's conversion intrinsics start from an "undefined" vector it then reports as
// (maybe) uninitialised.
#pragma GCC diagnostic push
#if !defined(__clang__)
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
#endif
#pragma GCC diagnostic ignored "-Wuninitialized"

#define SKINBUS_AVX2 __attribute__((target("avx2,fma")))
#define SKINBUS_AVX2_VNNI __attribute__((target("avx2,fma,avxvnni")))
// The same ymm dot product in its EVEX form (AVX512_VNNI + VL): what tests run on AVX-512 CPUs
// without AVX-VNNI, so that the dot-product variant of these kernels is checked there too.
#define SKINBUS_AVX2_VNNI_EVEX __attribute__((target("avx2,fma,avx512f,avx512vl,avx512vnni")))

constexpr int kHalf = 8;  // floats per ymm
// K steps ahead that a float32 pass prefetches its weights (measured: 4 and 16 slower than 8).
constexpr int kPrefetchSteps = 8;

// ymm columns (8 floats) per float32 pass for R rows: 2 R H accumulators plus the operands in
// the 16 ymm registers, at least 8 accumulators to cover the FMA latency where the rows allow:
// R = 1: 8 (+ A, B), 2: 6 x 2 = 12 (+ 2 A, B), 3: 4 x 3 = 12 (+ 3 A, B), 4: 3 x 4 = 12 (+ 3 B,
// A), 5: 2 x 5 = 10, 6: 2 x 6 = 12 (+ 2 B, A).
template <int R>
constexpr int f32_ymm_group() {
  return R == 1 ? 8 : R == 2 ? 6 : R == 3 ? 4 : R == 4 ? 3 : 2;
}
// int8 and bfloat16 need more temporaries per product: fewer columns, and rows beyond 4 split
// into a second pass (see row_split).
template <int R>
constexpr int narrow_group() {
  return R == 1 ? 4 : R == 2 ? 2 : 1;
}
constexpr int min_int(int a, int b) {
  return a < b ? a : b;
}

// R rows x H ymm columns starting at column `col` of a panel `ldb` floats wide. From 4 rows the
// B vectors of a K step stay in registers and each row's A value is broadcast once; below, the
// R A values stay and each B vector is loaded once.
template <int R, int H>
[[gnu::always_inline]] SKINBUS_AVX2 inline void f32_pass(const float* const* a,
                                                         const float* const* b, int segments, int k,
                                                         float* const* c, const float* bias,
                                                         bool relu, int col, int ldb) {
  __m256 acc[R][H];
#pragma GCC unroll 8
  for (int i = 0; i < R; ++i) {
#pragma GCC unroll 8
    for (int h = 0; h < H; ++h) {
      acc[i][h] = _mm256_loadu_ps((bias != nullptr ? bias : c[i]) + col + kHalf * h);
    }
  }
  for (int seg = 0; seg < segments; ++seg) {
    const float* ap[R];
#pragma GCC unroll 8
    for (int i = 0; i < R; ++i) ap[i] = a[seg * R + i];
    const float* bp = b[seg] + col;
    for (int kk = 0; kk < k; ++kk) {
      // The weights of a K step kPrefetchSteps ahead, both cache lines of this pass's columns:
      // at batch 1 they stream from L3, and the passes read a row's columns in stripes.
      _mm_prefetch(reinterpret_cast<const char*>(bp + kPrefetchSteps * ldb), _MM_HINT_T0);
      _mm_prefetch(reinterpret_cast<const char*>(bp + kPrefetchSteps * ldb + kHalf * H - 1),
                   _MM_HINT_T0);
      if constexpr (R >= 4) {
        __m256 bv[H];
#pragma GCC unroll 8
        for (int h = 0; h < H; ++h) bv[h] = _mm256_loadu_ps(bp + kHalf * h);
#pragma GCC unroll 8
        for (int i = 0; i < R; ++i) {
          const __m256 av = _mm256_broadcast_ss(ap[i] + kk);
#pragma GCC unroll 8
          for (int h = 0; h < H; ++h) acc[i][h] = _mm256_fmadd_ps(av, bv[h], acc[i][h]);
        }
      } else {
        __m256 av[R];
#pragma GCC unroll 8
        for (int i = 0; i < R; ++i) av[i] = _mm256_broadcast_ss(ap[i] + kk);
#pragma GCC unroll 8
        for (int h = 0; h < H; ++h) {
          const __m256 bv = _mm256_loadu_ps(bp + kHalf * h);
#pragma GCC unroll 8
          for (int i = 0; i < R; ++i) acc[i][h] = _mm256_fmadd_ps(av[i], bv, acc[i][h]);
        }
      }
      bp += ldb;
    }
  }
  const __m256 zero = _mm256_setzero_ps();
#pragma GCC unroll 8
  for (int i = 0; i < R; ++i) {
#pragma GCC unroll 8
    for (int h = 0; h < H; ++h) {
      _mm256_storeu_ps(c[i] + col + kHalf * h, relu ? _mm256_max_ps(acc[i][h], zero) : acc[i][h]);
    }
  }
}

template <int R, int V>
SKINBUS_AVX2 void gemm_f32_avx2(const float* const* a, const float* const* b, int segments, int k,
                                float* const* c, const float* bias, bool relu) {
  constexpr int kYmm = 2 * V;
  constexpr int H = min_int(kYmm, f32_ymm_group<R>());
  constexpr int kFull = kYmm / H, kRest = kYmm % H;
#pragma GCC unroll 8
  for (int g = 0; g < kFull; ++g) {
    f32_pass<R, H>(a, b, segments, k, c, bias, relu, kHalf * H * g, kLanes * V);
  }
  if constexpr (kRest > 0) {
    f32_pass<R, kRest>(a, b, segments, k, c, bias, relu, kHalf * H * kFull, kLanes * V);
  }
}

// ---- int8: exact int32 sums of u8 (0..kActMax) x s8 quads ---------------------------------------

// R rows x W vectors of int32 sums, starting at column `col` of a panel `ldb` bytes per K quad;
// sums[i * ldc + col ...] receive them. vpmaddubsw forms each pair's sum in 16 bits (exact:
// activations are at most 127), vpmaddwd by ones adds the two pairs of a quad in 32 bits.
#define SKINBUS_I8_PASS(ATTR, NAME, STEP)                                                       \
  template <int R, int W>                                                                       \
  [[gnu::always_inline]] ATTR inline void NAME(const uint8_t* const* a, const int8_t* b,        \
                                               int k_quads, int32_t* sums, int ldc, int col,    \
                                               int ldb) {                                       \
    constexpr int H = 2 * W;                                                                    \
    __m256i acc[R][H];                                                                          \
    _Pragma("GCC unroll 8") for (int i = 0; i < R; ++i) {                                       \
      _Pragma("GCC unroll 8") for (int h = 0; h < H; ++h) acc[i][h] = _mm256_setzero_si256();   \
    }                                                                                           \
    [[maybe_unused]] const __m256i ones = _mm256_set1_epi16(1);                                 \
    const int8_t* bp = b + 4 * col;                                                             \
    for (int kq = 0; kq < k_quads; ++kq) {                                                      \
      if constexpr (W == 1) {                                                                   \
        const __m256i b0 = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(bp));            \
        const __m256i b1 = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(bp + 32));       \
        _Pragma("GCC unroll 8") for (int i = 0; i < R; ++i) {                                   \
          int32_t quad;                                                                         \
          std::memcpy(&quad, a[i] + 4 * kq, sizeof quad);                                       \
          const __m256i av = _mm256_set1_epi32(quad);                                           \
          acc[i][0] = STEP(acc[i][0], av, b0);                                                  \
          acc[i][1] = STEP(acc[i][1], av, b1);                                                  \
        }                                                                                       \
      } else {                                                                                  \
        __m256i av[R];                                                                          \
        _Pragma("GCC unroll 8") for (int i = 0; i < R; ++i) {                                   \
          int32_t quad;                                                                         \
          std::memcpy(&quad, a[i] + 4 * kq, sizeof quad);                                       \
          av[i] = _mm256_set1_epi32(quad);                                                      \
        }                                                                                       \
        _Pragma("GCC unroll 8") for (int h = 0; h < H; ++h) {                                   \
          const __m256i bv = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(bp + 32 * h)); \
          _Pragma("GCC unroll 8") for (int i = 0; i < R; ++i) acc[i][h] =                       \
              STEP(acc[i][h], av[i], bv);                                                       \
        }                                                                                       \
      }                                                                                         \
      bp += ldb;                                                                                \
    }                                                                                           \
    _Pragma("GCC unroll 8") for (int i = 0; i < R; ++i) {                                       \
      _Pragma("GCC unroll 8") for (int h = 0; h < H; ++h) {                                     \
        _mm256_storeu_si256(reinterpret_cast<__m256i*>(sums + i * ldc + col + kHalf * h),       \
                            acc[i][h]);                                                         \
      }                                                                                         \
    }                                                                                           \
  }                                                                                             \
  /* R rows x 16V columns as passes over column groups of narrow_group<R>() vectors. */         \
  template <int R, int V>                                                                       \
  [[gnu::always_inline]] ATTR inline void NAME##_rows(const uint8_t* const* a, const int8_t* b, \
                                                      int k_quads, int32_t* sums) {             \
    constexpr int W = min_int(V, narrow_group<R>());                                            \
    constexpr int kFull = V / W, kRest = V % W;                                                 \
    _Pragma("GCC unroll 4") for (int g = 0; g < kFull; ++g) {                                   \
      NAME<R, W>(a, b, k_quads, sums, kLanes * V, kLanes * W * g, 4 * kLanes * V);              \
    }                                                                                           \
    if constexpr (kRest > 0) {                                                                  \
      NAME<R, kRest>(a, b, k_quads, sums, kLanes * V, kLanes * W * kFull, 4 * kLanes * V);      \
    }                                                                                           \
  }

#define SKINBUS_MADD_STEP(acc, av, bv) \
  _mm256_add_epi32(acc, _mm256_madd_epi16(_mm256_maddubs_epi16(av, bv), ones))
#define SKINBUS_VNNI_STEP(acc, av, bv) _mm256_dpbusd_avx_epi32(acc, av, bv)
#define SKINBUS_VNNI_EVEX_STEP(acc, av, bv) _mm256_dpbusd_epi32(acc, av, bv)
SKINBUS_I8_PASS(SKINBUS_AVX2, i8_pass_madd, SKINBUS_MADD_STEP)
SKINBUS_I8_PASS(SKINBUS_AVX2_VNNI, i8_pass_vnni, SKINBUS_VNNI_STEP)
SKINBUS_I8_PASS(SKINBUS_AVX2_VNNI_EVEX, i8_pass_vnni_evex, SKINBUS_VNNI_EVEX_STEP)
#undef SKINBUS_MADD_STEP
#undef SKINBUS_VNNI_STEP
#undef SKINBUS_VNNI_EVEX_STEP
#undef SKINBUS_I8_PASS

// The int32 sums of R rows x 16V columns into sums[R][16V]. The multiply-add form needs two
// temporaries per product: rows beyond 4 run in a second pass.
template <int R, int V>
[[gnu::noinline]] SKINBUS_AVX2 void sums_i8_madd(const uint8_t* const* a, const int8_t* b,
                                                 int k_quads, int32_t* sums) {
  constexpr int kFirst = R > 4 ? 3 : R;
  i8_pass_madd_rows<kFirst, V>(a, b, k_quads, sums);
  if constexpr (R > kFirst) {
    i8_pass_madd_rows<R - kFirst, V>(a + kFirst, b, k_quads, sums + kFirst * kLanes * V);
  }
}
template <int R, int V>
[[gnu::noinline]] SKINBUS_AVX2_VNNI void sums_i8_vnni(const uint8_t* const* a, const int8_t* b,
                                                      int k_quads, int32_t* sums) {
  i8_pass_vnni_rows<R, V>(a, b, k_quads, sums);
}

template <int R, int V>
[[gnu::noinline]] SKINBUS_AVX2_VNNI_EVEX void sums_i8_vnni_evex(const uint8_t* const* a,
                                                                const int8_t* b, int k_quads,
                                                                int32_t* sums) {
  i8_pass_vnni_evex_rows<R, V>(a, b, k_quads, sums);
}

// kDot: 0 vpmaddubsw + vpmaddwd, 1 AVX-VNNI, 2 the EVEX form of the same dot product.
template <int R, int V, int kDot>
SKINBUS_AVX2 void gemm_i8_avx2(const uint8_t* const* a, const int8_t* b, int k_quads,
                               float* const* c, const float* bias, const float* a_scale,
                               const float* w_scale, bool relu) {
  constexpr int kCols = kLanes * V;
  alignas(32) int32_t sums[R * kCols];
  if constexpr (kDot == 1) {
    sums_i8_vnni<R, V>(a, b, k_quads, sums);
  } else if constexpr (kDot == 2) {
    sums_i8_vnni_evex<R, V>(a, b, k_quads, sums);
  } else {
    sums_i8_madd<R, V>(a, b, k_quads, sums);
  }
  const __m256 zero = _mm256_setzero_ps();
#pragma GCC unroll 8
  for (int i = 0; i < R; ++i) {
    const __m256 as = _mm256_set1_ps(a_scale[i]);
#pragma GCC unroll 8
    for (int h = 0; h < 2 * V; ++h) {
      const __m256 start = _mm256_loadu_ps((bias != nullptr ? bias : c[i]) + kHalf * h);
      const __m256 sum = _mm256_cvtepi32_ps(
          _mm256_load_si256(reinterpret_cast<const __m256i*>(sums + i * kCols + kHalf * h)));
      const __m256 ws = _mm256_loadu_ps(w_scale + kHalf * h);
      __m256 y = _mm256_fmadd_ps(sum, _mm256_mul_ps(ws, as), start);
      if (relu) y = _mm256_max_ps(y, zero);
      _mm256_storeu_ps(c[i] + kHalf * h, y);
    }
  }
}

// ---- bfloat16: pairs widened to float32, summed with FMA ----------------------------------------

template <int R, int W>
[[gnu::always_inline]] SKINBUS_AVX2 inline void bf16_pass(const uint16_t* const* a,
                                                          const uint16_t* b, int k_pairs,
                                                          float* const* c, const float* bias,
                                                          bool relu, int col, int ldb) {
  constexpr int H = 2 * W;
  __m256 acc[R][H];
#pragma GCC unroll 8
  for (int i = 0; i < R; ++i) {
#pragma GCC unroll 8
    for (int h = 0; h < H; ++h) {
      acc[i][h] = _mm256_loadu_ps((bias != nullptr ? bias : c[i]) + col + kHalf * h);
    }
  }
  const __m256i high = _mm256_set1_epi32(static_cast<int>(0xffff0000u));
  const uint16_t* bp = b + 2 * col;
  for (int kp = 0; kp < k_pairs; ++kp) {
    float a0[R], a1[R];
#pragma GCC unroll 8
    for (int i = 0; i < R; ++i) {
      a0[i] = from_bf16_bits(a[i][2 * kp]);
      a1[i] = from_bf16_bits(a[i][2 * kp + 1]);
    }
#pragma GCC unroll 8
    for (int h = 0; h < H; ++h) {
      // 8 columns' (even, odd) pairs: the even element is the low half of each 32-bit lane.
      const __m256i x = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(bp + 2 * kHalf * h));
      const __m256 even = _mm256_castsi256_ps(_mm256_slli_epi32(x, 16));
      const __m256 odd = _mm256_castsi256_ps(_mm256_and_si256(x, high));
#pragma GCC unroll 8
      for (int i = 0; i < R; ++i) {
        acc[i][h] = _mm256_fmadd_ps(_mm256_set1_ps(a0[i]), even, acc[i][h]);
        acc[i][h] = _mm256_fmadd_ps(_mm256_set1_ps(a1[i]), odd, acc[i][h]);
      }
    }
    bp += ldb;
  }
  const __m256 zero = _mm256_setzero_ps();
#pragma GCC unroll 8
  for (int i = 0; i < R; ++i) {
#pragma GCC unroll 8
    for (int h = 0; h < H; ++h) {
      _mm256_storeu_ps(c[i] + col + kHalf * h, relu ? _mm256_max_ps(acc[i][h], zero) : acc[i][h]);
    }
  }
}

template <int R, int V>
[[gnu::always_inline]] SKINBUS_AVX2 inline void bf16_rows(const uint16_t* const* a,
                                                          const uint16_t* b, int k_pairs,
                                                          float* const* c, const float* bias,
                                                          bool relu) {
  constexpr int W = min_int(V, narrow_group<R>());
  constexpr int kFull = V / W, kRest = V % W;
#pragma GCC unroll 4
  for (int g = 0; g < kFull; ++g) {
    bf16_pass<R, W>(a, b, k_pairs, c, bias, relu, kLanes * W * g, 2 * kLanes * V);
  }
  if constexpr (kRest > 0) {
    bf16_pass<R, kRest>(a, b, k_pairs, c, bias, relu, kLanes * W * kFull, 2 * kLanes * V);
  }
}

template <int R, int V>
SKINBUS_AVX2 void gemm_bf16_avx2(const uint16_t* const* a, const uint16_t* b, int k_pairs,
                                 float* const* c, const float* bias, bool relu) {
  constexpr int kFirst = R > 4 ? 3 : R;
  bf16_rows<kFirst, V>(a, b, k_pairs, c, bias, relu);
  if constexpr (R > kFirst)
    bf16_rows<R - kFirst, V>(a + kFirst, b, k_pairs, c + kFirst, bias, relu);
}

// ---- element-wise -------------------------------------------------------------------------------

// Lanes of x that are finite: all ones (x - x is 0 only for finite x).
SKINBUS_AVX2 inline __m256 finite_mask(__m256 x) {
  return _mm256_cmp_ps(_mm256_sub_ps(x, x), _mm256_setzero_ps(), _CMP_EQ_OQ);
}

SKINBUS_AVX2 float quantise_u8_avx2(const float* x, int n, uint8_t* out) {
  const __m256 zero = _mm256_setzero_ps();
  __m256 mx = zero;
  __m256 all_finite = _mm256_castsi256_ps(_mm256_set1_epi32(-1));
  int i = 0;
  for (; i + kHalf <= n; i += kHalf) {
    const __m256 v = _mm256_loadu_ps(x + i);
    all_finite = _mm256_and_ps(all_finite, finite_mask(v));
    mx = _mm256_max_ps(mx, v);
  }
  alignas(32) float lanes[kHalf];
  _mm256_store_ps(lanes, mx);
  float m = 0.0f;
  for (const float v : lanes) m = v > m ? v : m;
  bool finite = _mm256_movemask_ps(all_finite) == 0xff;
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
  const __m256 vinv = _mm256_set1_ps(inv);
  const __m256i top = _mm256_set1_epi32(kActMax);
  for (i = 0; i + kHalf <= n; i += kHalf) {
    // Round to nearest even (the default mode), then saturate to 0..kActMax.
    const __m256 v = _mm256_mul_ps(_mm256_max_ps(_mm256_loadu_ps(x + i), zero), vinv);
    const __m256i q = _mm256_min_epi32(_mm256_cvtps_epi32(v), top);
    const __m128i w = _mm_packus_epi32(_mm256_castsi256_si128(q), _mm256_extracti128_si256(q, 1));
    _mm_storel_epi64(reinterpret_cast<__m128i*>(out + i), _mm_packus_epi16(w, w));
  }
  for (; i < n; ++i) {
    const float q = std::nearbyint((x[i] > 0.0f ? x[i] : 0.0f) * inv);
    out[i] = static_cast<uint8_t>(q > kActMaxF ? kActMaxF : q);
  }
  return scale;
}

SKINBUS_AVX2 void to_bf16_avx2(const float* in, uint16_t* out, int n, bool relu) {
  const __m256 zero = _mm256_setzero_ps();
  const __m256i one = _mm256_set1_epi32(1), bias = _mm256_set1_epi32(0x7fff);
  int i = 0;
  for (; i + kHalf <= n; i += kHalf) {
    __m256 x = _mm256_loadu_ps(in + i);
    if (relu) x = _mm256_max_ps(x, zero);
    // Round to nearest even, as to_bf16_bits: u + 0x7fff + ((u >> 16) & 1), then the top half.
    const __m256i u = _mm256_castps_si256(x);
    const __m256i lsb = _mm256_and_si256(_mm256_srli_epi32(u, 16), one);
    const __m256i r = _mm256_srli_epi32(_mm256_add_epi32(u, _mm256_add_epi32(bias, lsb)), 16);
    const __m128i w = _mm_packus_epi32(_mm256_castsi256_si128(r), _mm256_extracti128_si256(r, 1));
    _mm_storeu_si128(reinterpret_cast<__m128i*>(out + i), w);
  }
  to_bf16_portable(in + i, out + i, n - i, relu);
}

SKINBUS_AVX2 void relu_avx2(float* x, int n) {
  const __m256 zero = _mm256_setzero_ps();
  int i = 0;
  for (; i + kHalf <= n; i += kHalf)
    _mm256_storeu_ps(x + i, _mm256_max_ps(_mm256_loadu_ps(x + i), zero));
  relu_portable(x + i, n - i);
}

SKINBUS_AVX2 void pool_avx2(const float* x, int cells, int ld, int c, float* out) {
  const __m256 inv = _mm256_set1_ps(1.0f / static_cast<float>(cells));
  for (int j = 0; j < c; j += kHalf) {
    __m256 sum = _mm256_loadu_ps(x + j), mx = sum;
    for (int cell = 1; cell < cells; ++cell) {
      const __m256 v = _mm256_loadu_ps(x + static_cast<std::ptrdiff_t>(cell) * ld + j);
      sum = _mm256_add_ps(sum, v);
      mx = _mm256_max_ps(mx, v);
    }
    const int left = c - j < kHalf ? c - j : kHalf;
    // Lanes below `left` stored (their mask's sign bit set).
    const __m256i lane = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
    const __m256i m = _mm256_cmpgt_epi32(_mm256_set1_epi32(left), lane);
    _mm256_maskstore_ps(out + j, m, _mm256_mul_ps(sum, inv));
    _mm256_maskstore_ps(out + c + j, m, mx);
  }
}

SKINBUS_AVX2 void winograd_input_avx2(const float* const* d, float* const* v, int c) {
  for (int j = 0; j < c; j += kHalf) {
    __m256 x[16], y[16];
#pragma GCC unroll 16
    for (int p = 0; p < 16; ++p) x[p] = _mm256_loadu_ps(d[p] + j);
    winograd_input_tile(x, y);
#pragma GCC unroll 16
    for (int p = 0; p < 16; ++p) _mm256_storeu_ps(v[p] + j, y[p]);
  }
}

SKINBUS_AVX2 void winograd_output_avx2(const float* const* m, float* const* y, int c,
                                       const float* bias, bool relu) {
  const __m256 zero = _mm256_setzero_ps();
  for (int j = 0; j < c; j += kHalf) {
    __m256 x[16], out[4];
#pragma GCC unroll 16
    for (int p = 0; p < 16; ++p) x[p] = _mm256_loadu_ps(m[p] + j);
    winograd_output_tile(x, out);
    const __m256 b = _mm256_loadu_ps(bias + j);
#pragma GCC unroll 4
    for (int q = 0; q < 4; ++q) {
      const __m256 r = _mm256_add_ps(out[q], b);
      _mm256_storeu_ps(y[q] + j, relu ? _mm256_max_ps(r, zero) : r);
    }
  }
}

#pragma GCC diagnostic pop

template <int R, int V>
struct F32Avx2 {
  static GemmF32 get() { return &gemm_f32_avx2<R, V>; }
};
template <int R, int V>
struct Bf16Avx2 {
  static GemmBf16 get() { return &gemm_bf16_avx2<R, V>; }
};
template <int R, int V>
struct I8Avx2 {
  static GemmI8 get() { return &gemm_i8_avx2<R, V, 0>; }
};
template <int R, int V>
struct I8AvxVnni {
  static GemmI8 get() { return &gemm_i8_avx2<R, V, 1>; }
};
template <int R, int V>
struct I8AvxVnniEvex {
  static GemmI8 get() { return &gemm_i8_avx2<R, V, 2>; }
};

bool has_avx2() {
  __builtin_cpu_init();
  return __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma");
}

bool has_avx512_vnni_vl() {
  __builtin_cpu_init();
  return __builtin_cpu_supports("avx512vnni") && __builtin_cpu_supports("avx512vl");
}

bool has_avx_vnni() {
  // CPUID leaf 7 sub-leaf 1, EAX bit 4.
  unsigned eax = 0, ebx = 0, ecx = 0, edx = 0;
  if (__get_cpuid_count(7, 1, &eax, &ebx, &ecx, &edx) == 0) return false;
  return (eax & (1u << 4)) != 0;
}

}  // namespace

const KernelSet* avx2_kernels() {
  static const KernelSet k = [] {
    KernelSet s;
    if (!has_avx2()) return s;
    s.name = "avx2";
    fill<F32Avx2>(s.f32, RowSeq{});
    fill<Bf16Avx2>(s.bf16, RowSeq{});
    if (has_avx_vnni()) {
      fill<I8AvxVnni>(s.i8, RowSeq{});
      s.i8_name = "avx-vnni";
    } else {
      fill<I8Avx2>(s.i8, RowSeq{});
      s.i8_name = "avx2";
    }
    s.quantise_u8 = &quantise_u8_avx2;
    s.to_bf16 = &to_bf16_avx2;
    s.relu = &relu_avx2;
    s.pool = &pool_avx2;
    s.winograd_input = &winograd_input_avx2;
    s.winograd_output = &winograd_output_avx2;
    return s;
  }();
  return k.f32[0][0] != nullptr ? &k : nullptr;
}

const KernelSet* avx2_dot_product_kernels() {
  static const KernelSet k = [] {
    KernelSet s;
    const KernelSet* base = avx2_kernels();
    if (base == nullptr) return s;
    if (has_avx_vnni()) {
      s = *base;  // avx2_kernels() runs the VEX form already
    } else if (has_avx512_vnni_vl()) {
      s = *base;
      fill<I8AvxVnniEvex>(s.i8, RowSeq{});
      s.i8_name = "avx512-vnni ymm";
    }
    s.name = "avx2 (dot product)";
    return s;
  }();
  return k.f32[0][0] != nullptr ? &k : nullptr;
}

}  // namespace skinbus::estimators::detail
#endif  // __x86_64__
