// The portable kernels (plain C++, any CPU) and the choice of the kernels for this CPU.
#include <cstdlib>
#include <cstring>
#include <string_view>

#include "network_kernels.h"
#include "network_kernels_impl.h"

namespace skinbus::estimators::detail {
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

}  // namespace

float quantise_u8_portable(const float* x, int n, uint8_t* out) {
  float mx = 0.0f;
  bool finite = true;
  for (int i = 0; i < n; ++i) {
    finite = finite && std::isfinite(x[i]);
    mx = x[i] > mx ? x[i] : mx;
  }
  float inv = 0.0f;
  const float scale = act_scale(mx, finite, &inv);
  if (!finite) {  // the row's outputs become NaN through the scale; no NaN is converted
    std::memset(out, 0, static_cast<std::size_t>(n));
    return scale;
  }
  for (int i = 0; i < n; ++i) {
    const float q = std::nearbyint((x[i] > 0.0f ? x[i] : 0.0f) * inv);
    out[i] = static_cast<uint8_t>(q > kActMaxF ? kActMaxF : q);
  }
  return scale;
}

namespace {}  // namespace

void to_bf16_portable(const float* in, uint16_t* out, int n, bool relu) {
  for (int i = 0; i < n; ++i) out[i] = to_bf16_bits(relu && in[i] < 0.0f ? 0.0f : in[i]);
}

namespace {}  // namespace

void relu_portable(float* x, int n) {
  for (int i = 0; i < n; ++i) x[i] = x[i] < 0.0f ? 0.0f : x[i];
}

namespace {

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

// ---- tables ------------------------------------------------------------------------------------

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

KernelSet make_portable() {
  KernelSet k;
  k.name = "portable";
  fill<F32Portable>(k.f32, RowSeq{});
  fill<Bf16Portable>(k.bf16, RowSeq{});
  k.to_bf16 = &to_bf16_portable;
  fill<I8Portable>(k.i8, RowSeq{});
  k.i8_name = "portable";
  k.quantise_u8 = &quantise_u8_portable;
  k.relu = &relu_portable;
  k.pool = &pool_portable;
  k.winograd_input = &winograd_input_portable;
  k.winograd_output = &winograd_output_portable;
  return k;
}

}  // namespace

const KernelSet& portable_kernels() {
  static const KernelSet k = make_portable();
  return k;
}

#if !defined(__x86_64__)
const KernelSet* avx512_kernels() {
  return nullptr;
}
const KernelSet* avx2_kernels() {
  return nullptr;
}
const KernelSet* avx2_dot_product_kernels() {
  return nullptr;
}
#endif
#if !defined(__aarch64__)
const KernelSet* neon_kernels() {
  return nullptr;
}
const KernelSet* neon_widening_kernels() {
  return nullptr;
}
#endif

const KernelSet* kernels_for(KernelIsa isa) {
  switch (isa) {
    case KernelIsa::kAvx512:
      return avx512_kernels();
    case KernelIsa::kAvx2:
      return avx2_kernels();
    case KernelIsa::kNeon:
      return neon_kernels();
    case KernelIsa::kPortable:
      return &portable_kernels();
  }
  return nullptr;
}

const KernelSet& best_kernels(KernelIsa cap) {
  // From the widest down; neon and the x86 sets never both exist.
  for (KernelIsa isa : {KernelIsa::kAvx512, KernelIsa::kAvx2, KernelIsa::kNeon}) {
    if (!isa_allowed(isa, cap)) continue;
    if (const KernelSet* k = kernels_for(isa)) return *k;
  }
  return portable_kernels();
}

}  // namespace skinbus::estimators::detail
