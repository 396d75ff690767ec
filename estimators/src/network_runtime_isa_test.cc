// The network runtime's kernels (the widest instruction set this CPU has, within SKINBUS_MAX_ISA)
// against its portable backend, on random CNNs and MLPs and on the shipped model, in every
// precision the kernels serve. Needs no LibTorch (the random models are drawn here): this test
// also runs on Arm, under qemu-aarch64 in CI (scripts/arm_test.sh), where LibTorch has no build.
// network_runtime_test.cc compares both backends against LibTorch where it is present.
//
// float32: the kernels and the portable backend form the same sums, with or without FMA: within
// 1e-3 mm (and N). int8 and bfloat16: the kernels compute the same integer sums and the same
// bfloat16 roundings as the portable backend, but the float32 layers between them may round
// differently (FMA or not, another summation order), which can move an activation across a
// quantisation step: close, not equal (within 0.2 % of each output's scale).
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <numeric>
#include <ostream>
#include <random>
#include <string>
#include <vector>

#include "skinbus/estimators/network_runtime.h"

namespace skinbus::estimators {
namespace {

constexpr double kFloat32ToleranceMm = 1e-3;
constexpr double kReducedTolerance = 0.002;  // of each output's scale

// A random model of architecture `a` on a side x side sensor grid (30 mm pitch), drawn without
// LibTorch: weights uniform with He scaling (sqrt(6 / fan_in), so activations keep their scale
// through the ReLU layers and the outputs depend on every layer), biases uniform within
// 1 / sqrt(fan_in), sensors mapped to the grid cells in a shuffled order.
ModelFile random_model(Architecture a, int side, uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(-1, 1);
  ModelFile model;
  ModelMeta& m = model.meta;
  m.name = "random";
  const int sensors = side * side;
  for (int r = 0; r < side; ++r) {
    for (int c = 0; c < side; ++c) {
      m.sensors.push_back({30.0 * (c - (side - 1) / 2.0), 30.0 * (r - (side - 1) / 2.0), -17});
    }
  }
  if (a.kind == ArchitectureKind::kCnn) {
    a.grid_rows = a.grid_cols = side;
    a.sensor_cell.resize(static_cast<std::size_t>(sensors));
    std::iota(a.sensor_cell.begin(), a.sensor_cell.end(), 0);
    std::shuffle(a.sensor_cell.begin(), a.sensor_cell.end(), rng);
  }
  m.architecture = a;
  for (int c = 0; c < 3 * sensors; ++c) {
    m.input_mean.push_back(5 * u(rng));
    m.input_scale.push_back(100 + 30 * u(rng));
  }
  m.outputs = {"u_mm", "v_mm", "depth_mm", "force_n"};
  m.output_mean = {0, 0, 2, 4};
  m.output_scale = {40, 40, 1.2, 2.5};
  model.tensors = expected_tensors(a, 3 * sensors, 4);
  for (std::size_t i = 0; i < model.tensors.size(); ++i) {
    Tensor& t = model.tensors[i];
    t.data.resize(static_cast<std::size_t>(t.numel()));
    // fan_in: the weight's inputs (x 9 taps for a convolution); a bias follows its weight.
    const bool bias = t.shape.size() == 1;
    const Tensor& weight = bias ? model.tensors[i - 1] : t;
    const double fan_in = static_cast<double>(weight.numel() / weight.shape[0]);
    const double bound = bias ? 1.0 / std::sqrt(fan_in) : std::sqrt(6.0 / fan_in);
    for (float& x : t.data) x = static_cast<float>(bound * u(rng));
  }
  const Status st = validate_model(model);
  EXPECT_TRUE(st.ok()) << st.error().to_string();
  return model;
}

ModelFile model_for(const std::string& which) {
  if (which == "mlp") return random_model(mlp({256, 256}), 4, 11);
  if (which == "cnn") return random_model(seed_cnn(1.0, 4, 4), 4, 11);
  if (which == "cnn_w025_3x3") return random_model(seed_cnn(0.25, 3, 3), 3, 12);
  if (which == "cnn_w025_5x5") return random_model(seed_cnn(0.25, 5, 5), 5, 13);
  return random_model(seed_cnn(0.25, 4, 4), 4, 14);  // cnn_w025
}

// Tared fields of realistic scale: tens to hundreds of uT.
std::vector<double> fields(int batch, int channels, uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-250.0, 250.0);
  std::vector<double> f(static_cast<std::size_t>(batch) * static_cast<std::size_t>(channels));
  for (double& v : f) v = u(rng);
  return f;
}

Result<std::vector<double>> outputs(const ModelFile& model, const RuntimeOptions& o,
                                    const std::vector<double>& f, int batch,
                                    std::string* kernel_name = nullptr) {
  auto rt = NetworkRuntime::create(model, o);
  if (!rt.ok()) return rt.error();
  if (kernel_name != nullptr) *kernel_name = rt->kernel_name();
  std::vector<double> y(static_cast<std::size_t>(batch) * 4);
  if (Status st = rt->run_outputs(f, batch, y); !st.ok()) return st.error();
  return y;
}

// The largest |a - b| of output j over rows of 4 outputs.
double max_difference(const std::vector<double>& a, const std::vector<double>& b, int j) {
  double worst = 0;
  for (std::size_t i = static_cast<std::size_t>(j); i < a.size(); i += 4) {
    worst = std::max(worst, std::fabs(a[i] - b[i]));
  }
  return worst;
}

// The kernels' result (threads 1 and 2: the same bits) against the portable backend's.
void expect_kernels_match_portable(const ModelFile& model, RuntimePrecision precision,
                                   RuntimeConvolution convolution, int batch, uint32_t seed) {
  const std::vector<double> f = fields(batch, model.meta.channels(), seed);
  RuntimeOptions o;
  o.precision = precision;
  o.convolution = convolution;
  o.backend = RuntimeBackend::kPortable;
  auto want = outputs(model, o, f, batch);
  ASSERT_TRUE(want.ok()) << want.error().to_string();
  o.backend = RuntimeBackend::kKernels;
  std::string name;
  auto got = outputs(model, o, f, batch, &name);
  if (!got.ok()) {
    // Only a precision this CPU's kernels lack (the portable backend emulates it).
    ASSERT_EQ(got.error().code, ErrorCode::kUnsupported) << got.error().to_string();
    std::printf("%s: %s\n", runtime_precision_name(precision), got.error().message.c_str());
    return;
  }
  o.threads = 2;
  auto two = outputs(model, o, f, batch);
  ASSERT_TRUE(two.ok()) << two.error().to_string();
  EXPECT_EQ(*two, *got) << name << ": threads 2 differ from threads 1";
  int equal = 0;
  for (std::size_t i = 0; i < got->size(); ++i) equal += (*got)[i] == (*want)[i] ? 1 : 0;
  for (int j = 0; j < 4; ++j) {
    const double d = max_difference(*got, *want, j);
    const double scale = model.meta.output_scale[static_cast<std::size_t>(j)];
    const double tolerance =
        precision == RuntimePrecision::kFloat32 ? kFloat32ToleranceMm : kReducedTolerance * scale;
    EXPECT_LE(d, tolerance) << name << " output " << j << " batch " << batch;
  }
  std::printf("%s batch %d: %d of %zu outputs equal the portable backend's, u max |d| %.2e\n",
              name.c_str(), batch, equal, got->size(), max_difference(*got, *want, 0));
}

struct IsaCase {
  std::string model;
  RuntimePrecision precision;
  RuntimeConvolution convolution;
  int batch;
};

std::string case_name(const IsaCase& c) {
  return c.model + "_" + runtime_precision_name(c.precision) + "_" +
         runtime_convolution_name(c.convolution);
}
void PrintTo(const IsaCase& c, std::ostream* os) {
  *os << case_name(c) << " batch " << c.batch;
}

class KernelsMatchPortableTest : public ::testing::TestWithParam<IsaCase> {};

TEST_P(KernelsMatchPortableTest, OnARandomModel) {
  const IsaCase& p = GetParam();
  std::printf("%s: ", p.model.c_str());
  expect_kernels_match_portable(model_for(p.model), p.precision, p.convolution, p.batch,
                                static_cast<uint32_t>(21 + static_cast<int>(p.precision)));
}

// Every precision and convolution on the full-width CNN with a small batch (it costs the most
// under emulation), the narrow one on 3x3, 4x4 and 5x5 grids (Winograd's edge tiles) with batches
// that leave partial row blocks, and an MLP. int8 and bfloat16 run direct convolutions only.
std::vector<IsaCase> isa_cases() {
  using C = RuntimeConvolution;
  std::vector<IsaCase> out;
  for (RuntimePrecision p :
       {RuntimePrecision::kFloat32, RuntimePrecision::kInt8, RuntimePrecision::kBfloat16}) {
    const bool f32 = p == RuntimePrecision::kFloat32;
    for (C c : {C::kAuto, C::kDirect, C::kWinograd}) {
      if (!f32 && c != C::kAuto) continue;
      if (c != C::kWinograd) out.push_back({"cnn", p, c, 3});
      out.push_back({"cnn_w025", p, c, 13});
      if (c != C::kDirect) {
        out.push_back({"cnn_w025_3x3", p, c, 7});
        out.push_back({"cnn_w025_5x5", p, c, 7});
      }
    }
    out.push_back({"mlp", p, C::kAuto, 33});
  }
  return out;
}

INSTANTIATE_TEST_SUITE_P(Models, KernelsMatchPortableTest, ::testing::ValuesIn(isa_cases()),
                         [](const auto& param_info) { return case_name(param_info.param); });

// The trained default model (estimators/models/), every precision.
TEST(NetworkRuntimeIsaTest, ShippedModelMatchesPortable) {
  const char* dir = std::getenv("SKINBUS_SOURCE_DIR");
  std::string source = dir != nullptr ? dir : "";
  if (source.empty()) {
    source = __FILE__;
    source = source.substr(0, source.rfind("/estimators/src/"));
  }
  Result<ModelFile> m = read_model(source + "/estimators/models/nominal_seed_cnn");
  ASSERT_TRUE(m.ok()) << m.error().to_string();
  for (RuntimePrecision p :
       {RuntimePrecision::kFloat32, RuntimePrecision::kBfloat16, RuntimePrecision::kInt8}) {
    SCOPED_TRACE(runtime_precision_name(p));
    std::printf("nominal_seed_cnn: ");
    expect_kernels_match_portable(*m, p, RuntimeConvolution::kAuto, 6, 24);
  }
}

// What the kernel backend picked, for the log; the portable cap gives the portable kernels.
TEST(NetworkRuntimeIsaTest, NamesTheKernelsInUse) {
  const ModelFile model = model_for("mlp");
  for (RuntimePrecision p :
       {RuntimePrecision::kFloat32, RuntimePrecision::kBfloat16, RuntimePrecision::kInt8}) {
    RuntimeOptions o;
    o.backend = RuntimeBackend::kKernels;
    o.precision = p;
    auto rt = NetworkRuntime::create(model, o);
    if (!rt.ok()) {
      EXPECT_EQ(rt.error().code, ErrorCode::kUnsupported);
      std::printf("kernels %s: %s\n", runtime_precision_name(p), rt.error().message.c_str());
      continue;
    }
    std::printf("kernels in use: %s\n", rt->kernel_name());
#if defined(__aarch64__)
    if (std::getenv("SKINBUS_MAX_ISA") == nullptr) {
      EXPECT_NE(std::string(rt->kernel_name()).find("neon"), std::string::npos);
    }
#endif
    o.max_isa = RuntimeIsa::kPortable;
    auto capped = NetworkRuntime::create(model, o);
    ASSERT_TRUE(capped.ok()) << capped.error().to_string();
    EXPECT_EQ(std::string(capped->kernel_name()).rfind("kernels portable", 0), 0u)
        << capped->kernel_name();
  }
}

// The oneDNN backend serves float32 where it is built (SKINBUS_ONEDNN=ON, x86 here) and is
// refused by name where it is not (the Arm build).
TEST(NetworkRuntimeIsaTest, OneDnnWhereBuiltElseRefused) {
  const ModelFile model = model_for("cnn_w025");
  RuntimeOptions o;
  o.backend = RuntimeBackend::kOneDnn;
  const std::vector<double> f = fields(5, model.meta.channels(), 25);
  auto got = outputs(model, o, f, 5);
#if SKINBUS_HAS_ONEDNN
  ASSERT_TRUE(got.ok()) << got.error().to_string();
  o.backend = RuntimeBackend::kPortable;
  auto want = outputs(model, o, f, 5);
  ASSERT_TRUE(want.ok()) << want.error().to_string();
  for (int j = 0; j < 4; ++j) EXPECT_LE(max_difference(*got, *want, j), kFloat32ToleranceMm);
#else
  ASSERT_FALSE(got.ok());
  EXPECT_EQ(got.error().code, ErrorCode::kUnsupported);
  EXPECT_NE(got.error().message.find("SKINBUS_ONEDNN"), std::string::npos) << got.error().message;
#endif
}

}  // namespace
}  // namespace skinbus::estimators
