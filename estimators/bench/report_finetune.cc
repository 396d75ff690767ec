// `skinbus-bench finetune`: how a new unit's error falls with the presses spent on it:
// fine-tuning a base network against identifying the unit's physics, from the same presses.
#ifdef SKINBUS_HAVE_TORCH
#include <chrono>
#include <cmath>
#include <cstdio>
#include <fstream>

#include "skinbus/common/error_format.h"
#include "skinbus/common/stats.h"
#include "skinbus/estimators/network_runtime.h"
#include "skinbus/estimators/physics_estimator.h"
#include "skinbus/estimators/training.h"
#include "skinbus/estimators/unit_identification.h"
#include "skinbus/estimators_bench/reports.h"
#include "skinbus/sim/simulated_patch.h"

namespace skinbus::estimators_bench {
namespace {

using namespace skinbus::estimators;
using Clock = std::chrono::steady_clock;
constexpr double kHalfExtentMm = 67.5;    // the seed grid's extent
constexpr double kSecondsPerPress = 6.0;  // a 4 s ramp plus ~2 s to move to the next point

}  // namespace

Status bench_finetune(const FinetuneBenchArgs& a) {
  Result<ModelFile> base = read_model(a.base_path);
  if (!base.ok()) {
    return base.error();
  }
  const sim::PatchDesign design;
  sim::PatchDesign unit_design = design;
  unit_design.anisotropy = a.anisotropy;
  Result<sim::PatchModel> unit =
      sim::PatchModel::fabricated(unit_design, a.uid, sim::FabricationVariation{});
  if (!unit.ok()) return unit.error();
  sim::SimulatedPatch test_patch(*unit, sim::unit_noise_seed(a.uid, 2));
  const sim::Dataset test =
      sim::generate_random_test_set(test_patch, a.test_count, kHalfExtentMm, 4.0, 7);
  const std::size_t nc = static_cast<std::size_t>(unit->channel_count());
  // The mean CRLB of the presses at least 1 mm deep (those the table's XY means cover).
  const std::vector<double> crlb = crlb_per_row(*unit, test, static_cast<int>(test.rows()));
  std::vector<double> crlb_deep_rows;
  for (std::size_t r = 0; r < test.rows(); ++r) {
    if (test.depth_mm[r] >= 1.0) crlb_deep_rows.push_back(crlb[r]);
  }
  const double crlb_deep = mean(crlb_deep_rows);
  auto evaluate = [&](const ModelFile& m) {
    Result<NetworkRuntime> rt = NetworkRuntime::create(m);
    ContactEstimate rejected;
    rejected.flags = kEstimateRejected;
    std::vector<ContactEstimate> out(test.rows(), rejected);
    if (rt.ok() && !rt->run(test.field_ut, static_cast<int>(test.rows()), out).ok()) {
      std::fill(out.begin(), out.end(), rejected);
    }
    return summarize_errors(out, {test.u_mm, test.v_mm, test.depth_mm, test.force_n});
  };
  // The physics with no presses: the nominal model.
  ErrorSummary nominal_physics;
  {
    Result<PhysicsEstimator> lm =
        PhysicsEstimator::create(sim::PatchModel::nominal(design).value());
    if (!lm.ok()) return lm.error();
    std::vector<ContactEstimate> out(test.rows());
    for (std::size_t r = 0; r < test.rows(); ++r)
      out[r] = lm->estimate({test.field(r), nc}).contact;
    nominal_physics = summarize_errors(out, {test.u_mm, test.v_mm, test.depth_mm, test.force_n});
  }
  struct Line {
    int presses;
    double minutes;
    ErrorSummary tuned, physics;
    double tune_s, physics_s;
    bool physics_ok;
  };
  std::vector<Line> lines;
  const ErrorSummary before = evaluate(*base);
  std::fprintf(stderr, "skinbus-bench: base model on the new unit: XY %.3f mm (>= 1 mm deep)\n",
               xy_mean_from_bin(before));
  for (int n : a.points) {
    const int side = std::max(2, static_cast<int>(std::lround(std::sqrt(n))));
    const std::vector<sim::PressPoint> plan =
        a.plan == "grid" ? sim::plan_grid(side, 2 * kHalfExtentMm / (side - 1))
                         : sim::plan_halton(n, kHalfExtentMm, 1);
    const int presses_n = static_cast<int>(plan.size());
    std::fprintf(stderr, "skinbus-bench: %d presses ...\n", presses_n);
    sim::SimulatedPatch patch(*unit, sim::unit_noise_seed(a.uid, 1));
    const sim::Dataset presses = sim::generate_ramp_dataset(patch, plan, sim::RampProtocol{});
    Line line{presses_n, presses_n * kSecondsPerPress / 60, {}, {}, 0, 0, false};
    TrainOptions o;
    o.name = "finetuned";
    o.max_epochs = a.epochs;
    o.patience = a.epochs;
    o.learning_rate = a.learning_rate;
    o.threads = a.threads;
    o.validation_fraction = 0.15;
    const auto t0 = Clock::now();
    Result<TrainResult> tuned = train_model(presses, o, &*base);
    line.tune_s = std::chrono::duration<double>(Clock::now() - t0).count();
    if (tuned.ok()) {
      line.tuned = evaluate(tuned->model);
    } else {
      std::fprintf(stderr, "skinbus-bench:   fine-tuning: %s\n", tuned.error().to_string().c_str());
      line.tuned = summarize_errors({}, Truth{});  // NaN in the table, not a perfect score
    }
    const auto t1 = Clock::now();
    Result<IdentifiedUnit> id = identify_unit(design, presses);
    line.physics_s = std::chrono::duration<double>(Clock::now() - t1).count();
    if (id.ok()) {
      Result<PhysicsEstimator> lm = PhysicsEstimator::create(id->model);
      if (lm.ok()) {
        std::vector<ContactEstimate> out(test.rows());
        for (std::size_t r = 0; r < test.rows(); ++r)
          out[r] = lm->estimate({test.field(r), nc}).contact;
        line.physics = summarize_errors(out, {test.u_mm, test.v_mm, test.depth_mm, test.force_n});
        line.physics_ok = true;
      }
    } else {
      std::fprintf(stderr, "skinbus-bench:   identification: %s\n", id.error().to_string().c_str());
    }
    lines.push_back(line);
  }
  std::printf(
      "New unit: fabricated, UID 0x%llx, lattice anisotropy %.2f, presses on a %s plan. Base: %s "
      "(trained on the nominal "
      "patch). Test: %d "
      "off-grid presses, random depths to 4 mm; XY and depth means over presses >= 1 mm "
      "deep (CRLB there: %.3f mm). Robot time at %.0f s per press.\n\n",
      static_cast<unsigned long long>(a.uid), a.anisotropy, a.plan.c_str(), base->meta.name.c_str(),
      a.test_count, crlb_deep, kSecondsPerPress);
  std::printf(
      "| presses | robot time (min) | fine-tuned network XY (mm) | depth (mm) | fine-tuning "
      "(s) | identified physics + LM XY (mm) | depth (mm) | identification (s) |\n"
      "|---:|---:|---:|---:|---:|---:|---:|---:|\n");
  std::printf("| 0 | 0 | %.3f | %.3f | | %.3f (nominal model) | %.3f | |\n",
              xy_mean_from_bin(before), before.all.depth_mean_mm, xy_mean_from_bin(nominal_physics),
              nominal_physics.all.depth_mean_mm);
  for (const Line& l : lines) {
    std::printf("| %d | %.1f | %.3f | %.3f | %.0f |", l.presses, l.minutes,
                xy_mean_from_bin(l.tuned), l.tuned.all.depth_mean_mm, l.tune_s);
    if (l.physics_ok) {
      std::printf(" %.3f | %.3f | %.1f |\n", xy_mean_from_bin(l.physics),
                  l.physics.all.depth_mean_mm, l.physics_s);
    } else {
      std::printf(" refused: presses too few or not covering the patch | | |\n");
    }
  }
  if (!a.csv.empty()) {
    std::ofstream f(a.csv);
    if (!f) {
      return errorf(ErrorCode::kIo, "cannot write %s", a.csv.c_str());
    }
    f << "presses,robot_minutes,finetuned_xy_deep_mm,finetuned_depth_mm,finetune_s,physics_xy_deep_"
         "mm,physics_depth_mm,identify_s\n";
    f << "0,0," << xy_mean_from_bin(before) << ',' << before.all.depth_mean_mm << ",,"
      << xy_mean_from_bin(nominal_physics) << ',' << nominal_physics.all.depth_mean_mm << ",\n";
    for (const Line& l : lines) {
      f << l.presses << ',' << l.minutes << ',' << xy_mean_from_bin(l.tuned) << ','
        << l.tuned.all.depth_mean_mm << ',' << l.tune_s << ',';
      if (l.physics_ok)
        f << xy_mean_from_bin(l.physics) << ',' << l.physics.all.depth_mean_mm << ','
          << l.physics_s;
      else
        f << ",,";
      f << "\n";
    }
  }
  return Status::Ok();
}

}  // namespace skinbus::estimators_bench
#endif
