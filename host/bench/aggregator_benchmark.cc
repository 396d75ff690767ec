// Costs of the host aggregator's stages on one core: an idle stream-mode sample (reassembly and
// the flag test), one period of P patches with none touched, a touched period (T patches
// estimated in one batched run, placed, merged and tracked), and the common-mode estimate. The
// idle periods are stepped by the host loop (host_loop.h), as the daemon steps them.
//   cmake --build <build> --target host_aggregator_benchmark &&
//   <build>/host/host_aggregator_benchmark
// skinbus-bench host measures the same pipeline end to end with bus timing (latency, CPU use);
// docs/benchmarks/aggregator.md has both.
#include <benchmark/benchmark.h>

#include <array>
#include <cmath>
#include <span>
#include <vector>

#include "skinbus/bus/codec.h"
#include "skinbus/host/aggregator.h"
#include "skinbus/host/host_loop.h"
#include "skinbus/sim/rng.h"
#include "skinbus/sim/simulated_patch.h"

namespace {

using namespace skinbus;

constexpr int kMaxPatches = 120;

std::array<int16_t, bus::kChannelCount> to_lsb(std::span<const double> tared_ut) {
  std::array<int16_t, bus::kChannelCount> out{};
  for (int c = 0; c < bus::kChannelCount; ++c) {
    out[static_cast<std::size_t>(c)] = bus::field_ut_to_lsb(tared_ut[static_cast<std::size_t>(c)]);
  }
  return out;
}

// Encoded frames of a sample of every patch (1..kMaxPatches): idle and pressed variants.
struct Frames {
  body_map::SkinMap map;
  std::vector<std::array<bus::CanFrame, 2>> idle, pressed, heartbeat;
  Frames() {
    auto model = sim::PatchModel::nominal(sim::PatchDesign{}).value();
    sim::SimulatedPatch patch(model, 3);
    sim::Rng rng(4);
    std::vector<double> base(static_cast<std::size_t>(model.channel_count())), f(base.size());
    sim::Environment env;
    patch.tare(env, 32, base);
    for (int i = 0; i < kMaxPatches; ++i) {
      body_map::PatchPlacement p;
      p.node_id = 1 + i;
      p.hardware_uid = 0xBE00 + static_cast<uint64_t>(i);
      p.link = "base";
      p.pose_on_link.translation_mm = {200.0 * i, 0, 0};
      p.model = "estimators/models/nominal_seed_cnn";
      map.patches.push_back(p);
      const sim::Contact c{rng.uniform(-50, 50), rng.uniform(-50, 50), rng.uniform(1, 3), 5};
      bus::Sample s;
      s.flags = bus::sample_flags::kTared;
      patch.measure({}, env, f);
      for (std::size_t k = 0; k < f.size(); ++k) f[k] -= base[k];
      s.field_lsb = to_lsb(f);
      idle.push_back(encode(static_cast<uint8_t>(1 + i), s));
      patch.measure(std::span<const sim::Contact>(&c, 1), env, f);
      for (std::size_t k = 0; k < f.size(); ++k) f[k] -= base[k];
      s.field_lsb = to_lsb(f);
      s.flags |= bus::sample_flags::kContact;
      pressed.push_back(encode(static_cast<uint8_t>(1 + i), s));
      bus::Heartbeat hb;
      hb.state = bus::PatchState::kRunning;
      hb.hardware_uid = p.hardware_uid;
      heartbeat.push_back(encode(static_cast<uint8_t>(1 + i), hb));
    }
  }
  template <typename T>
  static std::array<bus::CanFrame, 2> encode(uint8_t node, const T& body) {
    std::array<bus::CanFrame, 2> out{};
    (void)bus::encode(bus::Message{node, 0, bus::FrameKind::kFd, body}, out);
    return out;
  }
};

const Frames& frames() {
  static const Frames f;
  return f;
}

struct NullSink : host::HostSink {
  void contacts(const host::ContactArray&, std::span<const uint64_t>) override {}
  void status(const host::PatchStatusArray&) override {}
};

// `options`: the touched period turns the lag bound off (see there).
std::unique_ptr<host::Aggregator> make(const host::AggregatorOptions& options = {}) {
  auto a = host::Aggregator::create(&frames().map, SKINBUS_SOURCE_DIR, nullptr, {"can0"}, options);
  if (!a) std::abort();
  uint64_t t = 1;
  for (const auto& hb : frames().heartbeat) {
    for (const bus::CanFrame& fr : hb) (*a)->on_frame(0, fr, t++);
  }
  return std::move(*a);
}

// Frames of one sample carry a fresh sequence number each time, so none is a duplicate.
void feed(host::Aggregator& a, const std::array<bus::CanFrame, 2>& fr, uint8_t seq, uint64_t t) {
  for (bus::CanFrame f : fr) {
    f.data[1] = seq;  // header byte 1: the transfer sequence (the CRC covers the payload only)
    a.on_frame(0, f, t);
  }
}

// One idle stream-mode sample: two frames reassembled, registry, clock, flag test.
void BM_IdleSample(benchmark::State& state) {
  auto a = make();
  host::ContactArray out;
  uint64_t t = 1'000'000;
  uint8_t seq = 0;
  for (auto _ : state) {
    feed(*a, frames().idle[0], seq++, t += 24'000);
    benchmark::DoNotOptimize(a->process(t, &out));
  }
  if (a->stats().estimated != 0) state.SkipWithError("an idle sample reached a model");
}
BENCHMARK(BM_IdleSample);

// One period of P streaming patches, none touched, then a step of the host loop (per-patch cost
// = time / P).
void BM_IdlePeriod(benchmark::State& state) {
  const int p = static_cast<int>(state.range(0));
  auto a = make();
  NullSink sink;
  host::HostLoopOptions o;
  o.status_period_us = 0;  // the stages' costs: no status messages
  host::HostLoop loop(*a, sink, o);
  uint64_t t = 1'000'000;
  loop.start(t);
  uint8_t seq = 0;
  for (auto _ : state) {
    t += 24'000;
    ++seq;
    for (int i = 0; i < p; ++i) feed(*a, frames().idle[static_cast<std::size_t>(i)], seq, t);
    loop.step(t);  // process(), tick() every 100 ms: the daemon's cadence
  }
  // Seconds per idle patch per period (printed with an SI prefix: 400n = 0.4 us).
  state.counters["per_idle_patch"] =
      benchmark::Counter(static_cast<double>(state.iterations()) * p,
                         benchmark::Counter::kIsRate | benchmark::Counter::kInvert);
}
BENCHMARK(BM_IdlePeriod)->Arg(16)->Arg(64)->Arg(120)->Unit(benchmark::kMicrosecond);

// One period with T touched patches: one batched model run, placement, merge, tracking. The
// recorded frames carry one patch timestamp, so with the host's clock advancing every sample
// would look older each period and the lag bound would supersede it: the bound is off here (this
// measures the stages' cost; skinbus-bench host measures the lag handling with real timestamps).
void BM_TouchedPeriod(benchmark::State& state) {
  const int n = static_cast<int>(state.range(0));
  host::AggregatorOptions o;
  o.max_lag_us = 0;
  auto a = make(o);
  host::ContactArray out;
  uint64_t t = 1'000'000;
  uint8_t seq = 0;
  for (auto _ : state) {
    t += 24'000;
    ++seq;
    for (int i = 0; i < n; ++i) feed(*a, frames().pressed[static_cast<std::size_t>(i)], seq, t);
    benchmark::DoNotOptimize(a->process(t, &out));
  }
  if (static_cast<int>(out.contacts.size()) != n) state.SkipWithError("contacts missing");
}
BENCHMARK(BM_TouchedPeriod)->Arg(1)->Arg(6)->Arg(16)->Arg(64)->Unit(benchmark::kMicrosecond);

void BM_CommonMode(benchmark::State& state) {
  std::vector<double> f(48);
  sim::Rng rng(5);
  for (double& v : f) v = rng.uniform(-50, 50);
  for (auto _ : state) {
    benchmark::DoNotOptimize(host::estimate_common_mode(f));
  }
}
BENCHMARK(BM_CommonMode);

}  // namespace

BENCHMARK_MAIN();
