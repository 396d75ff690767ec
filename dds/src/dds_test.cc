// The DDS layer over real Cyclone DDS (no mocks): round trips in one process, the real
// skinbus-listen in another process, refusal of non-finite values, joint states, and the IDL
// against the ROS 2 .msg files.
//
// Isolation: dds_test_support.h (loopback only, a random domain from the printed seed); the
// in-process tests also use topic names unique to the process.
#include "skinbus/dds/dds.h"

#include <fcntl.h>
#include <gtest/gtest.h>
#include <signal.h>
#include <spawn.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>
#include <mutex>
#include <nlohmann/json.hpp>
#include <random>
#include <sstream>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include "dds_test_support.h"
#include "skinbus/host/contacts_json.h"

extern char** environ;

namespace skinbus::dds {

using host::BodyContact;
using host::contact_flag_names;
using host::ContactArray;
using host::DiagnosticArray;
using host::PatchEvent;
using host::PatchEventKind;
using host::PatchLinkState;
using host::PatchStatus;
using host::PatchStatusArray;
using nlohmann::json;

namespace {

using namespace test_support;

constexpr double kTol = 1e-9;
constexpr int kMatchTimeoutMs = 10000;  // generous: discovery on a loaded machine

void expect_same(const ContactArray& got, const ContactArray& want) {
  EXPECT_EQ(got.stamp_us, want.stamp_us);
  EXPECT_EQ(got.base_frame, want.base_frame);
  ASSERT_EQ(got.contacts.size(), want.contacts.size());
  for (std::size_t i = 0; i < want.contacts.size(); ++i) {
    SCOPED_TRACE("contact " + std::to_string(i));
    const BodyContact& g = got.contacts[i];
    const BodyContact& w = want.contacts[i];
    for (int k = 0; k < 3; ++k) {
      EXPECT_NEAR(g.position_mm[k], w.position_mm[k], kTol);
      EXPECT_NEAR(g.normal[k], w.normal[k], kTol);
    }
    EXPECT_NEAR(g.depth_mm, w.depth_mm, kTol);
    EXPECT_NEAR(g.force_n, w.force_n, kTol);
    EXPECT_NEAR(g.u_mm, w.u_mm, kTol);
    EXPECT_NEAR(g.v_mm, w.v_mm, kTol);
    EXPECT_NEAR(g.uncertainty_mm, w.uncertainty_mm, kTol);
    EXPECT_EQ(g.node, w.node);
    EXPECT_EQ(g.hardware_uid, w.hardware_uid);
    EXPECT_EQ(g.link, w.link);
    EXPECT_EQ(g.track_id, w.track_id);
    EXPECT_EQ(g.patch_count, w.patch_count);
    EXPECT_EQ(g.flags, w.flags);
    EXPECT_EQ(g.first_seen_us, w.first_seen_us);
    for (int k = 0; k < 3; ++k) EXPECT_NEAR(g.shear_n[k], w.shear_n[k], kTol);
    EXPECT_NEAR(g.shear_uncertainty_n, w.shear_uncertainty_n, kTol);
  }
}

PatchStatusArray sample_status(uint64_t stamp_us) {
  PatchStatusArray s;
  s.stamp_us = stamp_us;
  PatchStatus a;
  a.node = 3;
  a.hardware_uid = 0xDEADBEEF00112233ull;
  a.interface = "can0";
  a.link = "left_forearm";
  a.state = PatchLinkState::kDegraded;
  a.node_state = 2;
  a.node_mode = 1;
  a.fault_mask = 0x8001;
  a.uptime_s = 123456;
  a.reboots = 2;
  a.samples = 10000000000ull;
  a.samples_lost = 17;
  a.contacts = 4242;
  a.clock_offset_us = -12345.678;
  a.clock_drift_ppm = 13.25;
  a.last_heard_us = stamp_us - 1500;
  a.duplicate_id = true;
  a.detail = "sensor 15 faulted";
  PatchStatus b;
  b.node = 125;
  b.interface = "can1";
  b.state = PatchLinkState::kOffline;
  b.last_heard_us = stamp_us - 9000000;
  s.patches = {a, b};
  s.events = {{stamp_us - 10, PatchEventKind::kRebooted, 3, a.hardware_uid, "uptime 5 s < 9 s"},
              {stamp_us - 5, PatchEventKind::kInterfaceDown, 0, 0, "can1: bus-off"},
              {stamp_us - 2, PatchEventKind::kKinematicsFresh, 0, 0, ""},
              {stamp_us - 1, PatchEventKind::kHostCaughtUp, 0, 0, "3 superseded"},
              {stamp_us, PatchEventKind::kLogTime, 0, 0, "bus.log:7: time went back 2.000 s"}};
  return s;
}

void expect_same(const PatchStatusArray& got, const PatchStatusArray& want) {
  EXPECT_EQ(got.stamp_us, want.stamp_us);
  ASSERT_EQ(got.patches.size(), want.patches.size());
  for (std::size_t i = 0; i < want.patches.size(); ++i) {
    SCOPED_TRACE("patch " + std::to_string(i));
    const PatchStatus& g = got.patches[i];
    const PatchStatus& w = want.patches[i];
    EXPECT_EQ(g.node, w.node);
    EXPECT_EQ(g.hardware_uid, w.hardware_uid);
    EXPECT_EQ(g.interface, w.interface);
    EXPECT_EQ(g.link, w.link);
    EXPECT_EQ(g.state, w.state);
    EXPECT_EQ(g.node_state, w.node_state);
    EXPECT_EQ(g.node_mode, w.node_mode);
    EXPECT_EQ(g.fault_mask, w.fault_mask);
    EXPECT_EQ(g.uptime_s, w.uptime_s);
    EXPECT_EQ(g.reboots, w.reboots);
    EXPECT_EQ(g.samples, w.samples);
    EXPECT_EQ(g.samples_lost, w.samples_lost);
    EXPECT_EQ(g.contacts, w.contacts);
    EXPECT_NEAR(g.clock_offset_us, w.clock_offset_us, kTol);
    EXPECT_NEAR(g.clock_drift_ppm, w.clock_drift_ppm, kTol);
    EXPECT_EQ(g.last_heard_us, w.last_heard_us);
    EXPECT_EQ(g.duplicate_id, w.duplicate_id);
    EXPECT_EQ(g.detail, w.detail);
  }
  ASSERT_EQ(got.events.size(), want.events.size());
  for (std::size_t i = 0; i < want.events.size(); ++i) {
    SCOPED_TRACE("event " + std::to_string(i));
    EXPECT_EQ(got.events[i].time_us, want.events[i].time_us);
    EXPECT_EQ(got.events[i].kind, want.events[i].kind);
    EXPECT_EQ(got.events[i].node, want.events[i].node);
    EXPECT_EQ(got.events[i].hardware_uid, want.events[i].hardware_uid);
    EXPECT_EQ(got.events[i].detail, want.events[i].detail);
  }
}

// Waits until `pub` has matched a reader of `topic` (the subscriber side is waited for
// separately): discovery is asynchronous even within a process.
void wait_publisher_matched(SkinPublisher& pub, SkinTopic topic) {
  const auto end = std::chrono::steady_clock::now() + std::chrono::milliseconds(kMatchTimeoutMs);
  while (must(pub.matched_subscribers(topic)) == 0) {
    ASSERT_LT(std::chrono::steady_clock::now(), end) << "the publisher never matched a reader";
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
}

// ---- in-process round trips ----------------------------------------------------------------

TEST(DdsTest, ContactsRoundTripInProcess) {
  std::mt19937_64 rng(dds_env().seed);
  const DdsOptions o = test_options("contacts");
  auto pub = must(SkinPublisher::create(o));
  auto sub = must(SkinSubscriber::create(o));
  ASSERT_TRUE(must(sub->wait_for_publisher(SkinTopic::kContacts, kMatchTimeoutMs)));
  wait_publisher_matched(*pub, SkinTopic::kContacts);

  const uint64_t t0 = now_us();
  const std::vector<ContactArray> sent = {random_contacts(rng, t0, 5),
                                          random_contacts(rng, t0 + 10000, 0),
                                          random_contacts(rng, t0 + 20000, 2)};
  for (const ContactArray& a : sent) {
    Status s = pub->publish(a);
    ASSERT_TRUE(s.ok()) << s.error().to_string();
  }
  for (const ContactArray& want : sent) {
    ContactArray got;
    got.base_frame = "garbage";
    ASSERT_TRUE(must(sub->wait_contacts(&got, kMatchTimeoutMs)));
    expect_same(got, want);
  }
}

TEST(DdsTest, PatchStatusReachesALateJoiner) {
  const DdsOptions o = test_options("status");
  auto pub = must(SkinPublisher::create(o));
  const PatchStatusArray sent = sample_status(now_us());
  Status s = pub->publish(sent);
  ASSERT_TRUE(s.ok()) << s.error().to_string();

  // Created after the publication: transient-local durability hands it over anyway.
  auto sub = must(SkinSubscriber::create(o));
  PatchStatusArray got;
  ASSERT_TRUE(must(sub->wait_patch_status(&got, kMatchTimeoutMs)));
  expect_same(got, sent);
  // And the contacts topic (volatile) has nothing for it.
  ContactArray none;
  EXPECT_FALSE(must(sub->wait_contacts(&none, 0)));
}

TEST(DdsTest, DiagnosticsFollowEveryPatchStatus) {
  const DdsOptions o = test_options("diagnostics");
  auto pub = must(SkinPublisher::create(o));
  auto sub = must(SkinSubscriber::create(o));
  ASSERT_TRUE(must(sub->wait_for_publisher(SkinTopic::kDiagnostics, kMatchTimeoutMs)));
  wait_publisher_matched(*pub, SkinTopic::kDiagnostics);

  PatchStatusArray sent = sample_status(now_us());
  ASSERT_GE(sent.patches.size(), 2u);
  sent.patches[0].state = host::PatchLinkState::kDegraded;
  sent.patches[0].fault_mask = 0x0009;  // sensors 0 and 3
  sent.patches[0].duplicate_id = false;
  sent.patches[0].clock_drift_ppm = 3;
  sent.patches[1].state = host::PatchLinkState::kStale;
  Status s = pub->publish(sent);
  ASSERT_TRUE(s.ok()) << s.error().to_string();

  const DiagnosticArray want = host::diagnose(sent);
  DiagnosticArray got;
  ASSERT_TRUE(must(sub->wait_diagnostics(&got, kMatchTimeoutMs)));
  EXPECT_EQ(got.stamp_us, want.stamp_us);
  ASSERT_EQ(got.status.size(), want.status.size());
  for (std::size_t i = 0; i < want.status.size(); ++i) {
    SCOPED_TRACE("status " + std::to_string(i));
    EXPECT_EQ(got.status[i].level, want.status[i].level);
    EXPECT_EQ(got.status[i].name, want.status[i].name);
    EXPECT_EQ(got.status[i].message, want.status[i].message);
    EXPECT_EQ(got.status[i].hardware_id, want.status[i].hardware_id);
    ASSERT_EQ(got.status[i].values.size(), want.status[i].values.size());
    for (std::size_t k = 0; k < want.status[i].values.size(); ++k) {
      EXPECT_EQ(got.status[i].values[k].key, want.status[i].values[k].key);
      EXPECT_EQ(got.status[i].values[k].value, want.status[i].values[k].value);
    }
  }
  EXPECT_EQ(got.status[0].level, host::DiagnosticLevel::kWarn);
  EXPECT_EQ(got.status[1].level, host::DiagnosticLevel::kStale);
}

TEST(DdsTest, DiagnosticsCanBeTurnedOff) {
  DdsOptions o = test_options("nodiagnostics");
  o.diagnostics_topic.clear();
  auto pub = must(SkinPublisher::create(o));
  auto sub = must(SkinSubscriber::create(o));
  Status s = pub->publish(sample_status(now_us()));
  ASSERT_TRUE(s.ok()) << s.error().to_string();
  DiagnosticArray got;
  Result<bool> r = sub->wait_diagnostics(&got, 0);
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().code, ErrorCode::kUnsupported);
  EXPECT_FALSE(pub->matched_subscribers(SkinTopic::kDiagnostics).ok());
}

TEST(DdsTest, NonFiniteValuesAreRefused) {
  const DdsOptions o = test_options("nonfinite");
  auto pub = must(SkinPublisher::create(o));
  auto sub = must(SkinSubscriber::create(o));
  ASSERT_TRUE(must(sub->wait_for_publisher(SkinTopic::kContacts, kMatchTimeoutMs)));
  wait_publisher_matched(*pub, SkinTopic::kContacts);
  std::mt19937_64 rng(dds_env().seed + 1);

  ContactArray bad = random_contacts(rng, now_us(), 3);
  bad.contacts[1].depth_mm = std::nan("");
  Status s = pub->publish(bad);
  ASSERT_FALSE(s.ok());
  EXPECT_EQ(s.error().code, ErrorCode::kInvalidArgument);
  EXPECT_NE(s.error().message.find("contacts[1].depth_mm is nan"), std::string::npos)
      << s.error().message;

  bad = random_contacts(rng, now_us(), 1);
  bad.contacts[0].normal[2] = -INFINITY;
  s = pub->publish(bad);
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.error().message.find("contacts[0].normal[2] is inf"), std::string::npos)
      << s.error().message;

