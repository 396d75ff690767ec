#include "skinbus/estimators/network_runtime.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <limits>
#include <random>
#include <string>
#include <thread>
#include <tuple>
#include <vector>

#include "skinbus/estimators/evaluation.h"
#include "skinbus/estimators/training.h"
#include "skinbus/sim/dataset.h"
#include "skinbus/sim/simulated_patch.h"

namespace skinbus::estimators {
namespace {

constexpr int kSensors = 16;
constexpr int kChannels = 3 * kSensors;
// LibTorch and the runtime both compute in float32; outputs are compared in mm (and N).
constexpr double kTorchToleranceMm = 1e-3;

ModelFile model_for(const std::string& which, uint64_t seed = 11) {
  Architecture a = which == "mlp"        ? mlp({256, 256})
                   : which == "cnn_w025" ? seed_cnn(0.25, 4, 4)
                                         : seed_cnn(1.0, 4, 4);
  auto m = random_model(a, kSensors, seed);
  EXPECT_TRUE(m.ok()) << m.error().to_string();
  return std::move(m.value());
}

// Tared fields of realistic scale: tens to hundreds of uT.
std::vector<double> fields(int batch, uint32_t seed, int channels = kChannels) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-250.0, 250.0);
  std::vector<double> f(static_cast<std::size_t>(batch) * static_cast<std::size_t>(channels));
  for (double& v : f) v = u(rng);
  return f;
}

// Whether the kernels chosen for this CPU (within SKINBUS_MAX_ISA) have bfloat16 / int8: AVX-512
// and AVX2 both do; the portable backend emulates both everywhere.
bool kernels_have_bf16() {
  RuntimeOptions o;
  o.backend = RuntimeBackend::kKernels;
  o.precision = RuntimePrecision::kBfloat16;
  return NetworkRuntime::create(model_for("cnn_w025"), o).ok();
}

bool kernels_have_int8() {
  RuntimeOptions o;
  o.backend = RuntimeBackend::kKernels;
  o.precision = RuntimePrecision::kInt8;
  return NetworkRuntime::create(model_for("cnn_w025"), o).ok();
}

// Max and mean |a - b| of output j over a batch of 4-output rows.
struct Difference {
  double max = 0, mean = 0;
};
Difference difference(const std::vector<double>& a, const std::vector<double>& b, int j) {
  Difference d;
  const std::size_t rows = a.size() / 4;
  for (std::size_t i = 0; i < rows; ++i) {
    const double e =
        std::fabs(a[4 * i + static_cast<std::size_t>(j)] - b[4 * i + static_cast<std::size_t>(j)]);
    d.max = std::max(d.max, e);
    d.mean += e / static_cast<double>(rows);
  }
  return d;
}

struct EqualityCase {
  std::string model;
  RuntimeBackend backend;
  RuntimeConvolution convolution = RuntimeConvolution::kAuto;
};

class TorchEqualityTest : public ::testing::TestWithParam<EqualityCase> {};

TEST_P(TorchEqualityTest, MatchesLibTorchForEveryBatchAndThreadCount) {
  const EqualityCase& p = GetParam();
  const ModelFile model = model_for(p.model);
  for (int threads : {1, 2}) {
    RuntimeOptions o;
    o.backend = p.backend;
    o.convolution = p.convolution;
    o.threads = threads;
    auto rt = NetworkRuntime::create(model, o);
    ASSERT_TRUE(rt.ok()) << rt.error().to_string();
    for (int batch : {1, 7, 64}) {
      const std::vector<double> f = fields(batch, static_cast<uint32_t>(batch * 10 + threads));
      auto want = torch_forward(model, f, batch, 1);
      ASSERT_TRUE(want.ok()) << want.error().to_string();
      std::vector<double> got(static_cast<std::size_t>(batch) * 4);
      ASSERT_TRUE(rt->run_outputs(f, batch, got).ok());
      double worst = 0;
      for (std::size_t i = 0; i < got.size(); ++i) {
        worst = std::max(worst, std::fabs(got[i] - (*want)[i]));
      }
      EXPECT_LE(worst, kTorchToleranceMm)
          << rt->kernel_name() << " threads " << threads << " batch " << batch;
      if (batch == 64 && threads == 1) {
        std::printf("%s %s: max |runtime - LibTorch| %.2e\n", p.model.c_str(), rt->kernel_name(),
                    worst);
      }
      // run() gives the same numbers as estimates.
      std::vector<ContactEstimate> est(static_cast<std::size_t>(batch));
      ASSERT_TRUE(rt->run(f, batch, est).ok());
      for (int i = 0; i < batch; ++i) {
        const ContactEstimate& e = est[static_cast<std::size_t>(i)];
        ASSERT_TRUE(e.valid());
        EXPECT_DOUBLE_EQ(e.u_mm, got[static_cast<std::size_t>(4 * i)]);
        EXPECT_DOUBLE_EQ(e.v_mm, got[static_cast<std::size_t>(4 * i + 1)]);
        EXPECT_DOUBLE_EQ(e.depth_mm, got[static_cast<std::size_t>(4 * i + 2)]);
        EXPECT_DOUBLE_EQ(e.force_n, got[static_cast<std::size_t>(4 * i + 3)]);
      }
    }
  }
}

