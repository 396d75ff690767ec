// network_kernels.h (internal): the register-blocked matrix kernels of the network runtime.
//
// Every layer is a sum of small matrix products C[rows, cols] (+)= A[rows, K] * B[K, cols]:
// a fully connected layer is one, a 3x3 convolution one per in-bounds tap (rows are the output
// cells whose neighbour at that tap lies inside the grid, A rows are those neighbours; or, for a
// float32 batch, rows are the samples' same cell and one call sums all of its taps). A kernel
// computes R rows (1..kMaxRows, each row given by its own pointer, so taps and samples gather
// freely) by 16 * V columns (V = 1..kMaxVectors) of a packed panel of B:
//   float32:  panel[k][16 * V]              (K rows of 16 * V floats)
//   bfloat16: panel[k / 2][16 * V][2]       (pairs of K, the vdpbf16ps layout; K padded to even
//                                            with zeros, A rows likewise zero at the pad)
//   int8:     panel[k / 4][16 * V][4]       (quads of K, the vpdpbusd layout: A rows unsigned
//                                            8-bit in 0..kActMax, B signed 8-bit in -127..127, K
//                                            padded to a multiple of 4 with zeros)
// The float32 kernels sum `segments` such products into the same accumulators, in order:
// segment s multiplies the R rows a[s * R .. s * R + R) by the panel b[s] (one call covers every
// in-bounds tap of a group of output rows, so the accumulators never leave the registers between
// taps); the other kernels take one A and one panel.
// The accumulators start from `bias` (16 * V floats) when it is not null, else from C; the
// result is stored to C, through max(0, .) when `relu`. The int8 kernels sum exact int32 products
// over their K and add sum * a_scale[row] * w_scale[column] to that float start.
#pragma once

#include <cstdint>

#include "skinbus/common/isa.h"

