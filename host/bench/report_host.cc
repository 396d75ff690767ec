// `skinbus-bench host`: the host aggregator's latency and CPU use for many patches, some touched.
//
// A synthetic bus: every patch samples on the same SYNC at 41.7 Hz; each bus carries its
// patches' frames one after another at their CAN FD wire time (bus/budget.h), in node order, so
// frames arrive in bursts as they would. Touched patches send the tared fields of simulated
// presses (the nominal unit, a pool of presses) with the contact flag; idle ones send noise
// without it (stream mode) or nothing but heartbeats (event mode). All frames are encoded before
// the clock starts.
//
// Two passes per configuration:
//  - paced: frames are fed at their arrival times (sleeping in between); whenever the next frame
//    is not due yet, the host loop (host_loop.h, the daemon's cadence: process, tick every 100
//    ms, status every second) steps over what arrived. The
//    latency of a sample runs from its last frame's arrival to the end of process() that
//    published its contact (the ContactArray ready for the outputs; the DDS write is not
//    included), over the samples after a 0.5 s warm-up. CPU use: the process's CPU time over the
//    wall time of the run (to the end of its last period).
//    With the lag bound on (--max-lag-ms, the aggregator's default 100 ms) the aggregator
//    reads the clock and supersedes the samples it cannot publish in time ("late"); the latency
//    is then over the samples it published. --model-delay-us makes every estimate slower, as a
//    slower CPU would.
//  - unpaced: the same frames fed as fast as possible, the loop stepping at every pause of more
//    than 1 ms on the bus: host time per period, and per idle patch per period (the 0 % touched
//    rows).
#include <time.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <span>
#include <string>
#include <thread>
#include <vector>

#include "skinbus/bus/budget.h"
#include "skinbus/bus/codec.h"
#include "skinbus/bus/socketcan.h"
#include "skinbus/common/error_format.h"
#include "skinbus/common/stats.h"
#include "skinbus/host/aggregator.h"
#include "skinbus/host/host_loop.h"
#include "skinbus/host_bench/reports.h"
#include "skinbus/record/recorder.h"
#include "skinbus/sim/rng.h"
#include "skinbus/sim/simulated_patch.h"

