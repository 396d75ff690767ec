// Shared by the DDS tests (dds_test, tests/interop/fastdds_interop_test): the test process's
// DDS environment and the values they publish. Test code only.
//
// Isolation: before the first DDS entity, every test process points CYCLONEDDS_URI at a
// configuration it writes itself (loopback interface only, no multicast, the peer 127.0.0.1) and
// picks a random domain id from the printed seed (SKINBUS_TEST_SEED=<seed> replays it), so
// parallel ctest runs and other DDS programs on the machine do not cross-talk.
#pragma once

#include <gtest/gtest.h>
#include <time.h>
#include <unistd.h>

#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <mutex>
#include <random>
#include <string>
#include <utility>

#include "skinbus/dds/dds.h"

namespace skinbus::dds::test_support {

namespace fs = std::filesystem;
using host::BodyContact;
using host::ContactArray;

// ---- the test process's DDS environment --------------------------------------------------

struct DdsTestEnv {
  uint64_t seed = 0;
  uint32_t domain_id = 0;
  fs::path config;
  ~DdsTestEnv() {
    std::error_code ec;
    if (!config.empty()) fs::remove(config, ec);
  }
};

// Writes the loopback-only configuration, sets CYCLONEDDS_URI and picks the domain, once per
// process (before any entity exists: Cyclone reads CYCLONEDDS_URI when a domain is created).
inline const DdsTestEnv& dds_env() {
  static DdsTestEnv env;
  static std::once_flag once;
  std::call_once(once, [] {
    if (const char* s = std::getenv("SKINBUS_TEST_SEED")) {
      env.seed = std::strtoull(s, nullptr, 0);
    } else {
      env.seed = (static_cast<uint64_t>(std::random_device{}()) << 32) ^ std::random_device{}();
    }
    // 1..100: not ROS 2's default domain 0, and apart from the end-to-end tests' 120..219
    // (tests/e2e/e2e_lib.sh), which publish the real topic names.
    env.domain_id = static_cast<uint32_t>(1 + env.seed % 100);
    std::printf("[ seed     ] DDS tests: SKINBUS_TEST_SEED=%llu (domain %u)\n",
                static_cast<unsigned long long>(env.seed), env.domain_id);
    std::fflush(stdout);
    env.config =
        fs::path(::testing::TempDir()) / ("skinbus_dds_test_" + std::to_string(getpid()) + ".xml");
    std::ofstream f(env.config);
    f << R"(<?xml version="1.0" encoding="UTF-8"?>
<CycloneDDS xmlns="https://cdds.io/config">
  <Domain Id="any">
    <General>
      <Interfaces>
        <NetworkInterface address="127.0.0.1"/>
      </Interfaces>
      <AllowMulticast>false</AllowMulticast>
    </General>
    <Discovery>
      <ParticipantIndex>auto</ParticipantIndex>
      <MaxAutoParticipantIndex>30</MaxAutoParticipantIndex>
      <Peers>
        <Peer Address="127.0.0.1"/>
      </Peers>
    </Discovery>
  </Domain>
</CycloneDDS>
)";
    f.close();
    setenv("CYCLONEDDS_URI", ("file://" + env.config.string()).c_str(), 1);
  });
  return env;
}

// Options on the test domain; `tag` makes the topic names unique to this process and test.
inline DdsOptions test_options(const std::string& tag) {
  DdsOptions o;
  o.domain_id = dds_env().domain_id;
  if (!tag.empty()) {
    const std::string suffix = "_" + tag + "_" + std::to_string(getpid());
    o.contacts_topic += suffix;
    o.patch_status_topic += suffix;
    o.joint_states_topic += suffix;
    o.diagnostics_topic += suffix;
  }
  return o;
}

template <typename T>
T must(Result<T> r) {
  if (!r.ok()) {
    ADD_FAILURE() << r.error().to_string();
    std::abort();
  }
  return std::move(r).value();
}

inline uint64_t now_us() {
  timespec ts{};
  clock_gettime(CLOCK_REALTIME, &ts);
  return static_cast<uint64_t>(ts.tv_sec) * 1000000u + static_cast<uint64_t>(ts.tv_nsec) / 1000u;
}

// ---- values ---------------------------------------------------------------------------------

inline ContactArray random_contacts(std::mt19937_64& rng, uint64_t stamp_us, int n) {
  std::uniform_real_distribution<double> mm(-900.0, 900.0), unit(-1.0, 1.0), pos(0.0, 30.0);
  std::uniform_int_distribution<uint64_t> u64;
  ContactArray a;
  a.stamp_us = stamp_us;
  a.base_frame = "base_link";
  for (int i = 0; i < n; ++i) {
    BodyContact c;
    for (int k = 0; k < 3; ++k) {
      c.position_mm[k] = mm(rng);
      c.normal[k] = unit(rng);
    }
    c.depth_mm = pos(rng) / 10;
    c.force_n = pos(rng);
    c.u_mm = mm(rng) / 20;
    c.v_mm = mm(rng) / 20;
    c.uncertainty_mm = pos(rng) / 30;
    c.node = static_cast<uint8_t>(1 + u64(rng) % 125);
    c.hardware_uid = u64(rng);
    c.link = "link_" + std::to_string(u64(rng) % 7) + (i % 2 == 0 ? "_forearm" : "");
    c.track_id = static_cast<uint32_t>(1 + u64(rng) % 100000);
    c.patch_count = static_cast<uint32_t>(1 + u64(rng) % 3);
    c.flags = static_cast<uint32_t>(u64(rng) & 0x3FF);
    c.first_seen_us = a.stamp_us - u64(rng) % 5'000'000u;
    for (double& s : c.shear_n) s = unit(rng) * 3;
    c.shear_uncertainty_n = pos(rng) / 60;
    a.contacts.push_back(c);
  }
  return a;
}

}  // namespace skinbus::dds::test_support
