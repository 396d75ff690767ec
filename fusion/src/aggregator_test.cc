#include "skinbus/fusion/aggregator.h"

#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <cstdlib>
#include <random>

#include "skinbus/bus/codec.h"
#include "skinbus/sim/simulated_patch.h"

namespace skinbus::fusion {
namespace {

constexpr uint64_t kUid3 = 0x5EED000000000003ull;
constexpr uint64_t kUid4 = 0x5EED000000000004ull;
constexpr uint64_t kPeriodUs = 23'981;  // 41.7 Hz

std::string source_dir() {
  const char* d = std::getenv("SKINBUS_SOURCE_DIR");
  return d != nullptr ? d : ".";
}

// Two flat patches side by side on one link, 150 mm apart along x, both with the shipped model.
body_map::SkinMap two_patch_map(const std::string& model = "fusion/models/nominal_seed_cnn") {
  body_map::SkinMap map;
  for (int i = 0; i < 2; ++i) {
    body_map::PatchPlacement p;
    p.node_id = 3 + i;
    p.hardware_uid = i == 0 ? kUid3 : kUid4;
    p.link = "arm";
    p.pose_on_link.translation_mm = {150.0 * i, 0, 0};
    p.model = model;
    map.patches.push_back(p);
  }
  return map;
}

// A robot: base -> (revolute about z at the origin) -> arm.
const char* kUrdf = R"(<?xml version="1.0"?>
<robot name="test_arm">
  <link name="base"/>
  <link name="arm"/>
  <joint name="shoulder" type="revolute">
    <parent link="base"/><child link="arm"/>
    <origin xyz="0 0 0.1" rpy="0 0 0"/><axis xyz="0 0 1"/>
    <limit lower="-3" upper="3" effort="1" velocity="1"/>
  </joint>
</robot>)";

// Sends messages of one node as frames into the aggregator.
struct Node {
  uint8_t node;
  uint64_t uid;
  uint8_t seq_sample = 0, seq_hb = 0;
  uint32_t clock_us = 1000;

  void heartbeat(Aggregator& a, uint64_t rx_us, uint32_t uptime_s) {
    bus::Heartbeat hb;
    hb.state = bus::PatchState::kRunning;
    hb.mode = bus::PatchMode::kEvent;
    hb.hardware_uid = uid;
    hb.uptime_s = uptime_s;
    send(a, bus::Message{node, seq_hb++, bus::FrameKind::kFd, hb}, rx_us);
  }
  void sample(Aggregator& a, uint64_t rx_us, std::span<const double> tared_ut, bool contact,
              uint16_t fault_mask = 0) {
    bus::Sample s;
    s.timestamp_us = clock_us;
    clock_us += static_cast<uint32_t>(kPeriodUs);
    s.flags = bus::sample_flags::kTared | (contact ? bus::sample_flags::kContact : 0);
    if (fault_mask) s.flags |= bus::sample_flags::kSensorFault;
    s.fault_mask = fault_mask;
    for (int c = 0; c < bus::kChannelCount; ++c) {
      s.field_lsb[static_cast<std::size_t>(c)] =
          bus::field_ut_to_lsb(tared_ut[static_cast<std::size_t>(c)]);
    }
    send(a, bus::Message{node, seq_sample++, bus::FrameKind::kFd, s}, rx_us);
  }
  static void send(Aggregator& a, const bus::Message& m, uint64_t rx_us) {
    std::array<bus::CanFrame, 4> frames;
    const bus::EncodeResult r = bus::encode(m, frames);
    ASSERT_EQ(r.error, bus::EncodeError::kNone);
    for (std::size_t i = 0; i < r.frames; ++i) a.on_frame(0, frames[i], rx_us + i * 50);
  }
};

// Tared fields of the nominal unit pressed at (u, v, depth), with an optional uniform change.
std::vector<double> press(double u_mm, double v_mm, double depth_mm, uint64_t seed,
                          sim::Vec3<double> ambient_change_ut = {}) {
  auto model = sim::PatchModel::nominal(sim::PatchDesign{});
  sim::SimulatedPatch patch(*model, seed);
  std::vector<double> base(static_cast<std::size_t>(patch.channel_count()));
  std::vector<double> f(base.size());
  sim::Environment env;
  patch.tare(env, 32, base);
  env.ambient_ut = ambient_change_ut;
  const sim::Contact c{u_mm, v_mm, depth_mm, 5.0};
  patch.measure(std::span<const sim::Contact>(&c, 1), env, f);
  for (std::size_t i = 0; i < f.size(); ++i) f[i] -= base[i];
  return f;
}

std::vector<double> idle() {
  return std::vector<double>(bus::kChannelCount, 0.0);
}

struct Fixture {
  body_map::SkinMap map;
  std::unique_ptr<body_map::RobotModel> robot;
  std::unique_ptr<Aggregator> agg;
  Node n3{3, kUid3}, n4{4, kUid4};