INSTANTIATE_TEST_SUITE_P(
    Backends, TorchEqualityTest,
    ::testing::Values(EqualityCase{"cnn", RuntimeBackend::kKernels},
                      EqualityCase{"cnn_w025", RuntimeBackend::kKernels},
                      EqualityCase{"mlp", RuntimeBackend::kKernels},
                      EqualityCase{"cnn", RuntimeBackend::kOneDnn},
                      EqualityCase{"cnn_w025", RuntimeBackend::kOneDnn},
                      EqualityCase{"mlp", RuntimeBackend::kOneDnn},
                      EqualityCase{"cnn", RuntimeBackend::kKernels, RuntimeConvolution::kDirect},
                      EqualityCase{"cnn_w025", RuntimeBackend::kKernels,
                                   RuntimeConvolution::kDirect},
                      EqualityCase{"cnn", RuntimeBackend::kPortable},
                      EqualityCase{"cnn", RuntimeBackend::kPortable, RuntimeConvolution::kDirect},
                      EqualityCase{"cnn_w025", RuntimeBackend::kPortable},
                      EqualityCase{"mlp", RuntimeBackend::kPortable}),
    [](const auto& param_info) {
      const EqualityCase& c = param_info.param;
      return c.model + "_" + runtime_backend_name(c.backend) +
             (c.convolution == RuntimeConvolution::kAuto
                  ? std::string()
                  : std::string("_") + runtime_convolution_name(c.convolution));
    });

TEST(NetworkRuntimeTest, ThreadsGiveTheSameResultsAsOneThread) {
  const ModelFile model = model_for("cnn");
  // Workers that spin between calls (the default), that sleep at once (spin_us 0), and that
  // have fallen asleep because the caller paused longer than their spin.
  for (auto [b, spin_us, pause_us] :
       {std::tuple{RuntimeBackend::kKernels, 200, 0}, std::tuple{RuntimeBackend::kKernels, 0, 0},
        std::tuple{RuntimeBackend::kKernels, 50, 2000},
        std::tuple{RuntimeBackend::kOneDnn, 200, 0}}) {
    RuntimeOptions o1, o2;
    o1.backend = o2.backend = b;
    o2.threads = 2;
    o2.spin_us = spin_us;
    auto one = NetworkRuntime::create(model, o1);
    auto two = NetworkRuntime::create(model, o2);
    ASSERT_TRUE(one.ok() && two.ok());
    for (int batch : {1, 2, 7, 33, 64, 64}) {
      std::this_thread::sleep_for(std::chrono::microseconds(pause_us));
      const std::vector<double> f = fields(batch, 5);
      std::vector<double> y1(static_cast<std::size_t>(batch) * 4), y2(y1.size());
      ASSERT_TRUE(one->run_outputs(f, batch, y1).ok());
      ASSERT_TRUE(two->run_outputs(f, batch, y2).ok());
      for (std::size_t i = 0; i < y1.size(); ++i) {
        if (b == RuntimeBackend::kKernels) {
          // Every row is computed in the same order wherever it lands: bit-identical.
          ASSERT_EQ(y1[i], y2[i]) << "batch " << batch << " value " << i;
        } else {
          // oneDNN may pick other kernels for other chunk sizes.
          ASSERT_NEAR(y1[i], y2[i], 1e-4) << "batch " << batch << " value " << i;
        }
      }
    }
  }
}