  // A stamp builtin_interfaces/Time cannot hold (int32 seconds).
  bad = random_contacts(rng, uint64_t{1} << 62, 1);
  s = pub->publish(bad);
  ASSERT_FALSE(s.ok());
  EXPECT_EQ(s.error().code, ErrorCode::kOutOfRange) << s.error().message;
  // A first_seen_us it cannot hold either: named, nothing published.
  bad = random_contacts(rng, now_us(), 2);
  bad.contacts[1].first_seen_us = uint64_t{1} << 62;
  s = pub->publish(bad);
  ASSERT_FALSE(s.ok());
  EXPECT_EQ(s.error().code, ErrorCode::kOutOfRange) << s.error().message;
  EXPECT_NE(s.error().message.find("contacts[1].first_seen_us"), std::string::npos)
      << s.error().message;

  PatchStatusArray bad_status = sample_status(now_us());
  bad_status.patches[1].clock_drift_ppm = INFINITY;
  s = pub->publish(bad_status);
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.error().message.find("patches[1].clock_drift_ppm is inf"), std::string::npos)
      << s.error().message;

  // Nothing of the refused went out: the first array the subscriber sees is the good one
  // published after them.
  const ContactArray good = random_contacts(rng, now_us(), 2);
  s = pub->publish(good);
  ASSERT_TRUE(s.ok()) << s.error().to_string();
  ContactArray got;
  ASSERT_TRUE(must(sub->wait_contacts(&got, kMatchTimeoutMs)));
  expect_same(got, good);
  PatchStatusArray no_status;
  EXPECT_FALSE(must(sub->wait_patch_status(&no_status, 0)));

