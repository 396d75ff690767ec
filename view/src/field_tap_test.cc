#include "skinbus/view/field_tap.h"

#include <gtest/gtest.h>

#include <array>
#include <nlohmann/json.hpp>

#include "skinbus/bus/codec.h"

namespace skinbus::view {
namespace {

// Feeds one sample of `node` (every channel `lsb`, channel 4 at `lsb_ch4`) as its frames.
void feed_sample(FieldTap& tap, uint8_t node, uint8_t seq, int16_t lsb, uint64_t rx_us,
                 uint16_t fault_mask = 0) {
  bus::Sample s;
  s.flags = bus::sample_flags::kTared;
  s.fault_mask = fault_mask;
  s.field_lsb.fill(lsb);
  bus::Message m;
  m.node = node;
  m.seq = seq;
  m.body = s;
  std::array<bus::CanFrame, bus::kMaxParts> frames;
  const auto r = bus::encode(m, frames);
  ASSERT_EQ(r.error, bus::EncodeError::kNone);
  for (std::size_t i = 0; i < r.frames; ++i) tap.feed(frames[i], rx_us, "can0");
}

TEST(FieldTap, SendsAPressedPatchAtItsRateAndClearsItOnce) {
  FieldTap tap({5.0, 10, 16});
  std::vector<std::string> out;
  feed_sample(tap, 3, 0, 10, 1'000'000);  // 1 uT everywhere: noise, nothing to show
  tap.take_updates(1'000'000, &out);
  EXPECT_TRUE(out.empty());

  feed_sample(tap, 3, 1, 123, 1'024'000, /*fault_mask=*/1u << 2);  // 12.3 uT: a press
  tap.take_updates(1'024'000, &out);
  ASSERT_EQ(out.size(), 1u);
  const auto j = nlohmann::json::parse(out[0]);
  EXPECT_EQ(j["type"], "fields");
  EXPECT_EQ(j["node"], 3);
  EXPECT_EQ(j["interface"], "can0");
  EXPECT_EQ(j["tared"], true);
  ASSERT_EQ(j["field_ut"].size(), 48u);
  EXPECT_NEAR(j["field_ut"][0].get<double>(), 12.3, 1e-9);
  EXPECT_TRUE(j["field_ut"][6].is_null());  // sensor 2 is faulty
  EXPECT_TRUE(j["field_ut"][8].is_null());

  out.clear();
  feed_sample(tap, 3, 2, 130, 1'048'000);  // 24 ms later: within the 100 ms of 10 Hz
  tap.take_updates(1'048'000, &out);
  EXPECT_TRUE(out.empty());
  tap.take_updates(1'130'000, &out);  // past it: the newest sample
  ASSERT_EQ(out.size(), 1u);
  EXPECT_NEAR(nlohmann::json::parse(out[0])["field_ut"][0].get<double>(), 13.0, 1e-9);

  out.clear();
  feed_sample(tap, 3, 3, 0, 1'150'000);  // released: one message to clear, then nothing
  tap.take_updates(1'150'000, &out);
  ASSERT_EQ(out.size(), 1u);
  out.clear();
  feed_sample(tap, 3, 4, 0, 1'300'000);
  tap.take_updates(1'300'000, &out);
  EXPECT_TRUE(out.empty());
  EXPECT_EQ(tap.stats().samples, 5u);
  EXPECT_EQ(tap.stats().updates, 3u);
}

TEST(FieldTap, ForeignFramesAreCountedAndIgnored) {
  FieldTap tap;
  bus::CanFrame f;
  f.id = 0x7ff;
  f.len = 3;
  tap.feed(f, 1, "can0");
  std::vector<std::string> out;
  tap.take_updates(2, &out);
  EXPECT_TRUE(out.empty());
  EXPECT_EQ(tap.stats().frames, 1u);
  EXPECT_EQ(tap.stats().samples, 0u);
}

}  // namespace
}  // namespace skinbus::view
