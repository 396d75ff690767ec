// The host network runtime against LibTorch: batch 1 on one thread, batch 64 on one and two
// threads, for every backend and precision (float32 on the kernels also with direct convolutions
// where the default is Winograd), the seed CNN at widths 1, 0.5, 0.25, 0.125 and an
// MLP 48-256-256-4. Results and the command line: docs/benchmarks/runtime.md.
//
// Arguments of every benchmark: model (0..3: CNN width 1, 0.5, 0.25, 0.125; 4: MLP), batch,
// threads. The per_sample counter is the wall time of one sample (batch time / batch).
//
// Accuracy of the reduced precisions on a trained model instead of timings:
//   estimators_network_benchmark --accuracy_model=<model> --accuracy_data=<dataset.csv>
// prints the XY, depth and force errors against the dataset's truth (evaluation.h, per depth bin)
// for float32, bfloat16 and int8, and how far each moves the outputs from float32.
#include <benchmark/benchmark.h>
#include <dlfcn.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <map>
#include <memory>
#include <random>
#include <string>
#include <vector>

#include "skinbus/estimators/evaluation.h"
#include "skinbus/estimators/network_runtime.h"
#include "skinbus/estimators/training.h"
#include "skinbus/sim/dataset.h"

namespace skinbus::estimators {
namespace {

constexpr int kSensors = 16;
constexpr int kChannels = 3 * kSensors;
constexpr double kWidths[] = {1.0, 0.5, 0.25, 0.125};

const ModelFile& model(int which) {
  static std::map<int, ModelFile> cache;
  auto it = cache.find(which);
  if (it == cache.end()) {
    const Architecture a = which < 4 ? seed_cnn(kWidths[which], 4, 4) : mlp({256, 256});
    auto m = random_model(a, kSensors, 3);
    if (!m.ok()) std::abort();
    it = cache.emplace(which, std::move(m.value())).first;
  }
  return it->second;
}

std::vector<double> fields(int batch) {
  std::mt19937 rng(1);
  std::uniform_real_distribution<double> u(-250.0, 250.0);
  std::vector<double> f(static_cast<std::size_t>(batch) * kChannels);
  for (double& v : f) v = u(rng);
  return f;
}

void set_counters(benchmark::State& state, int batch) {
  state.counters["per_sample"] = benchmark::Counter(
      batch, benchmark::Counter::kIsIterationInvariantRate | benchmark::Counter::kInvert);
}

void runtime(benchmark::State& state, RuntimeBackend backend, RuntimePrecision precision,
             RuntimeConvolution convolution = RuntimeConvolution::kAuto) {
  const int which = static_cast<int>(state.range(0));
  const int batch = static_cast<int>(state.range(1));
  RuntimeOptions o;
  o.backend = backend;
  o.precision = precision;
  o.convolution = convolution;
  o.threads = static_cast<int>(state.range(2));
  auto rt = NetworkRuntime::create(model(which), o);
  if (!rt.ok()) {
    state.SkipWithError(rt.error().to_string().c_str());
    return;
  }
  const std::vector<double> f = fields(batch);
  std::vector<ContactEstimate> out(static_cast<std::size_t>(batch));
  for (auto _ : state) {
    Status st = rt->run(f, batch, out);
    benchmark::DoNotOptimize(st);
    benchmark::DoNotOptimize(out.data());
  }
  state.SetLabel(rt->kernel_name());
  set_counters(state, batch);
}

// LibTorch at its best: a persistent module, the input tensor prepared once, and only the layers
// timed under inference mode (TorchRunner::prepare / forward_prepared), one LibTorch thread pool.
void torch(benchmark::State& state) {
  const int which = static_cast<int>(state.range(0));
  const int batch = static_cast<int>(state.range(1));
  const int threads = static_cast<int>(state.range(2));
  using SetThreads = void (*)(int);
  if (auto set = reinterpret_cast<SetThreads>(dlsym(RTLD_DEFAULT, "openblas_set_num_threads"))) {
    set(threads);
  }
  Result<TorchRunner> runner = TorchRunner::create(model(which), threads);
  if (!runner.ok() || !runner->prepare(fields(batch), batch).ok()) {
    state.SkipWithError("LibTorch could not run the model");
    return;
  }
  for (auto _ : state) {
    const double y = runner->forward_prepared();
    benchmark::DoNotOptimize(y);
  }
  set_counters(state, batch);
}

void args(benchmark::internal::Benchmark* b) {
  for (int which = 0; which < 5; ++which) {
    b->Args({which, 1, 1});
    b->Args({which, 64, 1});
    b->Args({which, 64, 2});
  }
  b->ArgNames({"model", "batch", "threads"})->UseRealTime()->Unit(benchmark::kMicrosecond);
}

BENCHMARK_CAPTURE(runtime, kernels_f32, RuntimeBackend::kKernels, RuntimePrecision::kFloat32)
    ->Apply(args);
BENCHMARK_CAPTURE(runtime, kernels_f32_direct, RuntimeBackend::kKernels, RuntimePrecision::kFloat32,
                  RuntimeConvolution::kDirect)
    ->Apply(args);
BENCHMARK_CAPTURE(runtime, kernels_bf16, RuntimeBackend::kKernels, RuntimePrecision::kBfloat16)
    ->Apply(args);
BENCHMARK_CAPTURE(runtime, kernels_int8, RuntimeBackend::kKernels, RuntimePrecision::kInt8)
    ->Apply(args);
BENCHMARK_CAPTURE(runtime, onednn_f32, RuntimeBackend::kOneDnn, RuntimePrecision::kFloat32)
    ->Apply(args);
BENCHMARK_CAPTURE(runtime, portable_f32, RuntimeBackend::kPortable, RuntimePrecision::kFloat32)
    ->Apply(args);
BENCHMARK(torch)->Apply(args);

int accuracy(const std::string& model_path, const std::string& data_path) {
  Result<ModelFile> m = read_model(model_path);
  if (!m.ok()) {
    std::fprintf(stderr, "%s\n", m.error().to_string().c_str());
    return 2;
  }
  Result<sim::Dataset> d = sim::read_dataset_csv(data_path);
  if (!d.ok()) {
    std::fprintf(stderr, "%s\n", d.error().to_string().c_str());
    return 2;
  }
  const sim::Dataset& data = *d;
  if (data.channels() != m->meta.channels()) {
    std::fprintf(stderr, "model has %d channels, the dataset %d\n", m->meta.channels(),
                 data.channels());
    return 2;
  }
  const int rows = static_cast<int>(data.rows());
  const Truth truth{data.u_mm, data.v_mm, data.depth_mm, data.force_n};
  std::printf("model %s, %d samples of %s\n", model_path.c_str(), rows, data_path.c_str());
  std::printf("%-9s %-26s %8s %8s", "precision", "kernels", "XY mean", "XY p95");
  for (int b = 0; b < kDepthBins; ++b) std::printf(" %8s", ("XY " + depth_bin_name(b)).c_str());
  std::printf(" %8s %8s %9s %9s\n", "depth", "force", "dXY mean", "dXY max");
  std::vector<ContactEstimate> ref;
  double ref_xy = 0;
  for (RuntimePrecision p :
       {RuntimePrecision::kFloat32, RuntimePrecision::kBfloat16, RuntimePrecision::kInt8}) {
    RuntimeOptions o;
    o.precision = p;
    auto rt = NetworkRuntime::create(*m, o);
    if (!rt.ok()) {
      std::printf("%-9s %s\n", runtime_precision_name(p), rt.error().to_string().c_str());
      continue;
    }
    std::vector<ContactEstimate> est(static_cast<std::size_t>(rows));
    constexpr int kBatch = 64;
    for (int b = 0; b < rows; b += kBatch) {
      const int k = std::min(kBatch, rows - b);
      const std::size_t ch = static_cast<std::size_t>(data.channels());
      Status st =
          rt->run({data.field(static_cast<std::size_t>(b)), static_cast<std::size_t>(k) * ch}, k,
                  {est.data() + b, static_cast<std::size_t>(k)});
      if (!st.ok()) {
        std::fprintf(stderr, "%s\n", st.error().to_string().c_str());
        return 2;
      }
    }
    const ErrorSummary e = summarize_errors(est, truth);
    if (ref.empty()) {
      ref = est;
      ref_xy = e.all.xy_mean_mm;
    }
    double dsum = 0, dmax = 0;
    int n = 0;
    for (std::size_t i = 0; i < est.size(); ++i) {
      if (!est[i].valid() || !ref[i].valid()) continue;
      const double dxy = std::hypot(est[i].u_mm - ref[i].u_mm, est[i].v_mm - ref[i].v_mm);
      dsum += dxy;
      dmax = std::max(dmax, dxy);
      ++n;
    }
    std::printf("%-9s %-26s %8.4f %8.4f", runtime_precision_name(p), rt->kernel_name(),
                e.all.xy_mean_mm, e.all.xy_p95_mm);
    for (int b = 0; b < kDepthBins; ++b) {
      std::printf(" %8.4f", e.bins[static_cast<std::size_t>(b)].xy_mean_mm);
    }
    std::printf(" %8.4f %8.4f %9.4f %9.4f   XY mean %+.2f %% of float32\n", e.all.depth_mean_mm,
                e.all.force_mean_n, n > 0 ? dsum / n : 0.0, dmax,
                100.0 * (e.all.xy_mean_mm / ref_xy - 1.0));
  }
  return 0;
}

}  // namespace
}  // namespace skinbus::estimators

int main(int argc, char** argv) {
  std::string model_path, data_path;
  int kept = 1;
  for (int i = 1; i < argc; ++i) {
    const char* a = argv[i];
    if (std::strncmp(a, "--accuracy_model=", 17) == 0) {
      model_path = a + 17;
    } else if (std::strncmp(a, "--accuracy_data=", 16) == 0) {
      data_path = a + 16;
    } else {
      argv[kept++] = argv[i];
    }
  }
  if (!model_path.empty() || !data_path.empty()) {
    if (model_path.empty() || data_path.empty()) {
      std::fprintf(stderr, "--accuracy_model and --accuracy_data go together\n");
      return 2;
    }
    return skinbus::estimators::accuracy(model_path, data_path);
  }
  argc = kept;
  benchmark::Initialize(&argc, argv);
  if (benchmark::ReportUnrecognizedArguments(argc, argv)) return 1;
  benchmark::RunSpecifiedBenchmarks();
  benchmark::Shutdown();
  return 0;
}