// A batch runs direct float32 convolutions cell by cell (all taps of a cell per kernel call), one
// sample tap by tap: the same products in the same order, so the same bits. Winograd computes
// every row alone in the same order whatever the batch: the same bits too.
TEST(NetworkRuntimeTest, ABatchGivesTheSameAsOneSampleAtATime) {
  const ModelFile model = model_for("cnn_w025");
  for (auto [b, conv] : {std::pair{RuntimeBackend::kKernels, RuntimeConvolution::kDirect},
                         std::pair{RuntimeBackend::kPortable, RuntimeConvolution::kDirect},
                         std::pair{RuntimeBackend::kKernels, RuntimeConvolution::kWinograd},
                         std::pair{RuntimeBackend::kPortable, RuntimeConvolution::kWinograd}}) {
    RuntimeOptions o;
    o.backend = b;
    o.convolution = conv;
    auto rt = NetworkRuntime::create(model, o);
    ASSERT_TRUE(rt.ok());
    const int batch = 20;
    const std::vector<double> f = fields(batch, 9);
    std::vector<ContactEstimate> est(batch);
    ASSERT_TRUE(rt->run(f, batch, est).ok());
    for (int i = 0; i < batch; ++i) {
      const ContactEstimate e = rt->estimate(
          std::span<const double>(f).subspan(static_cast<std::size_t>(i) * kChannels, kChannels));
      EXPECT_EQ(e.u_mm, est[static_cast<std::size_t>(i)].u_mm) << rt->kernel_name();
      EXPECT_EQ(e.depth_mm, est[static_cast<std::size_t>(i)].depth_mm) << rt->kernel_name();
    }
  }
}

// Winograd tiles cover the grid in 2x2 blocks: on odd sides the last tile reads zero padding
// beyond the grid and discards outputs there; on 1x1 every tile cell but one is outside.
TEST(NetworkRuntimeTest, WinogradMatchesLibTorchOnEveryGridSide) {
  for (int side : {1, 2, 3, 5}) {
    auto model = random_model(seed_cnn(0.25, side, side), side * side, 3);
    ASSERT_TRUE(model.ok()) << model.error().to_string();
    for (RuntimeBackend b : {RuntimeBackend::kKernels, RuntimeBackend::kPortable}) {
      RuntimeOptions o;
      o.backend = b;
      o.convolution = RuntimeConvolution::kWinograd;
      auto rt = NetworkRuntime::create(*model, o);
      ASSERT_TRUE(rt.ok()) << rt.error().to_string();
      ASSERT_EQ(rt->convolution(), RuntimeConvolution::kWinograd);
      for (int batch : {1, 9}) {
        const std::vector<double> f =
            fields(batch, static_cast<uint32_t>(side * 100 + batch), 3 * side * side);
        auto want = torch_forward(*model, f, batch, 1);
        ASSERT_TRUE(want.ok()) << want.error().to_string();
        std::vector<double> got(static_cast<std::size_t>(batch) * 4);
        ASSERT_TRUE(rt->run_outputs(f, batch, got).ok());
        for (std::size_t i = 0; i < got.size(); ++i) {
          ASSERT_NEAR(got[i], (*want)[i], kTorchToleranceMm)
              << rt->kernel_name() << " side " << side << " batch " << batch << " value " << i;
        }
      }
    }
  }
}