namespace skinbus::estimators::detail {

inline constexpr int kMaxRows = 6;
inline constexpr int kMaxVectors = 4;
inline constexpr int kLanes = 16;  // floats per column vector
// int8 activations are quantised to 0..kActMax: 7 bits, so that every instruction set computes
// the same exact int32 sums: a pair of products (AVX2 vpmaddubsw's 16-bit intermediate) stays
// within 2 x 127 x 127 = 32258 < 32767, and NEON's signed dot product takes them as they are.
inline constexpr int kActMax = 127;
inline constexpr float kActMaxF = 127.0f;

using GemmF32 = void (*)(const float* const* a, const float* const* b, int segments, int k,
                         float* const* c, const float* bias, bool relu);
using GemmBf16 = void (*)(const uint16_t* const* a, const uint16_t* b, int k_pairs, float* const* c,
                          const float* bias, bool relu);
using GemmI8 = void (*)(const uint8_t* const* a, const int8_t* b, int k_quads, float* const* c,
                        const float* bias, const float* a_scale, const float* w_scale, bool relu);
// Quantises `n` floats (one activation row, >= 0 after ReLU; negatives clamp to 0) to 0..kActMax:
// out = round(x / scale) with scale = max(x) / kActMax. Returns the scale: 0 when every value is
// 0, NaN when any value is not finite (so the sample's outputs become NaN).
using QuantiseU8 = float (*)(const float* x, int n, uint8_t* out);
// Rounds `n` floats to bfloat16 (round to nearest even), applying max(0, .) first when `relu`.
using ToBf16 = void (*)(const float* in, uint16_t* out, int n, bool relu);
// max(0, .) over `n` floats in place.
using ReluF32 = void (*)(float* x, int n);
// Winograd F(2x2, 3x3) transforms, over `c` channels (a multiple of 16) of one tile:
// input:  d[16] rows, the 4x4 input cells of the tile in row-major order (cells outside the grid
//         point at zeros) -> v[16] rows, B^T d B, position p = 4 * row + col.
// output: m[16] rows, the tile's products at the 16 positions -> y[4] rows, the 2x2 output cells
//         A^T m A + bias (row-major; cells outside the grid point at scratch), through max(0, .)
//         when `relu`.
// B^T = [1 0 -1 0; 0 1 1 0; 0 -1 1 0; 0 1 0 -1], A^T = [1 1 1 0; 0 1 -1 -1]: additions only.
using WinogradInput = void (*)(const float* const* d, float* const* v, int c);
using WinogradOutput = void (*)(const float* const* m, float* const* y, int c, const float* bias,
                                bool relu);
// Global average and max over `cells` rows of `ld` floats (`c` <= ld used): out[0, c) the
// averages, out[c, 2c) the maxima.
using PoolF32 = void (*)(const float* x, int cells, int ld, int c, float* out);

struct KernelSet {
  const char* name = "";
  GemmF32 f32[kMaxRows][kMaxVectors] = {};
  GemmBf16 bf16[kMaxRows][kMaxVectors] = {};  // null where the set has no bfloat16 kernels
  GemmI8 i8[kMaxRows][kMaxVectors] = {};      // null where the set has no int8 kernels
  const char* i8_name = "";                   // the int8 instructions, e.g. "avx512-vnni"
  QuantiseU8 quantise_u8 = nullptr;
  ToBf16 to_bf16 = nullptr;
  ReluF32 relu = nullptr;
  PoolF32 pool = nullptr;
  WinogradInput winograd_input = nullptr;
  WinogradOutput winograd_output = nullptr;
};

// The instruction sets the kernels are written for, widest first (skinbus/common/isa.h).
using KernelIsa = Isa;

// Plain C++ kernels for any CPU (bf16 entries emulate vdpbf16ps exactly enough for tests; int8
// entries compute the same integer sums as every vector set).
const KernelSet& portable_kernels();
// AVX-512 kernels when the CPU has AVX-512F/VL/BW/DQ and FMA, else null. bfloat16 runs vdpbf16ps
// with AVX512_BF16, int8 vpdpbusd with AVX512_VNNI; without them those entries are the AVX2
// set's.
const KernelSet* avx512_kernels();
// AVX2 + FMA kernels (x86-64-v3) when the CPU has them, else null. float32 in 8-float halves of
// each 16-column vector (a tile of R rows x 16V columns runs as column groups that fit the 16
// ymm registers); int8 as vpmaddubsw + vpmaddwd, or vpdpbusd (AVX-VNNI) where present; bfloat16
// widened to float32 and summed with FMA.
const KernelSet* avx2_kernels();
// The AVX2 set with its int8 entries in the ymm dot-product form: AVX-VNNI (as avx2_kernels()
// runs it) where the CPU has it, else the same kernels in the EVEX form on AVX512_VNNI + VL CPUs;
// null elsewhere. For tests: it checks the dot-product variant on CPUs without AVX-VNNI.
const KernelSet* avx2_dot_product_kernels();
// NEON kernels on aarch64, else null. float32 with FMA in column groups that fit the 32 q
// registers; int8 with SDOT (the dot-product instructions, HWCAP_ASIMDDP) where the CPU has them,
// else widening multiplies (SMULL + SADALP); bfloat16 widened to float32 and summed with FMA.
const KernelSet* neon_kernels();
// The NEON set with its int8 entries on the widening path even where the CPU has the dot-product
// instructions (so that tests check both int8 paths on one CPU); null off aarch64.
const KernelSet* neon_widening_kernels();
// The set for `isa`, or null when this CPU or build lacks it (portable: always).
const KernelSet* kernels_for(KernelIsa isa);
// The widest set this CPU has, at most `cap`: the portable set when none.
const KernelSet& best_kernels(KernelIsa cap);

// Round-to-nearest-even conversion of one float to bfloat16 bits (finite inputs).
inline uint16_t to_bf16_bits(float f) {
  uint32_t u;
  __builtin_memcpy(&u, &f, sizeof u);
  u += 0x7fffu + ((u >> 16) & 1u);
  return static_cast<uint16_t>(u >> 16);
}
inline float from_bf16_bits(uint16_t h) {
  const uint32_t u = static_cast<uint32_t>(h) << 16;
  float f;
  __builtin_memcpy(&f, &u, sizeof f);
  return f;
}

}  // namespace skinbus::estimators::detail
