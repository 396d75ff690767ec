// Simulator throughput on one core: the forward model, a full measurement, an idle patch, the
// Jacobian, a field correction's sums on each instruction set, and generating the seed
// protocol's dataset. The field model's benchmarks
// (BM_ForwardModel, BM_FieldJacobian) take the patch of `--design FILE` (docs/design_file.md;
// default: the built-in design), every other the built-in design.
//
//   build/sim/sim_benchmark --benchmark_min_time=0.5
//   build/sim/sim_benchmark --benchmark_filter='BM_ForwardModel|BM_FieldJacobian'
//       --design docs/benchmarks/design_9x9_uniform.yaml       (one command line)
#include <benchmark/benchmark.h>

#include <cstdio>
#include <cstring>
#include <vector>

#include "dipole_sum.h"
#include "skinbus/common/isa.h"
#include "skinbus/sim/dataset.h"
#include "skinbus/sim/design_file.h"

namespace skinbus::sim {
namespace {

PatchDesign& field_design() {  // the field model benchmarks' design (--design)
  static PatchDesign design;
  return design;
}

// Presses with a 5 mm tip, uniform over the patch less 2.5 mm at each edge, 0.05-4 mm deep.
std::vector<Contact> random_contacts(int n, const PatchDesign& d = PatchDesign{}) {
  Rng rng(3);
  const double hu = d.size_u_mm / 2 - 2.5, hv = d.size_v_mm / 2 - 2.5;
  std::vector<Contact> c;
  for (int i = 0; i < n; ++i)
    c.push_back({rng.uniform(-hu, hu), rng.uniform(-hv, hv), rng.uniform(0.05, 4.0), 5.0});
  return c;
}

void BM_ForwardModel(benchmark::State& state) {
  const PatchModel m = *PatchModel::fabricated(field_design(), 1, FabricationVariation{});
  const auto cs = random_contacts(4096, field_design());
  std::vector<double> out(static_cast<std::size_t>(m.channel_count()));
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
  const PatchModel m = *PatchModel::fabricated(field_design(), 1, FabricationVariation{});
  const auto cs = random_contacts(4096, field_design());
  const bool shear = state.range(0) != 0;
  const std::size_t nc = static_cast<std::size_t>(m.channel_count());
  std::vector<double> field(nc), jac(nc * 5);
  std::size_t i = 0;
  for (auto _ : state) {
    m.contact_field_jacobian_ut(std::span<const Contact>(&cs[i++ & 4095], 1), shear, field, jac);
    benchmark::DoNotOptimize(jac.data());
  }
}
BENCHMARK(BM_FieldJacobian)->Arg(0)->Arg(1);

// A field correction's sums with their derivatives (FieldCorrection::sums_with_derivatives: 48
// terms, 4 outputs, 48 channels) on each build this CPU has: arg 0 the baseline, 1 AVX2, 2
// AVX-512 (skipped without). Each build should reach its vector width's rate: a build that falls
// far behind a narrower one is miscompiled (a vector wider than its registers, spilled).
void BM_RowSums(benchmark::State& state) {
  const Isa isas[] = {Isa::kPortable, Isa::kAvx2, Isa::kAvx512};
  const Isa isa = isas[state.range(0)];
  const detail::RowSums fn = detail::row_sums_for(isa);
  if (fn == nullptr) {
    state.SkipWithError("this CPU or build lacks the instruction set");
    return;
  }
  constexpr std::size_t kTerms = 48, kChannels = 48, kRows = 24 * 24 * 3;
  Rng rng(5);
  std::vector<double> rows(kRows * kChannels), weight(4 * kTerms), out(4 * kChannels);
  for (double& r : rows) r = rng.uniform(-1, 1);
  for (double& w : weight) w = rng.uniform(-1, 1);
  std::vector<int> index(kTerms);
  for (std::size_t t = 0; t < kTerms; ++t) index[t] = static_cast<int>((t * 37) % kRows);
  for (auto _ : state) {
    fn(kTerms, index.data(), weight.data(), 4, rows.data(), kChannels, out.data());
    benchmark::DoNotOptimize(out.data());
  }
  state.SetLabel(isa_name(isa));
}
BENCHMARK(BM_RowSums)->Arg(0)->Arg(1)->Arg(2);

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

// google-benchmark's main, after taking `--design FILE` out of the arguments.
int main(int argc, char** argv) {
  std::vector<char*> args;
  for (int i = 0; i < argc; ++i) {
    if (std::strcmp(argv[i], "--design") == 0 && i + 1 < argc) {
      auto d = skinbus::sim::read_design_file(argv[++i]);
      if (!d.ok()) {
        std::fprintf(stderr, "sim_benchmark: %s\n", d.error().to_string().c_str());
        return 2;
      }
      skinbus::sim::field_design() = *d;
      continue;
    }
    args.push_back(argv[i]);
  }
  int n = static_cast<int>(args.size());
  benchmark::Initialize(&n, args.data());
  if (benchmark::ReportUnrecognizedArguments(n, args.data())) return 1;
  benchmark::RunSpecifiedBenchmarks();
  benchmark::Shutdown();
  return 0;
}
