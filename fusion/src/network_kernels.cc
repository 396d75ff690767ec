#include "network_kernels.h"

#include <cpuid.h>
#include <immintrin.h>

#include <cstring>
#include <utility>

namespace skinbus::fusion::detail {
namespace {

// ---- portable ----------------------------------------------------------------------------------

template <int R, int V>
void gemm_f32_portable(const float* const* a, const float* b, int k, float* const* c,
                       const float* bias, bool relu) {
  constexpr int kCols = kLanes * V;
  float acc[R][kCols];
  for (int i = 0; i < R; ++i) {
    for (int j = 0; j < kCols; ++j) acc[i][j] = bias != nullptr ? bias[j] : c[i][j];
  }
  for (int kk = 0; kk < k; ++kk) {
    const float* bk = b + static_cast<std::ptrdiff_t>(kk) * kCols;
    for (int i = 0; i < R; ++i) {
      const float av = a[i][kk];
      for (int j = 0; j < kCols; ++j) acc[i][j] += av * bk[j];
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

// ---- AVX-512 -----------------------------------------------------------------------------------

// The compiler's max intrinsic starts from an "undefined" vector it then reports as maybe
// uninitialised.
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"

#define SKINBUS_AVX512 __attribute__((target("avx512f,avx512vl,avx512bw,avx512dq,fma")))
#define SKINBUS_AVX512_BF16 \
  __attribute__((target("avx512f,avx512vl,avx512bw,avx512dq,fma,avx512bf16")))

template <int R, int V>
SKINBUS_AVX512 void gemm_f32_avx512(const float* const* a, const float* b, int k, float* const* c,
                                    const float* bias, bool relu) {
  __m512 acc[R][V];
  const float* ap[R];
#pragma GCC unroll 8
  for (int i = 0; i < R; ++i) {
    ap[i] = a[i];
#pragma GCC unroll 4
    for (int v = 0; v < V; ++v) {
      acc[i][v] = _mm512_loadu_ps((bias != nullptr ? bias : c[i]) + kLanes * v);
    }
  }
  for (int kk = 0; kk < k; ++kk) {
    __m512 bv[V];
#pragma GCC unroll 4
    for (int v = 0; v < V; ++v) bv[v] = _mm512_loadu_ps(b + kLanes * v);
    b += kLanes * V;
#pragma GCC unroll 8
    for (int i = 0; i < R; ++i) {
      const __m512 av = _mm512_set1_ps(ap[i][kk]);
#pragma GCC unroll 4
      for (int v = 0; v < V; ++v) acc[i][v] = _mm512_fmadd_ps(av, bv[v], acc[i][v]);
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
  k.relu = &relu_portable;
  k.pool = &pool_portable;
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
    if (has_avx512_bf16()) {
      fill<Bf16Avx512>(s.bf16, RowSeq{});
      s.to_bf16 = &to_bf16_avx512;
    }
    return s;
  }();
  return k.f32[0][0] != nullptr ? &k : nullptr;
}

}  // namespace skinbus::fusion::detail
