// `skinbus-bench cpu`: the host runtime on every instruction set this CPU has, against the CPU's
// own float32 limit and LibTorch at its best, with the error on the same presses.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <deque>
#include <functional>
#include <map>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#if defined(__x86_64__)
#include <immintrin.h>
#endif

#include "skinbus/common/error_format.h"
#include "skinbus/common/plot_script.h"
#include "skinbus/common/stats.h"
#include "skinbus/estimators/evaluation.h"
#include "skinbus/estimators/model_file.h"
#include "skinbus/estimators/network_runtime.h"
#include "skinbus/estimators_bench/reports.h"
#include "skinbus/sim/dataset.h"
#include "skinbus/sim/patch_model.h"
#include "skinbus/sim/simulated_patch.h"
#ifdef SKINBUS_HAVE_TORCH
#include "skinbus/estimators/training.h"
#endif

#ifndef SKINBUS_SOURCE_DIR
#define SKINBUS_SOURCE_DIR "."
#endif

namespace skinbus::estimators_bench {
namespace {

using namespace skinbus::estimators;
using Clock = std::chrono::steady_clock;

double seconds_since(Clock::time_point t0) {
  return std::chrono::duration<double>(Clock::now() - t0).count();
}

#if defined(__x86_64__)
// 12 independent FMA chains of `Vec` (named, so they stay in registers) for about 50 ms, best of
// 5: the core's float32 multiply-add peak in GFLOP/s with that vector width.
#define SKINBUS_FMA_PEAK(NAME, ATTR, VEC, LANES, LOAD, FMA, STORE)                                 \
  ATTR double NAME() {                                                                             \
    constexpr long kIterations = 400000;                                                           \
    float init[12 * LANES], fa[LANES], fb[LANES];                                                  \
    for (int k = 0; k < 12 * LANES; ++k) init[k] = 1.0f + 1e-3f * static_cast<float>(k);           \
    for (int k = 0; k < LANES; ++k) {                                                              \
      fa[k] = 0.999999f;                                                                           \
      fb[k] = 1e-7f;                                                                               \
    }                                                                                              \
    const VEC a = LOAD(fa), b = LOAD(fb);                                                          \
    VEC c0 = LOAD(init), c1 = LOAD(init + LANES), c2 = LOAD(init + 2 * LANES),                     \
        c3 = LOAD(init + 3 * LANES), c4 = LOAD(init + 4 * LANES), c5 = LOAD(init + 5 * LANES),     \
        c6 = LOAD(init + 6 * LANES), c7 = LOAD(init + 7 * LANES), c8 = LOAD(init + 8 * LANES),     \
        c9 = LOAD(init + 9 * LANES), c10 = LOAD(init + 10 * LANES), c11 = LOAD(init + 11 * LANES); \
    double best = 0;                                                                               \
    for (int rep = 0; rep < 5; ++rep) {                                                            \
      const auto t0 = Clock::now();                                                                \
      for (long i = 0; i < kIterations; ++i) {                                                     \
        c0 = FMA(c0, a, b);                                                                        \
        c1 = FMA(c1, a, b);                                                                        \
        c2 = FMA(c2, a, b);                                                                        \
        c3 = FMA(c3, a, b);                                                                        \
        c4 = FMA(c4, a, b);                                                                        \
        c5 = FMA(c5, a, b);                                                                        \
        c6 = FMA(c6, a, b);                                                                        \
        c7 = FMA(c7, a, b);                                                                        \
        c8 = FMA(c8, a, b);                                                                        \
        c9 = FMA(c9, a, b);                                                                        \
        c10 = FMA(c10, a, b);                                                                      \
        c11 = FMA(c11, a, b);                                                                      \
      }                                                                                            \
      best = std::max(                                                                             \
          best, 2.0 * LANES * 12 * static_cast<double>(kIterations) / seconds_since(t0) * 1e-9);   \
    }                                                                                              \
    float sink = 0;                                                                                \
    for (VEC c : {c0, c1, c2, c3, c4, c5, c6, c7, c8, c9, c10, c11}) {                             \
      STORE(init, c);                                                                              \
      for (int k = 0; k < LANES; ++k) sink += init[k];                                             \
    }                                                                                              \
    if (!std::isfinite(sink)) std::fprintf(stderr, "skinbus-bench: FMA probe overflowed\n");       \
    return best;                                                                                   \
  }

// Reads `floats` (a multiple of 128) floats with `Vec` loads into 8 independent sums, again and
// again: the fastest of 100 passes after 5 unmeasured ones, in GB/s. Sized as a network's
// weights, it is the best rate at which batch 1 can stream them from wherever they settle (L2 if
// they fit, else L3).
#define SKINBUS_READ_RATE(NAME, ATTR, VEC, LANES, LOAD, ADD, ZERO, STORE)                          \
  ATTR double NAME(const float* data, std::size_t floats) {                                        \
    double best = 0;                                                                               \
    VEC s[8];                                                                                      \
    for (VEC & x : s) x = ZERO();                                                                  \
    for (int pass = 0; pass < 105; ++pass) {                                                       \
      const auto t0 = Clock::now();                                                                \
      for (std::size_t i = 0; i < floats; i += 8 * LANES) {                                        \
        for (int k = 0; k < 8; ++k) s[k] = ADD(s[k], LOAD(data + i + k * LANES));                  \
      }                                                                                            \
      const double gbps = static_cast<double>(floats) * sizeof(float) / seconds_since(t0) * 1e-9;  \
      if (pass >= 5) best = std::max(best, gbps);                                                  \
    }                                                                                              \
    float out[LANES];                                                                              \
    STORE(out, ADD(ADD(ADD(s[0], s[1]), ADD(s[2], s[3])), ADD(ADD(s[4], s[5]), ADD(s[6], s[7])))); \
    if (!std::isfinite(out[0])) std::fprintf(stderr, "skinbus-bench: read probe overflowed\n");    \
    return best;                                                                                   \
  }

SKINBUS_READ_RATE(read_rate_avx512, __attribute__((target("avx512f"))), __m512, 16, _mm512_load_ps,
                  _mm512_add_ps, _mm512_setzero_ps, _mm512_storeu_ps)
SKINBUS_READ_RATE(read_rate_avx2, __attribute__((target("avx2"))), __m256, 8, _mm256_load_ps,
                  _mm256_add_ps, _mm256_setzero_ps, _mm256_storeu_ps)
#undef SKINBUS_READ_RATE

#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wuninitialized"
SKINBUS_FMA_PEAK(fma_peak_avx512, __attribute__((target("avx512f,fma"))), __m512, 16,
                 _mm512_loadu_ps, _mm512_fmadd_ps, _mm512_storeu_ps)
SKINBUS_FMA_PEAK(fma_peak_avx2, __attribute__((target("avx2,fma"))), __m256, 8, _mm256_loadu_ps,
                 _mm256_fmadd_ps, _mm256_storeu_ps)
#pragma GCC diagnostic pop
#undef SKINBUS_FMA_PEAK
#endif

struct Row {
  std::string kernels, precision;
  RuntimeIsa isa = RuntimeIsa::kPortable;
  bool torch = false;
  double macs = 0, peak_gflops = 0;
  double batch1_us = 0, batch64_1t_us = 0, batch64_2t_us = 0;
  double xy_mean_mm = 0, xy_deep_mm = 0, depth_mean_mm = 0;
  // Each layer's multiply-adds and weight bytes, and the rate this core reads that many bytes.
  std::vector<NetworkRuntime::LayerCost> layers;
  double read_gbps = 0;
  // Microseconds for `m` multiply-adds at the FMA peak.
  double fma_us(double m) const { return 2.0 * m / (peak_gflops * 1e3); }
  // The float32 floor: 2 x the multiply-adds computed / the FMA peak (0 for other precisions).
  double floor_us() const { return peak_gflops > 0 && precision == "float32" ? fma_us(macs) : 0; }
  // The packed weights one sample reads, all layers.
  int64_t weight_bytes() const {
    int64_t bytes = 0;
    for (const NetworkRuntime::LayerCost& l : layers) bytes += l.weight_bytes;
    return bytes;
  }
  // The floor at batch 1 with the weights read too: each layer takes at least its FMA time or
  // the time to read its weights, whichever is longer (0 where floor_us() is).
  double read_floor_us() const {
    if (floor_us() <= 0 || read_gbps <= 0) return 0;
    double us = 0;
    for (const NetworkRuntime::LayerCost& l : layers) {
      us += std::fmax(fma_us(static_cast<double>(l.macs)),
                      static_cast<double>(l.weight_bytes) / (read_gbps * 1e3));
    }
    return us;
  }
};

// The rate at which this core reads `bytes` over and over with `isa`'s widest loads (0 without
// them).
double read_rate_gbps(RuntimeIsa isa, std::size_t bytes) {
#if defined(__x86_64__)
  __builtin_cpu_init();
  const std::size_t floats = (bytes / sizeof(float) + 127) / 128 * 128;
  std::unique_ptr<float, decltype(&std::free)> data(
      static_cast<float*>(std::aligned_alloc(64, floats * sizeof(float))), &std::free);
  if (data == nullptr) return 0.0;
  std::fill(data.get(), data.get() + floats, 1.0f);
  if (isa == RuntimeIsa::kAvx512 && __builtin_cpu_supports("avx512f")) {
    return read_rate_avx512(data.get(), floats);
  }
  if (isa == RuntimeIsa::kAvx2 && __builtin_cpu_supports("avx2")) {
    return read_rate_avx2(data.get(), floats);
  }
#else
  (void)isa;
  (void)bytes;
#endif
  return 0.0;
}

// printf into a std::string.
template <typename... Args>
std::string format(const char* fmt, Args... args) {
  char buf[64];
  std::snprintf(buf, sizeof buf, fmt, args...);
  return buf;
}

// One timing of a row: `fn` does `per` units (samples); each round times it once.
struct Timing {
  Timing(std::function<void()> f, int units) : fn(std::move(f)), per(units) {}
  std::function<void()> fn;
  int per = 1;
  double* out_us = nullptr;  // the median over the rounds, microseconds per unit
  std::vector<double> us;
};

// The timings of every row in rounds, each round every row's timings in turn (rows with fewer
// `reps` drop out after those), so that rows are measured under the same conditions on a machine
// whose speed moves; each result is its median. `each_round` runs before every round.
void time_interleaved(std::vector<std::vector<Timing>>& rows, const std::vector<int>& reps,
                      const std::function<void()>& each_round) {
  const int rounds = *std::max_element(reps.begin(), reps.end());
  for (int round = 0; round < rounds; ++round) {
    each_round();
    for (std::size_t r = 0; r < rows.size(); ++r) {
      if (round >= reps[r]) continue;
      for (Timing& t : rows[r]) {
        const auto t0 = Clock::now();
        t.fn();
        t.us.push_back(seconds_since(t0) * 1e6 / t.per);
      }
    }
  }
  for (auto& row : rows) {
    for (Timing& t : row) {
      std::sort(t.us.begin(), t.us.end());
      *t.out_us = t.us[t.us.size() / 2];
    }
  }
}

}  // namespace

double fma_peak_gflops(RuntimeIsa isa) {
#if defined(__x86_64__)
  __builtin_cpu_init();
  const bool fma = __builtin_cpu_supports("fma");
  if (isa == RuntimeIsa::kAvx512 && fma && __builtin_cpu_supports("avx512f")) {
    return fma_peak_avx512();
  }
  if (isa == RuntimeIsa::kAvx2 && fma && __builtin_cpu_supports("avx2")) return fma_peak_avx2();
#else
  (void)isa;
#endif
  return 0.0;
}

Status bench_cpu(const CpuBenchArgs& a) {
  const std::string model_path =
      a.model_path.empty() ? std::string(SKINBUS_SOURCE_DIR) + "/estimators/models/nominal_seed_cnn"
                           : a.model_path;
  Result<ModelFile> model = read_model(model_path);
  if (!model.ok()) {
    return model.error();
  }
  sim::Dataset test;
  if (!a.test_path.empty()) {
    Result<sim::Dataset> d = sim::read_dataset_csv(a.test_path);
    if (!d.ok()) {
      return d.error();
    }
    test = std::move(d.value());
  } else {
    std::fprintf(stderr, "skinbus-bench: simulating %d test presses on the nominal patch ...\n",
                 a.samples);
    Result<sim::PatchModel> pm = sim::PatchModel::nominal(sim::PatchDesign{});
    if (!pm.ok()) {
      return pm.error();
    }
    sim::SimulatedPatch patch(*pm, 7);
    test = sim::generate_random_test_set(patch, a.samples, 67.5, 4.0, 7);
  }
  const int channels = test.channels();
  const int n = std::min(a.samples, static_cast<int>(test.rows()));
  if (channels != model->meta.channels() || n < 64) {
    return errorf(ErrorCode::kInvalidArgument,
                  "the test set has %d channels and %d rows; the model takes %d channels and the "
                  "benchmark needs 64 rows",
                  channels, n, model->meta.channels());
  }
  const std::span<const double> field(test.field_ut.data(), static_cast<std::size_t>(n) * channels);
  const Truth truth{{test.u_mm.data(), static_cast<std::size_t>(n)},
                    {test.v_mm.data(), static_cast<std::size_t>(n)},
                    {test.depth_mm.data(), static_cast<std::size_t>(n)},
                    {test.force_n.data(), static_cast<std::size_t>(n)}};
  const int lat_n = std::min(n, a.latency_samples);
  std::vector<ContactEstimate> est(static_cast<std::size_t>(n));
  auto errors = [&](Row& r) {
    const ErrorSummary s = summarize_errors(est, truth);
    r.xy_mean_mm = s.all.xy_mean_mm;
    r.xy_deep_mm = xy_mean_from_bin(s);
    r.depth_mean_mm = s.all.depth_mean_mm;
  };

  // Every row is set up and its errors taken first; then all are timed in interleaved rounds.
  // The runtimes stay where they are (a deque) for the timings' references.
  std::vector<Row> rows;
  std::deque<NetworkRuntime> runtimes;
  std::vector<std::vector<Timing>> timings;
  std::vector<int> row_reps;
  for (RuntimeIsa isa :
       {RuntimeIsa::kAvx512, RuntimeIsa::kAvx2, RuntimeIsa::kNeon, RuntimeIsa::kPortable}) {
    const double peak = fma_peak_gflops(isa);
    for (RuntimePrecision p : {RuntimePrecision::kFloat32, RuntimePrecision::kInt8}) {
      RuntimeOptions o;
      o.backend =
          isa == RuntimeIsa::kPortable ? RuntimeBackend::kPortable : RuntimeBackend::kKernels;
      o.max_isa = isa;
      o.precision = p;
      Result<NetworkRuntime> rt1 = NetworkRuntime::create(*model, o);
      o.threads = 2;
      Result<NetworkRuntime> rt2 = NetworkRuntime::create(*model, o);
      if (!rt1.ok() || !rt2.ok()) continue;
      // The kernels fall back to a narrower set when the CPU lacks this one: each set once.
      const std::string name = rt1->kernel_name();
      if (isa != RuntimeIsa::kPortable &&
          name.find(std::string(" ") + isa_name(isa)) == std::string::npos) {
        continue;
      }
      std::fprintf(stderr, "skinbus-bench: %s ...\n", name.c_str());
      Row r;
      r.kernels = name;
      r.precision = runtime_precision_name(p);
      r.isa = isa;
      r.macs = static_cast<double>(rt1->macs());
      r.peak_gflops = peak;
      r.layers.assign(rt1->layer_costs().begin(), rt1->layer_costs().end());
      if (peak > 0 && p == RuntimePrecision::kFloat32) {
        r.read_gbps = read_rate_gbps(isa, static_cast<std::size_t>(r.weight_bytes()));
      }
      auto batched = [&field, &est, n, channels](NetworkRuntime& rt) {
        for (int b = 0; b < n; b += 64) {
          const int k = std::min(64, n - b);
          (void)rt.run(field.subspan(static_cast<std::size_t>(b) * channels,
                                     static_cast<std::size_t>(k) * channels),
                       k, {est.data() + b, static_cast<std::size_t>(k)});
        }
      };
      NetworkRuntime& one = runtimes.emplace_back(std::move(rt1).value());
      NetworkRuntime& two = runtimes.emplace_back(std::move(rt2).value());
      batched(one);  // the errors (and a first run)
      errors(r);
      rows.push_back(r);
      timings.push_back(
          {Timing{[&one, &field, &est, lat_n, channels] {
                    for (int i = 0; i < lat_n; ++i) {
                      (void)one.run(field.subspan(static_cast<std::size_t>(i) * channels, channels),
                                    1, {est.data() + i, 1});
                    }
                  },
                  lat_n},
           Timing{[&one, batched] { batched(one); }, n},
           Timing{[&two, batched] { batched(two); }, n}});
      row_reps.push_back(isa == RuntimeIsa::kPortable ? 1 : a.reps);
    }
  }
#ifdef SKINBUS_HAVE_TORCH
  std::unique_ptr<TorchRunner> torch_one, torch_64_1, torch_64_2;
  double torch_sink = 0;
  {
    std::fprintf(stderr, "skinbus-bench: LibTorch ...\n");
    Row r;
    r.kernels = "LibTorch (forward on a prepared tensor, inference mode)";
    r.precision = "float32";
    r.torch = true;
    r.macs = static_cast<double>(model->macs());
    Result<TorchRunner> t1 = TorchRunner::create(*model, 1), t2 = TorchRunner::create(*model, 2);
    if (!t1.ok() || !t2.ok()) {
      return with_context((t1.ok() ? t2.error() : t1.error()), "LibTorch");
    }
    // Its errors, through the ordinary path (untimed).
    const ModelMeta& meta = model->meta;
    std::vector<double> y(static_cast<std::size_t>(n) * meta.outputs.size());
    if (t1->run(field, n, y).ok()) {
      auto at = [&](const char* name) {
        const auto it = std::find(meta.outputs.begin(), meta.outputs.end(), name);
        return it == meta.outputs.end() ? -1 : static_cast<int>(it - meta.outputs.begin());
      };
      const int iu = at("u_mm"), iv = at("v_mm"), id = at("depth_mm"), iforce = at("force_n");
      const std::size_t no = meta.outputs.size();
      for (int i = 0; i < n; ++i) {
        const double* yi = y.data() + static_cast<std::size_t>(i) * no;
        est[static_cast<std::size_t>(i)] = {yi[iu],      yi[iv],
                                            yi[id],      iforce >= 0 ? yi[iforce] : 0.0,
                                            kEstimateOk, RejectReason::kNone};
        flag_range(est[static_cast<std::size_t>(i)], meta.half_u_mm, meta.half_v_mm,
                   meta.max_depth_mm);
      }
      errors(r);
    }
    rows.push_back(r);
    // Batch 1: one prepared sample, run lat_n times; batch 64: 64 prepared samples, n / 64 runs
    // (LibTorch at its best: no conversion). A runner holds one prepared input, so the batch-1
    // timings use a runner of their own.
    Result<TorchRunner> t1_batch1 = TorchRunner::create(*model, 1);
    if (!t1_batch1.ok()) return with_context(t1_batch1.error(), "LibTorch");
    torch_one = std::make_unique<TorchRunner>(std::move(t1_batch1).value());
    torch_64_1 = std::make_unique<TorchRunner>(std::move(t1).value());
    torch_64_2 = std::make_unique<TorchRunner>(std::move(t2).value());
    (void)torch_one->prepare(field.subspan(0, channels), 1);
    (void)torch_64_1->prepare(field.subspan(0, static_cast<std::size_t>(64) * channels), 64);
    (void)torch_64_2->prepare(field.subspan(0, static_cast<std::size_t>(64) * channels), 64);
    const int calls = n / 64;
    auto forward = [&torch_sink](TorchRunner& tr, int times) {
      for (int i = 0; i < times; ++i) torch_sink += tr.forward_prepared();
    };
    timings.push_back(
        {Timing{[forward, &torch_one, lat_n] { forward(*torch_one, lat_n); }, lat_n},
         Timing{[forward, &torch_64_1, calls] { forward(*torch_64_1, calls); }, calls * 64},
         Timing{[forward, &torch_64_2, calls] { forward(*torch_64_2, calls); }, calls * 64}});
    row_reps.push_back(a.reps);
  }
#endif
  for (std::size_t i = 0; i < rows.size(); ++i) {
    timings[i][0].out_us = &rows[i].batch1_us;
    timings[i][1].out_us = &rows[i].batch64_1t_us;
    timings[i][2].out_us = &rows[i].batch64_2t_us;
  }
  std::fprintf(stderr, "skinbus-bench: timing %zu rows in %d interleaved rounds ...\n", rows.size(),
               *std::max_element(row_reps.begin(), row_reps.end()));
  // The FMA peak and the read rate are measured again before every round and the best kept: a
  // limit measured once could meet a loud moment of a shared machine and flatter every ratio to it.
  auto remeasure_limits = [&rows] {
    std::map<RuntimeIsa, double> peaks;  // one measurement of each set a round
    for (Row& r : rows) {
      if (!(r.peak_gflops > 0)) continue;
      if (!peaks.contains(r.isa)) peaks[r.isa] = fma_peak_gflops(r.isa);
      r.peak_gflops = std::max(r.peak_gflops, peaks[r.isa]);
      if (r.read_gbps > 0) {
        r.read_gbps = std::max(r.read_gbps,
                               read_rate_gbps(r.isa, static_cast<std::size_t>(r.weight_bytes())));
      }
    }
  };
  time_interleaved(timings, row_reps, remeasure_limits);
#ifdef SKINBUS_HAVE_TORCH
  if (!std::isfinite(torch_sink)) std::fprintf(stderr, "skinbus-bench: LibTorch returned NaN\n");
#endif

  // The table.
  std::printf("Model: %s (%.2f M multiply-adds per sample as defined). Test presses: %d (%s).\n",
              model->meta.name.c_str(), static_cast<double>(model->macs()) * 1e-6, n,
              a.test_path.empty() ? "simulated, nominal patch, seed 7" : a.test_path.c_str());
  std::printf(
      "Floor: 2 x multiply-adds the kernels compute / the FMA peak measured here with "
      "that vector width, one core. Read floor: per layer the longer of its FMA time and the "
      "time to read its weights at the rate measured here for the network's weight bytes, "
      "summed (at batch 1 every sample reads every weight). The peak and the read rate are the "
      "best of a measurement before the timings and one before each of their rounds.\n\n");
  std::printf(
      "| kernels | precision | FMA peak (GFLOP/s) | floor (µs) | batch 1 (µs) | x floor | "
      "weights (MB) | read (GB/s) | read floor (µs) | x read floor | "
      "batch 64, 1 thread (µs/sample) | batch 64, 2 threads (µs/sample) | XY mean (mm) "
      "| XY >= 1 mm (mm) | depth mean (mm) |\n|---|---|---:|---:|---:|---:|---:|---:|---:|---:|"
      "---:|---:|---:|---:|---:|\n");
  for (const Row& r : rows) {
    const int64_t bytes = r.weight_bytes();
    const double rf = r.read_floor_us();
    std::printf(
        "| %s | %s | %s | %s | %.1f | %s | %s | %s | %s | %s | %.1f | %.1f | %.3f | %.3f | "
        "%.3f |\n",
        r.kernels.c_str(), r.precision.c_str(),
        r.peak_gflops > 0 ? std::to_string(static_cast<int>(r.peak_gflops)).c_str() : "",
        r.floor_us() > 0 ? format("%.1f", r.floor_us()).c_str() : "", r.batch1_us,
        r.floor_us() > 0 ? format("%.2f", r.batch1_us / r.floor_us()).c_str() : "",
        bytes > 0 ? format("%.2f", static_cast<double>(bytes) * 1e-6).c_str() : "",
        r.read_gbps > 0 ? format("%.0f", r.read_gbps).c_str() : "",
        rf > 0 ? format("%.1f", rf).c_str() : "",
        rf > 0 ? format("%.2f", r.batch1_us / rf).c_str() : "", r.batch64_1t_us, r.batch64_2t_us,
        r.xy_mean_mm, r.xy_deep_mm, r.depth_mean_mm);
  }
  // Goals, per instruction set.
  const Row* torch = nullptr;
  for (const Row& r : rows) {
    if (r.torch) torch = &r;
  }
  std::printf("\nGoals (issue: fast and correct on the CPUs robots carry):\n");
  for (const Row& f : rows) {
    if (f.torch || f.precision != "float32" || f.isa == RuntimeIsa::kPortable) continue;
    std::printf("- %s:\n", f.kernels.c_str());
    if (f.peak_gflops > 0) {
      const double x = f.batch1_us / f.floor_us();
      std::printf("  - float32 batch 1 within 1.3x of the floor: %.2fx, %s\n", x,
                  x <= 1.3 ? "met" : "NOT met");
      if (f.read_floor_us() > 0) {
        std::printf(
            "    (reading the weights too, batch 1 can be no faster than %.1f us = %.2fx the "
            "floor; it runs at %.2fx that)\n",
            f.read_floor_us(), f.read_floor_us() / f.floor_us(), f.batch1_us / f.read_floor_us());
      }
    }
    for (const Row& q : rows) {
      if (q.isa != f.isa || q.precision != "int8") continue;
      const double s1 = f.batch1_us / q.batch1_us, s64 = f.batch64_1t_us / q.batch64_1t_us;
      const double dxy = (q.xy_mean_mm - f.xy_mean_mm) / f.xy_mean_mm * 100;
      std::printf(
          "  - int8 >= 1.8x float32 within 2 %% XY: %.2fx at batch 1, %.2fx at batch 64 "
          "(1 thread), XY %+.2f %%: %s\n",
          s1, s64, dxy, s1 >= 1.8 && s64 >= 1.8 && std::fabs(dxy) <= 2 ? "met" : "NOT met");
      if (torch != nullptr) {
        const double t = torch->batch1_us / q.batch1_us;
        std::printf("  - int8 vs LibTorch at its best, batch 1: %.1fx\n", t);
      }
    }
    if (torch != nullptr) {
      const double t = torch->batch1_us / f.batch1_us;
      std::printf("  - >= 3x faster than LibTorch at its best at batch 1 (float32): %.1fx, %s\n", t,
                  t >= 3 ? "met" : "NOT met");
    }
  }
  if (!a.csv.empty()) {
    std::FILE* f = std::fopen(a.csv.c_str(), "w");
    if (f == nullptr) {
      return errorf(ErrorCode::kIo, "cannot write %s", a.csv.c_str());
    }
    std::fprintf(f,
                 "kernels,precision,isa,fma_peak_gflops,floor_us,batch1_us,weight_bytes,"
                 "read_gbps,read_floor_us,batch64_1t_us,batch64_2t_us,xy_mean_mm,xy_deep_mm,"
                 "depth_mean_mm\n");
    for (const Row& r : rows) {
      std::fprintf(f, "\"%s\",%s,%s,%.1f,%.2f,%.2f,%lld,%.1f,%.2f,%.2f,%.2f,%.4f,%.4f,%.4f\n",
                   r.kernels.c_str(), r.precision.c_str(), r.torch ? "libtorch" : isa_name(r.isa),
                   r.peak_gflops, r.floor_us(), r.batch1_us,
                   static_cast<long long>(r.weight_bytes()), r.read_gbps, r.read_floor_us(),
                   r.batch64_1t_us, r.batch64_2t_us, r.xy_mean_mm, r.xy_deep_mm, r.depth_mean_mm);
    }
    if (std::fclose(f) != 0) {
      return errorf(ErrorCode::kIo, "cannot write %s", a.csv.c_str());
    }
    if (!a.plot.empty()) {
      if (Status s = run_plot_script(SKINBUS_SOURCE_DIR "/tools", "plot_cpu.py", {a.csv, a.plot});
          !s.ok()) {
        return s;
      }
    }
  }
  return Status::Ok();
}

}  // namespace skinbus::estimators_bench
