// The AVX-512 kernels (float32: AVX-512F; bfloat16: AVX512_BF16; int8: AVX512_VNNI), compiled
// with target attributes (no -march flags) and chosen at run time.
#if defined(__x86_64__)
#include <cpuid.h>
#include <immintrin.h>

#include <cmath>
#include <cstring>

#include "network_kernels.h"
#include "network_kernels_impl.h"

namespace skinbus::estimators::detail {
namespace {

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
  const float scale = act_scale(m, finite, &inv);
  if (!finite) {  // the row's outputs become NaN through the scale; no NaN is converted
    std::memset(out, 0, static_cast<std::size_t>(n));
    return scale;
  }
  const __m512 vinv = _mm512_set1_ps(inv);
  for (i = 0; i + kLanes <= n; i += kLanes) {
    // Round to nearest even (the default mode), then saturate to 0..255.
    const __m512 v = _mm512_mul_ps(_mm512_max_ps(_mm512_loadu_ps(x + i), zero), vinv);
    const __m512i q = _mm512_min_epi32(_mm512_cvtps_epi32(v), _mm512_set1_epi32(kActMax));
    _mm_storeu_si128(reinterpret_cast<__m128i*>(out + i), _mm512_cvtusepi32_epi8(q));
  }
  for (; i < n; ++i) {
    const float q = std::nearbyint((x[i] > 0.0f ? x[i] : 0.0f) * inv);
    out[i] = static_cast<uint8_t>(q > kActMaxF ? kActMaxF : q);
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
    // Without AVX512_BF16 or AVX512_VNNI (Skylake-SP, ...) those precisions run the AVX2 set's
    // kernels, which every AVX-512 CPU can run.
    const KernelSet* avx2 = avx2_kernels();
    if (has_avx512_bf16()) {
      fill<Bf16Avx512>(s.bf16, RowSeq{});
      s.to_bf16 = &to_bf16_avx512;
    } else if (avx2 != nullptr) {
      std::memcpy(s.bf16, avx2->bf16, sizeof s.bf16);
      s.to_bf16 = avx2->to_bf16;
    }
    if (has_avx512_vnni()) {
      fill<I8Avx512>(s.i8, RowSeq{});
      s.quantise_u8 = &quantise_u8_avx512;
      s.i8_name = "avx512-vnni";
    } else if (avx2 != nullptr) {
      std::memcpy(s.i8, avx2->i8, sizeof s.i8);
      s.quantise_u8 = avx2->quantise_u8;
      s.i8_name = avx2->i8_name;
    }
    return s;
  }();
  return k.f32[0][0] != nullptr ? &k : nullptr;
}

}  // namespace skinbus::estimators::detail
#endif  // __x86_64__
