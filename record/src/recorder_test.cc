#include "skinbus/record/recorder.h"

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>

#include <unistd.h>

namespace skinbus::record {
namespace {

std::string temp_path(const std::string& name) {
  return (std::filesystem::temp_directory_path() /
          ("skinbus_recorder_" + std::to_string(::getpid()) + "_" + name))
      .string();
}

TEST(RecorderTest, WritesEveryChannelAndTheAttachments) {
  const std::string path = temp_path("session.mcap");
  const std::string map = temp_path("skin.yaml");
  std::ofstream(map) << "robot: r.urdf\npatches: []\n";
  RecorderOptions o;
  o.attachments["skin.yaml"] = map;
  o.metadata["models"] = "m.onnx";
  auto r = Recorder::create(path, {"can0", "can1"}, nullptr, o);
  ASSERT_TRUE(r.ok()) << r.error().message;
  const uint64_t t0 = 1'700'000'000'000'000ull;
  bus::CanFrame f;
  f.id = 0x123;
  f.len = 2;
  f.data[0] = 0xAB;
  (*r)->frame(1, f, t0);
  host::PatchEntry e;
  e.node = 4;
  e.hardware_uid = 42;
  bus::Sample s;
  s.timestamp_us = 99;
  s.field_lsb[5] = -17;
  (*r)->sample(e, s, t0 + 10, t0 + 5);
  host::ContactArray c;
  c.stamp_us = t0 + 5;
  c.base_frame = "pelvis";
  c.contacts.resize(1);
  c.contacts[0].position_mm[0] = 12.5;
  c.contacts[0].track_id = 3;
  c.contacts[0].first_seen_us = t0;
  (*r)->contacts(c);
  host::PatchStatusArray st;
  st.stamp_us = t0 + 20;
  st.patches.resize(1);
  st.patches[0].node = 4;
  st.patches[0].last_heard_us = t0 + 10;
  (*r)->status(st);
  // Refused by the encoder (NaN): counted and reported, the recording goes on.
  c.contacts[0].depth_mm = std::nan("");
  (*r)->contacts(c);
  EXPECT_FALSE((*r)->error().ok());
  EXPECT_EQ((*r)->stats().dropped, 1u);
  EXPECT_FALSE((*r)->close().ok());  // the kept error

  auto rd = McapReader::open(path);
  ASSERT_TRUE(rd.ok()) << rd.error().message;
  std::map<std::string, int> per_topic;
  McapMessage m;
  for (;;) {
    auto more = (*rd)->next(&m);
    ASSERT_TRUE(more.ok()) << more.error().message;
    if (!*more) break;
    const std::string& topic = (*rd)->channels().at(m.channel_id).topic;
    ++per_topic[topic];
    if (topic == kContactsTopic) {
      auto back = decode_contacts(m.data);
      ASSERT_TRUE(back.ok());
      EXPECT_EQ(back->base_frame, "pelvis");
      ASSERT_EQ(back->contacts.size(), 1u);
      EXPECT_DOUBLE_EQ(back->contacts[0].position_mm[0], 12.5);
      EXPECT_EQ(m.log_time_ns, (t0 + 10) * 1000);  // the newest receive time seen
    } else if (topic == kCanTopic) {
      auto back = decode_can_frame(m.data);
      ASSERT_TRUE(back.ok());
      EXPECT_EQ(back->interface, "can1");
      EXPECT_TRUE(back->frame == f);
    } else if (topic == kSamplesTopic) {
      auto back = decode_patch_sample(m.data);
      ASSERT_TRUE(back.ok());
      EXPECT_EQ(back->node, 4);
      EXPECT_EQ(back->stamp_us, t0 + 5);
      EXPECT_FLOAT_EQ(back->field_ut[5], -1.7f);
    }
  }
  const std::map<std::string, int> want = {{kContactsTopic, 1},
                                           {kPatchStatusTopic, 1},
                                           {kDiagnosticsTopic, 1},
                                           {kSamplesTopic, 1},
                                           {kCanTopic, 1}};
  EXPECT_EQ(per_topic, want);
  EXPECT_EQ((*rd)->channels().size(), 5u);  // no robot: no /joint_states
  ASSERT_EQ((*rd)->attachments().size(), 1u);
  EXPECT_EQ((*rd)->attachments()[0].name, "skin.yaml");
  ASSERT_EQ((*rd)->metadata().size(), 1u);
  EXPECT_EQ((*rd)->metadata()[0].second.at("models"), "m.onnx");
  std::filesystem::remove(path);
  std::filesystem::remove(map);
}

TEST(RecorderTest, AFileThatCannotBeReadOrWrittenIsAnErrorNamingIt) {
  RecorderOptions o;
  o.attachments["skin.yaml"] = "/nonexistent/skin.yaml";
  const std::string path = temp_path("never.mcap");
  auto r = Recorder::create(path, {"can0"}, nullptr, o);
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error().message.find("/nonexistent/skin.yaml"), std::string::npos);
  EXPECT_FALSE(std::filesystem::exists(path));
  auto w = Recorder::create("/nonexistent/dir/x.mcap", {"can0"}, nullptr);
  ASSERT_FALSE(w.ok());
  EXPECT_NE(w.error().message.find("/nonexistent/dir/x.mcap"), std::string::npos);
}

}  // namespace
}  // namespace skinbus::record
