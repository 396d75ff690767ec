#include "skinbus/record/cdr.h"

#include <gtest/gtest.h>

#include <random>

#include "skinbus/common/test_seed.h"

namespace skinbus::record {
namespace {

uint32_t draw(std::mt19937& rng) {
  return static_cast<uint32_t>(rng());
}

TEST(CdrTest, AlignsFromTheByteAfterTheHeader) {
  std::vector<uint8_t> out;
  CdrWriter w(&out);
  w.u8(1);
  w.u32(0x04030201);
  w.u8(2);
  w.f64(1.0);
  w.string("ab");
  const std::vector<uint8_t> want = {0, 1, 0, 0,                        // header
                                     1, 0, 0, 0, 1,   2,   3,    4,     // u8, pad, u32
                                     2, 0, 0, 0, 0,   0,   0,    0,     // u8, pad
                                     0, 0, 0, 0, 0,   0,   0xF0, 0x3F,  // 1.0
                                     3, 0, 0, 0, 'a', 'b', 0};          // "ab"
  EXPECT_EQ(out, want);
}

TEST(CdrTest, RandomRoundTrip) {
  std::mt19937 rng(static_cast<uint32_t>(test_seed("CdrTest.RandomRoundTrip")));
  for (int round = 0; round < 200; ++round) {
    std::vector<int> kinds(draw(rng) % 20);
    for (int& k : kinds) k = static_cast<int>(draw(rng) % 7);
    std::vector<uint64_t> values(kinds.size());
    std::vector<std::string> strings(kinds.size());
    std::vector<uint8_t> out;
    CdrWriter w(&out);
    for (std::size_t i = 0; i < kinds.size(); ++i) {
      values[i] = (static_cast<uint64_t>(draw(rng)) << 32) | draw(rng);
      switch (kinds[i]) {
        case 0:
          w.u8(static_cast<uint8_t>(values[i]));
          break;
        case 1:
          w.u16(static_cast<uint16_t>(values[i]));
          break;
        case 2:
          w.u32(static_cast<uint32_t>(values[i]));
          break;
        case 3:
          w.u64(values[i]);
          break;
        case 4:
          w.f64(static_cast<double>(values[i] % 1000) / 7.0);
          break;
        case 5:
          strings[i] = std::string(draw(rng) % 9, static_cast<char>('a' + draw(rng) % 26));
          w.string(strings[i]);
          break;
        default:
          w.f32(static_cast<float>(values[i] % 100) / 3.0f);
          break;
      }
    }
    CdrReader r(out, "random");
    for (std::size_t i = 0; i < kinds.size(); ++i) {
      switch (kinds[i]) {
        case 0:
          EXPECT_EQ(r.u8("f"), static_cast<uint8_t>(values[i]));
          break;
        case 1:
          EXPECT_EQ(r.u16("f"), static_cast<uint16_t>(values[i]));
          break;
        case 2:
          EXPECT_EQ(r.u32("f"), static_cast<uint32_t>(values[i]));
          break;
        case 3:
          EXPECT_EQ(r.u64("f"), values[i]);
          break;
        case 4:
          EXPECT_EQ(r.f64("f"), static_cast<double>(values[i] % 1000) / 7.0);
          break;
        case 5:
          EXPECT_EQ(r.string("f"), strings[i]);
          break;
        default:
          EXPECT_EQ(r.f32("f"), static_cast<float>(values[i] % 100) / 3.0f);
          break;
      }
    }
    EXPECT_TRUE(r.ok()) << r.status().error().message;
    EXPECT_EQ(r.remaining(), 0u);
  }
}

TEST(CdrTest, ShortAndMalformedInputIsAnErrorNamingTheField) {
  std::vector<uint8_t> out;
  CdrWriter w(&out);
  w.u32(7);
  out.pop_back();
  CdrReader r(out, "Msg");
  EXPECT_EQ(r.u32("count"), 0u);
  EXPECT_EQ(r.u64("later"), 0u);  // reads on, zero values
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().error().message.find("Msg: count at byte 4"), std::string::npos)
      << r.status().error().message;

  const std::vector<uint8_t> big_endian = {0, 0, 0, 0, 0, 0, 0, 1};
  CdrReader be(big_endian, "Msg");
  (void)be.u32("x");
  EXPECT_FALSE(be.ok());

  std::vector<uint8_t> no_nul;
  CdrWriter w2(&no_nul);
  w2.string("abc");
  no_nul.back() = 'x';
  CdrReader s(no_nul, "Msg");
  EXPECT_EQ(s.string("name"), "");
  EXPECT_NE(s.status().error().message.find("NUL"), std::string::npos);

  std::vector<uint8_t> huge;
  CdrWriter w3(&huge);
  w3.u32(0xFFFFFFFF);
  CdrReader c(huge, "Msg");
  EXPECT_EQ(c.count("items", 8), 0u);
  EXPECT_NE(c.status().error().message.find("does not fit"), std::string::npos);
}

}  // namespace
}  // namespace skinbus::record
