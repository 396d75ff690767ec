#include "skinbus/common/error_format.h"
#include "skinbus/common/plot_script.h"
#include "skinbus/common/stats.h"
#include "skinbus/estimators_bench/reports.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <functional>
#include <memory>
#include <thread>

#include "skinbus/estimators/evaluation.h"
#include "skinbus/estimators/lookup_estimator.h"
#include "skinbus/estimators/network_runtime.h"
#include "skinbus/estimators/physics_estimator.h"
#include "skinbus/mlx90393/measurement.h"
#include "skinbus/sim/crlb.h"
#include "skinbus/sim/dataset.h"
#include "skinbus/sim/design_file.h"
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

// One estimator as the benchmark drives it: `run` estimates rows [begin, end) of the test set
// in batches of `batch` on `threads` threads.
struct Candidate {
  std::string name, kind;
  double macs = 0;  // multiply-adds per sample (networks), 0 otherwise
  std::function<void(int begin, int end, int batch, int threads, ContactEstimate* out)> run;
  // When set, the times come from this instead of `run` (µs per sample over `n` samples in
  // batches of `batch` on `threads`): for LibTorch at its best, whose estimates still come from
  // `run`.
  std::function<double(int n, int batch, int threads)> time_us;
};

struct Measured {
  std::string name, kind;
  double macs = 0;
  double batch1_us = 0, batch64_1t_us = 0, batch64_2t_us = 0;
  ErrorSummary errors;
  std::vector<ContactEstimate> estimates;
};

// The machine's float32 multiply-add peak on one core, GFLOP/s, with the widest vectors it has
// (report_cpu.cc). Printed before and after the estimators, so a table from a loaded or slower
// machine says so: a network's float32 floor is 2 x MACs / this peak.
double best_fma_peak_gflops() {
  const double avx512 = fma_peak_gflops(RuntimeIsa::kAvx512);
  return avx512 > 0 ? avx512 : fma_peak_gflops(RuntimeIsa::kAvx2);
}

// Marks `k` estimates rejected (a batch the estimator refused as a whole).
void reject(ContactEstimate* out, int k) {
  for (int i = 0; i < k; ++i) out[i] = {0, 0, 0, 0, kEstimateRejected, RejectReason::kWrongShape};
}

double seconds_since(Clock::time_point t0) {
  return std::chrono::duration<double>(Clock::now() - t0).count();
}

// Median over 3 repetitions of the time per sample (µs) of run(0, n, batch, threads).
double time_per_sample_us(const Candidate& c, int n, int batch, int threads,
                          std::vector<ContactEstimate>& out) {
  std::vector<double> reps;
  for (int r = 0; r < 3; ++r) {
    const auto t0 = Clock::now();
    c.run(0, n, batch, threads, out.data());
    reps.push_back(seconds_since(t0) * 1e6 / n);
  }
  return quantile(reps, 0.5);
}

// Splits [begin, end) over `threads` std::threads (for estimators without their own pool).
void split_threads(int begin, int end, int threads, const std::function<void(int, int)>& work) {
  if (threads <= 1) {
    work(begin, end);
    return;
  }
  std::vector<std::thread> pool;
  const int per = (end - begin + threads - 1) / threads;
  for (int t = 0; t < threads; ++t) {
    const int b = begin + t * per, e = std::min(end, b + per);
    if (b < e) pool.emplace_back(work, b, e);
  }
  for (std::thread& th : pool) th.join();
}

