#include "skinbus/host/host_loop.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <array>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "skinbus/body_map/robot_model.h"
#include "skinbus/bus/candump.h"
#include "skinbus/bus/codec.h"
#include "skinbus/sim/simulated_patch.h"

namespace skinbus::host {
namespace {

constexpr uint64_t kUid = 0x5EED000000000003ull;
constexpr uint64_t kPeriodUs = 23'981;               // 41.7 Hz
constexpr uint64_t kLogT0 = 1'700'000'000'000'000;   // the log's first stamp
constexpr uint64_t kWallT0 = 1'800'000'000'000'000;  // the injected clock's start

std::string source_dir() {
  const char* d = std::getenv("SKINBUS_SOURCE_DIR");
  return d != nullptr ? d : ".";
}

body_map::SkinMap one_patch_map() {
  body_map::SkinMap map;
  body_map::PatchPlacement p;
  p.node_id = 3;
  p.hardware_uid = kUid;
  p.link = "arm";
  p.model = "estimators/models/nominal_seed_cnn";
  map.patches.push_back(p);
  return map;
}

// Tared fields of the nominal unit pressed at (u, v, depth).
std::vector<double> press(double u_mm, double v_mm, double depth_mm) {
  auto model = sim::PatchModel::nominal(sim::PatchDesign{});
  sim::SimulatedPatch patch(*model, 7);
  std::vector<double> base(static_cast<std::size_t>(patch.channel_count())), f(base.size());
  sim::Environment env;
  patch.tare(env, 32, base);
  const sim::Contact c{u_mm, v_mm, depth_mm, 5.0};
  patch.measure(std::span<const sim::Contact>(&c, 1), env, f);
  for (std::size_t i = 0; i < f.size(); ++i) f[i] -= base[i];
  return f;
}

// A candump -L log of node 3: a heartbeat, then `samples` pressed samples at 41.7 Hz from
// kLogT0 (a silence of `gap_us` after the first half), then (`release`) one without the contact
// flag.
std::string make_log(int samples, const std::string& iface = "can0", uint64_t gap_us = 0,
                     bool release = true) {
  std::string out;
  uint8_t seq_hb = 0, seq = 0;
  auto put = [&](const bus::MessageBody& body, uint8_t s, uint64_t t_us) {
    std::array<bus::CanFrame, bus::kMaxParts> frames;
    const bus::EncodeResult r = bus::encode(bus::Message{3, s, bus::FrameKind::kFd, body}, frames);
    for (std::size_t i = 0; i < r.frames; ++i) {
      out += bus::format_candump_line(frames[i], t_us + i * 50, iface) + "\n";
    }
  };
  bus::Heartbeat hb;
  hb.state = bus::PatchState::kRunning;
  hb.mode = bus::PatchMode::kEvent;
  hb.hardware_uid = kUid;
  hb.uptime_s = 5;
  put(hb, seq_hb++, kLogT0);
  const std::vector<double> f = press(10, -15, 2.0);
  uint64_t t = kLogT0;
  for (int k = 0; k < samples + (release ? 1 : 0); ++k) {
    t += kPeriodUs;
    if (k == samples / 2) t += gap_us;
    bus::Sample s;
    s.timestamp_us = static_cast<uint32_t>(t);
    s.flags = bus::sample_flags::kTared | (k < samples ? bus::sample_flags::kContact : 0);
    for (int c = 0; c < bus::kChannelCount; ++c) {
      s.field_lsb[static_cast<std::size_t>(c)] =
          k < samples ? bus::field_ut_to_lsb(f[static_cast<std::size_t>(c)]) : 0;
    }
    put(s, seq++, t);
  }
  return out;
}

struct TempDir {
  std::filesystem::path path;
  TempDir() {
    char tmpl[] = "/tmp/host_loop_test.XXXXXX";
    path = ::mkdtemp(tmpl);
  }
  ~TempDir() { std::filesystem::remove_all(path); }
  std::string write(const std::string& name, const std::string& text) const {
    const std::string p = (path / name).string();
    std::ofstream(p) << text;
    return p;
  }
};

// Records what the loop hands its sink.
struct RecordingSink : HostSink {
  std::vector<ContactArray> publications;
  std::vector<std::size_t> measured;  // receive times given with each publication
  std::vector<PatchStatusArray> statuses;
  std::vector<std::string> lines;
  void contacts(const ContactArray& c, std::span<const uint64_t> rx_us) override {
    publications.push_back(c);
    measured.push_back(rx_us.size());
  }
  void status(const PatchStatusArray& s) override { statuses.push_back(s); }
  void log(const std::string& line) override { lines.push_back(line); }
  bool has_event(PatchEventKind k) const {
    for (const PatchStatusArray& s : statuses) {
      for (const PatchEvent& e : s.events) {
        if (e.kind == k) return true;
      }
    }
    return false;
  }
};

// A clock that only moves when the loop sleeps.
struct FakeClock {
  uint64_t now = kWallT0;
  uint64_t slept = 0;
  HostClock clock() {
    return HostClock{[this] { return now; },
                     [this](uint64_t us) {
                       now += us;
                       slept += us;
                     },
                     {}};
  }
};

struct Fixture {
  body_map::SkinMap map = one_patch_map();
  std::unique_ptr<Aggregator> agg;
  RecordingSink sink;
  FakeClock clock;
  explicit Fixture(const HostLoopOptions& o) {
    auto a = Aggregator::create(&map, source_dir(), nullptr, HostLoop::bus_names(o));
    EXPECT_TRUE(a.ok()) << a.error().to_string();
    agg = std::move(*a);
  }
};

TEST(HostLoop, ReplayAtRecordedSpeedIsPacedByTheLogsTime) {
  TempDir dir;
  HostLoopOptions o;
  o.replay = dir.write("bus.log", make_log(84));  // 2 s of presses
  Fixture f(o);
  o.clock = f.clock.clock();
  HostLoop loop(*f.agg, f.sink, o);
  ASSERT_TRUE(loop.run().ok());
  // The loop slept until every frame was due: the log's span (85 periods and the last parts).
  const uint64_t span_us = 85 * kPeriodUs + 50;
  EXPECT_GE(f.clock.slept, span_us - 1000);
  EXPECT_LE(f.clock.slept, span_us + 1000);
  EXPECT_EQ(loop.run_start_us(), kWallT0);
  // Every publication of the aggregator reached the sink, with receive times (host clock) for
  // those that estimated samples; the press sits on its patch; the last is the release.
  ASSERT_EQ(f.sink.publications.size(), f.agg->stats().publications);
  ASSERT_GE(f.sink.publications.size(), 2u);
  const ContactArray& first = f.sink.publications.front();
  ASSERT_EQ(first.contacts.size(), 1u);
  EXPECT_NEAR(first.contacts[0].position_mm[0], 10, 3);
  EXPECT_NEAR(first.contacts[0].position_mm[1], -15, 3);
  EXPECT_GE(first.stamp_us, kWallT0);  // host time, not the log's
  EXPECT_GT(f.sink.measured.front(), 0u);
  EXPECT_TRUE(f.sink.publications.back().contacts.empty());
  EXPECT_EQ(f.agg->stats().estimated, 84u);
  // Status at the start, after 1 s and 2 s, and at the end; the patch's discovery in it.
  EXPECT_EQ(f.sink.statuses.size(), 4u);
  EXPECT_TRUE(f.sink.has_event(PatchEventKind::kDiscovered));
  EXPECT_TRUE(f.sink.lines.empty());
}

TEST(HostLoop, FastReplayRunsOnTheLogsTimeWithoutSleeping) {
  TempDir dir;
  HostLoopOptions o;
  o.replay = dir.write("bus.log", make_log(84));
  o.pace = ReplayPace::kFast;
  EXPECT_FALSE(HostLoop::on_host_clock(o));
  Fixture f(o);
  o.clock = f.clock.clock();
  HostLoop loop(*f.agg, f.sink, o);
  ASSERT_TRUE(loop.run().ok());
  EXPECT_EQ(f.clock.slept, 0u);
  EXPECT_EQ(loop.run_start_us(), kLogT0);
  ASSERT_GE(f.sink.publications.size(), 2u);
  const ContactArray& first = f.sink.publications.front();
  EXPECT_GE(first.stamp_us, kLogT0);
  EXPECT_LT(first.stamp_us, kLogT0 + 1'000'000);
  for (std::size_t n : f.sink.measured) EXPECT_EQ(n, 0u);  // no latency on log time
  EXPECT_EQ(f.sink.statuses.size(), 4u);
}

TEST(HostLoop, ALongSilenceIsReplayedAsTheGapCapAndReported) {
  TempDir dir;
  HostLoopOptions o;
  o.replay = dir.write("bus.log", make_log(20, "can0", 60'000'000));
  o.max_gap_us = 2'000'000;
  Fixture f(o);
  o.clock = f.clock.clock();
  HostLoop loop(*f.agg, f.sink, o);
  ASSERT_TRUE(loop.run().ok());
  EXPECT_GE(f.clock.slept, 2'000'000u);
  EXPECT_LT(f.clock.slept, 3'000'000u);
  EXPECT_TRUE(f.sink.has_event(PatchEventKind::kLogTime));
}

TEST(HostLoop, DurationEndsAReplay) {
  TempDir dir;
  HostLoopOptions o;
  o.replay = dir.write("bus.log", make_log(84));
  o.pace = ReplayPace::kFast;
  o.duration_us = 500'000;
  Fixture f(o);
  HostLoop loop(*f.agg, f.sink, o);
  ASSERT_TRUE(loop.run().ok());
  EXPECT_GT(f.agg->stats().estimated, 10u);
  EXPECT_LT(f.agg->stats().estimated, 25u);
}

TEST(HostLoop, AStopRequestEndsAReplayAtOnce) {
  TempDir dir;
  HostLoopOptions o;
  o.replay = dir.write("bus.log", make_log(84));
  Fixture f(o);
  o.clock = f.clock.clock();
  o.clock.stop_requested = [&] { return f.clock.now > kWallT0 + 300'000; };
  HostLoop loop(*f.agg, f.sink, o);
  ASSERT_TRUE(loop.run().ok());
  EXPECT_LT(f.clock.slept, 400'000u);
  ASSERT_FALSE(f.sink.statuses.empty());  // the final status still goes out
}

TEST(HostLoop, FramesOfInterfacesNotNamedAreSkippedAndALogWithNoneIsAnError) {
  TempDir dir;
  HostLoopOptions o;
  o.replay = dir.write("other.log", make_log(10, "vcan7"));
  o.pace = ReplayPace::kFast;
  o.interfaces = {"can0"};
  Fixture f(o);
  HostLoop loop(*f.agg, f.sink, o);
  const Status st = loop.run();
  ASSERT_FALSE(st.ok());
  EXPECT_NE(st.error().message.find("other.log"), std::string::npos) << st.error().message;
  EXPECT_NE(st.error().message.find("vcan7"), std::string::npos) << st.error().message;
  EXPECT_TRUE(f.sink.has_event(PatchEventKind::kBadFrames));
  ASSERT_EQ(f.sink.lines.size(), 1u);
  EXPECT_NE(f.sink.lines[0].find("not named with -i"), std::string::npos);
}

TEST(HostLoop, ALogOutOfTimeOrderIsAnError) {
  TempDir dir;
  std::string lines;
  const std::string log = make_log(20);
  std::vector<std::string> all;
  for (std::size_t a = 0, b; (b = log.find('\n', a)) != std::string::npos; a = b + 1) {
    all.push_back(log.substr(a, b - a + 1));
  }
  for (auto it = all.rbegin(); it != all.rend(); ++it) lines += *it;  // reversed
  HostLoopOptions o;
  o.replay = dir.write("reversed.log", lines);
  o.pace = ReplayPace::kFast;
  Fixture f(o);
  HostLoop loop(*f.agg, f.sink, o);
  const Status st = loop.run();
  ASSERT_FALSE(st.ok());
  EXPECT_NE(st.error().message.find("reversed.log"), std::string::npos);
  EXPECT_NE(st.error().message.find("not in time order"), std::string::npos);
}

TEST(HostLoop, UnreadableInputsAreErrorsNamingThem) {
  TempDir dir;
  for (const std::string& replay : {(dir.path / "missing.log").string(), dir.path.string()}) {
    for (ReplayPace pace : {ReplayPace::kRecorded, ReplayPace::kFast, ReplayPace::kLive}) {
      HostLoopOptions o;
      o.replay = replay;
      o.pace = pace;
      Fixture f(o);
      HostLoop loop(*f.agg, f.sink, o);
      const Status st = loop.run();
      ASSERT_FALSE(st.ok()) << replay;
      EXPECT_NE(st.error().message.find(replay), std::string::npos) << st.error().message;
    }
  }
  HostLoopOptions o;
  o.interfaces = {"skinbus_nope0"};
  Fixture f(o);
  HostLoop loop(*f.agg, f.sink, o);
  const Status st = loop.run();
  ASSERT_FALSE(st.ok());
  EXPECT_NE(st.error().message.find("skinbus_nope0"), std::string::npos) << st.error().message;
  EXPECT_TRUE(f.sink.publications.empty());
}

TEST(HostLoop, OptionsWithoutAnInputAreRefused) {
  HostLoopOptions o;
  Fixture f(o);
  EXPECT_EQ(HostLoop(*f.agg, f.sink, o).run().error().code, ErrorCode::kInvalidArgument);
  o.interfaces = {"can0"};
  o.pace = ReplayPace::kLive;
  EXPECT_EQ(HostLoop(*f.agg, f.sink, o).run().error().code, ErrorCode::kInvalidArgument);
}

TEST(HostLoop, BusNamesFollowTheInputs) {
  HostLoopOptions o;
  o.replay = "x.log";
  EXPECT_EQ(HostLoop::bus_names(o), std::vector<std::string>{"can0"});
  o.interfaces = {"can1", "can2"};
  EXPECT_EQ(HostLoop::bus_names(o), (std::vector<std::string>{"can1", "can2"}));
  o.interfaces_and_replay = true;
  o.pace = ReplayPace::kFast;
  EXPECT_EQ(HostLoop::bus_names(o), (std::vector<std::string>{"can1", "can2", "replay"}));
  EXPECT_TRUE(HostLoop::on_host_clock(o));  // the interfaces are live
}

TEST(HostLoop, ALivePipeIsReadOnTheHostsClock) {
  TempDir dir;
  HostLoopOptions o;
  o.replay = dir.write("pipe.log", make_log(30, "can0", 0, /*release=*/false));
  o.pace = ReplayPace::kLive;
  Fixture f(o);
  HostLoop loop(*f.agg, f.sink, o);
  ASSERT_TRUE(loop.run().ok());
  // The log's stamps are years old: the frames take the time they were read.
  ASSERT_FALSE(f.sink.publications.empty());
  EXPECT_GT(f.sink.publications.front().stamp_us, kLogT0 + 1'000'000'000);
  EXPECT_GT(f.agg->stats().estimated, 0u);
}

TEST(HostLoop, StepKeepsTheCadence) {
  HostLoopOptions o;
  o.status_period_us = 1'000'000;
  Fixture f(o);
  HostLoop loop(*f.agg, f.sink, o);
  loop.start(kWallT0);
  for (uint64_t t = kWallT0; t < kWallT0 + 2'500'000; t += 20'000) loop.step(t);
  EXPECT_EQ(f.sink.statuses.size(), 3u);  // at 0, 1 and 2 s
  o.status_period_us = 0;
  Fixture g(o);
  HostLoop quiet(*g.agg, g.sink, o);
  quiet.start(kWallT0);
  for (uint64_t t = kWallT0; t < kWallT0 + 2'500'000; t += 20'000) quiet.step(t);
  EXPECT_TRUE(g.sink.statuses.empty());
  quiet.finish(kWallT0 + 2'500'000);
  EXPECT_EQ(g.sink.statuses.size(), 1u);
}

// Joint states from a trajectory: the pose now at most every 10 ms, the rows at their own times.
// What was fed shows in the states the history then refuses as older than its newest.
TEST(HostLoop, ATrajectoryFeedsThePoseNowAndItsRows) {
  auto robot = body_map::RobotModel::from_urdf_string(R"(<?xml version="1.0"?>
<robot name="test_arm">
  <link name="base"/><link name="arm"/>
  <joint name="shoulder" type="revolute">
    <parent link="base"/><child link="arm"/><axis xyz="0 0 1"/>
    <limit lower="-3" upper="3" effort="1" velocity="1"/>
  </joint>
</robot>)");
  ASSERT_TRUE(robot.ok());
  const body_map::SkinMap map = one_patch_map();
  auto agg = Aggregator::create(&map, source_dir(), &*robot, {"can0"});
  ASSERT_TRUE(agg.ok());
  Aggregator& a = **agg;
  body_map::JointTrajectory traj;
  traj.names = {"shoulder"};
  traj.t_s = {0, 1, 2};
  traj.q = {0, 1, 0};
  TrajectoryJointInput joints(std::move(traj));
  const std::vector<std::string> names = {"shoulder"};
  const std::vector<double> q = {0.5};
  auto refused = [&] { return a.stats().joint_states_out_of_order; };
  joints.update(a, kWallT0, kWallT0);  // the pose at time zero
  a.set_joint_state(names, q, kWallT0 - 1);
  EXPECT_EQ(refused(), 1u);
  joints.update(a, kWallT0 + 5'000, kWallT0);  // within 10 ms of the last: nothing
  a.set_joint_state(names, q, kWallT0 + 2'000);
  EXPECT_EQ(refused(), 1u);
  joints.update(a, kWallT0 + 1'500'000, kWallT0);  // the row at 1 s, then the pose at 1.5 s
  a.set_joint_state(names, q, kWallT0 + 1'400'000);
  EXPECT_EQ(refused(), 2u);
}

}  // namespace
}  // namespace skinbus::host
