// The host network runtime against LibTorch: batch 1 on one thread, batch 64 on one and two
// threads, for every backend and precision, the seed CNN at widths 1, 0.5, 0.25, 0.125 and an
// MLP 48-256-256-4. Results and the command line: docs/benchmarks/runtime.md.
//
// Arguments of every benchmark: model (0..3: CNN width 1, 0.5, 0.25, 0.125; 4: MLP), batch,
// threads. The per_sample counter is the wall time of one sample (batch time / batch).
#include <benchmark/benchmark.h>
#include <dlfcn.h>

#include <map>
#include <memory>
#include <random>
#include <vector>

#include "skinbus/fusion/network_runtime.h"
#include "skinbus/fusion/training.h"

namespace skinbus::fusion {
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

void runtime(benchmark::State& state, RuntimeBackend backend, RuntimePrecision precision) {
  const int which = static_cast<int>(state.range(0));
  const int batch = static_cast<int>(state.range(1));
  RuntimeOptions o;
  o.backend = backend;
  o.precision = precision;
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

// torch_forward builds the LibTorch module and copies the weights on every call; that fixed
// cost is included (see the report).
void torch(benchmark::State& state) {
  const int which = static_cast<int>(state.range(0));
  const int batch = static_cast<int>(state.range(1));
  const int threads = static_cast<int>(state.range(2));
  using SetThreads = void (*)(int);
  if (auto set = reinterpret_cast<SetThreads>(dlsym(RTLD_DEFAULT, "openblas_set_num_threads"))) {
    set(threads);
  }
  const std::vector<double> f = fields(batch);
  for (auto _ : state) {
    auto y = torch_forward(model(which), f, batch, threads);
    if (!y.ok()) {
      state.SkipWithError(y.error().to_string().c_str());
      return;
    }
    benchmark::DoNotOptimize(y->data());
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
BENCHMARK_CAPTURE(runtime, kernels_bf16, RuntimeBackend::kKernels, RuntimePrecision::kBfloat16)
    ->Apply(args);
BENCHMARK_CAPTURE(runtime, onednn_f32, RuntimeBackend::kOneDnn, RuntimePrecision::kFloat32)
    ->Apply(args);
BENCHMARK_CAPTURE(runtime, portable_f32, RuntimeBackend::kPortable, RuntimePrecision::kFloat32)
    ->Apply(args);
BENCHMARK(torch)->Apply(args);

}  // namespace
}  // namespace skinbus::fusion

BENCHMARK_MAIN();