// kAuto takes Winograd where it computes fewer products than the in-bounds taps, for layers of
// 32 inputs or more, and only for float32 on this library's kernels; asking for it elsewhere is
// refused by name.
TEST(NetworkRuntimeTest, ChoosesWinogradWhereItComputesLess) {
  auto kernels = [](const ModelFile& m, RuntimePrecision p, RuntimeConvolution c) {
    RuntimeOptions o;
    o.backend = RuntimeBackend::kPortable;
    o.precision = p;
    o.convolution = c;
    return NetworkRuntime::create(m, o);
  };
  const ModelFile cnn = model_for("cnn");
  auto four = kernels(cnn, RuntimePrecision::kFloat32, RuntimeConvolution::kAuto);
  ASSERT_TRUE(four.ok());
  EXPECT_EQ(four->convolution(), RuntimeConvolution::kWinograd);
  EXPECT_NE(std::string(four->kernel_name()).find("winograd"), std::string::npos);
  // 4x4 grid: 100 in-bounds (cell, tap) pairs direct, 4 tiles x 16 Winograd, for conv1-conv3
  // (conv0 has 3 inputs: direct), or every convolution when asked.
  const int64_t wide = 32 * 64 + 64 * 128 + 128 * 256;
  EXPECT_EQ(cnn.macs() - four->macs(), (100 - 64) * wide);
  auto every = kernels(cnn, RuntimePrecision::kFloat32, RuntimeConvolution::kWinograd);
  ASSERT_TRUE(every.ok());
  EXPECT_EQ(cnn.macs() - every->macs(), (100 - 64) * (wide + 3 * 32));
  auto direct = kernels(cnn, RuntimePrecision::kFloat32, RuntimeConvolution::kDirect);
  ASSERT_TRUE(direct.ok());
  EXPECT_EQ(direct->convolution(), RuntimeConvolution::kDirect);
  EXPECT_EQ(direct->macs(), cnn.macs());
  // Per layer: the multiply-adds sum to macs(); the weights read are the packed panels, 9 taps
  // direct (the first convolution) and 16 points Winograd, 4 bytes each in float32.
  for (const auto* rt : {&four.value(), &every.value(), &direct.value()}) {
    int64_t sum = 0;
    for (const NetworkRuntime::LayerCost& c : rt->layer_costs()) sum += c.macs;
    EXPECT_EQ(sum, rt->macs());
  }
  ASSERT_GE(four->layer_costs().size(), 5u);
  EXPECT_EQ(four->layer_costs()[0].weight_bytes, 9 * 3 * 32 * 4);  // 3 inputs, 32 outputs
  EXPECT_EQ(four->layer_costs()[3].weight_bytes, 16 * 128 * 256 * 4);
  EXPECT_EQ(direct->layer_costs()[3].weight_bytes, 9 * 128 * 256 * 4);
  EXPECT_EQ(four->layer_costs()[4].weight_bytes, 512 * 512 * 4);  // fc0: max and mean pooled
  auto int8 = kernels(cnn, RuntimePrecision::kInt8, RuntimeConvolution::kAuto);
  ASSERT_TRUE(int8.ok());
  EXPECT_EQ(int8->layer_costs()[3].weight_bytes, 9 * 128 * 256);  // int8: one byte a weight
  // Width 0.125: every convolution has fewer than 32 inputs.
  auto narrow = random_model(seed_cnn(0.125, 4, 4), 16, 3);
  ASSERT_TRUE(narrow.ok());
  auto rt_narrow = kernels(*narrow, RuntimePrecision::kFloat32, RuntimeConvolution::kAuto);
  ASSERT_TRUE(rt_narrow.ok());
  EXPECT_EQ(rt_narrow->convolution(), RuntimeConvolution::kDirect);
  // 3x3 grid: 49 pairs direct against 4 tiles x 16.
  auto three = random_model(seed_cnn(1.0, 3, 3), 9, 3);
  ASSERT_TRUE(three.ok());
  auto rt3 = kernels(*three, RuntimePrecision::kFloat32, RuntimeConvolution::kAuto);
  ASSERT_TRUE(rt3.ok());
  EXPECT_EQ(rt3->convolution(), RuntimeConvolution::kDirect);
  // MLPs have no convolution; reduced precisions run direct ones.
  auto mlp = kernels(model_for("mlp"), RuntimePrecision::kFloat32, RuntimeConvolution::kWinograd);
  ASSERT_TRUE(mlp.ok());
  EXPECT_EQ(mlp->convolution(), RuntimeConvolution::kDirect);
  auto i8 = kernels(cnn, RuntimePrecision::kInt8, RuntimeConvolution::kAuto);
  ASSERT_TRUE(i8.ok());
  EXPECT_EQ(i8->convolution(), RuntimeConvolution::kDirect);
  auto refused = kernels(cnn, RuntimePrecision::kInt8, RuntimeConvolution::kWinograd);
  ASSERT_FALSE(refused.ok());
  EXPECT_EQ(refused.error().code, ErrorCode::kUnsupported);
  EXPECT_NE(refused.error().message.find("Winograd"), std::string::npos);
  RuntimeOptions o;
  o.backend = RuntimeBackend::kOneDnn;
  o.convolution = RuntimeConvolution::kWinograd;
  auto dnn = NetworkRuntime::create(cnn, o);
  ASSERT_FALSE(dnn.ok());
  EXPECT_EQ(dnn.error().code, ErrorCode::kUnsupported);
  o.convolution = RuntimeConvolution::kAuto;
  auto dnn_auto = NetworkRuntime::create(cnn, o);
  ASSERT_TRUE(dnn_auto.ok());
  EXPECT_EQ(dnn_auto->convolution(), RuntimeConvolution::kDirect);
  EXPECT_EQ(dnn_auto->macs(), cnn.macs());
}

