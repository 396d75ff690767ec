// `skinbus-bench refine`: the host's physics refinement (AggregatorOptions::refiner_factory) on
// fabricated units: presses held and drifting as a finger does, sampled at 41.7 Hz, through the
// aggregator with the shipped network alone and with the network refined by the unit's physics
// model; the XY and depth error per depth bin next to the unit's Cramer-Rao bound, and the
// refinement's cost per touched sample, from the network's answer (cold) and from the press's
// previous refined contact (warm). Same frames, same run.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <optional>
#include <string>
#include <vector>

#include "skinbus/bus/codec.h"
#include "skinbus/estimators/physics_refiner.h"
#include "skinbus/host/aggregator.h"
#include "skinbus/host_bench/reports.h"
#include "skinbus/sim/crlb.h"
#include "skinbus/sim/design_file.h"
#include "skinbus/sim/rng.h"
#include "skinbus/sim/simulated_patch.h"
#include "skinbus/sim/unit_model.h"

namespace skinbus::host_bench {

namespace {

constexpr uint64_t kPeriodUs = 23'981;  // 41.7 Hz
constexpr int kBins = 3;                // 1-2, 2-3, 3-4 mm
constexpr double kBinLo[kBins] = {1, 2, 3};
constexpr const char* kShippedModel = "estimators/models/nominal_seed_cnn";

struct Sample {
  sim::Contact truth;
  std::vector<double> tared_ut;
  bool release = false;  // the sample after a press: no contact
};

// Presses held for `samples` periods with the design's indenter: a ramp to the depth over the
// first third, then held while the point drifts (0.1 mm a sample, a slow slide), then a release.
std::vector<Sample> make_session(const sim::PatchModel& unit, const RefineBenchArgs& a,
                                 uint64_t seed) {
  sim::SimulatedPatch patch(unit, seed);
  sim::Rng rng(seed ^ 0x9E3779B97F4A7C15ull);
  sim::Environment env;
  const double tip_mm = unit.design().indenter_tip_radius_mm;
  std::vector<double> base(static_cast<std::size_t>(patch.channel_count()));
  patch.tare(env, 32, base);
  std::vector<Sample> out;
  for (int p = 0; p < a.presses; ++p) {
    double u = rng.uniform(-a.half_extent_mm, a.half_extent_mm);
    double v = rng.uniform(-a.half_extent_mm, a.half_extent_mm);
    const double depth = rng.uniform(1.0, 4.0);
    const double dir = rng.uniform(0, 2 * M_PI);
    for (int k = 0; k < a.samples_per_press; ++k) {
      Sample s;
      const double ramp = std::min(1.0, (k + 1.0) / (a.samples_per_press / 3.0));
      s.truth = {u, v, std::max(0.3, depth * ramp), tip_mm};
      s.tared_ut.resize(base.size());
      patch.measure(std::span<const sim::Contact>(&s.truth, 1), env, s.tared_ut);
      for (std::size_t c = 0; c < base.size(); ++c) s.tared_ut[c] -= base[c];
      out.push_back(std::move(s));
      u += 0.1 * std::cos(dir);
      v += 0.1 * std::sin(dir);
    }
    Sample r;
    r.release = true;
    r.tared_ut.assign(base.size(), 0.0);
    out.push_back(std::move(r));
  }
  return out;
}

struct Outcome {
  std::vector<host::BodyContact> published;  // one per contact sample (empty contact if none)
  std::vector<bool> have;
  host::AggregatorStats stats;
  double process_us = 0;  // time in process(), all samples
  std::string error;      // the aggregator refused, or the model or the refiner did not load
};

Outcome run(const sim::PatchModel& unit, const std::vector<Sample>& session, uint64_t uid,
            const std::string& model, bool refine, double warm_start_mm, double basin_check_mm) {
  Outcome out;
  body_map::SkinMap map;
  body_map::PatchPlacement p;
  p.node_id = 1;
  p.hardware_uid = uid;
  p.link = "patch";
  p.model = model;
  if (refine) p.unit = "unit";  // the factory below gives the unit's model
  map.patches.push_back(p);
  host::AggregatorOptions o;
  o.max_lag_us = 0;
  o.refine_budget_us = 1'000'000;  // the whole call: every sample refined, each timed
  o.refine_warm_start_mm = warm_start_mm;
  o.refine_basin_check_mm = basin_check_mm;
  o.refiner_factory = [&unit](const host::RefinerRequest&) {
    estimators::RefinerOptions ro;  // as make_physics_refiner() from files: the design's tip
    ro.physics.tip_radius_mm = unit.design().indenter_tip_radius_mm;
    return estimators::make_physics_refiner(unit, ro);
  };
  auto agg = host::Aggregator::create(&map, SKINBUS_SOURCE_DIR, nullptr, {"can0"}, o);
  if (!agg.ok()) {
    out.error = agg.error().to_string();
    return out;
  }
  host::PatchStatusArray status;
  (*agg)->status(0, &status);
  for (const host::PatchEvent& e : status.events) {
    if (e.kind == host::PatchEventKind::kNoModel) out.error = e.detail;
  }
  if (!out.error.empty()) return out;
  auto send = [&](const bus::Message& m, uint64_t rx) {
    std::array<bus::CanFrame, 4> frames;
    const bus::EncodeResult r = bus::encode(m, frames);
    for (std::size_t i = 0; i < r.frames; ++i) (*agg)->on_frame(0, frames[i], rx + i * 50);
  };
  uint64_t t = 1'000'000;
  uint8_t seq = 0;
  bus::Heartbeat hb;
  hb.state = bus::PatchState::kRunning;
  hb.mode = bus::PatchMode::kEvent;
  hb.hardware_uid = uid;
  hb.uptime_s = 1;
  send(bus::Message{1, 0, bus::FrameKind::kFd, hb}, t);
  uint32_t clock = 1000;
  for (const Sample& s : session) {
    bus::Sample b;
    b.timestamp_us = clock;
    clock += static_cast<uint32_t>(kPeriodUs);
    b.flags = bus::sample_flags::kTared | (s.release ? 0 : bus::sample_flags::kContact);
    for (int c = 0; c < bus::kChannelCount; ++c) {
      b.field_lsb[static_cast<std::size_t>(c)] =
          bus::field_ut_to_lsb(s.tared_ut[static_cast<std::size_t>(c)]);
    }
    send(bus::Message{1, seq++, bus::FrameKind::kFd, b}, t += kPeriodUs);
    host::ContactArray arr;
    const auto t0 = std::chrono::steady_clock::now();
    const bool published = (*agg)->process(t + 100, &arr);
    out.process_us +=
        std::chrono::duration<double, std::micro>(std::chrono::steady_clock::now() - t0).count();
    if (s.release) continue;
    const bool one = published && arr.contacts.size() == 1;
    out.have.push_back(one);
    out.published.push_back(one ? arr.contacts[0] : host::BodyContact{});
  }
  out.stats = (*agg)->stats();
  return out;
}

struct Acc {
  double xy = 0, bound = 0, depth = 0;
  int n = 0;
};

}  // namespace

Status bench_refine(const RefineBenchArgs& a) {
  auto read = sim::read_design_or_builtin(a.design_path);
  if (!read.ok()) return read.error();
  const sim::PatchDesign design = *read;
  const int channels = design.channel_count();
  if (channels != bus::kChannelCount) {
    return make_error(ErrorCode::kInvalidArgument,
                      a.design_path + ": " + std::to_string(channels / 3) +
                          " sensors; the host refines patches that send " +
                          std::to_string(bus::kChannelCount / 3) + " (docs/protocol.md)");
  }
  // The skin map's model path is taken from the source tree; one given here from where it runs.
  const std::string model =
      a.model_path.empty() ? kShippedModel : std::filesystem::absolute(a.model_path).string();
  const estimators::ChannelNoise noise = estimators::ChannelNoise::of(design);
  std::printf(
      "Physics refinement in the host: %d presses per unit held %d samples at 41.7 Hz (a ramp "
      "over the first third, then a 0.1 mm/sample drift), uniform within +-%.0f mm, 1-4 mm deep "
      "(%g mm tips); the network %s alone and refined by Levenberg-Marquardt on the unit's "
      "model; %s%s; seed %llu; the field evaluation on %s (SKINBUS_MAX_ISA "
      "caps it and the network's kernels).\n\n",
      a.presses, a.samples_per_press, a.half_extent_mm, design.indenter_tip_radius_mm,
      a.model_path.empty() ? kShippedModel : a.model_path.c_str(),
      a.unit_path.empty() ? "fabricated units of " : ("the unit " + a.unit_path + " on ").c_str(),
      a.design_path.empty() ? "the built-in design" : a.design_path.c_str(),
      static_cast<unsigned long long>(a.seed), isa_name(sim::field_isa()));
  std::printf(
      "| unit | depth (mm) | samples | network XY (mm) | x CRLB | refined XY (mm) | x CRLB | "
      "network depth (mm) | refined depth (mm) |\n"
      "|---|---:|---:|---:|---:|---:|---:|---:|---:|\n");
  std::string csv =
      "uid,depth_bin,samples,network_xy_mm,network_x_crlb,refined_xy_mm,refined_x_crlb,"
      "network_depth_mm,refined_depth_mm\n";
  std::string cost_rows;
  // A unit file is one unit, read once: pressed once, its noise seeded by the first UID.
  std::optional<sim::PatchModel> file_unit;
  if (!a.unit_path.empty()) {
    auto loaded = sim::read_unit_model(a.unit_path, design);  // names the file
    if (!loaded.ok()) return loaded.error();
    file_unit = std::move(loaded->model);
  }
  const std::size_t units = file_unit ? std::min<std::size_t>(1, a.uids.size()) : a.uids.size();
  for (std::size_t ui = 0; ui < units; ++ui) {
    const uint64_t uid = a.uids[ui];
    auto unit = file_unit ? Result<sim::PatchModel>(*file_unit)
                          : sim::PatchModel::fabricated(design, uid, sim::FabricationVariation{});
    if (!unit.ok()) return unit.error();
    const std::vector<Sample> session = make_session(*unit, a, a.seed + ui);
    const Outcome net = run(*unit, session, uid, model, false, 0, 0);
    const Outcome cold = run(*unit, session, uid, model, true, 0, a.basin_check_mm);
    const Outcome warm = run(*unit, session, uid, model, true, 3.0, a.basin_check_mm);
    for (const Outcome* o : {&net, &cold, &warm}) {
      if (!o->error.empty()) return make_error(ErrorCode::kInvalidArgument, o->error);
    }
    if (net.published.empty() || cold.published.size() != net.published.size() ||
        warm.published.size() != net.published.size()) {
      return make_error(ErrorCode::kInternal, "refine report: the runs published differently");
    }
    Acc acc_net[kBins + 1], acc_ref[kBins + 1];
    std::size_t k = 0;
    for (const Sample& s : session) {
      if (s.release) continue;
      const std::size_t i = k++;
      if (s.truth.depth_mm < 1.0 || !net.have[i] || !warm.have[i]) continue;
      const int bin = std::min(kBins - 1, static_cast<int>(s.truth.depth_mm) - 1);
      const sim::CrlbPoint b = sim::crlb_at(*unit, s.truth, noise.xy_ut, noise.z_ut, true);
      for (int slot : {bin, kBins}) {
        for (auto [acc, c] : {std::pair{&acc_net[slot], &net.published[i]},
                              std::pair{&acc_ref[slot], &warm.published[i]}}) {
          acc->xy += std::hypot(c->u_mm - s.truth.u_mm, c->v_mm - s.truth.v_mm);
          acc->depth += std::fabs(c->depth_mm - s.truth.depth_mm);
          acc->bound += b.sd_xy_mm;
          ++acc->n;
        }
      }
    }
    for (int bin = 0; bin <= kBins; ++bin) {
      const Acc& n = acc_net[bin];
      const Acc& r = acc_ref[bin];
      if (n.n == 0) continue;
      char name[32];
      if (bin < kBins) {
        std::snprintf(name, sizeof name, "%.0f-%.0f", kBinLo[bin], kBinLo[bin] + 1);
      } else {
        std::snprintf(name, sizeof name, "1-4");
      }
      std::printf("| 0x%llx | %s | %d | %.3f | %.2f | %.3f | %.2f | %.3f | %.3f |\n",
                  static_cast<unsigned long long>(uid), name, n.n, n.xy / n.n, n.xy / n.bound,
                  r.xy / r.n, r.xy / r.bound, n.depth / n.n, r.depth / r.n);
      char line[256];
      std::snprintf(line, sizeof line, "0x%llx,%s,%d,%.4f,%.3f,%.4f,%.3f,%.4f,%.4f\n",
                    static_cast<unsigned long long>(uid), name, n.n, n.xy / n.n, n.xy / n.bound,
                    r.xy / r.n, r.xy / r.bound, n.depth / n.n, r.depth / r.n);
      csv += line;
    }
    const double samples = static_cast<double>(net.published.size());
    char row[256];
    std::snprintf(
        row, sizeof row,
        "| 0x%llx | %.0f | %.1f | %.1f | %.1f | %.0f %% | %llu | %llu (%llu) | %.1f | %.1f |\n",
        static_cast<unsigned long long>(uid), samples, net.process_us / samples,
        cold.stats.refine_us / static_cast<double>(std::max<uint64_t>(1, cold.stats.refined)),
        warm.stats.refine_us / static_cast<double>(std::max<uint64_t>(1, warm.stats.refined)),
        100.0 * static_cast<double>(warm.stats.refine_warm_starts) /
            static_cast<double>(std::max<uint64_t>(1, warm.stats.refined)),
        static_cast<unsigned long long>(warm.stats.refine_restarts),
        static_cast<unsigned long long>(warm.stats.refine_basin_checks),
        static_cast<unsigned long long>(warm.stats.refine_basin_moves), cold.process_us / samples,
        warm.process_us / samples);
    cost_rows += row;
    if (warm.stats.unrefined_poor_fit + cold.stats.unrefined_poor_fit > 0) {
      std::printf("(unit 0x%llx: %llu cold and %llu warm refinements ended poor: network kept)\n",
                  static_cast<unsigned long long>(uid),
                  static_cast<unsigned long long>(cold.stats.unrefined_poor_fit),
                  static_cast<unsigned long long>(warm.stats.unrefined_poor_fit));
    }
  }
  std::printf(
      "\nCost per touched sample (us; process(): the whole pipeline of a sample, network run and "
      "placement included; restarts: warm fits the host rejected, made again from the network's "
      "answer; basin checks: deepening presses searched again from the start table, at %g mm "
      "and each doubling of the depth (moved: the search's contact published instead, 1 mm or more "
      "from the warm fit's), warm run):\n\n| unit | samples | network process() | refine, cold | "
      "refine, warm | warm "
      "starts | restarts | basin checks (moved) | process(), cold | process(), warm |\n"
      "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n%s",
      a.basin_check_mm, cost_rows.c_str());
  std::printf(
      "\nXY: mean distance to the press; x CRLB: over the mean of the unit's Cramer-Rao bound "
      "(RMS radial) at the same presses, with the ambient nuisance (the mean of a 2-D Gaussian "
      "error is ~0.89 of its RMS). Samples shallower than 1 mm (the ramps' first) are left out. "
      "The refiner fits the unit's own model: identification's residual (skinbus-bench budget) "
      "is not included.\n");
  if (!a.csv.empty()) {
    std::ofstream f(a.csv);
    f << csv;
    if (!f) return make_error(ErrorCode::kIo, a.csv + ": write failed");
  }
  return Status::Ok();
}

}  // namespace skinbus::host_bench