namespace skinbus::host_bench {

namespace {

constexpr double kRateHz = 41.7;
// Latencies of samples in the first half second are left out: the first model runs touch cold
// memory and wake the worker threads (a start-up cost, not a steady-state one).
constexpr uint64_t kWarmUpUs = 500'000;

double cpu_s() {
  timespec ts;
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
  return static_cast<double>(ts.tv_sec) + static_cast<double>(ts.tv_nsec) * 1e-9;
}

struct TimedFrame {
  uint64_t at_us;  // arrival, from the start of the run
  int bus;
  bus::CanFrame frame;
};

struct Setup {
  body_map::SkinMap map;
  std::vector<std::string> buses;
  std::vector<TimedFrame> frames;
  int periods = 0;
  int touched = 0;
  uint64_t end_us = 0;  // the end of the last period
};

// Tared press fields (LSB) of the nominal unit at random points, and idle noise samples.
struct Pool {
  std::vector<std::array<int16_t, bus::kChannelCount>> press, idle;
};

Pool make_pool(uint64_t seed) {
  Pool pool;
  auto model = sim::PatchModel::nominal(sim::PatchDesign{});
  sim::SimulatedPatch patch(*model, seed);
  sim::Rng rng(seed);
  std::vector<double> base(static_cast<std::size_t>(patch.channel_count())), f(base.size());
  sim::Environment env;
  patch.tare(env, 32, base);
  auto to_lsb = [](std::span<const double> tared, std::array<int16_t, bus::kChannelCount>* out) {
    for (int c = 0; c < bus::kChannelCount; ++c) {
      (*out)[static_cast<std::size_t>(c)] =
          bus::field_ut_to_lsb(tared[static_cast<std::size_t>(c)]);
    }
  };
  std::vector<double> tared(base.size());
  for (int k = 0; k < 64; ++k) {
    const sim::Contact c{rng.uniform(-55, 55), rng.uniform(-55, 55), rng.uniform(1, 3), 5.0};
    patch.measure(std::span<const sim::Contact>(&c, 1), env, f);
    for (std::size_t i = 0; i < f.size(); ++i) tared[i] = f[i] - base[i];
    to_lsb(tared, &pool.press.emplace_back());
    patch.measure({}, env, f);
    for (std::size_t i = 0; i < f.size(); ++i) tared[i] = f[i] - base[i];
    to_lsb(tared, &pool.idle.emplace_back());
  }
  return pool;
}

Setup make_setup(const Pool& pool, int patches, double touched_fraction, double seconds,
                 bool stream) {
  Setup s;
  const bus::BusTiming timing;
  bus::PatchTraffic traffic;
  traffic.sample_rate_hz = kRateHz;
  const int per_bus = std::max(1, bus::compute_budget(timing, traffic, 1, 0.85).max_patches);
  const int nbus = (patches + per_bus - 1) / per_bus;
  for (int b = 0; b < nbus; ++b) s.buses.push_back("can" + std::to_string(b));
  s.touched = static_cast<int>(std::lround(touched_fraction * patches));
  for (int i = 0; i < patches; ++i) {
    body_map::PatchPlacement p;
    p.node_id = 1 + i / nbus;  // patches dealt over the buses: node IDs repeat across buses
    p.hardware_uid = 0xB0000000000000ull + static_cast<uint64_t>(i);
    p.link = "base";
    // Spread the patches on a plane so no two presses merge.
    p.pose_on_link.translation_mm = {200.0 * (i % 20), 200.0 * (i / 20), 0};
    p.model = "estimators/models/nominal_seed_cnn";
    s.map.patches.push_back(p);
  }
  // Touched patches: every (patches / touched)-th, so they spread over the buses.
  std::vector<bool> is_touched(static_cast<std::size_t>(patches), false);
  for (int k = 0; k < s.touched; ++k) {
    is_touched[static_cast<std::size_t>(static_cast<long>(k) * patches / s.touched)] = true;
  }
  const double period_us = 1e6 / kRateHz;
  s.periods = static_cast<int>(seconds * kRateHz);
  std::array<bus::CanFrame, 4> buf;
  std::vector<uint8_t> seq(static_cast<std::size_t>(patches), 0);
  std::vector<double> bus_free_us(static_cast<std::size_t>(nbus), 0);
  auto put = [&](int i, const bus::Message& m, uint64_t t0) {
    const bus::EncodeResult r = bus::encode(m, buf);
    const int b = i % nbus;
    double& free_us = bus_free_us[static_cast<std::size_t>(b)];
    free_us = std::max(free_us, static_cast<double>(t0));
    for (std::size_t f = 0; f < r.frames; ++f) {
      free_us += bus::frame_time_us(timing, buf[f].len);
      s.frames.push_back({static_cast<uint64_t>(free_us), b, buf[f]});
    }
  };
  // Heartbeats first, so every patch is identified by its UID before samples flow, then one a
  // second (at the start of the period where the second turns).
  std::vector<uint8_t> hb_seq(static_cast<std::size_t>(patches), 0);
  auto heartbeats = [&](uint64_t t0, uint32_t uptime_s) {
    for (int i = 0; i < patches; ++i) {
      bus::Heartbeat hb;
      hb.state = bus::PatchState::kRunning;
      hb.mode = stream ? bus::PatchMode::kStream : bus::PatchMode::kEvent;
      hb.hardware_uid = s.map.patches[static_cast<std::size_t>(i)].hardware_uid;
      hb.uptime_s = uptime_s;
      put(i,
          bus::Message{static_cast<uint8_t>(s.map.patches[static_cast<std::size_t>(i)].node_id),
                       hb_seq[static_cast<std::size_t>(i)]++, bus::FrameKind::kFd, hb},
          t0);
    }
  };
  heartbeats(0, 10);
  const uint64_t start_us = 50'000;
  for (int k = 0; k < s.periods; ++k) {
    const uint64_t t0 = start_us + static_cast<uint64_t>(k * period_us);
    if (k > 0 && static_cast<int>(k / kRateHz) != static_cast<int>((k - 1) / kRateHz)) {
      heartbeats(t0, 10 + static_cast<uint32_t>(k / kRateHz));
    }
    for (int i = 0; i < patches; ++i) {
      const bool touched = is_touched[static_cast<std::size_t>(i)];
      if (!touched && !stream) continue;
      bus::Sample smp;
      smp.timestamp_us = static_cast<uint32_t>(t0);
      smp.flags = bus::sample_flags::kTared | bus::sample_flags::kSynced |
                  (touched ? bus::sample_flags::kContact : 0);
      const auto& f = touched
                          ? pool.press[static_cast<std::size_t>((i + k / 40) % pool.press.size())]
                          : pool.idle[static_cast<std::size_t>((i + k) % pool.idle.size())];
      smp.field_lsb = f;
      put(i,
          bus::Message{static_cast<uint8_t>(s.map.patches[static_cast<std::size_t>(i)].node_id),
                       seq[static_cast<std::size_t>(i)]++, bus::FrameKind::kFd, smp},
          t0);
    }
  }
  s.end_us = start_us + static_cast<uint64_t>(s.periods * period_us);
  std::stable_sort(s.frames.begin(), s.frames.end(),
                   [](const TimedFrame& a, const TimedFrame& b) { return a.at_us < b.at_us; });
  return s;
}

struct Row {
  int patches = 0, buses = 0, touched = 0;
  double p50_us = NAN, p99_us = NAN, max_us = NAN, cpu_percent = NAN;
  double period_us = NAN, idle_patch_us = NAN;
  uint64_t estimated = 0, publications = 0, late = 0;
  // --record: the same unpaced run while recorded (us/period) and the recording's size.
  double recorded_period_us = NAN, mb_per_min = NAN, messages_per_s = NAN;
  double recorded_cpu_percent = NAN;  // the paced run, recorded
};

// `paced`: on the monotonic clock (the frames' times), with the lag bound measuring the runs.
skinbus::Result<std::unique_ptr<host::Aggregator>> make_aggregator(const Setup& s,
                                                                   const HostBenchArgs& a,
                                                                   bool paced,
                                                                   host::InputTap* tap = nullptr) {
  host::AggregatorOptions o;
  o.tap = tap;
  o.runtime.threads = a.threads;
  o.runtime.precision = a.precision == "int8"       ? estimators::RuntimePrecision::kInt8
                        : a.precision == "bfloat16" ? estimators::RuntimePrecision::kBfloat16
                                                    : estimators::RuntimePrecision::kFloat32;
  parse_isa(a.isa, &o.runtime.max_isa);
  o.max_lag_us = static_cast<uint64_t>(std::llround(a.max_lag_ms * 1000));
  o.model_delay_us = static_cast<uint64_t>(a.model_delay_us);
  if (paced) o.clock_us = bus::monotonic_now_us;
  const char* src = SKINBUS_SOURCE_DIR;
  auto agg = host::Aggregator::create(&s.map, src, nullptr, s.buses, o);
  if (!agg) return agg.error();
  static bool said = false;  // the kernels in use, once
  if (!said) {
    said = true;
    for (const std::string& m : (*agg)->model_descriptions()) std::printf("model: %s\n", m.c_str());
  }
  return std::move(*agg);
}

// The latencies of the loop's publications: from each estimated sample's receive time to the
// end of the process() that published it, over the samples received from `from_us` on.
class LatencySink : public host::HostSink {
 public:
  LatencySink(uint64_t from_us, std::vector<double>* latencies_us,
              record::Recorder* recorder = nullptr)
      : from_us_(from_us), lat_(latencies_us), recorder_(recorder) {}
  void contacts(const host::ContactArray& c, std::span<const uint64_t> rx_us) override {
    if (recorder_ != nullptr) recorder_->contacts(c);
    if (lat_ == nullptr) return;
    const uint64_t done = bus::monotonic_now_us();
    for (uint64_t rx : rx_us) {
      if (rx >= from_us_) lat_->push_back(static_cast<double>(done - rx));
    }
  }
  void status(const host::PatchStatusArray& s) override {
    if (recorder_ != nullptr) recorder_->status(s);
  }