TEST(NetworkRuntimeTest, RejectsUnusableSamplesWithTheReasonAndNoNaN) {
  const ModelFile model = model_for("cnn_w025");
  for (RuntimeBackend b : {RuntimeBackend::kKernels, RuntimeBackend::kOneDnn}) {
    RuntimeOptions o;
    o.backend = b;
    o.threads = 2;
    auto rt = NetworkRuntime::create(model, o);
    ASSERT_TRUE(rt.ok());
    const int batch = 6;
    std::vector<double> f = fields(batch, 3);
    std::vector<uint8_t> ok(f.size(), 1);
    f[1 * kChannels + 5] = std::numeric_limits<double>::quiet_NaN();
    f[2 * kChannels + 7] = std::numeric_limits<double>::infinity();
    f[3 * kChannels + 0] = 2.0e4;  // beyond the default saturation (1e4 uT)
    ok[4 * kChannels + 47] = 0;    // dead, by the caller's mask
    std::vector<ContactEstimate> est(batch);
    ASSERT_TRUE(rt->run(f, batch, est, ok).ok());
    const RejectReason want[batch] = {RejectReason::kNone,      RejectReason::kNonFinite,
                                      RejectReason::kNonFinite, RejectReason::kSaturated,
                                      RejectReason::kDead,      RejectReason::kNone};
    for (int i = 0; i < batch; ++i) {
      const ContactEstimate& e = est[static_cast<std::size_t>(i)];
      EXPECT_EQ(e.reason, want[i]) << "sample " << i;
      EXPECT_EQ(e.valid(), want[i] == RejectReason::kNone) << "sample " << i;
      EXPECT_TRUE(std::isfinite(e.u_mm) && std::isfinite(e.v_mm) && std::isfinite(e.depth_mm) &&
                  std::isfinite(e.force_n));
    }
    // The good samples are what they are alone.
    const ContactEstimate alone =
        rt->estimate(std::span<const double>(f).subspan(5 * kChannels, kChannels));
    EXPECT_EQ(alone.u_mm, est[5].u_mm);

    // Wrong shapes: a batch call refuses and marks every estimate; one sample is rejected.
    std::vector<double> short_f(f.begin(), f.end() - 1);
    EXPECT_FALSE(rt->run(short_f, batch, est).ok());
    for (const ContactEstimate& e : est) EXPECT_EQ(e.reason, RejectReason::kWrongShape);
    const ContactEstimate e = rt->estimate(std::span<const double>(f).first(kChannels - 3));
    EXPECT_FALSE(e.valid());
    EXPECT_EQ(e.reason, RejectReason::kWrongShape);
  }
}

TEST(NetworkRuntimeTest, FlagsContactsOutsideThePatch) {
  ModelFile model = model_for("cnn_w025");
  model.meta.output_mean[0] = 500.0;  // every u far beyond the 70 mm half width
  model.meta.output_mean[2] = -50.0;  // every depth above the skin
  auto rt = NetworkRuntime::create(model, {});
  ASSERT_TRUE(rt.ok());
  const std::vector<double> f = fields(4, 1);
  std::vector<ContactEstimate> est(4);
  ASSERT_TRUE(rt->run(f, 4, est).ok());
  for (const ContactEstimate& e : est) {
    EXPECT_TRUE(e.valid());
    EXPECT_NE(e.flags & kEstimateOutsidePatch, 0u);
    EXPECT_NE(e.flags & kEstimateDepthRange, 0u);
    EXPECT_GT(e.u_mm, 400.0);  // flagged, not clipped
  }
}

