// Simulator throughput on one core: the forward model, a full measurement, an idle patch, the
// Jacobian, and generating the seed protocol's dataset.
//
//   build/sim/sim_benchmark --benchmark_min_time=0.5
#include <benchmark/benchmark.h>

#include <vector>

#include "skinbus/sim/dataset.h"

namespace skinbus::sim {
namespace {

std::vector<Contact> random_contacts(int n) {
  Rng rng(3);
  std::vector<Contact> c;
  for (int i = 0; i < n; ++i)
    c.push_back({rng.uniform(-67.5, 67.5), rng.uniform(-67.5, 67.5), rng.uniform(0.05, 4.0),
                 5.0});  // 5 mm tip
  return c;
}

void BM_ForwardModel(benchmark::State& state) {
  const PatchModel m = *PatchModel::fabricated(PatchDesign{}, 1, FabricationVariation{});
  const auto cs = random_contacts(4096);
  std::vector<double> out(48);
  std::size_t i = 0;
  for (auto _ : state) {
    m.contact_field_ut(std::span<const Contact>(&cs[i++ & 4095], 1), out);
    benchmark::DoNotOptimize(out.data());
  }
  state.counters["patch_samples_per_s"] =
      benchmark::Counter(static_cast<double>(state.iterations()), benchmark::Counter::kIsRate);
}
BENCHMARK(BM_ForwardModel);

void BM_MeasureTouched(benchmark::State& state) {
  SimulatedPatch p(*PatchModel::fabricated(PatchDesign{}, 1, FabricationVariation{}), 2);
  const auto cs = random_contacts(4096);
  std::vector<double> out(48);
  std::size_t i = 0;
  for (auto _ : state) {
    p.measure(std::span<const Contact>(&cs[i++ & 4095], 1), Environment{}, out);
    benchmark::DoNotOptimize(out.data());
  }
  state.counters["patch_samples_per_s"] =
      benchmark::Counter(static_cast<double>(state.iterations()), benchmark::Counter::kIsRate);
}
BENCHMARK(BM_MeasureTouched);

void BM_MeasureIdle(benchmark::State& state) {
  SimulatedPatch p(*PatchModel::fabricated(PatchDesign{}, 1, FabricationVariation{}), 2);
  std::vector<double> out(48);
  for (auto _ : state) {
    p.measure({}, Environment{}, out);
    benchmark::DoNotOptimize(out.data());
  }
  state.counters["patch_samples_per_s"] =
      benchmark::Counter(static_cast<double>(state.iterations()), benchmark::Counter::kIsRate);
}
BENCHMARK(BM_MeasureIdle);

void BM_Jacobian(benchmark::State& state) {
  const PatchModel m = *PatchModel::nominal(PatchDesign{});
  const auto cs = random_contacts(1024);
  std::vector<double> jac(144);
  std::size_t i = 0;
  for (auto _ : state) {
    m.contact_jacobian(cs[i++ & 1023], jac);
    benchmark::DoNotOptimize(jac.data());
  }
}
BENCHMARK(BM_Jacobian);

// The field and its exact Jacobian as the fits take them (contact_field_jacobian_ut): one
// contact's (u, v, depth), then with its shear; against BM_ForwardModel's one evaluation.
void BM_FieldJacobian(benchmark::State& state) {
  const PatchModel m = *PatchModel::fabricated(PatchDesign{}, 1, FabricationVariation{});
  const auto cs = random_contacts(4096);
  const bool shear = state.range(0) != 0;
  std::vector<double> field(48), jac(48 * 5);
  std::size_t i = 0;
  for (auto _ : state) {
    m.contact_field_jacobian_ut(std::span<const Contact>(&cs[i++ & 4095], 1), shear, field, jac);
    benchmark::DoNotOptimize(jac.data());
  }
}
BENCHMARK(BM_FieldJacobian)->Arg(0)->Arg(1);

void BM_SeedProtocolDataset(benchmark::State& state) {
  for (auto _ : state) {
    SimulatedPatch p(*PatchModel::nominal(PatchDesign{}), 1);
    const Dataset d = generate_ramp_dataset(p, plan_grid(19, 7.5), RampProtocol{});
    benchmark::DoNotOptimize(d.field_ut.data());
    state.counters["rows"] = static_cast<double>(d.rows());
  }
  state.SetLabel("19 x 19 grid, 4 mm ramps at 2 mm/s, 41.7 Hz");
}
BENCHMARK(BM_SeedProtocolDataset)->Unit(benchmark::kMillisecond);

}  // namespace
}  // namespace skinbus::sim

BENCHMARK_MAIN();
