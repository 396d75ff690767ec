#include "skinbus/record/ros2_messages.h"

#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "skinbus/common/test_seed.h"

namespace skinbus::record {
namespace {

uint32_t draw(std::mt19937& rng) {
  return static_cast<uint32_t>(rng());
}

int count_of(const std::string& text, const std::string& what) {
  int n = 0;
  for (std::size_t at = text.find(what); at != std::string::npos; at = text.find(what, at + 1)) ++n;
  return n;
}

TEST(Ros2MessagesTest, SchemasCarryEveryUsedTypeOnceAfterASeparator) {
  auto s = ros2_schema("skin_msgs/msg/ContactArray");
  ASSERT_TRUE(s.ok()) << s.error().message;
  EXPECT_EQ(s->find("std_msgs/Header header"), s->find("std_msgs/Header"));
  for (const char* dep : {"MSG: std_msgs/Header\n", "MSG: skin_msgs/Contact\n",
                          "MSG: builtin_interfaces/Time\n", "MSG: geometry_msgs/Point\n",
                          "MSG: geometry_msgs/Vector3\n", "MSG: geometry_msgs/Wrench\n"}) {
    EXPECT_EQ(count_of(*s, dep), 1) << dep;
  }
  EXPECT_EQ(count_of(*s, std::string(80, '=') + "\nMSG: "), 6);
  auto d = ros2_schema("diagnostic_msgs/msg/DiagnosticArray");
  ASSERT_TRUE(d.ok());
  EXPECT_EQ(count_of(*d, "MSG: diagnostic_msgs/KeyValue\n"), 1);
  EXPECT_FALSE(ros2_schema("nav_msgs/msg/Odometry").ok());
}

host::ContactArray random_contacts(std::mt19937& rng) {
  std::uniform_real_distribution<double> u(-500, 500);
  host::ContactArray a;
  a.stamp_us = 1'700'000'000'000'000ull + draw(rng) % 1000000;
  a.base_frame = "pelvis";
  a.contacts.resize(draw(rng) % 5);
  for (host::BodyContact& c : a.contacts) {
    for (double& p : c.position_mm) p = u(rng);
    for (double& n : c.normal) n = u(rng) / 500;
    c.depth_mm = std::abs(u(rng)) / 100;
    c.force_n = std::abs(u(rng)) / 10;
    c.u_mm = u(rng) / 10;
    c.v_mm = u(rng) / 10;
    c.uncertainty_mm = std::abs(u(rng)) / 1000;
    c.node = static_cast<uint8_t>(draw(rng) % 126);
    c.hardware_uid = (static_cast<uint64_t>(draw(rng)) << 32) | draw(rng);
    c.link = draw(rng) % 2 ? "left_forearm" : "";
    c.track_id = draw(rng);
    c.patch_count = draw(rng) % 4 + 1;
    c.flags = draw(rng) % 256;
    c.first_seen_us = a.stamp_us - draw(rng) % 1000;
  }
  return a;
}

TEST(Ros2MessagesTest, ContactsRoundTrip) {
  std::mt19937 rng(static_cast<uint32_t>(test_seed("Ros2MessagesTest.ContactsRoundTrip")));
  std::vector<uint8_t> buf;
  for (int i = 0; i < 100; ++i) {
    const host::ContactArray a = random_contacts(rng);
    ASSERT_TRUE(encode(a, &buf).ok());
    auto b = decode_contacts(buf);
    ASSERT_TRUE(b.ok()) << b.error().message;
    EXPECT_EQ(b->stamp_us, a.stamp_us);
    EXPECT_EQ(b->base_frame, a.base_frame);
    ASSERT_EQ(b->contacts.size(), a.contacts.size());
    for (std::size_t k = 0; k < a.contacts.size(); ++k) {
      const host::BodyContact &x = a.contacts[k], &y = b->contacts[k];
      for (int j = 0; j < 3; ++j) EXPECT_NEAR(y.position_mm[j], x.position_mm[j], 1e-9);
      EXPECT_NEAR(y.depth_mm, x.depth_mm, 1e-12);
      EXPECT_EQ(y.hardware_uid, x.hardware_uid);
      EXPECT_EQ(y.link, x.link);
      EXPECT_EQ(y.track_id, x.track_id);
      EXPECT_EQ(y.flags, x.flags);
      EXPECT_EQ(y.first_seen_us, x.first_seen_us);
    }
    // Every cut of the message is an error, never a crash.
    for (std::size_t cut = 0; cut + 1 < buf.size(); cut += 5) {
      EXPECT_FALSE(decode_contacts(std::span<const uint8_t>(buf.data(), cut)).ok());
    }
  }
}

TEST(Ros2MessagesTest, NonFiniteOrTimesBeyondTheTypeAreRefused) {
  host::ContactArray a;
  a.stamp_us = 1'700'000'000'000'000ull;
  a.contacts.resize(1);
  a.contacts[0].depth_mm = std::nan("");
  std::vector<uint8_t> buf;
  Status st = encode(a, &buf);
  ASSERT_FALSE(st.ok());
  EXPECT_NE(st.error().message.find("contacts[0].depth is nan"), std::string::npos);
  a.contacts[0].depth_mm = 1;
  a.stamp_us = 3'000'000'000ull * 1'000'000ull;  // year 2065
  EXPECT_EQ(encode(a, &buf).error().code, ErrorCode::kOutOfRange);
}

TEST(Ros2MessagesTest, FramesSamplesAndJointStatesRoundTrip) {
  std::vector<uint8_t> buf;
  CanFrameMsg f;
  f.rx_us = 1'700'000'000'123'456ull;
  f.interface = "can1";
  f.frame.id = 0x1ABCDE;
  f.frame.extended = true;
  f.frame.fd = true;
  f.frame.brs = true;
  f.frame.len = 48;
  for (int i = 0; i < 48; ++i)
    f.frame.data[static_cast<std::size_t>(i)] = static_cast<uint8_t>(i * 3);
  ASSERT_TRUE(encode(f, &buf).ok());
  auto g = decode_can_frame(buf);
  ASSERT_TRUE(g.ok()) << g.error().message;
  EXPECT_EQ(g->rx_us, f.rx_us);
  EXPECT_EQ(g->interface, "can1");
  EXPECT_TRUE(g->frame == f.frame);
  f.frame.len = 40;  // not a CAN FD length
  ASSERT_TRUE(encode(f, &buf).ok());
  EXPECT_EQ(decode_can_frame(buf).error().code, ErrorCode::kOutOfRange);
  f.frame.fd = false;
  f.frame.len = 12;  // over classic's 8
  ASSERT_TRUE(encode(f, &buf).ok());
  EXPECT_FALSE(decode_can_frame(buf).ok());

  PatchSampleMsg s;
  s.stamp_us = 1'700'000'000'000'001ull;
  s.link = "torso";
  s.node = 7;
  s.hardware_uid = 0x1122334455667788ull;
  s.patch_time_us = 123456;
  s.flags = 3;
  s.field_ut.assign(48, 0.0f);
  for (int i = 0; i < 48; ++i)
    s.field_ut[static_cast<std::size_t>(i)] = static_cast<float>(i) * 0.1f - 2.0f;
  ASSERT_TRUE(encode(s, &buf).ok());
  auto t = decode_patch_sample(buf);
  ASSERT_TRUE(t.ok());
  EXPECT_EQ(*t, s);

  JointStateMsg j{1'700'000'000'000'000ull, {"a", "b"}, {0.5, -0.01}};
  ASSERT_TRUE(encode(j, &buf).ok());
  auto k = decode_joint_state(buf);
  ASSERT_TRUE(k.ok());
  EXPECT_EQ(*k, j);
  j.positions.pop_back();
  EXPECT_FALSE(encode(j, &buf).ok());
}

}  // namespace
}  // namespace skinbus::record