TEST(NetworkRuntimeTest, RefusesACorruptModel) {
  ModelFile model = model_for("cnn_w025");
  for (Tensor& t : model.tensors) {
    if (t.name == "conv1.weight") {
      t.shape[1] += 1;
      t.data.resize(static_cast<std::size_t>(t.numel()));
    }
  }
  for (RuntimeBackend b :
       {RuntimeBackend::kAuto, RuntimeBackend::kKernels, RuntimeBackend::kOneDnn}) {
    RuntimeOptions o;
    o.backend = b;
    auto rt = NetworkRuntime::create(model, o);
    ASSERT_FALSE(rt.ok());
    EXPECT_EQ(rt.error().code, ErrorCode::kInvalidArgument);
    EXPECT_NE(rt.error().message.find("conv1.weight"), std::string::npos) << rt.error().message;
  }
  RuntimeOptions bad_threads;
  bad_threads.threads = 0;
  EXPECT_FALSE(NetworkRuntime::create(model_for("mlp"), bad_threads).ok());
  for (int spin_us : {-1, 100001}) {
    RuntimeOptions bad_spin;
    bad_spin.spin_us = spin_us;
    auto rt = NetworkRuntime::create(model_for("mlp"), bad_spin);
    ASSERT_FALSE(rt.ok());
    EXPECT_NE(rt.error().message.find("spin_us"), std::string::npos) << rt.error().message;
  }
}

TEST(NetworkRuntimeTest, Bfloat16IsUnsupportedOnOneDnn) {
  RuntimeOptions o;
  o.backend = RuntimeBackend::kOneDnn;
  o.precision = RuntimePrecision::kBfloat16;
  auto rt = NetworkRuntime::create(model_for("mlp"), o);
  ASSERT_FALSE(rt.ok());
  EXPECT_EQ(rt.error().code, ErrorCode::kUnsupported);
}

// bfloat16 rounds weights and activations to 8 significant bits; products accumulate in float32.
// Stated tolerance: max difference from float32 within 1.5 % of each output's scale (0.6 mm for
// u and v at a 40 mm scale), mean within 0.3 %.
TEST(NetworkRuntimeTest, Bfloat16StaysCloseToFloat32) {
  if (!kernels_have_bf16()) GTEST_SKIP() << "no bfloat16 kernels for this CPU";
  for (const std::string which : {"cnn", "cnn_w025", "mlp"}) {
    const ModelFile model = model_for(which);
    RuntimeOptions o32, o16;
    o16.precision = RuntimePrecision::kBfloat16;
    o16.threads = 2;
    auto r32 = NetworkRuntime::create(model, o32);
    auto r16 = NetworkRuntime::create(model, o16);
    ASSERT_TRUE(r32.ok() && r16.ok());
    const int batch = 64;
    const std::vector<double> f = fields(batch, 77);
    std::vector<double> y32(batch * 4), y16(batch * 4);
    ASSERT_TRUE(r32->run_outputs(f, batch, y32).ok());
    ASSERT_TRUE(r16->run_outputs(f, batch, y16).ok());
    for (int j = 0; j < 4; ++j) {
      double worst = 0, sum = 0;
      for (int i = 0; i < batch; ++i) {
        const double d = std::fabs(y32[static_cast<std::size_t>(4 * i + j)] -
                                   y16[static_cast<std::size_t>(4 * i + j)]);
        worst = std::max(worst, d);
        sum += d;
      }
      const double scale = model.meta.output_scale[static_cast<std::size_t>(j)];
      EXPECT_LE(worst, 0.015 * scale) << which << " output " << j;
      EXPECT_LE(sum / batch, 0.003 * scale) << which << " output " << j;
      std::printf("%s output %d: bf16 - f32 max %.4f mean %.4f (scale %.1f)\n", which.c_str(), j,
                  worst, sum / batch, scale);
    }
  }
}

TEST(NetworkRuntimeTest, Int8IsUnsupportedOnOneDnnAndNamed) {
  RuntimeOptions o;
  o.backend = RuntimeBackend::kOneDnn;
  o.precision = RuntimePrecision::kInt8;
  auto rt = NetworkRuntime::create(model_for("mlp"), o);
  ASSERT_FALSE(rt.ok());
  EXPECT_EQ(rt.error().code, ErrorCode::kUnsupported);
  EXPECT_STREQ(runtime_precision_name(RuntimePrecision::kInt8), "int8");
  // The portable backend serves int8 on any CPU.
  o.backend = RuntimeBackend::kPortable;
  auto portable = NetworkRuntime::create(model_for("mlp"), o);
  ASSERT_TRUE(portable.ok()) << portable.error().to_string();
  EXPECT_STREQ(portable->kernel_name(), "portable int8");
  EXPECT_EQ(portable->precision(), RuntimePrecision::kInt8);
}