 private:
  uint64_t from_us_;
  std::vector<double>* lat_;
  record::Recorder* recorder_;
};

// A recorder into `path` for a run of `s` (none for an empty path).
Status open_recorder(const std::string& path, const Setup& s,
                     std::unique_ptr<record::Recorder>* out) {
  if (path.empty()) return Status::Ok();
  auto made = record::Recorder::create(path, s.buses, nullptr);
  if (!made.ok()) return made.error();
  *out = std::move(*made);
  return Status::Ok();
}

// Paced; with `record_path`, recorded into it (only r->recorded_cpu_percent is set then).
Status run_paced(const Setup& s, const HostBenchArgs& a, Row* r,
                 const std::string& record_path = {}) {
  std::unique_ptr<record::Recorder> recorder;
  if (Status st = open_recorder(record_path, s, &recorder); !st.ok()) return st;
  auto made = make_aggregator(s, a, true, recorder.get());
  if (!made.ok()) return made.error();
  std::unique_ptr<host::Aggregator> agg = std::move(made.value());
  std::vector<double> lat;
  lat.reserve(s.frames.size());
  const uint64_t t_start = bus::monotonic_now_us() + 1000;
  LatencySink sink(t_start + kWarmUpUs, &lat, recorder.get());
  host::HostLoop loop(*agg, sink);
  loop.start(t_start);
  const double cpu0 = cpu_s();
  bool fed = false;
  for (std::size_t i = 0; i < s.frames.size(); ++i) {
    const TimedFrame& f = s.frames[i];
    const uint64_t due = t_start + f.at_us;
    uint64_t t = bus::monotonic_now_us();
    if (t < due) {
      if (fed) {
        loop.step(t);  // the bus is quiet until the next frame: the pipeline runs
        fed = false;
      }
      t = bus::monotonic_now_us();
      if (t < due) std::this_thread::sleep_for(std::chrono::microseconds(due - t));
    }
    // The frame is stamped with its arrival time (as the kernel stamps it), not with when this
    // loop got to it: a late loop shows as latency.
    agg->on_frame(f.bus, f.frame, due);
    fed = true;
  }
  // Idle to the end of the last period, as the daemon's poll loop (20 ms timeouts): an
  // event-mode bus with nothing touched still costs its timers.
  uint64_t t = bus::monotonic_now_us();
  loop.step(t);
  while ((t = bus::monotonic_now_us()) < t_start + s.end_us) {
    loop.step(t);
    std::this_thread::sleep_for(
        std::chrono::microseconds(std::min<uint64_t>(20'000, t_start + s.end_us - t)));
  }
  if (recorder) {
    loop.finish(bus::monotonic_now_us());
    if (Status st = recorder->close(); !st.ok()) return st;
  }
  const double wall = static_cast<double>(bus::monotonic_now_us() - t_start) * 1e-6;
  if (recorder) {
    r->recorded_cpu_percent = 100 * (cpu_s() - cpu0) / wall;
    return Status::Ok();
  }
  r->cpu_percent = 100 * (cpu_s() - cpu0) / wall;
  if (!lat.empty()) {
    r->p50_us = quantile(lat, 0.5);
    r->p99_us = quantile(lat, 0.99);
    r->max_us = *std::max_element(lat.begin(), lat.end());
  }
  r->estimated = agg->stats().estimated;
  r->publications = agg->stats().publications;
  r->late = agg->stats().late_superseded;
  return Status::Ok();
}

// Fed as fast as possible; with `record_path`, recorded into it (r->recorded_period_us and the
// recording's size; else r->period_us).
Status run_unpaced(const Setup& s, const HostBenchArgs& a, Row* r,
                   const std::string& record_path = {}) {
  std::unique_ptr<record::Recorder> recorder;
  if (Status st = open_recorder(record_path, s, &recorder); !st.ok()) return st;
  auto made = make_aggregator(s, a, false, recorder.get());
  if (!made.ok()) return made.error();
  std::unique_ptr<host::Aggregator> agg = std::move(made.value());
  LatencySink sink(0, nullptr, recorder.get());
  host::HostLoop loop(*agg, sink);
  // Warm-up: the heartbeats (identification), outside the timing.
  std::size_t i = 0;
  for (; i < s.frames.size() && s.frames[i].at_us < 50'000; ++i) {
    agg->on_frame(s.frames[i].bus, s.frames[i].frame, s.frames[i].at_us);
  }
  loop.start(i < s.frames.size() ? s.frames[i].at_us : 0);
  const auto t0 = std::chrono::steady_clock::now();
  uint64_t last = 0;
  for (; i < s.frames.size(); ++i) {
    const TimedFrame& f = s.frames[i];
    if (f.at_us > last + 1000) loop.step(f.at_us);  // a pause on the bus: the loop runs here
    last = f.at_us;
    agg->on_frame(f.bus, f.frame, f.at_us);
  }
  loop.step(last + 1);
  if (recorder) {
    loop.finish(last + 1);
    if (Status st = recorder->close(); !st.ok()) return st;
  }
  const double us =
      std::chrono::duration<double, std::micro>(std::chrono::steady_clock::now() - t0).count();
  if (recorder) {
    r->recorded_period_us = us / s.periods;
    const double minutes = static_cast<double>(s.end_us) / 60e6;
    r->mb_per_min = static_cast<double>(recorder->stats().bytes) / 1e6 / minutes;
    r->messages_per_s = static_cast<double>(recorder->stats().messages) / (minutes * 60);
    return Status::Ok();
  }
  r->period_us = us / s.periods;
  if (r->touched == 0) r->idle_patch_us = r->period_us / r->patches;
  return Status::Ok();
}

}  // namespace

Status bench_host(const HostBenchArgs& a) {
  if (a.mode != "stream" && a.mode != "event") {
    return make_error(ErrorCode::kInvalidArgument, "--mode stream or event");
  }
  const bool stream = a.mode == "stream";
  const Pool pool = make_pool(0xB0B0);
  std::printf(
      "host aggregator: %s mode, 41.7 Hz, SYNC'd patches, CAN FD 1/5 Mbit/s buses of up "
      "to 85%% load, %.0f s per configuration, model runtime threads %d (%s, at most %s), %u "
      "cores, lag bound %g ms, model delay %d us\n",
      a.mode.c_str(), a.seconds, a.threads, a.precision.c_str(), a.isa.c_str(),
      std::thread::hardware_concurrency(), a.max_lag_ms, a.model_delay_us);
  std::printf("\n%8s %6s %8s %10s %10s %10s %8s %12s %14s %10s %8s\n", "patches", "buses",
              "touched", "p50 us", "p99 us", "max us", "CPU %", "us/period", "us/idle patch",
              "estimated", "late");
  std::vector<Row> rows;
  for (int n : a.patches) {
    for (double pct : a.touched_percent) {
      const Setup s = make_setup(pool, n, pct / 100, a.seconds, stream);
      Row r;
      r.patches = n;
      r.buses = static_cast<int>(s.buses.size());
      r.touched = s.touched;
      // Unpaced runs time the host's own work: not with an artificial delay.
      if (Status st = run_paced(s, a, &r); !st.ok()) return st;
      if (a.model_delay_us == 0) {
        if (Status st = run_unpaced(s, a, &r); !st.ok()) return st;
        if (!a.record.empty()) {
          if (Status st = run_unpaced(s, a, &r, a.record); !st.ok()) return st;
          if (Status st = run_paced(s, a, &r, a.record); !st.ok()) return st;
        }
      }
      std::printf(
          "%8d %6d %7.0f%% %10.0f %10.0f %10.0f %8.1f %12.1f %14s %10llu %8llu\n", n, r.buses, pct,
          r.p50_us, r.p99_us, r.max_us, r.cpu_percent, r.period_us,
          std::isfinite(r.idle_patch_us) ? std::to_string(r.idle_patch_us).substr(0, 6).c_str()
                                         : "-",
          static_cast<unsigned long long>(r.estimated), static_cast<unsigned long long>(r.late));
      std::fflush(stdout);
      rows.push_back(r);
    }
  }
  std::printf(
      "\nlatency: last frame of a sample on the bus -> its ContactArray ready (p50/p99/max "
      "over every touched sample; '-' rows have none). CPU %%: process CPU time / wall "
      "time while paced. us/period: host time per 1/41.7 s period when fed as fast as "
      "possible; us/idle patch: that over the patches, with none touched. late: samples the lag "
      "bound superseded while paced.\n");
  if (!a.record.empty()) {
    std::printf(
        "\nrecording (skinbus-host --record: every frame, sample, publication and status "
        "into %s; the same unpaced runs, recorded and not):\n",
        a.record.c_str());
    std::printf("\n%8s %8s %12s %14s %12s %8s %15s %12s %12s\n", "patches", "touched", "us/period",
                "recorded us/p", "added CPU", "CPU %", "recorded CPU %", "MB/minute", "messages/s");
    for (const Row& r : rows) {
      const double added = 100 * (r.recorded_period_us - r.period_us) / (1e6 / kRateHz);
      std::printf("%8d %8d %12.1f %14.1f %11.2f%% %8.1f %15.1f %12.2f %12.0f\n", r.patches,
                  r.touched, r.period_us, r.recorded_period_us, added, r.cpu_percent,
                  r.recorded_cpu_percent, r.mb_per_min, r.messages_per_s);
    }
    std::printf(
        "\nus/period: the host's time per 1/41.7 s period fed as fast as possible, without "
        "and with recording; added CPU: their difference, in percent of one core at "
        "41.7 Hz. CPU %%: of one core while paced (as the host runs), without and with "
        "(noisier: the model runs' own spread).\n");
  }
  if (!a.csv.empty()) {
    std::ofstream f(a.csv);
    f << "mode,patches,buses,touched,p50_us,p99_us,max_us,cpu_percent,us_per_period,us_per_idle_"
         "patch,late,recorded_us_per_period,recording_mb_per_min,recorded_cpu_percent\n";
    for (const Row& r : rows) {
      f << a.mode << ',' << r.patches << ',' << r.buses << ',' << r.touched << ',' << r.p50_us
        << ',' << r.p99_us << ',' << r.max_us << ',' << r.cpu_percent << ',' << r.period_us << ','
        << r.idle_patch_us << ',' << r.late << ',' << r.recorded_period_us << ',' << r.mb_per_min
        << ',' << r.recorded_cpu_percent << '\n';
    }
  }
  return Status::Ok();
}

}  // namespace skinbus::host_bench
