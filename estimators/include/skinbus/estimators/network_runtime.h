// skinbus/estimators/network_runtime.h: the host inference runtime of a per-patch network (no
// LibTorch).
//
// A NetworkRuntime is built once from a ModelFile (model_file.h gives the exact network) and then
// turns batches of tared samples into contacts:
//
//   auto rt = NetworkRuntime::create(model, {.threads = 2});
//   if (!rt) ...;                                   // rt.error() says why
//   rt->run(fields_ut, batch, estimates);           // batch x channels in, batch estimates out
//
// Contract of a run:
//   - input: `batch` samples of `channels()` tared fields each (uT, double, row-major, channel
//     order of estimate.h). Optionally a per-sample channel mask (0 = dead channel).
//   - every sample is checked with check_sample(); a network cannot drop channels, so a sample
//     with any unusable channel is rejected (kEstimateRejected) with the reason of its first bad
//     channel (kNonFinite, kSaturated or kDead) and costs no compute;
//   - the usable samples go through the network; outputs are de-normalised to physical units
//     (u_mm, v_mm, depth_mm, force_n matched by the model's output names; a missing output is 0)
//     and passed through flag_range() with the patch extent and deepest press of the metadata:
//     out-of-patch or out-of-depth contacts are flagged, never clipped; no NaN/Inf ever leaves.
//
// Costs: create() validates the model, packs the weights into the layout of the chosen kernels
// (a few MB for the seed CNN), allocates every work buffer and starts `threads - 1` worker
// threads that live as long as the runtime. run() allocates nothing with the kernel backends
// (the oneDNN backend allocates small execution contexts inside the library). A batch is split
// into `threads` contiguous parts; the calling thread computes the first part, workers the
// others, and run() returns when all are done. With threads > 1, the workers waiting for the next
// call and the caller waiting for the workers spin for up to RuntimeOptions::spin_us before they
// sleep (waking a sleeping thread costs tens to hundreds of microseconds on a virtual machine, as
// much as a small batch): each call keeps every thread busy that much longer. A runtime serves one
// caller at a time: run() and run_outputs() must not be called concurrently on the same object (use
// one runtime per thread or a lock); different runtimes are independent.
//
// Backends (RuntimeOptions::backend):
//   kAuto     kKernels, on every CPU (the fastest measured everywhere; docs/benchmarks/runtime.md).
//   kKernels  this library's register-blocked kernels on packed weights; convolutions compute
//             only the in-bounds taps of the grid. The widest instruction set the CPU has (and
//             RuntimeOptions::max_isa allows) is selected at run time: AVX-512 (F/VL/BW/DQ;
//             bfloat16 with AVX512_BF16, int8 with AVX512_VNNI, else those two from the AVX2
//             set), AVX2 + FMA (int8 with AVX-VNNI where present, else vpmaddubsw), NEON on
//             aarch64 (int8 with SDOT where the CPU has the dot-product instructions, else
//             widening multiplies); else the portable kernels.
//   kPortable the same plan with plain C++ kernels (any CPU; for comparison and fallback).
//   kOneDnn   oneDNN primitives (convolution with fused ReLU, inner product), float32 only; only
//             when asked for (slower than kKernels on every CPU measured). Builds without oneDNN
//             (SKINBUS_ONEDNN=OFF, as the Arm build) refuse it with kUnsupported.
// Precision (RuntimeOptions::precision):
//   kFloat32   matches LibTorch on the same weights to well below 1e-3 mm.
//   kBfloat16  weights and activations rounded to bfloat16, products accumulated in float32
//              (vdpbf16ps on AVX512_BF16; widened to float32 and FMA on AVX2 and NEON, which
//              saves memory traffic, not arithmetic), convolutions direct. Outputs differ from
//              float32 by a fraction of a percent of each output's scale (speed and error:
//              docs/benchmarks/runtime.md). create() returns kUnsupported when the backend is
//              kOneDnn; kKernels serves it on every CPU (on one without AVX2, AVX-512 or NEON
//              with the portable kernels, slowly); kPortable emulates it anywhere (for tests).
//   kInt8      the layers that carry at least 1/40 of the multiply-adds and whose input is a
//              ReLU output (seed CNN: conv1, conv2, conv3, fc0, fc1 = 99 % of the work) run as
//              7-bit unsigned activations (0..127) x signed 8-bit weights with exact int32 sums
//              (vpdpbusd on AVX512_VNNI or AVX-VNNI, vpmaddubsw + vpmaddwd on AVX2, sdot on
//              NEON); 7 bits so that every instruction set computes the same exact sums, and a
//              sample's result is the same on every CPU. The first layer (signed fields), the
//              head and the small layers stay float32. Weights: symmetric per output channel and
//              3x3 tap (scale max |w| / 127), quantised at create(). Activations: per input row
//              (a grid cell of one sample, or one sample), scale max / 127 of that row,
//              computed during the run (no calibration data), so a sample's result does not
//              depend on its batch. Scales, bias, ReLU and pooling in float32; convolutions
//              direct. Speed and the error it adds: docs/benchmarks/runtime.md. create()
//              returns kUnsupported when the backend is kOneDnn; kKernels serves it on every CPU
//              (the portable kernels where no vector set is), and kPortable computes the same
//              integer sums anywhere (slowly, for tests).
// Convolutions (RuntimeOptions::convolution; kKernels and kPortable, float32):
//   kDirect    the in-bounds taps of the grid, each a product of the cells' rows by the tap's
//              weights (on the seed CNN's 4x4 grid: 100 (cell, tap) pairs per channel pair).
//   kWinograd  Winograd F(2x2, 3x3): the grid in 2x2 output tiles, each tile's 4x4 input
//              transformed (B^T d B, additions only), 16 products per tile and channel pair with
//              weights transformed at create() (G g G^T, computed in double, stored in float32),
//              and the result transformed back (A^T m A) with bias and ReLU. On a 4x4 grid: 64
//              products per channel pair instead of 100, for 16/9 the conv weight bytes. Still
//              float32 throughout; the outputs differ from kDirect by rounding only (LibTorch
//              equality holds for both; docs/benchmarks/runtime.md).
//   kAuto      Winograd for the float32 convolutions with at least 32 input channels (narrower
//              ones run faster direct) when the grid needs fewer products with it (16 per tile
//              against the in-bounds taps: true on square grids from 4x4 up, false on 2x2 and
//              3x3), else kDirect. On the seed CNN: conv1-conv3 Winograd (the speed-up:
//              docs/benchmarks/runtime.md). kWinograd runs every convolution so. bfloat16 and int8
//              always run direct; create() returns kUnsupported for kWinograd with them or with the
//              oneDNN backend.
#pragma once