void write_table(const std::vector<Measured>& rows, const std::array<double, kDepthBins>& crlb,
                 FILE* f) {
  std::fprintf(f,
               "| estimator | kind | batch 1, 1 thread (µs) | batch 64, 1 thread (µs/sample) | "
               "batch 64, 2 threads (µs/sample) | XY mean (mm) | XY p95 (mm) |");
  for (int b = 0; b < kDepthBins; ++b) {
    std::fprintf(f, " XY %s mm (x CRLB) |", depth_bin_name(b).c_str());
  }
  std::fprintf(
      f, " depth mean (mm) | force mean (N) | rejected |\n|---|---|---:|---:|---:|---:|---:|");
  for (int b = 0; b < kDepthBins; ++b) std::fprintf(f, "---:|");
  std::fprintf(f, "---:|---:|---:|\n");
  for (const Measured& m : rows) {
    std::fprintf(f, "| %s | %s | %.1f | %.1f | %.1f | %.3f | %.3f |", m.name.c_str(),
                 m.kind.c_str(), m.batch1_us, m.batch64_1t_us, m.batch64_2t_us,
                 m.errors.all.xy_mean_mm, m.errors.all.xy_p95_mm);
    for (int b = 0; b < kDepthBins; ++b) {
      const ErrorStats& s = m.errors.bins[static_cast<std::size_t>(b)];
      std::fprintf(f, " %.3f (%.2f) |", s.xy_mean_mm,
                   crlb[static_cast<std::size_t>(b)] > 0
                       ? s.xy_mean_mm / crlb[static_cast<std::size_t>(b)]
                       : 0.0);
    }
    std::fprintf(f, " %.3f | %.3f | %d |\n", m.errors.all.depth_mean_mm, m.errors.all.force_mean_n,
                 m.errors.all.rejected);
  }
  std::fprintf(f, "| CRLB (RMS XY bound, mean over the test presses) | bound | | | | | |");
  for (int b = 0; b < kDepthBins; ++b)
    std::fprintf(f, " %.3f |", crlb[static_cast<std::size_t>(b)]);
  std::fprintf(f, " | | |\n");
}

// Per depth bin: XY p95, depth and force mean errors (the first table has the XY means).
void write_bin_table(const std::vector<Measured>& rows, FILE* f) {
  std::fprintf(f, "| estimator |");
  for (int b = 0; b < kDepthBins; ++b) {
    std::fprintf(f, " %s mm: XY p95 / depth / force |", depth_bin_name(b).c_str());
  }
  std::fprintf(f, "\n|---|");
  for (int b = 0; b < kDepthBins; ++b) std::fprintf(f, "---:|");
  std::fprintf(f, "\n");
  for (const Measured& m : rows) {
    std::fprintf(f, "| %s |", m.name.c_str());
    for (int b = 0; b < kDepthBins; ++b) {
      const ErrorStats& s = m.errors.bins[static_cast<std::size_t>(b)];
      std::fprintf(f, " %.2f mm / %.3f mm / %.3f N |", s.xy_p95_mm, s.depth_mean_mm,
                   s.force_mean_n);
    }
    std::fprintf(f, "\n");
  }
}

}  // namespace

std::vector<sim::CrlbPoint> crlb_points_per_row(const sim::PatchModel& model,
                                                const sim::Dataset& data, int n) {
  const mlx90393::Config& cfg = model.design().sensor_config;
  const double nxy = sim::mlx90393_noise_xy_ut(cfg), nz = sim::mlx90393_noise_z_ut(cfg);
  // The tip the presses were made with: the recording's, else the design's indenter.
  const Result<double> tip = sim::presses_tip_radius_mm(data, model.design());
  if (!tip.ok()) {
    std::fprintf(stderr, "skinbus-bench: %s; the bound takes the design's indenter\n",
                 tip.error().message.c_str());
  }
  const double tip_mm = tip.ok() ? *tip : model.design().indenter_tip_radius_mm;
  std::vector<sim::CrlbPoint> out(static_cast<std::size_t>(n));
  for (int r = 0; r < n; ++r) {
    const sim::Contact c{data.u_mm[r], data.v_mm[r], data.depth_mm[r], tip_mm};
    out[static_cast<std::size_t>(r)] = sim::crlb_at(model, c, nxy, nz);
  }
  return out;
}

std::vector<double> crlb_per_row(const sim::PatchModel& model, const sim::Dataset& data, int n) {
  std::vector<double> out;
  for (const sim::CrlbPoint& p : crlb_points_per_row(model, data, n)) out.push_back(p.sd_xy_mm);
  return out;
}

std::array<double, kDepthBins> mean_per_bin(std::span<const double> values,
                                            std::span<const double> depth_mm) {
  std::array<double, kDepthBins> sum{};
  std::array<int, kDepthBins> count{};
  for (std::size_t r = 0; r < values.size(); ++r) {
    const int b = depth_bin(depth_mm[r]);
    if (b < 0) continue;
    sum[static_cast<std::size_t>(b)] += values[r];
    ++count[static_cast<std::size_t>(b)];
  }
  for (std::size_t b = 0; b < sum.size(); ++b) {
    if (count[b] > 0) sum[b] /= count[b];
  }
  return sum;
}

