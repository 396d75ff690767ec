// The project's DDS topics against a second DDS implementation: fastdds_peer (eProsima Fast DDS,
// ROS 2's default middleware, types written from the ROS 2 .msg files) in another process
// receives rt/skin/contacts and rt/skin/patch_status as skinbus::dds::SkinPublisher (Cyclone DDS)
// writes them, field for field, and publishes rt/joint_states that skinbus's
// JointStateSubscriber reads. Both on loopback only, in a domain of the test's own
// (dds_test_support.h; the peer is told the same: 127.0.0.1, unicast discovery).
#include <fcntl.h>
#include <gtest/gtest.h>
#include <signal.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>
#include <nlohmann/json.hpp>

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <map>
#include <random>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "dds_test_support.h"
#include "skinbus/dds/dds.h"

extern char** environ;

namespace skinbus::dds {
namespace {

using namespace test_support;
using host::BodyContact;
using host::ContactArray;
using host::PatchStatus;
using host::PatchStatusArray;
using nlohmann::json;

constexpr double kTol = 1e-12;

struct Child {
  pid_t pid = 0;
  int out = -1;
  std::string printed;
  void drain() {
    char buf[8192];
    ssize_t n = 0;
    while ((n = read(out, buf, sizeof buf)) > 0) printed.append(buf, static_cast<size_t>(n));
  }
};

Child spawn(std::vector<std::string> args) {
  Child c;
  int p[2];
  EXPECT_EQ(pipe2(p, O_CLOEXEC), 0);
  posix_spawn_file_actions_t fa;
  posix_spawn_file_actions_init(&fa);
  posix_spawn_file_actions_adddup2(&fa, p[1], STDOUT_FILENO);
  std::vector<char*> argv;
  for (std::string& a : args) argv.push_back(a.data());
  argv.push_back(nullptr);
  const int rc = posix_spawn(&c.pid, argv[0], &fa, nullptr, argv.data(), environ);
  posix_spawn_file_actions_destroy(&fa);
  close(p[1]);
  EXPECT_EQ(rc, 0) << "cannot start " << args[0];
  c.out = p[0];
  fcntl(c.out, F_SETFL, O_NONBLOCK);
  return c;
}

uint64_t time_us(const json& t) {
  return static_cast<uint64_t>(t.at("sec").get<int64_t>()) * 1000000u +
         t.at("nanosec").get<uint64_t>() / 1000u;
}

TEST(FastDdsInterop, AFastDdsSubscriberDecodesEveryFieldOfContactsStatusAndDiagnostics) {
  const uint64_t seed = dds_env().seed;
  const uint32_t domain = dds_env().domain_id;
  DdsOptions o;
  o.domain_id = domain;
  auto pub = SkinPublisher::create(o);
  ASSERT_TRUE(pub.ok()) << pub.error().to_string();

  PatchStatusArray status;
  status.stamp_us = now_us();
  PatchStatus ps;
  ps.node = 9;
  ps.hardware_uid = 0x5EED000000000009ull;
  ps.interface = "can1";
  ps.link = "right_forearm";
  ps.state = host::PatchLinkState::kDegraded;
  ps.fault_mask = 0x0104;
  ps.uptime_s = 77;
  ps.reboots = 2;
  ps.samples = 123456;
  ps.samples_lost = 12;
  ps.contacts = 4321;
  ps.clock_offset_us = -1234.5;
  ps.clock_drift_ppm = 17.25;
  ps.last_heard_us = status.stamp_us - 1000;
  ps.detail = "sensor faults";
  status.patches.push_back(ps);
  status.events.push_back({status.stamp_us - 5000, host::PatchEventKind::kRebooted, 9,
                           ps.hardware_uid, "uptime went back"});
  // Transient local: the peer gets it whenever it joins.
  ASSERT_TRUE((*pub)->publish(status).ok());

  Child peer = spawn({SKINBUS_FASTDDS_PEER, "listen", std::to_string(domain), "3", "30"});
  std::mt19937_64 rng(seed);
  std::map<uint64_t, ContactArray> sent;
  const uint64_t t0 = now_us();
  int wstatus = 0;
  bool exited = false;
  const auto end = std::chrono::steady_clock::now() + std::chrono::seconds(35);
  for (uint64_t k = 0; !exited && std::chrono::steady_clock::now() < end; ++k) {
    ContactArray a = random_contacts(rng, t0 + k * 1000, 1 + static_cast<int>(k % 3));
    ASSERT_TRUE((*pub)->publish(a).ok());
    sent.emplace(a.stamp_us, std::move(a));
    // The status again now and then: the diagnostics written with it are volatile.
    if (k % 4 == 0) {
      ASSERT_TRUE((*pub)->publish(status).ok());
    }
    peer.drain();
    exited = waitpid(peer.pid, &wstatus, WNOHANG) == peer.pid;
    if (!exited) std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
  if (!exited) {
    kill(peer.pid, SIGKILL);
    waitpid(peer.pid, &wstatus, 0);
  }
  fcntl(peer.out, F_SETFL, 0);
  peer.drain();
  close(peer.out);
  ASSERT_TRUE(exited) << "the Fast DDS peer did not finish; it printed:\n" << peer.printed;
  ASSERT_TRUE(WIFEXITED(wstatus));
  ASSERT_EQ(WEXITSTATUS(wstatus), 0) << peer.printed;

  std::istringstream lines(peer.printed);
  std::string line;
  int arrays = 0, statuses = 0, diagnostics = 0;
  const host::DiagnosticArray health = host::diagnose(status);
  while (std::getline(lines, line)) {
    SCOPED_TRACE(line);
    const json j = json::parse(line);
    if (j.at("type") == "diagnostics") {
      ++diagnostics;
      EXPECT_EQ(time_us(j.at("stamp")), status.stamp_us);
      ASSERT_EQ(j.at("status").size(), 1u);
      const json& d = j.at("status")[0];
      const host::PatchDiagnostic& w = health.status[0];
      EXPECT_EQ(d.at("level"), static_cast<int>(w.level));
      EXPECT_EQ(d.at("level"), 1) << "WARN: degraded with dead sensors";
      EXPECT_EQ(d.at("name"), w.name);
      EXPECT_EQ(d.at("message"), w.message);
      EXPECT_EQ(d.at("hardware_id"), w.hardware_id);
      ASSERT_EQ(d.at("values").size(), w.values.size());
      for (const host::DiagnosticValue& v : w.values) EXPECT_EQ(d.at("values").at(v.key), v.value);
      continue;
    }
    if (j.at("type") == "patch_status") {
      ++statuses;
      EXPECT_EQ(time_us(j.at("stamp")), status.stamp_us);
      ASSERT_EQ(j.at("patches").size(), 1u);
      const json& p = j.at("patches")[0];
      EXPECT_EQ(p.at("node"), ps.node);
      EXPECT_EQ(p.at("hardware_uid").get<uint64_t>(), ps.hardware_uid);
      EXPECT_EQ(p.at("can_interface"), ps.interface);
      EXPECT_EQ(p.at("link_name"), ps.link);
      EXPECT_EQ(p.at("state"), static_cast<int>(ps.state));
      EXPECT_EQ(p.at("state_name"), "degraded");
      EXPECT_EQ(p.at("fault_mask"), ps.fault_mask);
      EXPECT_EQ(p.at("uptime"), ps.uptime_s);
      EXPECT_EQ(p.at("reboots"), ps.reboots);
      EXPECT_EQ(p.at("samples"), ps.samples);
      EXPECT_EQ(p.at("samples_lost"), ps.samples_lost);
      EXPECT_EQ(p.at("contacts"), ps.contacts);
      EXPECT_NEAR(p.at("clock_offset").get<double>() * 1e6, ps.clock_offset_us, 1e-6);
      EXPECT_EQ(p.at("clock_drift_ppm").get<double>(), ps.clock_drift_ppm);
      EXPECT_EQ(time_us(p.at("last_heard")), ps.last_heard_us);
      EXPECT_EQ(p.at("duplicate_id"), false);
      EXPECT_EQ(p.at("detail"), ps.detail);
      ASSERT_EQ(j.at("events").size(), 1u);
      const json& e = j.at("events")[0];
      EXPECT_EQ(time_us(e.at("stamp")), status.events[0].time_us);
      EXPECT_EQ(e.at("kind"), static_cast<int>(host::PatchEventKind::kRebooted));
      EXPECT_EQ(e.at("kind_name"), "rebooted");
      EXPECT_EQ(e.at("node"), 9);
      EXPECT_EQ(e.at("hardware_uid").get<uint64_t>(), ps.hardware_uid);
      EXPECT_EQ(e.at("detail"), "uptime went back");
      continue;
    }
    ASSERT_EQ(j.at("type"), "contacts");
    ++arrays;
    auto it = sent.find(time_us(j.at("stamp")));
    ASSERT_NE(it, sent.end()) << "a stamp that was never published";
    const ContactArray& want = it->second;
    EXPECT_EQ(j.at("frame_id"), want.base_frame);
    const json& cs = j.at("contacts");
    ASSERT_EQ(cs.size(), want.contacts.size());
    for (std::size_t i = 0; i < cs.size(); ++i) {
      const json& c = cs[i];
      const BodyContact& w = want.contacts[i];
      for (int k = 0; k < 3; ++k) {
        EXPECT_NEAR(c.at("position")[k].get<double>(), w.position_mm[k] / 1000, kTol);
        EXPECT_EQ(c.at("normal")[k].get<double>(), w.normal[k]);
      }
      EXPECT_NEAR(c.at("depth").get<double>(), w.depth_mm / 1000, kTol);
      EXPECT_EQ(c.at("force").get<double>(), w.force_n);
      EXPECT_EQ(c.at("patch_id"), w.node);
      EXPECT_EQ(c.at("hardware_uid").get<uint64_t>(), w.hardware_uid);
      EXPECT_EQ(c.at("link_name"), w.link);
      EXPECT_NEAR(c.at("u").get<double>(), w.u_mm / 1000, kTol);
      EXPECT_NEAR(c.at("v").get<double>(), w.v_mm / 1000, kTol);
      EXPECT_NEAR(c.at("uncertainty").get<double>(), w.uncertainty_mm / 1000, kTol);
      EXPECT_EQ(c.at("track_id"), w.track_id);
      EXPECT_EQ(c.at("patch_count"), w.patch_count);
      EXPECT_EQ(c.at("flags"), w.flags);
      EXPECT_EQ(time_us(c.at("first_seen")), w.first_seen_us);
      // The wrench, computed here from its definition in Contact.msg.
      double force[3], r[3];
      for (int k = 0; k < 3; ++k) {
        EXPECT_NEAR(c.at("shear")[k].get<double>(), w.shear_n[k], kTol);
        force[k] = -w.force_n * w.normal[k] + w.shear_n[k];
        r[k] = w.position_mm[k] / 1000;
        EXPECT_NEAR(c.at("wrench").at("force")[k].get<double>(), force[k], kTol);
      }
      const double torque[3] = {r[1] * force[2] - r[2] * force[1],
                                r[2] * force[0] - r[0] * force[2],
                                r[0] * force[1] - r[1] * force[0]};
      for (int k = 0; k < 3; ++k)
        EXPECT_NEAR(c.at("wrench").at("torque")[k].get<double>(), torque[k], kTol);
      EXPECT_NEAR(c.at("shear_uncertainty").get<double>(), w.shear_uncertainty_n, kTol);
    }
  }
  EXPECT_GE(arrays, 3);
  EXPECT_GE(statuses, 1);
  EXPECT_GE(diagnostics, 1);
}

TEST(FastDdsInterop, JointStatesFromAFastDdsPublisherReachTheHostsSubscriber) {
  DdsOptions o;
  o.domain_id = dds_env().domain_id;
  auto sub = JointStateSubscriber::create(o);
  ASSERT_TRUE(sub.ok()) << sub.error().to_string();
  const uint64_t before = now_us();
  Child peer = spawn({SKINBUS_FASTDDS_PEER, "joints", std::to_string(o.domain_id), "20",
                      "left_elbow=0.5", "right_elbow=-1.25", "torso_lift=0.031"});
  JointStateSample got;
  bool have = false;
  const auto end = std::chrono::steady_clock::now() + std::chrono::seconds(20);
  while (!have && std::chrono::steady_clock::now() < end) {
    have = (*sub)->take_latest(&got);
    if (!have) std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  kill(peer.pid, SIGTERM);
  int wstatus = 0;
  waitpid(peer.pid, &wstatus, 0);
  close(peer.out);
  ASSERT_TRUE(have) << "no joint state from the Fast DDS publisher";
  EXPECT_EQ(got.names, (std::vector<std::string>{"left_elbow", "right_elbow", "torso_lift"}));
  EXPECT_EQ(got.positions, (std::vector<double>{0.5, -1.25, 0.031}));
  EXPECT_GE(got.stamp_us, before - 1'000'000);
  EXPECT_LE(got.stamp_us, now_us());
  EXPECT_EQ((*sub)->rejected_samples(), 0u);
}

}  // namespace
}  // namespace skinbus::dds
