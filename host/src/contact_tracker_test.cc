#include "skinbus/host/contact_tracker.h"

#include <gtest/gtest.h>

#include "skinbus/common/test_seed.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <numbers>
#include <random>
#include <set>
#include <string>
#include <vector>

namespace skinbus::host {
namespace {

// The seed of a randomized test (skinbus/common/test_seed.h), named after the running test.
uint64_t test_seed() {
  const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
  const std::string name = std::string(info->test_suite_name()) + "." + info->name();
  return skinbus::test_seed(name.c_str());
}

constexpr uint64_t kPeriodUs = 24'000;  // ~41.7 Hz

PatchContact contact(const double* p, uint8_t node, double sigma_mm, double depth_mm = 1.0) {
  PatchContact c;
  for (int k = 0; k < 3; ++k) c.position_mm[k] = p[k];
  c.normal[0] = 0;
  c.normal[1] = 0;
  c.normal[2] = 1;
  c.depth_mm = depth_mm;
  c.force_n = depth_mm * 2;
  c.u_mm = node * 1.5;
  c.v_mm = -node * 0.5;
  c.uncertainty_mm = sigma_mm;
  c.node = node;
  c.hardware_uid = 0x1000 + node;
  c.link = "link_" + std::to_string(node);
  return c;
}

void expect_finite(const BodyContact& b) {
  for (int k = 0; k < 3; ++k) {
    EXPECT_TRUE(std::isfinite(b.position_mm[k]));
    EXPECT_TRUE(std::isfinite(b.normal[k]));
  }
  EXPECT_TRUE(std::isfinite(b.depth_mm));
  EXPECT_TRUE(std::isfinite(b.force_n));
  EXPECT_TRUE(std::isfinite(b.u_mm));
  EXPECT_TRUE(std::isfinite(b.v_mm));
  EXPECT_TRUE(std::isfinite(b.uncertainty_mm));
  EXPECT_NEAR(std::hypot(b.normal[0], b.normal[1], b.normal[2]), 1.0, 1e-12);
  EXPECT_NE(b.track_id, 0u);
}

TEST(ContactTracker, TwoPatchesSeeingOnePressMergeWithTheWeightedPosition) {
  const uint64_t seed = test_seed();
  SCOPED_TRACE("seed " + std::to_string(seed));
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> pos(-500, 500), off(-4, 4), sig(0.3, 4), dep(0.2, 4);
  for (int trial = 0; trial < 100; ++trial) {
    const double press[3] = {pos(rng), pos(rng), pos(rng)};
    double pa[3], pb[3];
    for (int k = 0; k < 3; ++k) {
      pa[k] = press[k] + off(rng);
      pb[k] = press[k] + off(rng);
    }
    const double sa = sig(rng), sb = sig(rng);
    PatchContact a = contact(pa, 4, sa, dep(rng));
    PatchContact b = contact(pb, 9, sb, dep(rng));
    a.normal[0] = 0.3;  // tilted normals, not unit
    b.normal[1] = -0.2;
    b.normal[2] = 2.0;
    a.flags = kContactOutsidePatch;
    b.flags = kContactMaskedChannels;
    const std::vector<PatchContact> in = {a, b};
    ContactTracker tracker;
    std::vector<BodyContact> out;
    tracker.update(1'000'000, in, &out);
    ASSERT_EQ(out.size(), 1u);
    const BodyContact& m = out[0];
    expect_finite(m);
    const double wa = 1 / (sa * sa), wb = 1 / (sb * sb);
    for (int k = 0; k < 3; ++k) {
      EXPECT_NEAR(m.position_mm[k], (wa * pa[k] + wb * pb[k]) / (wa + wb), 1e-9);
    }
    // The normal: the weighted mean of the unit normals, re-normalised.
    double na[3] = {0.3, 0, 1}, nb[3] = {0, -0.2, 2.0}, n[3];
    const double la = std::hypot(na[0], na[1], na[2]), lb = std::hypot(nb[0], nb[1], nb[2]);
    for (int k = 0; k < 3; ++k) n[k] = wa * na[k] / la + wb * nb[k] / lb;
    const double ln = std::hypot(n[0], n[1], n[2]);
    for (int k = 0; k < 3; ++k) EXPECT_NEAR(m.normal[k], n[k] / ln, 1e-12);
    EXPECT_NEAR(m.depth_mm, (wa * a.depth_mm + wb * b.depth_mm) / (wa + wb), 1e-12);
    EXPECT_EQ(m.force_n, std::max(a.force_n, b.force_n));
    EXPECT_NEAR(m.uncertainty_mm, 1 / std::sqrt(wa + wb), 1e-12);
    const PatchContact& deep = a.depth_mm >= b.depth_mm ? a : b;
    EXPECT_EQ(m.node, deep.node);
    EXPECT_EQ(m.hardware_uid, deep.hardware_uid);
    EXPECT_EQ(m.link, deep.link);
    EXPECT_EQ(m.u_mm, deep.u_mm);
    EXPECT_EQ(m.v_mm, deep.v_mm);
    EXPECT_EQ(m.patch_count, 2u);
    EXPECT_EQ(m.flags, kContactMerged | kContactOutsidePatch | kContactMaskedChannels);
    EXPECT_EQ(m.track_id, 1u);
    EXPECT_EQ(m.first_seen_us, 1'000'000u);
  }
}

TEST(ContactTracker, TwoPressesFortyMillimetresApartStayTwo) {
  const double p1[3] = {100, 0, 50}, p2[3] = {140, 0, 50};
  ContactTracker tracker;
  std::vector<BodyContact> out;
  const std::vector<PatchContact> in = {contact(p1, 1, 1), contact(p2, 2, 1)};
  tracker.update(0, in, &out);
  ASSERT_EQ(out.size(), 2u);
  EXPECT_EQ(out[0].position_mm[0], 100);
  EXPECT_EQ(out[1].position_mm[0], 140);
  EXPECT_NE(out[0].track_id, out[1].track_id);
  for (const BodyContact& b : out) {
    EXPECT_EQ(b.patch_count, 1u);
    EXPECT_EQ(b.flags & kContactMerged, 0u);
  }
  EXPECT_EQ(tracker.active_tracks(), 2u);
}

TEST(ContactTracker, ContactsOfOnePatchAreNeverMerged) {
  // Two contacts of node 3 (same UID) 5 mm apart stay two; in a chain A(3) - B(7) - C(3), B
  // joins the closer of A and C only.
  const double pa[3] = {0, 0, 0}, pb[3] = {6, 0, 0}, pc[3] = {10, 0, 0};
  ContactTracker tracker;
  std::vector<BodyContact> out;
  std::vector<PatchContact> in = {contact(pa, 3, 1), contact(pc, 3, 1)};
  tracker.update(0, in, &out);
  EXPECT_EQ(out.size(), 2u);

  ContactTracker chain;
  in = {contact(pa, 3, 1), contact(pb, 7, 1), contact(pc, 3, 1)};
  chain.update(0, in, &out);
  ASSERT_EQ(out.size(), 2u);
  EXPECT_EQ(out[0].patch_count, 1u);  // A alone
  EXPECT_EQ(out[0].position_mm[0], 0);
  EXPECT_EQ(out[1].patch_count, 2u);  // B + C
  EXPECT_NEAR(out[1].position_mm[0], 8, 1e-12);

  // The same node ID on another bus (another UID) is another patch: merged.
  ContactTracker buses;
  PatchContact other = contact(pb, 3, 1);
  other.hardware_uid = 0xBEEF;
  in = {contact(pa, 3, 1), other};
  buses.update(0, in, &out);
  ASSERT_EQ(out.size(), 1u);
  EXPECT_EQ(out[0].patch_count, 2u);
}

TEST(ContactTracker, MovingPressKeepsItsTrackForAHundredPeriods) {
  const uint64_t seed = test_seed();
  SCOPED_TRACE("seed " + std::to_string(seed));
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> noise(0, 0.3);
  const double heading = std::uniform_real_distribution<double>(0, 2 * std::numbers::pi)(rng);
  double p[3] = {200, -100, 300};
  ContactTracker tracker;
  std::vector<BodyContact> out;
  uint32_t id = 0;
  for (int period = 0; period < 100; ++period) {
    p[0] += 2 * std::cos(heading);
    p[1] += 2 * std::sin(heading);
    // Seen by one or two patches as it crosses their edges.
    std::vector<PatchContact> in;
    for (uint8_t node : {uint8_t{5}, uint8_t{6}}) {
      if (node == 6 && (period / 10) % 2 == 0) continue;
      double q[3];
      for (int k = 0; k < 3; ++k) q[k] = p[k] + noise(rng);
      in.push_back(contact(q, node, 1.5));
    }
    tracker.update(static_cast<uint64_t>(period) * kPeriodUs, in, &out);
    ASSERT_EQ(out.size(), 1u) << "period " << period;
    if (period == 0) id = out[0].track_id;
    EXPECT_EQ(out[0].track_id, id) << "period " << period;
    EXPECT_EQ(out[0].first_seen_us, 0u);
    EXPECT_EQ(out[0].patch_count, in.size());
  }
  EXPECT_EQ(tracker.active_tracks(), 1u);
  EXPECT_EQ(tracker.tracks_started(), 1u);
}

TEST(ContactTracker, PressThatLiftsAndLandsAfterHoldGetsANewId) {
  const double p[3] = {0, 0, 0}, q[3] = {60, 0, 0};
  ContactTracker tracker;  // hold 100 ms
  std::vector<BodyContact> out;
  std::vector<PatchContact> in = {contact(p, 1, 1)};
  tracker.update(0, in, &out);
  ASSERT_EQ(out.size(), 1u);
  const uint32_t first = out[0].track_id;
  // Lifted: empty periods until past hold_us.
  tracker.update(50'000, {}, &out);
  EXPECT_TRUE(out.empty());
  EXPECT_EQ(tracker.active_tracks(), 1u);
  tracker.update(100'001, {}, &out);
  EXPECT_EQ(tracker.active_tracks(), 0u);
  // Lands elsewhere.
  in = {contact(q, 2, 1)};
  tracker.update(120'000, in, &out);
  ASSERT_EQ(out.size(), 1u);
  EXPECT_NE(out[0].track_id, first);
  EXPECT_EQ(out[0].first_seen_us, 120'000u);
  // Lifts again and lands on the same spot after hold_us, with no update in between: new ID.
  const uint32_t second = out[0].track_id;
  tracker.update(120'000 + 100'001, in, &out);
  ASSERT_EQ(out.size(), 1u);
  EXPECT_NE(out[0].track_id, second);
  EXPECT_NE(out[0].track_id, first);
}

TEST(ContactTracker, BriefDropoutShorterThanHoldKeepsTheId) {
  const double p[3] = {10, 20, 30};
  ContactTracker tracker;
  std::vector<BodyContact> out;
  const std::vector<PatchContact> in = {contact(p, 1, 1)};
  tracker.update(1'000, in, &out);
  const uint32_t id = out.at(0).track_id;
  for (int i = 1; i <= 4; ++i)
    tracker.update(1'000 + static_cast<uint64_t>(i) * kPeriodUs, {}, &out);
  tracker.update(1'000 + 100'000, in, &out);  // exactly hold_us later: still held
  ASSERT_EQ(out.size(), 1u);
  EXPECT_EQ(out[0].track_id, id);
  EXPECT_EQ(out[0].first_seen_us, 1'000u);
}

TEST(ContactTracker, StampGoingBackDoesNotHoldTracksForever) {
  const double p[3] = {0, 0, 0}, q[3] = {100, 0, 0};
  ContactTracker tracker;
  std::vector<BodyContact> out;
  std::vector<PatchContact> in = {contact(p, 1, 1)};
  tracker.update(10'000'000, in, &out);
  tracker.update(5'000'000, {}, &out);  // the host clock stepped back 5 s
  EXPECT_EQ(tracker.active_tracks(), 1u);
  tracker.update(5'000'000 + 100'001, {}, &out);
  EXPECT_EQ(tracker.active_tracks(), 0u);
  in = {contact(q, 1, 1)};
  tracker.update(5'200'000, in, &out);
  EXPECT_EQ(out.at(0).first_seen_us, 5'200'000u);
}

TEST(ContactTracker, IdsAreUniqueAndNonZero) {
  const uint64_t seed = test_seed();
  SCOPED_TRACE("seed " + std::to_string(seed));
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> pos(-1000, 1000);
  ContactTracker tracker;
  std::vector<BodyContact> out;
  std::set<uint32_t> seen;
  uint64_t t = 0;
  for (int period = 0; period < 300; ++period) {
    // Brand-new presses far from each other every 6 periods (beyond hold_us), so every contact
    // starts a track.
    t += 6 * kPeriodUs;
    std::vector<PatchContact> in;
    const int n = std::uniform_int_distribution<int>(0, 6)(rng);
    for (int i = 0; i < n; ++i) {
      const double p[3] = {i * 300.0 + pos(rng) * 0.05, pos(rng), pos(rng)};
      in.push_back(contact(p, static_cast<uint8_t>(i + 1), 1));
    }
    tracker.update(t, in, &out);
    ASSERT_EQ(out.size(), in.size());
    for (const BodyContact& b : out) {
      EXPECT_NE(b.track_id, 0u);
      EXPECT_TRUE(seen.insert(b.track_id).second) << "ID " << b.track_id << " reused";
    }
  }
  EXPECT_EQ(seen.size(), tracker.tracks_started());
  // IDs count up from 1.
  if (!seen.empty()) {
    EXPECT_EQ(*seen.begin(), 1u);
    EXPECT_EQ(*seen.rbegin(), seen.size());
  }
  tracker.reset();
  const double p[3] = {0, 0, 0};
  const std::vector<PatchContact> one = {contact(p, 1, 1)};
  tracker.update(t, one, &out);
  EXPECT_EQ(out.at(0).track_id, 1u);
}

TEST(ContactTracker, NonFiniteInputIsDroppedAndCounted) {
  const double good[3] = {0, 0, 0}, other[3] = {100, 0, 0};
  std::vector<PatchContact> in;
  for (int i = 0; i < 8; ++i) in.push_back(contact(good, static_cast<uint8_t>(i + 1), 1));
  in[0].position_mm[1] = std::nan("");
  in[1].normal[2] = std::numeric_limits<double>::infinity();
  in[2].depth_mm = std::nan("");
  in[3].force_n = -std::numeric_limits<double>::infinity();
  in[4].uncertainty_mm = std::nan("");
  in[5].u_mm = std::nan("");
  in[6].position_mm[0] = 1e300;  // finite but absurd
  in.push_back(contact(other, 20, 1));
  ContactTracker tracker;
  std::vector<BodyContact> out;
  tracker.update(0, in, &out);
  EXPECT_EQ(tracker.dropped(), 7u);
  ASSERT_EQ(out.size(), 2u);
  for (const BodyContact& b : out) expect_finite(b);
  EXPECT_EQ(out[0].node, 8);
  EXPECT_EQ(out[1].node, 20);
}

TEST(ContactTracker, DegenerateNormalsAndUncertaintiesStayFinite) {
  const double p[3] = {0, 0, 0}, q[3] = {3, 0, 0};
  PatchContact a = contact(p, 1, 0.0), b = contact(q, 2, -1.0);
  a.normal[2] = 0;  // zero normals
  b.normal[2] = 0;
  ContactTracker tracker;
  std::vector<BodyContact> out;
  std::vector<PatchContact> in = {a, b};
  tracker.update(0, in, &out);
  ASSERT_EQ(out.size(), 1u);
  expect_finite(out[0]);
  EXPECT_EQ(out[0].normal[2], 1.0);
  EXPECT_NEAR(out[0].uncertainty_mm, kMinUncertaintyMm / std::sqrt(2.0), 1e-15);
  EXPECT_NEAR(out[0].position_mm[0], 1.5, 1e-12);
  // Opposite normals cancel: the deepest member's normal.
  a.normal[0] = 1;
  b.normal[0] = -1;
  b.depth_mm = 3;
  in = {a, b};
  tracker.update(kPeriodUs, in, &out);
  ASSERT_EQ(out.size(), 1u);
  EXPECT_EQ(out[0].normal[0], -1.0);
  // A single contact with a zero normal and huge uncertainty.
  a.normal[0] = 0;
  a.uncertainty_mm = std::numeric_limits<double>::infinity();
  in = {a};
  tracker.update(2 * kPeriodUs, in, &out);
  ASSERT_EQ(out.size(), 1u);
  expect_finite(out[0]);
  EXPECT_EQ(out[0].normal[2], 1.0);
}

TEST(ContactTracker, RandomSceneGivesOneContactPerPress) {
  // Up to 10 presses in slots 80 mm apart, each coming and going, wandering within its slot,
  // seen by 1-3 patches with 1 mm noise; a slot stays empty for at least 5 periods (> hold_us)
  // between presses. Every period: one contact per press, each press keeps its ID for its
  // life, no ID is ever given to two presses.
  const uint64_t seed = test_seed();
  SCOPED_TRACE("seed " + std::to_string(seed));
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u01(0, 1), jitter(-10, 10), sig(0.5, 3);
  std::normal_distribution<double> noise(0, 1.0), step(0, 0.5);
  constexpr int kSlots = 10;
  struct Press {
    bool on = false;
    int off_periods = 100;
    double centre[3], p[3];
    uint32_t id = 0;
  };
  std::vector<Press> presses(kSlots);
  for (int s = 0; s < kSlots; ++s) {
    presses[s].centre[0] = (s % 5) * 80.0;
    presses[s].centre[1] = (s / 5) * 80.0;
    presses[s].centre[2] = 500;
  }
  ContactTracker tracker;
  std::vector<BodyContact> out;
  std::vector<PatchContact> in;
  std::set<uint32_t> used;
  int max_on = 0;
  for (int period = 0; period < 200; ++period) {
    in.clear();
    int on = 0;
    for (int s = 0; s < kSlots; ++s) {
      Press& pr = presses[s];
      if (pr.on && u01(rng) < 0.03) {
        pr.on = false;
        pr.off_periods = 0;
      } else if (!pr.on && pr.off_periods >= 5 && u01(rng) < 0.1) {
        pr.on = true;
        pr.id = 0;
        for (int k = 0; k < 3; ++k) pr.p[k] = pr.centre[k] + (k < 2 ? jitter(rng) : 0);
      }
      if (!pr.on) {
        ++pr.off_periods;
        continue;
      }
      ++on;
      for (int k = 0; k < 2; ++k) {
        pr.p[k] = std::clamp(pr.p[k] + step(rng), pr.centre[k] - 15, pr.centre[k] + 15);
      }
      const int seen_by = std::uniform_int_distribution<int>(1, 3)(rng);
      for (int j = 0; j < seen_by; ++j) {
        double q[3];
        for (int k = 0; k < 3; ++k) q[k] = pr.p[k] + noise(rng);
        PatchContact c = contact(q, static_cast<uint8_t>(1 + s * 3 + j), sig(rng));
        c.link = "slot" + std::to_string(s);
        in.push_back(c);
      }
    }
    std::shuffle(in.begin(), in.end(), rng);
    tracker.update(static_cast<uint64_t>(period) * kPeriodUs, in, &out);
    max_on = std::max(max_on, on);
    ASSERT_EQ(static_cast<int>(out.size()), on) << "period " << period;
    std::set<uint32_t> this_period;
    for (const BodyContact& b : out) {
      expect_finite(b);
      EXPECT_TRUE(this_period.insert(b.track_id).second);
      // Which press: the slot named by its link.
      const int s = std::stoi(b.link.substr(4));
      Press& pr = presses[s];
      ASSERT_TRUE(pr.on);
      EXPECT_LT(std::hypot(b.position_mm[0] - pr.p[0], b.position_mm[1] - pr.p[1]), 8.0);
      if (pr.id == 0) {
        pr.id = b.track_id;
        EXPECT_TRUE(used.insert(b.track_id).second) << "ID " << b.track_id << " reused";
      } else {
        EXPECT_EQ(b.track_id, pr.id) << "slot " << s << " period " << period;
      }
    }
  }
  std::printf("random scene: %zu presses over 200 periods, up to %d at once\n", used.size(),
              max_on);
  EXPECT_GT(max_on, 3);
  EXPECT_EQ(tracker.dropped(), 0u);
}

TEST(ContactTracker, OptionsAreChecked) {
  EXPECT_TRUE(check_options(TrackerOptions{}).ok());
  TrackerOptions o;
  o.merge_radius_mm = -1;
  Status s = check_options(o);
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.error().message.find("merge_radius_mm"), std::string::npos);
  o = {};
  o.gate_mm = std::nan("");
  s = check_options(o);
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.error().message.find("gate_mm"), std::string::npos);
  // The constructor takes them as 0: nothing merges.
  o.merge_radius_mm = -1;
  ContactTracker tracker(o);
  EXPECT_EQ(tracker.options().merge_radius_mm, 0.0);
  const double p[3] = {0, 0, 0}, q[3] = {1, 0, 0};
  const std::vector<PatchContact> in = {contact(p, 1, 1), contact(q, 2, 1)};
  std::vector<BodyContact> out;
  tracker.update(0, in, &out);
  EXPECT_EQ(out.size(), 2u);
}

}  // namespace
}  // namespace skinbus::host