Status bench_models(const ModelsBenchArgs& a) {
  if (!a.plot.empty() && (a.csv.empty() || a.errors_csv.empty())) {
    return make_error(ErrorCode::kInvalidArgument, "--plot needs --csv and --errors-csv");
  }
  Result<sim::Dataset> test_r = sim::read_dataset_csv(a.test_path);
  if (!test_r.ok()) {
    return test_r.error();
  }
  sim::Dataset& test = test_r.value();
  const int n =
      static_cast<int>(std::min<std::size_t>(test.rows(), static_cast<std::size_t>(a.max_test)));
  const int channels = test.channels();
  Result<sim::PatchDesign> design_r = sim::read_design_or_builtin(a.design_path);
  if (!design_r.ok()) return design_r.error();
  const sim::PatchDesign& design = design_r.value();
  Result<sim::PatchModel> nominal = sim::PatchModel::nominal(design);
  if (!nominal.ok() || nominal->channel_count() != channels) {
    return errorf(ErrorCode::kInvalidArgument,
                  "the test split does not have the nominal patch's %d channels (its design: "
                  "--design)",
                  nominal.ok() ? nominal->channel_count() : 0);
  }
  const double nxy = sim::mlx90393_noise_xy_ut(design.sensor_config);
  const double nz = sim::mlx90393_noise_z_ut(design.sensor_config);
  const std::vector<double> crlb_rows = crlb_per_row(*nominal, test, n);
  const std::array<double, kDepthBins> crlb =
      mean_per_bin(crlb_rows, {test.depth_mm.data(), static_cast<std::size_t>(n)});

  std::vector<Candidate> candidates;
  // Keep what the candidates point to alive for the whole run.
  std::vector<std::shared_ptr<void>> keep;
  const double* field = test.field_ut.data();
  const ModelFile* reference = nullptr;
  std::vector<ModelFile> models;
  models.reserve(a.model_paths.size());
  for (const std::string& path : a.model_paths) {
    Result<ModelFile> m = read_model(path);
    if (!m.ok()) {
      return m.error();
    }
    models.push_back(std::move(m.value()));
  }
  for (const ModelFile& m : models) {
    if (m.meta.channels() != channels) {
      return errorf(ErrorCode::kInvalidArgument, "model %s has %d channels, the test split %d",
                    m.meta.name.c_str(), m.meta.channels(), channels);
    }
    const bool cnn = m.meta.architecture.kind == ArchitectureKind::kCnn;
    if (a.reference_path.empty() && cnn && m.meta.architecture.width == 1.0 &&
        reference == nullptr) {
      reference = &m;
    }
    // The default runtime, then, for a CNN, float32 with direct convolutions (the measurement
    // behind the default's choice of Winograd), then the reduced precisions.
    struct Variant {
      RuntimePrecision precision;
      RuntimeConvolution convolution;
    };
    std::vector<Variant> variants = {{RuntimePrecision::kFloat32, RuntimeConvolution::kAuto}};
    if (cnn) variants.push_back({RuntimePrecision::kFloat32, RuntimeConvolution::kDirect});
    if (a.reduced) {
      variants.push_back({RuntimePrecision::kBfloat16, RuntimeConvolution::kAuto});
      variants.push_back({RuntimePrecision::kInt8, RuntimeConvolution::kAuto});
    }
    RuntimeConvolution default_convolution = RuntimeConvolution::kDirect;
    for (const auto [p, conv] : variants) {
      auto rts = std::make_shared<std::array<std::unique_ptr<NetworkRuntime>, 2>>();
      bool ok = true;
      for (int t = 1; t <= 2; ++t) {
        RuntimeOptions o;
        o.precision = p;
        o.convolution = conv;
        o.threads = t;
        Result<NetworkRuntime> rt = NetworkRuntime::create(m, o);
        if (!rt.ok()) {
          std::fprintf(stderr, "skinbus-bench: %s %s: %s (row left out)\n", m.meta.name.c_str(),
                       runtime_precision_name(p), rt.error().to_string().c_str());
          ok = false;
          break;
        }
        (*rts)[static_cast<std::size_t>(t - 1)] =
            std::make_unique<NetworkRuntime>(std::move(rt.value()));
      }
      if (!ok) continue;
      // Direct convolutions are a row of their own only where the default is not direct.
      if (conv == RuntimeConvolution::kAuto && p == RuntimePrecision::kFloat32) {
        default_convolution = (*rts)[0]->convolution();
      } else if (conv == RuntimeConvolution::kDirect &&
                 default_convolution == RuntimeConvolution::kDirect) {
        continue;
      }
      keep.push_back(rts);
      Candidate c;
      c.name = m.meta.name + (p == RuntimePrecision::kFloat32
                                  ? std::string()
                                  : std::string(" ") + runtime_precision_name(p));
      if (conv == RuntimeConvolution::kDirect) c.name += " direct";
      c.kind = std::string("runtime ") + (*rts)[0]->kernel_name();
      c.macs = static_cast<double>((*rts)[0]->macs());
      c.run = [rts, field, channels](int begin, int end, int batch, int threads,
                                     ContactEstimate* out) {
        NetworkRuntime& rt = *(*rts)[static_cast<std::size_t>(std::clamp(threads, 1, 2) - 1)];
        for (int b = begin; b < end; b += batch) {
          const int k = std::min(batch, end - b);
          const Status s = rt.run({field + static_cast<std::size_t>(b) * channels,
                                   static_cast<std::size_t>(k) * channels},
                                  k, {out + b, static_cast<std::size_t>(k)});
          if (!s.ok()) reject(out + b, k);
        }
      };
      candidates.push_back(std::move(c));
    }
  }
#ifdef SKINBUS_HAVE_TORCH
  if (!a.reference_path.empty()) {
    Result<ModelFile> m = read_model(a.reference_path);
    if (!m.ok()) {
      return m.error();
    }
    models.push_back(std::move(m.value()));
    reference = &models.back();
  }
  if (reference != nullptr) {
    auto runners = std::make_shared<std::array<std::unique_ptr<TorchRunner>, 2>>();
    for (int t = 1; t <= 2; ++t) {
      Result<TorchRunner> r = TorchRunner::create(*reference, t);
      if (!r.ok()) {
        return with_context(r.error(), "LibTorch");
      }
      (*runners)[static_cast<std::size_t>(t - 1)] =
          std::make_unique<TorchRunner>(std::move(r.value()));
    }
    keep.push_back(runners);
    const ModelMeta meta = reference->meta;
    // The reference's outputs by name (the runtime reads them the same way).
    const auto index_of = [&](const char* name) {
      const auto it = std::find(meta.outputs.begin(), meta.outputs.end(), name);
      return it == meta.outputs.end() ? -1 : static_cast<int>(it - meta.outputs.begin());
    };
    const std::array<int, 4> at = {index_of("u_mm"), index_of("v_mm"), index_of("depth_mm"),
                                   index_of("force_n")};
    if (at[0] < 0 || at[1] < 0 || at[2] < 0) {
      return make_error(ErrorCode::kInvalidArgument,
                        "the reference model lacks u_mm, v_mm or depth_mm");
    }
    const int n_out = static_cast<int>(meta.outputs.size());
    Candidate c;
    c.name = reference->meta.name + " (LibTorch)";
    c.kind = "LibTorch at its best: the layers on a prepared tensor, inference mode";
    // Timed as LibTorch runs best: the input tensor prepared once per batch size, only the
    // layers timed (median of 3 repetitions).
    c.time_us = [runners, field, channels](int count, int batch, int threads) {
      TorchRunner& r = *(*runners)[static_cast<std::size_t>(std::clamp(threads, 1, 2) - 1)];
      if (!r.prepare({field, static_cast<std::size_t>(batch) * channels}, batch).ok()) return 0.0;
      const int calls = std::max(1, count / batch);
      std::vector<double> reps;
      double sink = 0;
      for (int rep = 0; rep < 3; ++rep) {
        const auto t0 = Clock::now();
        for (int i = 0; i < calls; ++i) sink += r.forward_prepared();
        reps.push_back(seconds_since(t0) * 1e6 / (static_cast<double>(calls) * batch));
      }
      if (!std::isfinite(sink)) std::fprintf(stderr, "skinbus-bench: LibTorch returned NaN\n");
      return quantile(reps, 0.5);
    };
    c.macs = static_cast<double>(reference->macs());
    c.run = [runners, field, channels, meta, at, n_out](int begin, int end, int batch, int threads,
                                                        ContactEstimate* out) {
      TorchRunner& r = *(*runners)[static_cast<std::size_t>(std::clamp(threads, 1, 2) - 1)];
      std::vector<double> y(static_cast<std::size_t>(batch) * n_out);
      for (int b = begin; b < end; b += batch) {
        const int k = std::min(batch, end - b);
        const Status s = r.run({field + static_cast<std::size_t>(b) * channels,
                                static_cast<std::size_t>(k) * channels},
                               k, {y.data(), static_cast<std::size_t>(k) * n_out});
        if (!s.ok()) {
          reject(out + b, k);
          continue;
        }
        for (int i = 0; i < k; ++i) {
          const double* yi = y.data() + static_cast<std::ptrdiff_t>(i) * n_out;
          ContactEstimate& e = out[b + i];
          e = {yi[at[0]],   yi[at[1]],          yi[at[2]], at[3] >= 0 ? yi[at[3]] : 0.0,
               kEstimateOk, RejectReason::kNone};
          flag_range(e, meta.half_u_mm, meta.half_v_mm, meta.max_depth_mm);
        }
      }
    };
    candidates.push_back(std::move(c));
  }
#endif
  if (!a.train_path.empty()) {
    Result<sim::Dataset> train = sim::read_dataset_csv(a.train_path);
    if (!train.ok()) {
      return train.error();
    }
    Result<LookupEstimator> lk = LookupEstimator::from_dataset(design, *train);
    if (!lk.ok()) {
      return with_context(lk.error(), "lookup");
    }
    auto table = std::make_shared<LookupEstimator>(std::move(lk.value()));
    keep.push_back(table);
    Candidate c;
    c.name = "nearest-neighbour lookup";
    c.kind = "table of " + std::to_string(table->rows()) + " training samples";
    c.run = [table, field, channels](int begin, int end, int, int threads, ContactEstimate* out) {
      split_threads(begin, end, threads, [&](int b, int e) {
        for (int i = b; i < e; ++i) {
          out[i] = table->estimate(
              {field + static_cast<std::size_t>(i) * channels, static_cast<std::size_t>(channels)});
        }
      });
    };
    candidates.push_back(std::move(c));
  }
  if (a.physics) {
    Result<PhysicsEstimator> pe = PhysicsEstimator::create(*nominal);
    if (!pe.ok()) {
      return with_context(pe.error(), "physics");
    }
    auto est = std::make_shared<PhysicsEstimator>(std::move(pe.value()));
    keep.push_back(est);
    Candidate c;
    c.name = "physics LM (nominal model)";
    c.kind = "Ceres Levenberg-Marquardt, lookup start";
    c.run = [est, field, channels](int begin, int end, int, int threads, ContactEstimate* out) {
      split_threads(begin, end, threads, [&](int b, int e) {
        for (int i = b; i < e; ++i) {
          out[i] = est->estimate({field + static_cast<std::size_t>(i) * channels,
                                  static_cast<std::size_t>(channels)})
                       .contact;
        }
      });
    };
    candidates.push_back(std::move(c));
  }

  const double peak_before = best_fma_peak_gflops();
  std::vector<Measured> rows;
  const Truth truth{{test.u_mm.data(), static_cast<std::size_t>(n)},
                    {test.v_mm.data(), static_cast<std::size_t>(n)},
                    {test.depth_mm.data(), static_cast<std::size_t>(n)},
                    {test.force_n.data(), static_cast<std::size_t>(n)}};
  for (const Candidate& c : candidates) {
    std::fprintf(stderr, "skinbus-bench: %s ...\n", c.name.c_str());
    Measured m;
    m.name = c.name;
    m.kind = c.kind;
    m.macs = c.macs;
    m.estimates.resize(static_cast<std::size_t>(n));
    const int lat_n = std::min(n, a.latency_samples);
    if (c.time_us) {
      c.run(0, n, 64, 1, m.estimates.data());
      m.batch1_us = c.time_us(lat_n, 1, 1);
      m.batch64_1t_us = c.time_us(n, 64, 1);
      m.batch64_2t_us = c.time_us(n, 64, 2);
    } else {
      m.batch1_us = time_per_sample_us(c, lat_n, 1, 1, m.estimates);
      m.batch64_1t_us = time_per_sample_us(c, n, 64, 1, m.estimates);
      m.batch64_2t_us = time_per_sample_us(c, n, 64, 2, m.estimates);
    }
    m.errors = summarize_errors(m.estimates, truth);
    rows.push_back(std::move(m));
  }
  std::printf(
      "Test split: %s (%d samples). CRLB: nominal unit, sensor noise %.3f / %.3f uT (xy / z).\n"
      "Times are per sample; errors on the same samples. x CRLB: mean XY error over the mean\n"
      "CRLB RMS XY bound of the bin.\n\n",
      a.test_path.c_str(), n, nxy, nz);
  if (peak_before > 0) {
    const double peak_after = best_fma_peak_gflops();
    std::printf(
        "This machine: an AVX-512 FMA loop reached %.0f GFLOP/s on one core before the estimators\n"
        "and %.0f after (a network's float32 floor is 2 x the multiply-adds it computes / that\n"
        "peak; Winograd convolutions compute fewer than direct ones).\n",
        peak_before, peak_after);
    for (const Measured& m : rows) {
      if (m.macs > 0 && m.kind.find("float32") != std::string::npos) {
        const double floor_us = 2e-3 * m.macs / peak_before;
        std::printf(
            "  %s: %.2f M multiply-adds, floor %.1f us per sample at %.0f GFLOP/s; batch 1 runs "
            "at %.0f %% of that peak, batch 64 (one thread) at %.0f %%\n",
            m.name.c_str(), 1e-6 * m.macs, floor_us, peak_before, 100.0 * floor_us / m.batch1_us,
            100.0 * floor_us / m.batch64_1t_us);
      }
    }
    std::printf("\n");
  }
  write_table(rows, crlb, stdout);
  std::printf("\nPer depth bin: XY p95, depth mean and force mean errors.\n\n");
  write_bin_table(rows, stdout);
  if (!a.csv.empty()) {
    std::ofstream f(a.csv);
    if (!f) {
      return errorf(ErrorCode::kIo, "cannot write %s", a.csv.c_str());
    }
    f << "estimator,kind,macs,batch1_us,batch64_1t_us,batch64_2t_us,xy_mean_mm,xy_p95_mm,depth_"
         "mean_mm,"
         "force_mean_n,rejected";
    for (int b = 0; b < kDepthBins; ++b) {
      const std::string bin = depth_bin_name(b);
      f << ",xy_mean_mm_" << bin << ",crlb_mm_" << bin << ",xy_p95_mm_" << bin << ",depth_mean_mm_"
        << bin << ",force_mean_n_" << bin;
    }
    f << "\n";
    for (const Measured& m : rows) {
      f << '"' << m.name << "\",\"" << m.kind << "\"," << m.macs << ',' << m.batch1_us << ','
        << m.batch64_1t_us << ',' << m.batch64_2t_us << ',' << m.errors.all.xy_mean_mm << ','
        << m.errors.all.xy_p95_mm << ',' << m.errors.all.depth_mean_mm << ','
        << m.errors.all.force_mean_n << ',' << m.errors.all.rejected;
      for (int b = 0; b < kDepthBins; ++b) {
        const ErrorStats& st = m.errors.bins[static_cast<std::size_t>(b)];
        f << ',' << st.xy_mean_mm << ',' << crlb[static_cast<std::size_t>(b)] << ',' << st.xy_p95_mm
          << ',' << st.depth_mean_mm << ',' << st.force_mean_n;
      }
      f << "\n";
    }
  }
  if (!a.errors_csv.empty()) {
    std::ofstream f(a.errors_csv);
    if (!f) {
      return errorf(ErrorCode::kIo, "cannot write %s", a.errors_csv.c_str());
    }
    f << "estimator,u_mm,v_mm,depth_mm,xy_error_mm,depth_error_mm,valid,crlb_xy_mm\n";
    for (const Measured& m : rows) {
      for (int r = 0; r < n; ++r) {
        const ContactEstimate& e = m.estimates[static_cast<std::size_t>(r)];
        f << '"' << m.name << "\"," << test.u_mm[r] << ',' << test.v_mm[r] << ','
          << test.depth_mm[r] << ','
          << (e.valid() ? std::hypot(e.u_mm - test.u_mm[r], e.v_mm - test.v_mm[r]) : 0.0) << ','
          << (e.valid() ? std::fabs(e.depth_mm - test.depth_mm[r]) : 0.0) << ','
          << (e.valid() ? 1 : 0) << ',' << crlb_rows[static_cast<std::size_t>(r)] << "\n";
      }
    }
  }
  if (!a.plot.empty() && !a.csv.empty() && !a.errors_csv.empty()) {
    if (Status s = run_plot_script(SKINBUS_SOURCE_DIR "/tools", "plot_models.py",
                                   {a.csv, a.errors_csv, a.plot});
        !s.ok()) {
      return s;
    }
  }
  return Status::Ok();
}

}  // namespace skinbus::estimators_bench
