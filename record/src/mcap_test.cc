#include "skinbus/record/mcap.h"

#include <gtest/gtest.h>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <random>

#include <unistd.h>

#include "skinbus/common/test_seed.h"

namespace skinbus::record {
namespace {

uint32_t draw(std::mt19937& rng) {
  return static_cast<uint32_t>(rng());
}

std::string temp_path(const std::string& name) {
  return (std::filesystem::temp_directory_path() /
          ("skinbus_mcap_" + std::to_string(::getpid()) + "_" + name))
      .string();
}

std::vector<uint8_t> read_all(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return std::vector<uint8_t>(std::istreambuf_iterator<char>(in), {});
}

void write_all(const std::string& path, const std::vector<uint8_t>& bytes) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out.write(reinterpret_cast<const char*>(bytes.data()),
            static_cast<std::streamsize>(bytes.size()));
}

std::span<const uint8_t> as_bytes(const std::string& s) {
  return {reinterpret_cast<const uint8_t*>(s.data()), s.size()};
}

TEST(McapTest, Crc32MatchesTheCheckValue) {
  EXPECT_EQ(crc32(as_bytes("123456789")), 0xCBF43926u);  // CRC-32/ISO-HDLC check value
  EXPECT_EQ(crc32(as_bytes("6789"), crc32(as_bytes("12345"))), 0xCBF43926u);
  // Eight bytes a step and one at a time agree at every length and split.
  std::string text;
  for (int i = 0; i < 100; ++i) text += static_cast<char>(i * 37 + 11);
  auto bytewise = [](std::span<const uint8_t> d) {
    uint32_t c = ~0u;
    for (uint8_t b : d) {
      c ^= b;
      for (int k = 0; k < 8; ++k) c = (c & 1u) ? 0xEDB88320u ^ (c >> 1) : c >> 1;
    }
    return ~c;
  };
  for (std::size_t n = 0; n <= text.size(); ++n) {
    const auto d = as_bytes(text).first(n);
    EXPECT_EQ(crc32(d), bytewise(d)) << n;
    EXPECT_EQ(crc32(d.subspan(n / 3), crc32(d.first(n / 3))), bytewise(d)) << n;
  }
}

TEST(McapTest, RandomMessagesRoundTripAcrossChunks) {
  std::mt19937 rng(
      static_cast<uint32_t>(test_seed("McapTest.RandomMessagesRoundTripAcrossChunks")));
  const std::string path = temp_path("roundtrip.mcap");
  McapWriterOptions o;
  o.chunk_bytes = 2000;  // many chunks
  auto w = McapWriter::create(path, o);
  ASSERT_TRUE(w.ok());
  const std::string def = "float64 x\n";
  const uint16_t schema = (*w)->add_schema("pkg/msg/A", "ros2msg", as_bytes(def));
  const uint16_t a = (*w)->add_channel(schema, "/a", "cdr", {{"k", "v"}});
  const uint16_t b = (*w)->add_channel(schema, "/b", "cdr");
  std::vector<McapMessage> sent;
  uint64_t t = 1'700'000'000'000'000'000ull;
  for (int i = 0; i < 300; ++i) {
    McapMessage m;
    m.channel_id = draw(rng) % 2 ? a : b;
    t += draw(rng) % 1000000;
    m.log_time_ns = t;
    m.publish_time_ns = t - 5;
    m.data.resize(draw(rng) % 200);
    for (uint8_t& byte : m.data) byte = static_cast<uint8_t>(draw(rng));
    ASSERT_TRUE((*w)->write_message(m.channel_id, m.log_time_ns, m.publish_time_ns, m.data).ok());
    sent.push_back(std::move(m));
    if (i == 150) {
      ASSERT_TRUE(
          (*w)->write_attachment("map.yaml", "application/yaml", as_bytes("a: 1\n"), t, t).ok());
      ASSERT_TRUE((*w)->write_metadata("skinbus", {{"version", "1"}}).ok());
    }
  }
  EXPECT_FALSE((*w)->write_message(99, 0, 0, {}).ok());
  ASSERT_TRUE((*w)->close().ok());

  auto r = McapReader::open(path);
  ASSERT_TRUE(r.ok()) << r.error().message;
  EXPECT_EQ((*r)->profile(), "ros2");
  std::map<uint16_t, uint32_t> seq;
  McapMessage m;
  std::size_t n = 0;
  for (;;) {
    auto more = (*r)->next(&m);
    ASSERT_TRUE(more.ok()) << more.error().message;
    if (!*more) break;
    ASSERT_LT(n, sent.size());
    EXPECT_EQ(m.channel_id, sent[n].channel_id);
    EXPECT_EQ(m.log_time_ns, sent[n].log_time_ns);
    EXPECT_EQ(m.publish_time_ns, sent[n].publish_time_ns);
    EXPECT_EQ(m.data, sent[n].data);
    EXPECT_EQ(m.sequence, seq[m.channel_id]++);
    ++n;
  }
  EXPECT_EQ(n, sent.size());
  ASSERT_EQ((*r)->channels().size(), 2u);
  EXPECT_EQ((*r)->channels().at(a).metadata.at("k"), "v");
  EXPECT_EQ((*r)->schemas().at(schema).name, "pkg/msg/A");
  ASSERT_EQ((*r)->attachments().size(), 1u);
  EXPECT_EQ((*r)->attachments()[0].name, "map.yaml");
  ASSERT_EQ((*r)->metadata().size(), 1u);
  std::filesystem::remove(path);
}

// A small file, then damaged copies of it: each read names what is wrong and where.
TEST(McapTest, DamagedFilesAreErrorsNamingTheFileAndByte) {
  const std::string path = temp_path("damaged.mcap");
  {
    auto w = McapWriter::create(path);
    ASSERT_TRUE(w.ok());
    const uint16_t s = (*w)->add_schema("pkg/msg/A", "ros2msg", as_bytes("uint8 x\n"));
    const uint16_t c = (*w)->add_channel(s, "/a", "cdr");
    for (int i = 0; i < 10; ++i) {
      const std::vector<uint8_t> data(16, static_cast<uint8_t>(i));
      ASSERT_TRUE((*w)->write_message(c, 1000 + i, 1000 + i, data).ok());
    }
    ASSERT_TRUE((*w)->close().ok());
  }
  const std::vector<uint8_t> good = read_all(path);
  auto read_to_end = [&](const std::vector<uint8_t>& bytes) -> std::string {
    write_all(path, bytes);
    auto r = McapReader::open(path);
    if (!r.ok()) return r.error().message;
    McapMessage m;
    for (;;) {
      auto more = (*r)->next(&m);
      if (!more.ok()) return more.error().message;
      if (!*more) return "";
    }
  };
  EXPECT_EQ(read_to_end(good), "");
  // Not MCAP.
  std::vector<uint8_t> bad = good;
  bad[1] = 'X';
  EXPECT_NE(read_to_end(bad).find("not an MCAP file"), std::string::npos);
  // A flipped byte inside the chunk's messages: its CRC.
  bad = good;
  const std::size_t chunk_payload = good.size() / 3;
  bad[chunk_payload] ^= 0x5A;
  const std::string crc_error = read_to_end(bad);
  EXPECT_NE(crc_error, "");
  EXPECT_NE(crc_error.find(path + ": byte "), std::string::npos) << crc_error;
  // Cut anywhere before the data end: an error, never a crash or a hang.
  for (std::size_t cut = 9; cut < good.size() / 2; cut += 7) {
    const std::string e =
        read_to_end(std::vector<uint8_t>(good.begin(), good.begin() + static_cast<long>(cut)));
    EXPECT_NE(e, "") << "cut at " << cut;
  }
  std::filesystem::remove(path);
}

}  // namespace
}  // namespace skinbus::record