// int8: weights 7 bits per output channel, activations 8 bits per sample and layer; int32
// sums. Stated tolerance on random models: max difference from float32 within 3 % of each
// output's scale (1.2 mm for u and v at a 40 mm scale), mean within 0.75 %.
TEST(NetworkRuntimeTest, Int8StaysCloseToFloat32) {
  for (RuntimeBackend b : {RuntimeBackend::kKernels, RuntimeBackend::kPortable}) {
    if (b == RuntimeBackend::kKernels && !kernels_have_int8()) continue;
    for (const std::string which : {"cnn", "cnn_w025", "mlp"}) {
      const ModelFile model = model_for(which);
      RuntimeOptions o32, o8;
      o8.backend = b;
      o8.precision = RuntimePrecision::kInt8;
      o8.threads = 2;
      auto r32 = NetworkRuntime::create(model, o32);
      auto r8 = NetworkRuntime::create(model, o8);
      ASSERT_TRUE(r32.ok() && r8.ok());
      const int batch = b == RuntimeBackend::kPortable ? 16 : 64;
      const std::vector<double> f = fields(batch, 77);
      std::vector<double> y32(static_cast<std::size_t>(batch) * 4), y8(y32.size());
      ASSERT_TRUE(r32->run_outputs(f, batch, y32).ok());
      ASSERT_TRUE(r8->run_outputs(f, batch, y8).ok());
      for (int j = 0; j < 4; ++j) {
        const Difference d = difference(y32, y8, j);
        const double scale = model.meta.output_scale[static_cast<std::size_t>(j)];
        EXPECT_LE(d.max, 0.03 * scale) << which << " output " << j << " " << r8->kernel_name();
        EXPECT_LE(d.mean, 0.0075 * scale) << which << " output " << j << " " << r8->kernel_name();
        if (b == RuntimeBackend::kKernels) {
          std::printf("%s output %d: int8 - f32 max %.4f mean %.4f (scale %.1f)\n", which.c_str(),
                      j, d.max, d.mean, scale);
        }
      }
    }
  }
}

// The int8 kernels (AVX-512 VNNI, AVX2, NEON) and the portable emulation compute the same integer
// sums; they may
// differ only where float32 rounding of the first layer or the dequantisation moves a value
// across a quantisation step.
TEST(NetworkRuntimeTest, Int8KernelsMatchThePortableEmulation) {
  if (!kernels_have_int8()) GTEST_SKIP() << "no int8 kernels for this CPU";
  for (const std::string which : {"cnn_w025", "mlp"}) {
    const ModelFile model = model_for(which);
    RuntimeOptions ok, op;
    ok.backend = RuntimeBackend::kKernels;
    op.backend = RuntimeBackend::kPortable;
    ok.precision = op.precision = RuntimePrecision::kInt8;
    auto rk = NetworkRuntime::create(model, ok);
    auto rp = NetworkRuntime::create(model, op);
    ASSERT_TRUE(rk.ok() && rp.ok());
    const int batch = 24;
    const std::vector<double> f = fields(batch, 31);
    std::vector<double> yk(static_cast<std::size_t>(batch) * 4), yp(yk.size());
    ASSERT_TRUE(rk->run_outputs(f, batch, yk).ok());
    ASSERT_TRUE(rp->run_outputs(f, batch, yp).ok());
    for (int j = 0; j < 4; ++j) {
      const double scale = model.meta.output_scale[static_cast<std::size_t>(j)];
      EXPECT_LE(difference(yk, yp, j).max, 0.002 * scale) << which << " output " << j;
    }
  }
}

