// Costs of the physics side of the per-patch estimators: the Levenberg-Marquardt inversion (from
// the lookup start and from a guess), the nearest-neighbour lookup, and one per-unit
// identification at the seed protocol's size (19 x 19 presses, 4 depths each).
//   cmake --build <build> --target estimators_physics_benchmark &&
//   <build>/estimators/estimators_physics_benchmark
#include <benchmark/benchmark.h>

#include <vector>

#include "skinbus/estimators/lookup_estimator.h"
#include "skinbus/estimators/physics_estimator.h"
#include "skinbus/estimators/unit_identification.h"
#include "skinbus/sim/dataset.h"
#include "skinbus/sim/rng.h"
#include "skinbus/sim/simulated_patch.h"

namespace {

using namespace skinbus;

// Noisy tared samples of random presses on the nominal patch, with an ambient offset.
struct Samples {
  sim::PatchModel model = sim::PatchModel::nominal(sim::PatchDesign{}).value();
  std::vector<std::vector<double>> fields;
  std::vector<sim::Contact> truth;
  Samples() {
    sim::SimulatedPatch patch(model, 1);
    sim::Rng rng(2);
    std::vector<double> base(static_cast<std::size_t>(model.channel_count())), m(base.size());
    sim::Environment env;
    patch.tare(env, 32, base);
    env.ambient_ut = {5, -7, 9};
    for (int i = 0; i < 256; ++i) {
      const sim::Contact c{rng.uniform(-60, 60), rng.uniform(-60, 60), rng.uniform(0.5, 4), 5};
      patch.measure(std::span<const sim::Contact>(&c, 1), env, m);
      for (std::size_t k = 0; k < m.size(); ++k) m[k] -= base[k];
      fields.push_back(m);
      truth.push_back(c);
    }
  }
};
const Samples& samples() {
  static const Samples s;
  return s;
}

// Arg: PhysicsOptions::other_basins (0: the nearest starts only; 2: the default).
void BM_PhysicsEstimate(benchmark::State& state) {
  const Samples& s = samples();
  estimators::PhysicsOptions o;
  o.other_basins = static_cast<int>(state.range(0));
  const estimators::PhysicsEstimator est = estimators::PhysicsEstimator::create(s.model, o).value();
  std::size_t i = 0;
  double iterations = 0, n = 0;
  for (auto _ : state) {
    const estimators::PhysicsEstimate e = est.estimate(s.fields[i]);
    benchmark::DoNotOptimize(e);
    iterations += e.iterations;
    n += 1;
    i = (i + 1) % s.fields.size();
  }
  state.counters["lm_iterations"] = iterations / n;
}
BENCHMARK(BM_PhysicsEstimate)->Arg(0)->Arg(2)->Unit(benchmark::kMicrosecond);

void BM_PhysicsRefineFromGuess(benchmark::State& state) {
  const Samples& s = samples();
  const estimators::PhysicsEstimator est = estimators::PhysicsEstimator::create(s.model).value();
  std::size_t i = 0;
  for (auto _ : state) {
    estimators::ContactEstimate guess;
    guess.u_mm = s.truth[i].u_mm + 1.0;
    guess.v_mm = s.truth[i].v_mm - 1.0;
    guess.depth_mm = s.truth[i].depth_mm + 0.3;
    benchmark::DoNotOptimize(est.refine(s.fields[i], {}, guess));
    i = (i + 1) % s.fields.size();
  }
}
BENCHMARK(BM_PhysicsRefineFromGuess)->Unit(benchmark::kMicrosecond);

// The lookup baseline on the default grid (2.5 mm pitch, 12 depths: 39k rows), and the LM's
// coarse start table (5 mm, 6 depths: 5k rows).
void BM_LookupEstimate(benchmark::State& state) {
  const Samples& s = samples();
  estimators::LookupGrid grid;
  if (state.range(0) == 1) {
    grid = estimators::PhysicsOptions{}.start_grid;
    grid.pitch_mm = estimators::start_pitch_mm(s.model.design());
  }
  const estimators::LookupEstimator lookup =
      estimators::LookupEstimator::from_model(s.model, grid).value();
  std::size_t i = 0;
  for (auto _ : state) {
    benchmark::DoNotOptimize(lookup.estimate(s.fields[i]));
    i = (i + 1) % s.fields.size();
  }
  state.counters["rows"] = lookup.rows();
}
BENCHMARK(BM_LookupEstimate)->Arg(0)->Arg(1)->Unit(benchmark::kMicrosecond);

// Arg 0: a fabricated unit (default variation); arg 1: the same with anisotropy 0.05 (which
// identification fits since 2026-11-28; before, it was left in the residual).
void BM_IdentifyUnit(benchmark::State& state) {
  sim::PatchDesign design;
  design.anisotropy = state.range(0) == 1 ? 0.05 : 0.0;
  const sim::PatchModel unit =
      sim::PatchModel::fabricated(design, 4242, sim::FabricationVariation{}).value();
  sim::SimulatedPatch patch(unit, 4242);
  const sim::Dataset train =
      sim::generate_ramp_dataset(patch, sim::plan_grid(19, 7.5), sim::RampProtocol{});
  const sim::Dataset test = sim::generate_random_test_set(patch, 400, 65, 4.0, 4243);
  estimators::IdentificationOptions opt;
  for (auto _ : state) {
    const Result<estimators::IdentifiedUnit> id =
        estimators::identify_unit(design, train, opt, &test);
    if (!id.ok()) {
      state.SkipWithError(id.error().to_string().c_str());
      break;
    }
    state.counters["rows"] = id->rows_used;
    state.counters["lm_iterations"] = id->iterations;
    state.counters["fit_rms"] = id->fit.rms;
    state.counters["held_out_rms"] = id->held_out.rms;
    state.counters["nominal_held_out_rms"] = id->nominal_held_out.rms;
    state.counters["held_out_rms_3_4mm"] = id->held_out.bins[3].rms;
  }
}
BENCHMARK(BM_IdentifyUnit)->Arg(0)->Arg(1)->Iterations(1)->Unit(benchmark::kSecond);

}  // namespace

BENCHMARK_MAIN();
