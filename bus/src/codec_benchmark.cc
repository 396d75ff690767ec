// Throughput of the bus hot path on one core: encode, decode and reassemble samples.
// Reported as frames per second and as a multiple of a full CAN FD bus carrying samples
// (1 Mbit/s arbitration, 5 Mbit/s data, worst-case stuffing; see skinbus/bus/budget.h).
//
//   build/bus/bus_codec_benchmark --benchmark_min_time=0.5
#include <benchmark/benchmark.h>

#include <chrono>
#include <random>
#include <vector>

#include "skinbus/bus/budget.h"
#include "skinbus/bus/candump.h"
#include "skinbus/bus/codec.h"
#include "skinbus/bus/reassembler.h"
#include "testing.h"

namespace skinbus::bus {
namespace {

double full_bus_frames_per_s(FrameKind kind) {
  const BusTiming t{kind == FrameKind::kFd, 1e6, kind == FrameKind::kFd ? 5e6 : 1e6};
  const BudgetResult b = compute_budget(t, PatchTraffic{41.7, 1.0, 0.0}, 1, 1.0);
  return b.sample_frames * 1e6 / b.sample_time_us;  // a bus carrying nothing but samples
}

std::vector<Message> samples(FrameKind kind, int n) {
  std::mt19937_64 rng(42);
  std::vector<Message> out;
  for (int i = 0; i < n; ++i) {
    out.push_back(testing::random_message(rng, MessageClass::kSample, kind,
                                          static_cast<uint8_t>(1 + i % 64),
                                          static_cast<uint8_t>(i / 64)));
  }
  return out;
}

using Clock = std::chrono::steady_clock;

// Frames per second over the timed loop (wall clock, one thread), and that rate as a multiple of
// a full bus of the same frame kind.
void set_counters(benchmark::State& state, FrameKind kind, double frames, Clock::time_point start) {
  const double s = std::chrono::duration<double>(Clock::now() - start).count();
  const double rate = s > 0 ? frames / s : 0;
  state.counters["frames_per_s"] = rate;
  state.counters["x_full_bus"] = rate / full_bus_frames_per_s(kind);
}

void BM_Encode(benchmark::State& state) {
  const auto kind = static_cast<FrameKind>(state.range(0));
  const auto msgs = samples(kind, 1024);
  CanFrame out[kMaxParts];
  std::size_t i = 0;
  double frames = 0;
  const auto start = Clock::now();
  for (auto _ : state) {
    const EncodeResult r = encode(msgs[i++ & 1023], out);
    benchmark::DoNotOptimize(out[0].data[5]);
    frames += static_cast<double>(r.frames);
  }
  set_counters(state, kind, frames, start);
}
BENCHMARK(BM_Encode)
    ->ArgName("fd")
    ->Arg(static_cast<int>(FrameKind::kFd))
    ->Arg(static_cast<int>(FrameKind::kClassic));

void BM_DecodeReassemble(benchmark::State& state) {
  const auto kind = static_cast<FrameKind>(state.range(0));
  const auto msgs = samples(kind, 1024);
  std::vector<CanFrame> wire;
  for (const Message& m : msgs) {
    for (const CanFrame& f : testing::encode_frames(m)) wire.push_back(f);
  }
  Reassembler r;
  uint64_t t = 0;
  std::size_t i = 0;
  double emitted = 0;
  const auto start = Clock::now();
  for (auto _ : state) {
    const FeedResult res = r.feed(wire[i], t += 10);
    emitted += res.status == FeedStatus::kMessage;
    if (++i == wire.size()) {
      i = 0;
      state.PauseTiming();
      r.reset();  // the same sequences come round again: start a fresh history
      state.ResumeTiming();
    }
  }
  set_counters(state, kind, static_cast<double>(state.iterations()), start);
  state.counters["samples"] = emitted;
}
BENCHMARK(BM_DecodeReassemble)
    ->ArgName("fd")
    ->Arg(static_cast<int>(FrameKind::kFd))
    ->Arg(static_cast<int>(FrameKind::kClassic));

// The whole host-side path a frame takes in a log replay: parse a candump line, reassemble.
void BM_CandumpParseReassemble(benchmark::State& state) {
  const auto msgs = samples(FrameKind::kFd, 256);
  std::vector<std::string> lines;
  for (const Message& m : msgs) {
    for (const CanFrame& f : testing::encode_frames(m))
      lines.push_back(format_candump_line(f, 1000000, "can0"));
  }
  Reassembler r;
  uint64_t t = 0;
  std::size_t i = 0;
  const auto start = Clock::now();
  for (auto _ : state) {
    CandumpRecord rec;
    parse_candump_line(lines[i], &rec);
    benchmark::DoNotOptimize(r.feed(rec.frame, t += 10));
    if (++i == lines.size()) {
      i = 0;
      state.PauseTiming();
      r.reset();
      state.ResumeTiming();
    }
  }
  set_counters(state, FrameKind::kFd, static_cast<double>(state.iterations()), start);
}
BENCHMARK(BM_CandumpParseReassemble);

// Encode, then decode and reassemble the same frames: the round trip of one sample.
void BM_RoundTrip(benchmark::State& state) {
  const auto kind = static_cast<FrameKind>(state.range(0));
  const auto msgs = samples(kind, 1024);
  Reassembler r;
  CanFrame out[kMaxParts];
  uint64_t t = 0;
  std::size_t i = 0;
  double frames = 0;
  const auto start = Clock::now();
  for (auto _ : state) {
    const EncodeResult e = encode(msgs[i], out);
    for (std::size_t k = 0; k < e.frames; ++k) benchmark::DoNotOptimize(r.feed(out[k], t += 10));
    frames += static_cast<double>(e.frames);
    if (++i == msgs.size()) {
      i = 0;
      state.PauseTiming();
      r.reset();
      state.ResumeTiming();
    }
  }
  set_counters(state, kind, frames, start);
}
BENCHMARK(BM_RoundTrip)
    ->ArgName("fd")
    ->Arg(static_cast<int>(FrameKind::kFd))
    ->Arg(static_cast<int>(FrameKind::kClassic));

}  // namespace
}  // namespace skinbus::bus

BENCHMARK_MAIN();
