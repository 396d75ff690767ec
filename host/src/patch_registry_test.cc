#include "skinbus/host/patch_registry.h"

#include <gtest/gtest.h>

#include <algorithm>

namespace skinbus::host {
namespace {

constexpr uint64_t kUidA = 0x5EED000000000003ull;
constexpr uint64_t kUidB = 0x5EED0000000000B0ull;
constexpr uint64_t kS = 1'000'000;  // one second, us

body_map::SkinMap one_patch_map() {
  body_map::SkinMap map;
  body_map::PatchPlacement p;
  p.node_id = 3;
  p.hardware_uid = kUidA;
  p.link = "torso";
  p.model = "m";
  map.patches.push_back(p);
  return map;
}

bus::Heartbeat heartbeat(uint64_t uid, uint32_t uptime_s) {
  bus::Heartbeat hb;
  hb.state = bus::PatchState::kRunning;
  hb.mode = bus::PatchMode::kEvent;
  hb.hardware_uid = uid;
  hb.uptime_s = uptime_s;
  return hb;
}

std::vector<PatchEventKind> kinds(PatchRegistry& r) {
  std::vector<PatchEvent> ev;
  r.take_events(&ev);
  std::vector<PatchEventKind> k;
  for (const PatchEvent& e : ev) k.push_back(e.kind);
  return k;
}

bool has(const std::vector<PatchEventKind>& k, PatchEventKind x) {
  return std::find(k.begin(), k.end(), x) != k.end();
}

TEST(PatchRegistry, DiscoversAndGoesOnline) {
  const auto map = one_patch_map();
  PatchRegistry r(&map, {"can0"});
  r.set_models({0});
  bus::Sample s;
  // Before a heartbeat, a sample is placed by its node ID (provisionally).
  EXPECT_NE(r.on_sample(0, 3, s, 0, 1000), nullptr);
  EXPECT_EQ(r.entry(0, 3).state, PatchLinkState::kDiscovering);
  r.on_heartbeat(0, 3, heartbeat(kUidA, 5), 2000);
  EXPECT_EQ(r.entry(0, 3).state, PatchLinkState::kOnline);
  const auto k = kinds(r);
  EXPECT_TRUE(has(k, PatchEventKind::kDiscovered));
  EXPECT_TRUE(has(k, PatchEventKind::kOnline));
  // A node without a map entry is not used before its heartbeat.
  EXPECT_EQ(r.on_sample(0, 9, s, 0, 3000), nullptr);
}

TEST(PatchRegistry, UnknownUidAndMissingModelDegrade) {
  const auto map = one_patch_map();
  PatchRegistry r(&map, {"can0"});
  r.set_models({-1});
  r.on_heartbeat(0, 3, heartbeat(kUidA, 1), kS);
  EXPECT_EQ(r.entry(0, 3).state, PatchLinkState::kDegraded);
  EXPECT_NE(r.entry(0, 3).detail.find("no usable model"), std::string::npos);
  EXPECT_TRUE(has(kinds(r), PatchEventKind::kNoModel));

  r.on_heartbeat(0, 4, heartbeat(kUidB, 1), kS);
  EXPECT_EQ(r.entry(0, 4).state, PatchLinkState::kDegraded);
  EXPECT_NE(r.entry(0, 4).detail.find("not in the skin map"), std::string::npos);
  EXPECT_TRUE(has(kinds(r), PatchEventKind::kUnknownPatch));
  bus::Sample s;
  EXPECT_EQ(r.on_sample(0, 4, s, 0, kS + 10), nullptr);
  EXPECT_EQ(r.entry(0, 4).samples_dropped, 1u);
}

TEST(PatchRegistry, StaleOfflineAndReturn) {
  const auto map = one_patch_map();
  PatchRegistry r(&map, {"can0"});
  r.set_models({0});
  r.on_heartbeat(0, 3, heartbeat(kUidA, 1), kS);
  (void)kinds(r);
  r.tick(kS + 2 * kS);
  EXPECT_EQ(r.entry(0, 3).state, PatchLinkState::kOnline);
  r.tick(kS + 3 * kS);
  EXPECT_EQ(r.entry(0, 3).state, PatchLinkState::kStale);
  EXPECT_TRUE(has(kinds(r), PatchEventKind::kStale));
  r.tick(kS + 11 * kS);
  EXPECT_EQ(r.entry(0, 3).state, PatchLinkState::kOffline);
  EXPECT_TRUE(has(kinds(r), PatchEventKind::kOffline));
  r.on_heartbeat(0, 3, heartbeat(kUidA, 13), 13 * kS);
  EXPECT_EQ(r.entry(0, 3).state, PatchLinkState::kOnline);
  EXPECT_TRUE(has(kinds(r), PatchEventKind::kReturned));
}

TEST(PatchRegistry, RebootIsReported) {
  const auto map = one_patch_map();
  PatchRegistry r(&map, {"can0"});
  r.set_models({0});
  r.on_heartbeat(0, 3, heartbeat(kUidA, 100), kS);
  r.on_heartbeat(0, 3, heartbeat(kUidA, 101), 2 * kS);
  (void)kinds(r);
  r.on_heartbeat(0, 3, heartbeat(kUidA, 0), 3 * kS);
  EXPECT_EQ(r.entry(0, 3).reboots, 1u);
  EXPECT_TRUE(has(kinds(r), PatchEventKind::kRebooted));
  std::vector<PatchStatus> st;
  r.status(&st);
  ASSERT_EQ(st.size(), 1u);
  EXPECT_EQ(st[0].reboots, 1u);
  EXPECT_EQ(st[0].state, PatchLinkState::kOnline);
}

TEST(PatchRegistry, DuplicateIdIsLoudAndDropsSamples) {
  const auto map = one_patch_map();
  PatchRegistry r(&map, {"can0"});
  r.set_models({0});
  r.on_heartbeat(0, 3, heartbeat(kUidA, 10), kS);
  r.on_heartbeat(0, 3, heartbeat(kUidB, 20), kS + 300'000);
  const auto k = kinds(r);
  EXPECT_TRUE(has(k, PatchEventKind::kDuplicateId));
  EXPECT_TRUE(r.entry(0, 3).duplicate);
  EXPECT_EQ(r.entry(0, 3).state, PatchLinkState::kDegraded);
  bus::Sample s;
  EXPECT_EQ(r.on_sample(0, 3, s, 0, kS + 400'000), nullptr);
  std::vector<PatchStatus> st;
  r.status(&st);
  EXPECT_TRUE(st[0].duplicate_id);
  EXPECT_NE(st[0].detail.find("5eed0000000000b0"), std::string::npos);
  // The intruder stops; after the window the ID is unique again and samples flow.
  for (uint64_t t = 2; t <= 8; ++t)
    r.on_heartbeat(0, 3, heartbeat(kUidA, 10 + static_cast<uint32_t>(t)), t * kS);
  EXPECT_FALSE(r.entry(0, 3).duplicate);
  EXPECT_EQ(r.entry(0, 3).state, PatchLinkState::kOnline);
  EXPECT_NE(r.on_sample(0, 3, s, 0, 8 * kS + 1), nullptr);
}

// One hardware UID in the heartbeats of two nodes (a cloned board): both are duplicates, and the
// one whose node ID is not the map's for that UID is never placed at the other's place.
TEST(PatchRegistry, OneUidOnTwoNodesIsADuplicateAndTheOtherNodeIsNotPlaced) {
  const auto map = one_patch_map();  // UID A is node 3
  PatchRegistry r(&map, {"can0"});
  r.set_models({0});
  r.on_heartbeat(0, 3, heartbeat(kUidA, 10), kS);
  r.on_heartbeat(0, 5, heartbeat(kUidA, 20), kS + 300'000);
  std::vector<PatchEvent> ev;
  r.take_events(&ev);
  int duplicates = 0;
  for (const PatchEvent& e : ev) duplicates += e.kind == PatchEventKind::kDuplicateId;
  EXPECT_EQ(duplicates, 2);  // one for each node
  std::vector<PatchStatus> st;
  r.status(&st);
  ASSERT_EQ(st.size(), 2u);
  for (const PatchStatus& p : st) {
    EXPECT_TRUE(p.duplicate_id) << int(p.node);
    EXPECT_EQ(p.state, PatchLinkState::kDegraded) << int(p.node);
    EXPECT_NE(p.detail.find("5eed000000000003 also heard on can0 node"), std::string::npos)
        << p.detail;
  }
  bus::Sample s;
  EXPECT_EQ(r.on_sample(0, 5, s, 0, kS + 400'000), nullptr);  // would be placed as node 3
  EXPECT_NE(r.on_sample(0, 3, s, 0, kS + 400'000), nullptr);  // the map's node for UID A
  EXPECT_FALSE(r.attributable(r.entry(0, 5)));
  // Node 5 stops: after the window node 3 is unique again.
  for (uint64_t t = 2; t <= 8; ++t)
    r.on_heartbeat(0, 3, heartbeat(kUidA, 10 + static_cast<uint32_t>(t)), t * kS);
  EXPECT_EQ(r.entry(0, 3).uid_clash, -1);
  EXPECT_EQ(r.entry(0, 3).state, PatchLinkState::kOnline);
  st.clear();
  r.status(&st);
  EXPECT_FALSE(st[0].duplicate_id);
}

TEST(PatchRegistry, OneUidOnTwoNodesNeitherTheMapsDropsBoth) {
  const auto map = one_patch_map();  // UID A is node 3; heard on 5 and on 6 of another bus
  PatchRegistry r(&map, {"can0", "can1"});
  r.set_models({0});
  r.on_heartbeat(0, 5, heartbeat(kUidA, 10), kS);
  r.on_heartbeat(1, 6, heartbeat(kUidA, 20), kS + 1000);
  bus::Sample s;
  EXPECT_EQ(r.on_sample(0, 5, s, 0, kS + 2000), nullptr);
  EXPECT_EQ(r.on_sample(1, 6, s, 0, kS + 2000), nullptr);
  EXPECT_NE(r.entry(1, 6).detail.find("also heard on can0 node 5"), std::string::npos)
      << r.entry(1, 6).detail;
}

TEST(PatchRegistry, AModelThatGivesNoEstimatesDegradesUntilOneSucceeds) {
  const auto map = one_patch_map();
  PatchRegistry r(&map, {"can0"});
  r.set_models({0});
  r.on_heartbeat(0, 3, heartbeat(kUidA, 10), kS);
  (void)kinds(r);
  PatchEntry& e = r.entry(0, 3);
  r.set_estimator_problem(e, "no estimate for 10 samples (non_finite)", 2 * kS);
  EXPECT_EQ(e.state, PatchLinkState::kDegraded);
  EXPECT_EQ(e.detail, "no estimate for 10 samples (non_finite)");
  EXPECT_TRUE(has(kinds(r), PatchEventKind::kDegraded));
  r.set_estimator_problem(e, "no estimate for 10 samples (non_finite)", 3 * kS);
  EXPECT_TRUE(kinds(r).empty());  // said once
  r.set_estimator_problem(e, "", 4 * kS);
  EXPECT_EQ(e.state, PatchLinkState::kOnline);
  EXPECT_TRUE(has(kinds(r), PatchEventKind::kOnline));
}

TEST(PatchRegistry, BoardSwappedAfterSilenceTakesTheId) {
  const auto map = one_patch_map();
  PatchRegistry r(&map, {"can0"});
  r.set_models({0});
  r.on_heartbeat(0, 3, heartbeat(kUidA, 10), kS);
  r.on_heartbeat(0, 3, heartbeat(kUidB, 1), 20 * kS);  // long after A went quiet
  EXPECT_FALSE(r.entry(0, 3).duplicate);
  EXPECT_EQ(r.entry(0, 3).hardware_uid, kUidB);
  EXPECT_EQ(r.entry(0, 3).placement, nullptr);  // B is not in the map
  EXPECT_EQ(r.entry(0, 3).state, PatchLinkState::kDegraded);
  EXPECT_EQ(r.entry(0, 3).reboots, 0u);  // B's uptime is not compared with A's
  EXPECT_FALSE(has(kinds(r), PatchEventKind::kRebooted));
}

TEST(PatchRegistry, AHostClockStepBackIsNotASilenceOrAClash) {
  const auto map = one_patch_map();
  PatchRegistry r(&map, {"can0"});
  r.set_models({0});
  r.on_heartbeat(0, 3, heartbeat(kUidA, 10), 100 * kS);
  r.on_heartbeat(0, 3, heartbeat(kUidB, 20), 99 * kS);  // the clock stepped back 1 s
  EXPECT_TRUE(r.entry(0, 3).duplicate);                 // still a clash, not a swap
  r.on_heartbeat(0, 3, heartbeat(kUidA, 11), 98 * kS);
  EXPECT_TRUE(r.entry(0, 3).duplicate);  // and not cleared by the negative interval
  bus::Sample s;
  EXPECT_EQ(r.on_sample(0, 3, s, 0, 98 * kS + 1), nullptr);
}

TEST(PatchRegistry, SequenceGapsAreCounted) {
  const auto map = one_patch_map();
  PatchRegistry r(&map, {"can0", "can1"});
  r.set_models({0});
  bus::Sample s;
  (void)r.on_sample(0, 3, s, 4, 1000);
  EXPECT_EQ(r.entry(0, 3).samples_lost, 4u);
  EXPECT_TRUE(has(kinds(r), PatchEventKind::kSequenceGap));
  // The same node ID on the other bus is another patch.
  (void)r.on_sample(1, 3, s, 0, 1000);
  EXPECT_EQ(r.entry(1, 3).samples_lost, 0u);
  EXPECT_EQ(r.patches_heard(), 2u);
}

TEST(PatchRegistry, EventQueueIsBounded) {
  const auto map = one_patch_map();
  RegistryOptions o;
  o.max_events = 3;
  PatchRegistry r(&map, {"can0"}, o);
  for (int i = 0; i < 10; ++i) r.add_event(PatchEventKind::kBadFrames, 1, "x");
  EXPECT_EQ(kinds(r).size(), 3u);
  EXPECT_EQ(r.events_dropped(), 7u);
}

}  // namespace
}  // namespace skinbus::host