  explicit Fixture(AggregatorOptions o = {}, bool with_robot = false,
                   body_map::SkinMap m = two_patch_map())
      : map(std::move(m)) {
    if (with_robot) {
      auto r = body_map::RobotModel::from_urdf_string(kUrdf);
      EXPECT_TRUE(r.ok());
      robot = std::make_unique<body_map::RobotModel>(std::move(*r));
    }
    auto a = Aggregator::create(&map, source_dir(), robot.get(), {"can0"}, o);
    EXPECT_TRUE(a.ok()) << a.error().to_string();
    agg = std::move(*a);
  }
  std::vector<PatchEvent> events(uint64_t now) {
    PatchStatusArray s;
    agg->status(now, &s);
    return s.events;
  }
};

bool has_event(const std::vector<PatchEvent>& ev, PatchEventKind k) {
  for (const PatchEvent& e : ev)
    if (e.kind == k) return true;
  return false;
}

TEST(Aggregator, PlacesAPressOnItsPatch) {
  Fixture f;
  uint64_t t = 1'000'000;
  f.n3.heartbeat(*f.agg, t, 1);
  f.n4.heartbeat(*f.agg, t, 1);
  ContactArray out;
  const auto x = press(12, -20, 2.0, 11);
  f.n4.sample(*f.agg, t += kPeriodUs, x, true);
  ASSERT_TRUE(f.agg->process(t + 100, &out));
  ASSERT_EQ(out.contacts.size(), 1u);
  const BodyContact& c = out.contacts[0];
  // Patch 4 sits at x = 150 mm on the link; no robot: the link frame is the base frame.
  EXPECT_NEAR(c.position_mm[0], 150 + 12, 3.0);
  EXPECT_NEAR(c.position_mm[1], -20, 3.0);
  EXPECT_NEAR(c.position_mm[2], 0, 1e-9);
  EXPECT_NEAR(c.normal[2], 1, 1e-12);
  EXPECT_NEAR(c.depth_mm, 2.0, 0.3);
  EXPECT_EQ(c.node, 4);
  EXPECT_EQ(c.hardware_uid, kUid4);
  EXPECT_EQ(c.link, "arm");
  EXPECT_NE(c.track_id, 0u);
  EXPECT_GT(c.uncertainty_mm, 0.0);
  EXPECT_EQ(f.agg->stats().estimated, 1u);
  // Nothing new: nothing to publish.
  EXPECT_FALSE(f.agg->process(t + 200, &out));
  // The press goes on: same track.
  const uint32_t id = c.track_id;
  f.n4.sample(*f.agg, t += kPeriodUs, press(12.5, -20, 2.1, 12), true);
  ASSERT_TRUE(f.agg->process(t + 100, &out));
  ASSERT_EQ(out.contacts.size(), 1u);
  EXPECT_EQ(out.contacts[0].track_id, id);
  // Released (the event-mode tail sample has no contact flag): an empty publication.
  f.n4.sample(*f.agg, t += kPeriodUs, idle(), false);
  ASSERT_TRUE(f.agg->process(t + 100, &out));
  EXPECT_TRUE(out.contacts.empty());
}

TEST(Aggregator, IdlePatchesNeverReachAModel) {
  Fixture f;
  uint64_t t = 1'000'000;
  f.n3.heartbeat(*f.agg, t, 1);
  f.n4.heartbeat(*f.agg, t, 1);
  ContactArray out;
  for (int i = 0; i < 200; ++i) {  // stream mode, untouched
    t += kPeriodUs;
    f.n3.sample(*f.agg, t, idle(), false);
    f.n4.sample(*f.agg, t, idle(), false);
    EXPECT_FALSE(f.agg->process(t + 10, &out));
  }
  EXPECT_EQ(f.agg->stats().idle_samples, 400u);
  EXPECT_EQ(f.agg->stats().estimated, 0u);
  EXPECT_EQ(f.agg->stats().model_runs, 0u);
}

TEST(Aggregator, TouchedPatchesShareOneBatchedRun) {
  Fixture f;
  uint64_t t = 1'000'000;
  f.n3.heartbeat(*f.agg, t, 1);
  f.n4.heartbeat(*f.agg, t, 1);
  t += kPeriodUs;
  f.n3.sample(*f.agg, t, press(-30, 30, 2.5, 1), true);
  f.n4.sample(*f.agg, t, press(20, 10, 1.5, 2), true);
  ContactArray out;
  ASSERT_TRUE(f.agg->process(t + 500, &out));
  EXPECT_EQ(out.contacts.size(), 2u);
  EXPECT_EQ(f.agg->stats().model_runs, 1u);
  EXPECT_EQ(f.agg->stats().estimated, 2u);
  EXPECT_EQ(f.agg->processed_rx_us().size(), 2u);
}

TEST(Aggregator, ContactEndsWhenThePatchGoesQuiet) {
  AggregatorOptions o;
  o.contact_hold_us = 50'000;
  Fixture f(o);
  uint64_t t = 1'000'000;
  f.n3.heartbeat(*f.agg, t, 1);
  f.n3.sample(*f.agg, t += kPeriodUs, press(0, 0, 2, 3), true);
  ContactArray out;
  ASSERT_TRUE(f.agg->process(t, &out));
  EXPECT_EQ(out.contacts.size(), 1u);
  EXPECT_FALSE(f.agg->process(t + 40'000, &out));
  ASSERT_TRUE(f.agg->process(t + 60'000, &out));
  EXPECT_TRUE(out.contacts.empty());
}

TEST(Aggregator, AmbientChangeIsRejected) {
  // A 60 uT uniform change since the tare (a limb turned in the Earth's field).
  const sim::Vec3<double> change{35, -30, 38};
  double err[2];
  for (int reject = 0; reject < 2; ++reject) {
    AggregatorOptions o;
    o.common_mode.method = reject ? CommonModeMethod::kQuietMean : CommonModeMethod::kNone;
    Fixture f(o);
    uint64_t t = 1'000'000;
    f.n3.heartbeat(*f.agg, t, 1);
    f.n3.sample(*f.agg, t += kPeriodUs, press(-25, 15, 2.5, 5, change), true);
    ContactArray out;
    ASSERT_TRUE(f.agg->process(t, &out));
    if (out.contacts.empty()) {
      err[reject] = 1e9;
      continue;
    }
    err[reject] =
        std::hypot(out.contacts[0].position_mm[0] + 25, out.contacts[0].position_mm[1] - 15);
  }
  EXPECT_LT(err[1], 3.0);
  EXPECT_GT(err[0], 3 * err[1]) << "without rejection the change should move the estimate";
}

TEST(Aggregator, DeadSensorRejectsWithoutAContact) {
  Fixture f;
  uint64_t t = 1'000'000;
  f.n3.heartbeat(*f.agg, t, 1);
  f.n3.sample(*f.agg, t += kPeriodUs, press(0, 0, 2, 3), true, /*fault_mask=*/0x0010);
  ContactArray out;
  if (f.agg->process(t, &out)) {
    EXPECT_TRUE(out.contacts.empty());
  }
  EXPECT_EQ(f.agg->stats().rejected, 1u);
}

TEST(Aggregator, KinematicsPlaceContactsAndStaleStatesAreFlagged) {
  AggregatorOptions o;
  o.kinematics_stale_us = 200'000;
  Fixture f(o, /*with_robot=*/true);
  uint64_t t = 1'000'000;
  f.n3.heartbeat(*f.agg, t, 1);
  ContactArray out;
  // Before any joint state: the zero pose, flagged.
  f.n3.sample(*f.agg, t += kPeriodUs, press(40, 0, 2.5, 7), true);
  ASSERT_TRUE(f.agg->process(t, &out));
  ASSERT_EQ(out.contacts.size(), 1u);
  EXPECT_TRUE(out.contacts[0].flags & kContactNoKinematics);
  EXPECT_NEAR(out.contacts[0].position_mm[0], 40, 3);
  EXPECT_NEAR(out.contacts[0].position_mm[2], 100, 1e-6);  // the joint sits 0.1 m up
  // The arm turns 90 degrees about z: x -> y.
  const std::vector<std::string> names = {"shoulder", "not_a_joint"};
  const std::vector<double> q = {M_PI / 2, 1.0};
  f.agg->set_joint_state(names, q, t);
  f.n3.sample(*f.agg, t += kPeriodUs, press(40, 0, 2.5, 8), true);
  ASSERT_TRUE(f.agg->process(t, &out));
  ASSERT_EQ(out.contacts.size(), 1u);
  EXPECT_EQ(out.contacts[0].flags & (kContactNoKinematics | kContactStaleKinematics), 0u);
  EXPECT_NEAR(out.contacts[0].position_mm[0], 0, 3);
  EXPECT_NEAR(out.contacts[0].position_mm[1], 40, 3);
  EXPECT_EQ(f.agg->stats().unknown_joints, 1u);
  // The joint-state stream stops: contacts keep flowing, flagged, and an event says so.
  t += 300'000;
  f.agg->tick(t);
  EXPECT_TRUE(has_event(f.events(t), PatchEventKind::kKinematicsStale));
  f.n3.sample(*f.agg, t, press(40, 0, 2.5, 9), true);
  ASSERT_TRUE(f.agg->process(t, &out));
  ASSERT_EQ(out.contacts.size(), 1u);
  EXPECT_TRUE(out.contacts[0].flags & kContactStaleKinematics);
  EXPECT_NEAR(out.contacts[0].position_mm[1], 40, 3);  // the last known pose
  f.agg->set_joint_state(names, q, t + 1000);
  EXPECT_TRUE(has_event(f.events(t), PatchEventKind::kKinematicsFresh));
}

TEST(Aggregator, BadOptionsAreRefused) {
  const body_map::SkinMap map = two_patch_map();
  AggregatorOptions o;
  o.runtime.threads = 0;
  auto a = Aggregator::create(&map, source_dir(), nullptr, {"can0"}, o);
  ASSERT_FALSE(a.ok());
  EXPECT_EQ(a.error().code, ErrorCode::kInvalidArgument);
  o = {};
  o.tracker.gate_mm = -1;
  EXPECT_FALSE(Aggregator::create(&map, source_dir(), nullptr, {"can0"}, o).ok());
  o = {};
  o.registry.offline_us = 1;  // before stale
  EXPECT_FALSE(Aggregator::create(&map, source_dir(), nullptr, {"can0"}, o).ok());
}

TEST(Aggregator, JointStatesOfOtherJointsAreNotKinematics) {
  Fixture f({}, /*with_robot=*/true);
  uint64_t t = 1'000'000;
  f.n3.heartbeat(*f.agg, t, 1);
  const std::vector<std::string> names = {"not_a_joint"};
  const std::vector<double> q = {1.0};
  f.agg->set_joint_state(names, q, t);
  f.n3.sample(*f.agg, t += kPeriodUs, press(40, 0, 2.5, 7), true);
  ContactArray out;
  ASSERT_TRUE(f.agg->process(t, &out));
  ASSERT_EQ(out.contacts.size(), 1u);
  EXPECT_TRUE(out.contacts[0].flags & kContactNoKinematics);
}

TEST(Aggregator, ALinkMissingFromTheRobotIsFlagged) {
  body_map::SkinMap map = two_patch_map();
  map.patches[0].link = "tail";  // not in the test robot
  Fixture f({}, /*with_robot=*/true, map);
  uint64_t t = 1'000'000;
  f.n3.heartbeat(*f.agg, t, 1);
  f.n3.sample(*f.agg, t += kPeriodUs, press(0, 20, 2.5, 7), true);
  ContactArray out;
  ASSERT_TRUE(f.agg->process(t, &out));
  ASSERT_EQ(out.contacts.size(), 1u);
  EXPECT_TRUE(out.contacts[0].flags & kContactUnmapped);
}

TEST(Aggregator, MissingModelDegradesThePatch) {
  Fixture f({}, false, two_patch_map("no/such/model"));
  uint64_t t = 1'000'000;
  const auto ev = f.events(t);
  EXPECT_TRUE(has_event(ev, PatchEventKind::kNoModel));
  f.n3.heartbeat(*f.agg, t, 1);
  f.n3.sample(*f.agg, t += kPeriodUs, press(0, 0, 2, 3), true);
  ContactArray out;
  EXPECT_FALSE(f.agg->process(t, &out));
  EXPECT_EQ(f.agg->registry().entry(0, 3).state, PatchLinkState::kDegraded);
}

TEST(Aggregator, ASampleQueuedBeforeItsNodeIsReidentifiedIsDropped) {
  // Found by fuzzing: a contact sample placed by its node ID, then a heartbeat naming a UID
  // that is not in the map (or another patch's), before process().
  for (uint64_t uid : {uint64_t{0xDEAD}, kUid4}) {
    Fixture f;
    uint64_t t = 1'000'000;
    f.n3.sample(*f.agg, t, press(0, 0, 2, 3), true);  // no heartbeat yet: placed by node 3
    Node other{3, uid};
    other.heartbeat(*f.agg, t + 100, 1);
    ContactArray out;
    EXPECT_FALSE(f.agg->process(t + 200, &out));
    EXPECT_EQ(f.agg->stats().estimated, 0u);
    EXPECT_EQ(f.agg->stats().unattributed, 1u);
  }
}

TEST(Aggregator, GarbageFramesNeverBecomeContacts) {
  // Random, truncated and corrupted frames between real ones: no crash, no contact from them,
  // and the real press still comes through.
  const uint64_t seed = std::random_device{}();
  std::printf("seed %llu\n", static_cast<unsigned long long>(seed));
  std::mt19937_64 rng(seed);
  Fixture f;
  uint64_t t = 1'000'000;
  f.n3.heartbeat(*f.agg, t, 1);
  ContactArray out;
  for (int i = 0; i < 5000; ++i) {
    bus::CanFrame fr;
    fr.id = static_cast<uint32_t>(rng() & 0x7FF);
    fr.fd = (rng() & 1) != 0;
    fr.len = static_cast<uint8_t>(rng() % (fr.fd ? 65 : 9));
    for (int b = 0; b < fr.len; ++b)
      fr.data[static_cast<std::size_t>(b)] = static_cast<uint8_t>(rng());
    f.agg->on_frame(0, fr, t += 37);
    if (f.agg->process(t, &out)) {
      for (const BodyContact& c : out.contacts) {
        for (int k = 0; k < 3; ++k) ASSERT_TRUE(std::isfinite(c.position_mm[k]));
      }
    }
  }
  // A real sample still decodes.
  f.n3.sample(*f.agg, t += kPeriodUs, press(10, 10, 2, 3), true);
  ASSERT_TRUE(f.agg->process(t + 100, &out));
  ASSERT_GE(out.contacts.size(), 1u);
  EXPECT_GT(f.agg->reassembly_stats().rejected + f.agg->reassembly_stats().integrity_failures, 0u);
}

}  // namespace
}  // namespace skinbus::fusion