// Activation scales are per sample: a sample's int8 result does not depend on its batch, the
// thread count or where in a chunk it lands.
TEST(NetworkRuntimeTest, Int8SamplesAreIndependentOfTheirBatch) {
  if (!kernels_have_int8()) GTEST_SKIP() << "no int8 kernels for this CPU";
  const ModelFile model = model_for("cnn");
  RuntimeOptions o1, o2;
  o1.precision = o2.precision = RuntimePrecision::kInt8;
  o2.threads = 2;
  auto one = NetworkRuntime::create(model, o1);
  auto two = NetworkRuntime::create(model, o2);
  ASSERT_TRUE(one.ok() && two.ok());
  const int batch = 37;
  std::vector<double> f = fields(batch, 12);
  // One sample far larger than the others: it must not coarsen their scales.
  for (int c = 0; c < kChannels; ++c) f[static_cast<std::size_t>(5 * kChannels + c)] *= 30.0;
  std::vector<double> y1(static_cast<std::size_t>(batch) * 4), y2(y1.size());
  ASSERT_TRUE(one->run_outputs(f, batch, y1).ok());
  ASSERT_TRUE(two->run_outputs(f, batch, y2).ok());
  for (std::size_t i = 0; i < y1.size(); ++i) ASSERT_EQ(y1[i], y2[i]) << "value " << i;
  for (int i = 0; i < batch; i += 6) {
    std::vector<double> alone(4);
    ASSERT_TRUE(one->run_outputs(std::span<const double>(f).subspan(
                                     static_cast<std::size_t>(i) * kChannels, kChannels),
                                 1, alone)
                    .ok());
    for (int j = 0; j < 4; ++j) {
      EXPECT_EQ(alone[static_cast<std::size_t>(j)], y1[static_cast<std::size_t>(4 * i + j)])
          << "sample " << i;
    }
  }
  // Non-finite inputs are rejected by run() like every precision, with finite outputs.
  f[static_cast<std::size_t>(2 * kChannels + 1)] = std::numeric_limits<double>::quiet_NaN();
  std::vector<ContactEstimate> est(static_cast<std::size_t>(batch));
  ASSERT_TRUE(one->run(f, batch, est).ok());
  EXPECT_EQ(est[2].reason, RejectReason::kNonFinite);
  EXPECT_TRUE(est[3].valid());
}

// The trained default model (estimators/models/) on a fresh simulated split of the nominal patch:
// the reduced precisions keep the XY mean error within 2 % of float32's, overall and in every depth
// bin from 1 mm (the shallower bins hold presses too light to localise).
TEST(NetworkRuntimeTest, ReducedPrecisionKeepsTheTrainedModelsXYError) {
  const char* dir = std::getenv("SKINBUS_SOURCE_DIR");
  std::string source = dir != nullptr ? dir : "";
  if (source.empty()) {
    source = __FILE__;
    source = source.substr(0, source.rfind("/estimators/src/"));
  }
  Result<ModelFile> m = read_model(source + "/estimators/models/nominal_seed_cnn");
  if (!m.ok()) GTEST_SKIP() << m.error().to_string();
  sim::SimulatedPatch patch(sim::PatchModel::nominal(sim::PatchDesign{}).value(), 7);
  const sim::Dataset test = sim::generate_random_test_set(patch, 1500, 67.5, 4.0, 4321);
  const int rows = static_cast<int>(test.rows());
  const Truth truth{test.u_mm, test.v_mm, test.depth_mm, test.force_n};
  ErrorSummary ref;
  int compared = 0;
  for (RuntimePrecision p :
       {RuntimePrecision::kFloat32, RuntimePrecision::kBfloat16, RuntimePrecision::kInt8}) {
    RuntimeOptions o;
    o.precision = p;
    auto rt = NetworkRuntime::create(*m, o);
    if (!rt.ok()) {
      EXPECT_EQ(rt.error().code, ErrorCode::kUnsupported);
      continue;
    }
    std::vector<ContactEstimate> out(static_cast<std::size_t>(rows));
    ASSERT_TRUE(rt->run(test.field_ut, rows, out).ok());
    const ErrorSummary e = summarize_errors(out, truth);
    if (p == RuntimePrecision::kFloat32) {
      ref = e;
      continue;
    }
    ++compared;
    std::printf("%s: XY mean %.4f mm (float32 %.4f)", runtime_precision_name(p), e.all.xy_mean_mm,
                ref.all.xy_mean_mm);
    EXPECT_LE(e.all.xy_mean_mm, 1.02 * ref.all.xy_mean_mm) << runtime_precision_name(p);
    for (int b = 2; b < kDepthBins; ++b) {
      const double got = e.bins[static_cast<std::size_t>(b)].xy_mean_mm;
      const double want = ref.bins[static_cast<std::size_t>(b)].xy_mean_mm;
      std::printf(", %s mm %.4f (%.4f)", depth_bin_name(b).c_str(), got, want);
      EXPECT_LE(got, 1.02 * want) << runtime_precision_name(p) << " bin " << depth_bin_name(b);
    }
    std::printf("\n");
  }
  if (compared == 0) GTEST_SKIP() << "no bfloat16 or int8 kernels for this CPU";
}

}  // namespace
}  // namespace skinbus::estimators