#include <cstdint>
#include <memory>
#include <span>

#include "skinbus/common/isa.h"
#include "skinbus/common/result.h"
#include "skinbus/estimators/estimate.h"
#include "skinbus/estimators/model_file.h"

namespace skinbus::estimators {

enum class RuntimeBackend : uint8_t { kAuto, kKernels, kPortable, kOneDnn };
enum class RuntimePrecision : uint8_t { kFloat32, kBfloat16, kInt8 };
enum class RuntimeConvolution : uint8_t { kAuto, kDirect, kWinograd };
// The instruction sets of the kernel backend, widest first (skinbus/common/isa.h: isa_name(),
// parse_isa()); RuntimeOptions::max_isa caps them.
using RuntimeIsa = Isa;

constexpr const char* runtime_backend_name(RuntimeBackend b) {
  switch (b) {
    case RuntimeBackend::kAuto:
      return "auto";
    case RuntimeBackend::kKernels:
      return "kernels";
    case RuntimeBackend::kPortable:
      return "portable";
    case RuntimeBackend::kOneDnn:
      return "onednn";
  }
  return "unknown";
}

constexpr const char* runtime_precision_name(RuntimePrecision p) {
  switch (p) {
    case RuntimePrecision::kFloat32:
      return "float32";
    case RuntimePrecision::kBfloat16:
      return "bfloat16";
    case RuntimePrecision::kInt8:
      return "int8";
  }
  return "unknown";
}

constexpr const char* runtime_convolution_name(RuntimeConvolution c) {
  switch (c) {
    case RuntimeConvolution::kAuto:
      return "auto";
    case RuntimeConvolution::kDirect:
      return "direct";
    case RuntimeConvolution::kWinograd:
      return "winograd";
  }
  return "unknown";
}

struct RuntimeOptions {
  RuntimeBackend backend = RuntimeBackend::kAuto;
  RuntimePrecision precision = RuntimePrecision::kFloat32;
  RuntimeConvolution convolution = RuntimeConvolution::kAuto;
  // kKernels: the widest instruction set the kernels may use (kAvx512: every one the CPU has).
  // The environment variable SKINBUS_MAX_ISA (same names) caps it further, for a whole process.
  RuntimeIsa max_isa = RuntimeIsa::kAvx512;
  int threads = 1;         // calling thread + (threads - 1) persistent workers; 1..64
  int spin_us = 200;       // threads > 1: spin this long before sleeping; 0..100000, 0 = never
  InputLimits limits;      // saturation threshold for check_sample()
  double margin_mm = 2.0;  // flag_range() margins
  double margin_depth_mm = 0.2;
};

// kInvalidArgument naming the first option out of range (threads 1..64, spin_us 0..100000):
// what NetworkRuntime::create() checks of its options, for callers that hold options before
// they have a model.
Status check_runtime_options(const RuntimeOptions& options);

class NetworkRuntime {
 public:
  // Validates `model` (validate_model) and builds the runtime. Errors: kInvalidArgument for a
  // model that does not validate or whose outputs lack u_mm/v_mm/depth_mm, or bad options;
  // kUnsupported for a precision or backend this CPU or build cannot serve.
  static Result<NetworkRuntime> create(const ModelFile& model, const RuntimeOptions& options = {});

