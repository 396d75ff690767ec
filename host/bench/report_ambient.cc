// `skinbus-bench ambient`: accuracy of a per-patch model when the ambient field turns between the
// patch's tare and the press (a limb moving in the Earth's field), with and without common-mode
// rejection (host/ambient.h). Run time and error on the same presses.
#include <chrono>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <string>
#include <vector>

#include "skinbus/common/error_format.h"
#include "skinbus/common/stats.h"
#include "skinbus/estimators/evaluation.h"
#include "skinbus/estimators/network_runtime.h"
#include "skinbus/host/ambient.h"
#include "skinbus/host_bench/reports.h"
#include "skinbus/sim/rng.h"
#include "skinbus/sim/simulated_patch.h"

namespace skinbus::host_bench {

namespace {

using BenchClock = std::chrono::steady_clock;

sim::Vec3<double> random_direction(sim::Rng& rng) {
  for (;;) {
    const sim::Vec3<double> v{rng.uniform(-1, 1), rng.uniform(-1, 1), rng.uniform(-1, 1)};
    const double n = std::sqrt(v.x * v.x + v.y * v.y + v.z * v.z);
    if (n > 0.1 && n <= 1) return {v.x / n, v.y / n, v.z / n};
  }
}

struct Presses {
  std::vector<double> clean, turned;  // tared fields: ambient unchanged / turned since the tare
  std::vector<double> u, v, depth, force, change_ut;
};

Presses make_presses(sim::SimulatedPatch& patch, const AmbientBenchArgs& a, uint64_t seed) {
  sim::Rng rng(seed);
  const int ch = patch.channel_count();
  Presses p;
  std::vector<double> base(static_cast<std::size_t>(ch)), f(static_cast<std::size_t>(ch));
  for (int k = 0; k < a.count; ++k) {
    const sim::Contact c{rng.uniform(-a.half_extent_mm, a.half_extent_mm),
                         rng.uniform(-a.half_extent_mm, a.half_extent_mm),
                         rng.uniform(a.min_depth_mm, a.max_depth_mm), 5.0};
    const sim::Vec3<double> d0 = random_direction(rng);
    sim::Vec3<double> d1 = random_direction(rng);
    if (a.max_turn_deg < 180) {  // turn d0 by at most max_turn about a random perpendicular axis
      const double ang = rng.uniform(0, a.max_turn_deg) * M_PI / 180;
      sim::Vec3<double> w = random_direction(rng);
      const double dot = w.x * d0.x + w.y * d0.y + w.z * d0.z;
      w = {w.x - dot * d0.x, w.y - dot * d0.y, w.z - dot * d0.z};
      const double wn = std::sqrt(w.x * w.x + w.y * w.y + w.z * w.z);
      w = {w.x / wn, w.y / wn, w.z / wn};
      d1 = {std::cos(ang) * d0.x + std::sin(ang) * w.x, std::cos(ang) * d0.y + std::sin(ang) * w.y,
            std::cos(ang) * d0.z + std::sin(ang) * w.z};
    }
    sim::Environment e0, e1;
    e0.ambient_ut = {a.field_ut * d0.x, a.field_ut * d0.y, a.field_ut * d0.z};
    e1.ambient_ut = {a.field_ut * d1.x, a.field_ut * d1.y, a.field_ut * d1.z};
    const sim::Vec3<double> dc{e1.ambient_ut.x - e0.ambient_ut.x, e1.ambient_ut.y - e0.ambient_ut.y,
                               e1.ambient_ut.z - e0.ambient_ut.z};
    patch.tare(e0, 32, base);
    patch.measure(std::span<const sim::Contact>(&c, 1), e0, f);
    for (int i = 0; i < ch; ++i)
      p.clean.push_back(f[static_cast<std::size_t>(i)] - base[static_cast<std::size_t>(i)]);
    patch.measure(std::span<const sim::Contact>(&c, 1), e1, f);
    for (int i = 0; i < ch; ++i)
      p.turned.push_back(f[static_cast<std::size_t>(i)] - base[static_cast<std::size_t>(i)]);
    p.u.push_back(c.u_mm);
    p.v.push_back(c.v_mm);
    p.depth.push_back(c.depth_mm);
    p.force.push_back(0);
    p.change_ut.push_back(std::sqrt(dc.x * dc.x + dc.y * dc.y + dc.z * dc.z));
  }
  return p;
}

struct Row {
  std::string unit, method, field;
  double xy_mm = 0, p95_mm = 0, depth_mm = 0, residual_ut = 0, us_per_sample = 0;
  int rejected = 0;
};

}  // namespace

Status bench_ambient(const AmbientBenchArgs& a) {
  auto model = estimators::read_model(a.model_path);
  if (!model) {
    return model.error();
  }
  auto rt = estimators::NetworkRuntime::create(*model, {});
  if (!rt) {
    return rt.error();
  }
  std::printf(
      "ambient rejection: %d presses per unit, depth %.1f..%.1f mm, a %.0f uT field "
      "turned by up to %.0f deg between tare and press; model %s (%s)\n",
      a.count, a.min_depth_mm, a.max_depth_mm, a.field_ut, a.max_turn_deg, model->meta.name.c_str(),
      rt->kernel_name());
  std::vector<Row> rows;
  const struct {
    const char* name;
    host::CommonModeMethod m;
  } methods[] = {{"none", host::CommonModeMethod::kNone},
                 {"median", host::CommonModeMethod::kMedian},
                 {"quiet-mean", host::CommonModeMethod::kQuietMean}};
  for (const std::string& unit : a.units) {
    sim::PatchDesign design;
    auto pm = unit == "nominal"
                  ? sim::PatchModel::nominal(design)
                  : sim::PatchModel::fabricated(design, a.uid, sim::FabricationVariation{});
    if (!pm || (unit != "nominal" && unit != "fabricated")) {
      return errorf(ErrorCode::kInvalidArgument, "unknown unit '%s'", unit.c_str());
    }
    sim::SimulatedPatch patch(*pm, sim::unit_noise_seed(a.uid, 2));
    const Presses p = make_presses(patch, a, a.uid ^ 0xA3B1);
    const int ch = patch.channel_count();
    const estimators::Truth truth{p.u, p.v, p.depth, p.force};
    for (const auto& m : methods) {
      for (int turned = 0; turned < 2; ++turned) {
        std::vector<double> x = turned ? p.turned : p.clean;
        const std::vector<double>& ref = p.clean;
        const auto t0 = BenchClock::now();
        host::CommonModeOptions o;
        o.method = m.m;
        double resid2 = 0;
        for (int k = 0; k < a.count; ++k) {
          std::span<double> s(x.data() + static_cast<std::size_t>(k) * ch,
                              static_cast<std::size_t>(ch));
          const auto e = host::estimate_common_mode(s, {}, o);
          host::remove_common_mode(s, e);
        }
        const double us =
            std::chrono::duration<double, std::micro>(BenchClock::now() - t0).count() / a.count;
        // What is left of the ambient change (or what the rejection took from a clean press),
        // RMS over the channels: the input error the network sees.
        for (std::size_t i = 0; i < x.size(); ++i) resid2 += (x[i] - ref[i]) * (x[i] - ref[i]);
        std::vector<estimators::ContactEstimate> est(static_cast<std::size_t>(a.count));
        if (Status s = rt->run(x, a.count, est); !s.ok()) return s;
        const estimators::ErrorSummary s = estimators::summarize_errors(est, truth);
        Row r;
        r.unit = unit;
        r.method = m.name;
        r.field = turned ? "turned" : "still";
        r.xy_mm = estimators::xy_mean_from_bin(s);
        r.p95_mm = s.all.xy_p95_mm;
        r.depth_mm = s.all.depth_mean_mm;
        r.rejected = s.all.rejected;
        r.residual_ut = std::sqrt(resid2 / static_cast<double>(x.size()));
        r.us_per_sample = us;
        rows.push_back(r);
      }
    }
  }
  std::printf("\n%-11s %-11s %-7s %10s %9s %9s %12s %9s %11s\n", "unit", "rejection", "field",
              "XY>=1mm", "XY p95", "depth", "input err", "loss", "us/sample");
  for (const Row& r : rows) {
    double base = NAN;  // no rejection, still field: the model's own error
    for (const Row& b : rows)
      if (b.unit == r.unit && b.method == std::string("none") && b.field == "still") base = b.xy_mm;
    std::printf("%-11s %-11s %-7s %8.3f mm %6.2f mm %6.3f mm %9.2f uT %+8.1f%% %11.3f\n",
                r.unit.c_str(), r.method.c_str(), r.field.c_str(), r.xy_mm, r.p95_mm, r.depth_mm,
                r.residual_ut, 100 * (r.xy_mm / base - 1), r.us_per_sample);
  }
  std::printf(
      "\nloss: XY mean error (presses >= 1 mm deep) against the same model on the same "
      "presses with the field still and no rejection. input err: RMS over the channels of "
      "what the ambient change leaves (turned) or what the rejection removes from the "
      "press (still).\n");
  if (!a.csv.empty()) {
    std::ofstream f(a.csv);
    f << "unit,rejection,field,xy_mean_mm,xy_p95_mm,depth_mean_mm,input_error_ut,us_per_sample\n";
    for (const Row& r : rows)
      f << r.unit << ',' << r.method << ',' << r.field << ',' << r.xy_mm << ',' << r.p95_mm << ','
        << r.depth_mm << ',' << r.residual_ut << ',' << r.us_per_sample << '\n';
  }
  return Status::Ok();
}

}  // namespace skinbus::host_bench