  // Joint states likewise.
  auto joints = must(JointStatePublisher::create(o));
  s = joints->publish({"a", "b"}, {0.0, std::nan("")}, now_us());
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.error().message.find("position[1] (b) is nan"), std::string::npos)
      << s.error().message;
  s = joints->publish({"a", "b"}, {0.0}, now_us());
  ASSERT_FALSE(s.ok());
  EXPECT_EQ(s.error().code, ErrorCode::kInvalidArgument);
}

TEST(DdsTest, BadOptionsAreRefused) {
  DdsOptions o = test_options("options");
  o.history_depth = 0;
  auto p = SkinPublisher::create(o);
  ASSERT_FALSE(p.ok());
  EXPECT_NE(p.error().message.find("history_depth"), std::string::npos);
  o = test_options("options");
  o.domain_id = 233;
  auto s = SkinSubscriber::create(o);
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.error().message.find("domain_id 233"), std::string::npos);
}

TEST(DdsTest, JointStatesRoundTripTakeLatestGivesTheNewestTakeAllGivesEach) {
  const DdsOptions o = test_options("joints");
  auto pub = must(JointStatePublisher::create(o));
  auto sub = must(JointStateSubscriber::create(o));
  JointStateSample sample;
  EXPECT_FALSE(sub->take_latest(&sample)) << "nothing published yet";
  ASSERT_TRUE(must(sub->wait_for_publisher(kMatchTimeoutMs)));
  const auto end = std::chrono::steady_clock::now() + std::chrono::milliseconds(kMatchTimeoutMs);
  while (must(pub->matched_subscribers()) == 0) {
    ASSERT_LT(std::chrono::steady_clock::now(), end);
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }

  const std::vector<std::string> names = {"shoulder_pan", "shoulder_lift", "elbow", "wrist_1"};
  const uint64_t before_us = now_us();
  const uint64_t t0 = before_us - 5000;
  for (int k = 0; k < 3; ++k) {
    const std::vector<double> q = {0.1 * k, -0.2 * k, 1.5 + k, -3.0 / (k + 1)};
    Status s = pub->publish(names, q, t0 + static_cast<uint64_t>(k) * 1000);
    ASSERT_TRUE(s.ok()) << s.error().to_string();
  }
  // Delivery may be asynchronous: keep taking until the last one shows up. Each sample is
  // handed out at most once, and never an older one after a newer one.
  uint64_t last_stamp = 0;
  int takes = 0;
  const auto take_end =
      std::chrono::steady_clock::now() + std::chrono::milliseconds(kMatchTimeoutMs);
  while (last_stamp != t0 + 2000) {
    ASSERT_LT(std::chrono::steady_clock::now(), take_end) << "the newest sample never arrived";
    if (!sub->take_latest(&sample)) {
      std::this_thread::sleep_for(std::chrono::milliseconds(5));
      continue;
    }
    ++takes;
    EXPECT_GT(sample.stamp_us, last_stamp);
    last_stamp = sample.stamp_us;
  }
  EXPECT_LE(takes, 3);
  EXPECT_EQ(sample.names, names);
  const std::vector<double> want = {0.2, -0.4, 3.5, -1.0};
  ASSERT_EQ(sample.positions.size(), want.size());
  for (std::size_t i = 0; i < want.size(); ++i) EXPECT_NEAR(sample.positions[i], want[i], kTol);
  EXPECT_GE(sample.received_us, before_us);
  EXPECT_LE(sample.received_us, now_us());
  EXPECT_FALSE(sub->take_latest(&sample)) << "the newest was already taken";
  EXPECT_EQ(sub->rejected_samples(), 0u);

  // take_all: every sample, in order, each once.
  for (int k = 3; k < 8; ++k) {
    const std::vector<double> q = {0.1 * k, 0, 0, 0};
    ASSERT_TRUE(pub->publish(names, q, t0 + static_cast<uint64_t>(k) * 1000).ok());
  }
  std::vector<JointStateSample> all, got;
  while (all.size() < 5) {
    ASSERT_LT(std::chrono::steady_clock::now(), take_end) << "samples never arrived";
    sub->take_all(&got);
    for (JointStateSample& s : got) all.push_back(std::move(s));
    if (all.size() < 5) std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
  ASSERT_EQ(all.size(), 5u);
  for (std::size_t i = 0; i < all.size(); ++i) {
    EXPECT_EQ(all[i].stamp_us, t0 + (3 + i) * 1000);
    EXPECT_NEAR(all[i].positions[0], 0.1 * static_cast<double>(3 + i), kTol);
  }
  EXPECT_EQ(sub->take_all(&got), 0u);
  EXPECT_EQ(sub->overflowed_samples(), 0u);
}

// ---- another process: the real skinbus-listen ----------------------------------------------

// Publishes until `skinbus-listen --count 3` (a child process on the same loopback domain) has
// printed three arrays and exited, then checks what it printed.
TEST(DdsTest, ListenToolInAnotherProcessPrintsThePublishedValues) {
  const DdsTestEnv& env = dds_env();
  const DdsOptions o = test_options("");  // the default topic names: the tool's defaults
  auto pub = must(SkinPublisher::create(o));

  int out[2];
  ASSERT_EQ(pipe2(out, O_CLOEXEC), 0);
  posix_spawn_file_actions_t fa;
  posix_spawn_file_actions_init(&fa);
  posix_spawn_file_actions_adddup2(&fa, out[1], STDOUT_FILENO);
  const std::string domain = std::to_string(env.domain_id);
  std::vector<std::string> args = {SKINBUS_LISTEN_PATH, "--domain", domain,        "--count", "3",
                                   "--timeout",         "20",       "--wait-match"};
  std::vector<char*> argv;
  for (std::string& a : args) argv.push_back(a.data());
  argv.push_back(nullptr);
  pid_t child = 0;
  const int rc = posix_spawn(&child, SKINBUS_LISTEN_PATH, &fa, nullptr, argv.data(), environ);
  posix_spawn_file_actions_destroy(&fa);
  close(out[1]);
  ASSERT_EQ(rc, 0) << "cannot start " << SKINBUS_LISTEN_PATH;
  ASSERT_EQ(fcntl(out[0], F_SETFL, O_NONBLOCK), 0);

  std::string printed;
  auto drain = [&] {
    char buf[4096];
    ssize_t n = 0;
    while ((n = read(out[0], buf, sizeof buf)) > 0) printed.append(buf, static_cast<size_t>(n));
  };
  std::mt19937_64 rng(env.seed + 2);
  std::map<uint64_t, ContactArray> sent;  // by stamp
  const uint64_t t0 = now_us();
  int status = 0;
  bool exited = false;
  const auto end = std::chrono::steady_clock::now() + std::chrono::seconds(25);
  for (uint64_t k = 0; !exited && std::chrono::steady_clock::now() < end; ++k) {
    // Until the child has matched, publications may go nowhere; that is fine, it counts only
    // what it receives.
    ContactArray a = random_contacts(rng, t0 + k * 1000, 1 + static_cast<int>(k % 4));
    Status s = pub->publish(a);
    ASSERT_TRUE(s.ok()) << s.error().to_string();
    sent.emplace(a.stamp_us, std::move(a));
    drain();
    const pid_t w = waitpid(child, &status, WNOHANG);
    ASSERT_GE(w, 0);
    exited = w == child;
    if (!exited) std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
  if (!exited) {
    kill(child, SIGKILL);
    waitpid(child, &status, 0);
  }
  // The child is gone: read the rest (EOF once the pipe is empty).
  ASSERT_EQ(fcntl(out[0], F_SETFL, 0), 0);
  drain();
  close(out[0]);
  ASSERT_TRUE(exited) << "skinbus-listen did not finish; it printed:\n" << printed;
  ASSERT_TRUE(WIFEXITED(status));
  EXPECT_EQ(WEXITSTATUS(status), 0) << printed;

  std::istringstream lines(printed);
  std::string line;
  int n = 0;
  uint64_t previous = 0;
  while (std::getline(lines, line)) {
    SCOPED_TRACE(line);
    ++n;
    const json j = json::parse(line);
    EXPECT_EQ(j.at("type"), "contacts");
    const uint64_t stamp = j.at("stamp_us").get<uint64_t>();
    EXPECT_GT(stamp, previous) << "in publication order";
    previous = stamp;
    auto it = sent.find(stamp);
    ASSERT_NE(it, sent.end()) << "a stamp that was never published";
    const ContactArray& want = it->second;
    EXPECT_EQ(j.at("base_frame"), want.base_frame);
    const json& cs = j.at("contacts");
    ASSERT_EQ(cs.size(), want.contacts.size());
    for (std::size_t i = 0; i < cs.size(); ++i) {
      const json& c = cs[i];
      const BodyContact& w = want.contacts[i];
      for (int k = 0; k < 3; ++k) {
        EXPECT_NEAR(c.at("position_mm")[k].get<double>(), w.position_mm[k], kTol);
        EXPECT_NEAR(c.at("normal")[k].get<double>(), w.normal[k], kTol);
      }
      EXPECT_NEAR(c.at("depth_mm").get<double>(), w.depth_mm, kTol);
      EXPECT_NEAR(c.at("force_n").get<double>(), w.force_n, kTol);
      EXPECT_NEAR(c.at("u_mm").get<double>(), w.u_mm, kTol);
      EXPECT_NEAR(c.at("v_mm").get<double>(), w.v_mm, kTol);
      EXPECT_NEAR(c.at("uncertainty_mm").get<double>(), w.uncertainty_mm, kTol);
      EXPECT_EQ(c.at("node").get<int>(), w.node);
      EXPECT_EQ(std::strtoull(c.at("hardware_uid").get<std::string>().c_str(), nullptr, 16),
                w.hardware_uid);
      EXPECT_EQ(c.at("link").get<std::string>(), w.link);
      EXPECT_EQ(c.at("track_id").get<uint32_t>(), w.track_id);
      EXPECT_EQ(c.at("patch_count").get<uint32_t>(), w.patch_count);
      EXPECT_EQ(c.at("flags").get<std::vector<std::string>>(), contact_flag_names(w.flags));
      EXPECT_EQ(c.at("first_seen_us").get<uint64_t>(), w.first_seen_us);
      for (int k = 0; k < 3; ++k) EXPECT_NEAR(c.at("shear_n")[k].get<double>(), w.shear_n[k], kTol);
      EXPECT_NEAR(c.at("shear_uncertainty_n").get<double>(), w.shear_uncertainty_n, kTol);
    }
  }
  EXPECT_EQ(n, 3);
}

// ---- the IDL against the ROS 2 .msg files ---------------------------------------------------

struct Field {
  std::string type;
  std::string name;
  std::string value;  // constants only
  bool operator==(const Field&) const = default;
};
std::ostream& operator<<(std::ostream& os, const Field& f) {
  return os << f.type << " " << f.name << (f.value.empty() ? "" : "=" + f.value);
}

struct Idl {
  std::map<std::string, std::vector<Field>> structs;    // full name -> members
  std::map<std::string, std::vector<Field>> constants;  // full module name -> consts
};

std::string read_text(const fs::path& p) {
  std::ifstream f(p);
  EXPECT_TRUE(f.good()) << "cannot read " << p;
  std::stringstream ss;
  ss << f.rdbuf();
  return ss.str();
}

// Tokens of IDL text: identifiers and scoped names ("a::b"), numbers, single punctuation.
// Comments, preprocessor lines and annotations are dropped.
std::vector<std::string> idl_tokens(const std::string& text) {
  std::vector<std::string> out;
  std::size_t i = 0;
  auto ident = [](char c) { return std::isalnum(static_cast<unsigned char>(c)) || c == '_'; };
  while (i < text.size()) {
    const char c = text[i];
    if (std::isspace(static_cast<unsigned char>(c))) {
      ++i;
    } else if (text.compare(i, 2, "//") == 0 || c == '#') {
      i = text.find('\n', i);
      if (i == std::string::npos) break;
    } else if (text.compare(i, 2, "/*") == 0) {
      i = text.find("*/", i);
      if (i == std::string::npos) break;
      i += 2;
    } else if (c == '@') {  // @final etc.
      ++i;
      while (i < text.size() && ident(text[i])) ++i;
    } else if (ident(c)) {
      std::size_t j = i;
      while (j < text.size() && (ident(text[j]) || text.compare(j, 2, "::") == 0))
        j += text.compare(j, 2, "::") == 0 ? 2 : 1;
      out.push_back(text.substr(i, j - i));
      i = j;
    } else {
      out.emplace_back(1, c);
      ++i;
    }
  }
  return out;
}

// Parses the subset of IDL the msg/ files use: nested modules, structs whose member types are
// single (scoped) names or sequence<name>, and constants. Types must be fully scoped.
void parse_idl(const std::vector<std::string>& t, std::size_t& i, const std::string& scope,
               Idl* idl) {
  auto tok = [&t](std::size_t j) { return j < t.size() ? t[j] : std::string("<end>"); };
  while (i < t.size() && t[i] != "}") {
    if (t[i] == "module") {
      const std::string name = scope + tok(i + 1);
      ASSERT_EQ(tok(i + 2), "{") << name;
      i += 3;
      parse_idl(t, i, name + "::", idl);
      if (::testing::Test::HasFatalFailure()) return;
      ASSERT_EQ(tok(i), "}");
      ASSERT_EQ(tok(i + 1), ";");
      i += 2;
    } else if (t[i] == "struct") {
      const std::string name = scope + tok(i + 1);
      ASSERT_EQ(tok(i + 2), "{") << name;
      i += 3;
      std::vector<Field>& members = idl->structs[name];
      while (tok(i) != "}") {
        ASSERT_LT(i, t.size()) << name << ": no closing brace";
        std::string type = t[i++];
        if (type == "sequence") {
          ASSERT_EQ(tok(i), "<");
          type = "sequence<" + tok(i + 1) + ">";
          ASSERT_EQ(tok(i + 2), ">") << "bounded sequences are not expected";
          i += 3;
        }
        members.push_back({type, tok(i), ""});
        ASSERT_EQ(tok(i + 1), ";") << name << "." << tok(i);
        i += 2;
      }
      ASSERT_EQ(tok(i + 1), ";");
      i += 2;
    } else if (t[i] == "const") {
      ASSERT_EQ(tok(i + 3), "=") << "const " << tok(i + 2);
      std::string value;
      std::size_t j = i + 4;
      while (tok(j) != ";") {
        ASSERT_LT(j, t.size()) << "const " << tok(i + 2) << ": no ';'";
        value += t[j++];
      }
      idl->constants[scope.substr(0, scope.size() - 2)].push_back({tok(i + 1), tok(i + 2), value});
      i = j + 1;
    } else {
      FAIL() << "unexpected IDL token '" << t[i] << "'";
    }
  }
}

// The IDL type a ROS 2 .msg type becomes on the wire.
std::string idl_type_of(std::string msg_type, const std::string& package) {
  if (msg_type.size() > 2 && msg_type.ends_with("[]")) {
    return "sequence<" + idl_type_of(msg_type.substr(0, msg_type.size() - 2), package) + ">";
  }
  static const std::map<std::string, std::string> kPrimitive = {
      {"bool", "boolean"},   {"byte", "octet"},   {"char", "uint8"},    {"float32", "float"},
      {"float64", "double"}, {"int8", "int8"},    {"uint8", "uint8"},   {"int16", "int16"},
      {"uint16", "uint16"},  {"int32", "int32"},  {"uint32", "uint32"}, {"int64", "int64"},
      {"uint64", "uint64"},  {"string", "string"}};
  if (auto it = kPrimitive.find(msg_type); it != kPrimitive.end()) return it->second;
  if (msg_type == "Header") msg_type = "std_msgs/Header";
  const std::size_t slash = msg_type.find('/');
  const std::string pkg = slash == std::string::npos ? package : msg_type.substr(0, slash);
  const std::string name = slash == std::string::npos ? msg_type : msg_type.substr(slash + 1);
  return pkg + "::msg::dds_::" + name + "_";
}

// Fields and constants of one .msg file, with IDL types.
std::pair<std::vector<Field>, std::vector<Field>> parse_msg(const fs::path& p,
                                                            const std::string& package) {
  std::vector<Field> fields, constants;
  std::istringstream in(read_text(p));
  std::string line;
  while (std::getline(in, line)) {
    if (const std::size_t hash = line.find('#'); hash != std::string::npos) line.erase(hash);
    std::istringstream words(line);
    std::string type, rest, extra;
    if (!(words >> type)) continue;
    words >> rest;
    EXPECT_FALSE(words >> extra) << p << ": default values are not expected: " << line;
    if (const std::size_t eq = rest.find('='); eq != std::string::npos) {
      constants.push_back({idl_type_of(type, package), rest.substr(0, eq), rest.substr(eq + 1)});
    } else {
      fields.push_back({idl_type_of(type, package), rest, ""});
    }
  }
  return {fields, constants};
}

const fs::path kMsgDir = SKINBUS_MSG_DIR;

void load_idl(Idl* idl) {
  for (const char* file : {"ros2_common.idl", "skin_msgs.idl"}) {
    SCOPED_TRACE(file);
    const std::vector<std::string> t = idl_tokens(read_text(kMsgDir / file));
    std::size_t i = 0;
    parse_idl(t, i, "", idl);
    if (::testing::Test::HasFatalFailure()) return;
    ASSERT_EQ(i, t.size()) << "unbalanced braces";
  }
}

TEST(DdsMessagesTest, MsgFilesAndIdlListTheSameFields) {
  Idl idl;
  ASSERT_NO_FATAL_FAILURE(load_idl(&idl));
  const std::string prefix = "skin_msgs::msg::dds_::";
  int checked = 0;
  for (const auto& entry : fs::directory_iterator(kMsgDir / "ros2/skin_msgs/msg")) {
    if (entry.path().extension() != ".msg") continue;
    const std::string name = entry.path().stem().string();
    SCOPED_TRACE(name + ".msg");
    const auto [fields, constants] = parse_msg(entry.path(), "skin_msgs");
    auto it = idl.structs.find(prefix + name + "_");
    ASSERT_NE(it, idl.structs.end()) << "no struct " << prefix << name << "_ in skin_msgs.idl";
    EXPECT_EQ(it->second, fields);
    auto c = idl.constants.find(prefix + name + "_Constants");
    if (constants.empty()) {
      EXPECT_EQ(c, idl.constants.end());
    } else {
      ASSERT_NE(c, idl.constants.end()) << "no module " << name << "_Constants in the IDL";
      EXPECT_EQ(c->second, constants);
    }
    ++checked;
  }
  EXPECT_EQ(checked, 7);
  int skin_structs = 0;
  for (const auto& [name, members] : idl.structs) {
    if (name.starts_with(prefix)) ++skin_structs;
  }
  EXPECT_EQ(skin_structs, checked) << "a struct of skin_msgs.idl has no .msg file";
}

TEST(DdsMessagesTest, StandardTypesHaveTheRos2Layouts) {
  Idl idl;
  ASSERT_NO_FATAL_FAILURE(load_idl(&idl));
  const std::string time = "builtin_interfaces::msg::dds_::Time_";
  const std::map<std::string, std::vector<Field>> want = {
      {time, {{"int32", "sec", ""}, {"uint32", "nanosec", ""}}},
      {"std_msgs::msg::dds_::Header_", {{time, "stamp", ""}, {"string", "frame_id", ""}}},
      {"geometry_msgs::msg::dds_::Point_",
       {{"double", "x", ""}, {"double", "y", ""}, {"double", "z", ""}}},
      {"geometry_msgs::msg::dds_::Vector3_",
       {{"double", "x", ""}, {"double", "y", ""}, {"double", "z", ""}}},
      {"geometry_msgs::msg::dds_::Wrench_",
       {{"geometry_msgs::msg::dds_::Vector3_", "force", ""},
        {"geometry_msgs::msg::dds_::Vector3_", "torque", ""}}},
      {"sensor_msgs::msg::dds_::JointState_",
       {{"std_msgs::msg::dds_::Header_", "header", ""},
        {"sequence<string>", "name", ""},
        {"sequence<double>", "position", ""},
        {"sequence<double>", "velocity", ""},
        {"sequence<double>", "effort", ""}}},
      {"diagnostic_msgs::msg::dds_::KeyValue_", {{"string", "key", ""}, {"string", "value", ""}}},
      {"diagnostic_msgs::msg::dds_::DiagnosticStatus_",
       {{"octet", "level", ""},
        {"string", "name", ""},
        {"string", "message", ""},
        {"string", "hardware_id", ""},
        {"sequence<diagnostic_msgs::msg::dds_::KeyValue_>", "values", ""}}},
      {"diagnostic_msgs::msg::dds_::DiagnosticArray_",
       {{"std_msgs::msg::dds_::Header_", "header", ""},
        {"sequence<diagnostic_msgs::msg::dds_::DiagnosticStatus_>", "status", ""}}}};
  for (const auto& [name, fields] : want) {
    auto it = idl.structs.find(name);
    ASSERT_NE(it, idl.structs.end()) << name;
    EXPECT_EQ(it->second, fields) << name;
  }
}

TEST(DdsNamespaceTest, PutsTheSkinTopicsUnderIt) {
  DdsOptions o;
  ASSERT_TRUE(apply_namespace(&o, "").ok());
  EXPECT_EQ(o.contacts_topic, "rt/skin/contacts");
  ASSERT_TRUE(apply_namespace(&o, "/robot1/arm_left/").ok());
  EXPECT_EQ(o.contacts_topic, "rt/robot1/arm_left/skin/contacts");
  EXPECT_EQ(o.patch_status_topic, "rt/robot1/arm_left/skin/patch_status");
  EXPECT_EQ(o.joint_states_topic, "rt/joint_states");
  for (const char* bad : {"1arm", "arm-left", "arm//left", "a b", "arm/_x"}) {
    DdsOptions b;
    const Status st = apply_namespace(&b, bad);
    EXPECT_FALSE(st.ok()) << bad;
    EXPECT_EQ(b.contacts_topic, "rt/skin/contacts") << bad;
  }
}

}  // namespace
}  // namespace skinbus::dds