  NetworkRuntime(NetworkRuntime&&) noexcept;
  NetworkRuntime& operator=(NetworkRuntime&&) noexcept;
  ~NetworkRuntime();

  // Estimates `batch` samples. `field_ut` holds batch * channels() values; `out` at least
  // `batch` entries; `channel_ok`, if not empty, batch * channels() entries (0 = dead channel,
  // read only). Returns kInvalidArgument (and, if `out` is large enough, marks every estimate
  // rejected with kWrongShape) when the sizes do not agree; per-sample problems are never an
  // error, they are rejections in `out`.
  Status run(std::span<const double> field_ut, int batch, std::span<ContactEstimate> out,
             std::span<const uint8_t> channel_ok = {});

  // One sample on the calling thread; a sample of the wrong size is rejected with kWrongShape.
  ContactEstimate estimate(std::span<const double> field_ut,
                           std::span<const uint8_t> channel_ok = {});

  // The bare network: `outputs` receives batch x outputs() values in physical units, in the
  // model's output order, with no input checks and no range flags (a non-finite input gives a
  // non-finite output). For comparisons with other implementations and for benchmarks.
  Status run_outputs(std::span<const double> field_ut, int batch, std::span<double> outputs);

  int channels() const;
  int outputs() const;
  int threads() const;
  RuntimeBackend backend() const;  // the backend in use (kAuto resolved)
  RuntimePrecision precision() const;
  // Multiply-adds per sample as this runtime computes them: ModelFile::macs() with direct
  // convolutions, 16 per 2x2 tile and channel pair for Winograd ones (the transforms' additions
  // not counted). For a float32 floor: 2 x macs() / the FMA peak.
  int64_t macs() const;
  // One layer's work per sample as this runtime computes it (kernel backends): its
  // multiply-adds (they sum to macs()) and the bytes of packed weights it reads (at batch 1 every
  // sample reads them all; a network whose weights outgrow the core's cache streams them from
  // the next level on every sample). Empty for the oneDNN backend.
  struct LayerCost {
    int64_t macs = 0;
    int64_t weight_bytes = 0;
  };
  // In layer order; the span lives as long as this runtime.
  std::span<const LayerCost> layer_costs() const;
  // The convolution algorithm in use: kWinograd when any convolution runs so, else kDirect (also
  // for MLPs and the oneDNN backend).
  RuntimeConvolution convolution() const;
  // A short description of the kernels in use, e.g. "kernels avx512 float32 winograd".
  const char* kernel_name() const;

  struct Impl;

 private:
  explicit NetworkRuntime(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

}  // namespace skinbus::estimators
