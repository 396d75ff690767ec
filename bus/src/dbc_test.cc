#include "skinbus/bus/dbc.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdlib>
#include <fstream>
#include <map>
#include <sstream>

#include "skinbus/bus/candump.h"
#include "skinbus/bus/codec.h"
#include "testing.h"

namespace skinbus::bus {
namespace {

// A minimal reader of the DBC subset the generator writes (little-endian signals, one level of
// multiplexing): enough to decode frames through the file's own definitions.
struct Signal {
  std::string name;
  int mux = -1;  // -1: always present
  bool is_mux = false;
  int start = 0, len = 0;
  bool is_signed = false;
  double scale = 1;
};
std::map<uint32_t, std::vector<Signal>> parse_dbc(const std::string& text) {
  std::map<uint32_t, std::vector<Signal>> msgs;
  std::istringstream in(text);
  std::string line;
  uint32_t current = 0;
  while (std::getline(in, line)) {
    std::istringstream l(line);
    std::string tok;
    l >> tok;
    if (tok == "BO_") {
      l >> current;
      msgs[current];
    } else if (tok == "SG_") {
      Signal s;
      l >> s.name >> tok;
      if (tok == "M") {
        s.is_mux = true;
        l >> tok;
      } else if (tok[0] == 'm') {
        s.mux = std::stoi(tok.substr(1));
        l >> tok;
      }
      std::string spec, scale;
      l >> spec >> scale;  // "16|32@1+" "(0.1,0)"
      std::sscanf(spec.c_str(), "%d|%d@1", &s.start, &s.len);
      s.is_signed = spec.back() == '-';
      s.scale = std::stod(scale.substr(1));
      msgs[current].push_back(s);
    }
  }
  return msgs;
}

std::map<std::string, double> decode_with_dbc(const std::map<uint32_t, std::vector<Signal>>& dbc,
                                              const CanFrame& f) {
  std::map<std::string, double> out;
  const auto& sigs = dbc.at(f.id);
  auto raw = [&](const Signal& s) {
    uint64_t v = 0;
    for (int b = 0; b < s.len; ++b)
      v |= static_cast<uint64_t>((f.data[(s.start + b) / 8] >> ((s.start + b) % 8)) & 1) << b;
    if (s.is_signed && (v >> (s.len - 1)) & 1)
      return static_cast<double>(static_cast<int64_t>(v | (~0ull << s.len)));
    return static_cast<double>(v);
  };
  int mux = -1;
  for (const Signal& s : sigs) {
    if (s.is_mux) mux = static_cast<int>(raw(s));
  }
  for (const Signal& s : sigs) {
    if (s.mux < 0 || s.mux == mux) out[s.name] = raw(s) * s.scale;
  }
  return out;
}

TEST(DbcTest, DecodesGoldenFramesThroughTheFile) {
  const auto dbc = parse_dbc(generate_dbc(FrameKind::kFd, 1, 16));
  ASSERT_EQ(dbc.size(), 16u * 5 + 2);
  CanFrame f;
  ASSERT_EQ(
      parse_frame_text(
          "185##1202A04030201090000000000A0F604F768F7CCF730F894F8F8F85CF9C0F924FA88FAECFA50FBB4FB18"
          "FC7CFCE0FC44FDA8FD0CFE70FED4FE38FF9CFF00006400",
          &f),
      CandumpError::kNone);
  auto v = decode_with_dbc(dbc, f);
  EXPECT_EQ(v["part"], 0);
  EXPECT_EQ(v["seq"], 42);
  EXPECT_EQ(v["version"], 1);
  EXPECT_EQ(v["timestamp"], 0x01020304);
  EXPECT_NEAR(v["s00_x"], -240.0, 1e-9);
  EXPECT_NEAR(v["s08_x"], 0.0, 1e-9);
  EXPECT_EQ(v.count("s15_z"), 0u);  // carried by part 1
  ASSERT_EQ(parse_frame_text("08C#2007034A10000000", &f), CandumpError::kNone);
  v = decode_with_dbc(dbc, f);
  EXPECT_EQ(v["opcode"], 3);
  EXPECT_EQ(v["arg0"], 0x4A);
  // The other tables, field by field, on the golden frames of docs/protocol.md.
  ASSERT_EQ(parse_frame_text("10C##12002010008010000", &f), CandumpError::kNone);
  v = decode_with_dbc(dbc, f);
  EXPECT_EQ(v["opcode"], 1);
  EXPECT_EQ(v["status"], 0);
  EXPECT_EQ(v["command_seq"], 8);
  EXPECT_EQ(v["flags"], 1);
  EXPECT_EQ(v["value"], 0);
  ASSERT_EQ(parse_frame_text("07F#2001785634120201", &f), CandumpError::kNone);
  v = decode_with_dbc(dbc, f);
  EXPECT_EQ(v["host_time_us"], 0x12345678);
  EXPECT_EQ(v["counter"], 0x0102);
  ASSERT_EQ(parse_frame_text(
                "205##12003EFCDAB8967452301010203011003070003024A101027D0076400AD020000", &f),
            CandumpError::kNone);
  v = decode_with_dbc(dbc, f);
  EXPECT_EQ(v["fw_major"], 1);
  EXPECT_EQ(v["fw_patch"], 3);
  EXPECT_EQ(v["protocol_version"], 1);
  EXPECT_EQ(v["sensor_count"], 16);
  EXPECT_EQ(v["axis_count"], 3);
  EXPECT_EQ(v["gain_sel"], 7);
  EXPECT_EQ(v["oversampling"], 3);
  EXPECT_EQ(v["digital_filter"], 2);
  EXPECT_NEAR(v["rate"], 41.70, 1e-9);
  EXPECT_NEAR(v["max_rate"], 100.0, 1e-9);
  EXPECT_EQ(v["conversion_time"], 2000);
  EXPECT_EQ(v["field_lsb"], 100);
  ASSERT_EQ(parse_frame_text("285##"
                             "1200901024A10100E0000EFCDAB89674523010102030502000700010009004E0CA5CB"
                             "0000000000000000000000000000",
                             &f),
            CandumpError::kNone);
  v = decode_with_dbc(dbc, f);
  EXPECT_EQ(v["state"], 1);
  EXPECT_EQ(v["mode"], 2);
  EXPECT_EQ(v["uptime"], 3600);
  EXPECT_EQ(v["status"], 5);
  EXPECT_EQ(v["fault_mask"], 2);
  EXPECT_EQ(v["i2c_errors"], 7);
  EXPECT_EQ(v["can_errors"], 1);
  EXPECT_EQ(v["saturation_count"], 9);
  EXPECT_NEAR(v["temperature"], 31.5, 1e-9);
}

TEST(DbcTest, EverySampleChannelOfEveryPartDecodes) {
  // Random samples, classic and FD: each channel read through the DBC equals the message.
  std::mt19937_64 rng(testing::test_seed("DbcTest.EverySampleChannelOfEveryPartDecodes"));
  for (FrameKind kind : {FrameKind::kFd, FrameKind::kClassic}) {
    const auto dbc = parse_dbc(generate_dbc(kind, 1, 3));
    for (int i = 0; i < 20; ++i) {
      const Message m =
          testing::random_message(rng, MessageClass::kSample, kind, 2, static_cast<uint8_t>(i));
      std::map<std::string, double> all;
      for (const CanFrame& f : testing::encode_frames(m)) {
        for (const auto& [k, x] : decode_with_dbc(dbc, f)) all[k] = x;
      }
      const Sample& s = std::get<Sample>(m.body);
      for (int ch = 0; ch < kChannelCount; ++ch) {
        char name[8];
        std::snprintf(name, sizeof name, "s%02d_%c", ch / 3, "xyz"[ch % 3]);
        ASSERT_EQ(all.count(name), 1u) << name;
        EXPECT_NEAR(all[name], s.field_lsb[ch] * kFieldUtPerLsb, 1e-6) << name;
      }
      EXPECT_EQ(all["timestamp"], s.timestamp_us);
    }
  }
}

TEST(DbcTest, DeclaredLengthsAreTheLongestFrames) {
  std::mt19937_64 rng(5);
  for (FrameKind kind : {FrameKind::kFd, FrameKind::kClassic}) {
    std::map<uint32_t, std::size_t> declared;
    std::istringstream in(generate_dbc(kind, 1, 2));
    std::string line;
    while (std::getline(in, line)) {
      unsigned id = 0, len = 0;
      char name[64];
      if (std::sscanf(line.c_str(), "BO_ %u %63[^:]: %u", &id, name, &len) == 3) declared[id] = len;
    }
    for (int c = 0; c < kMessageClassCount; ++c) {
      const Message m = testing::random_message(rng, static_cast<MessageClass>(c), kind, 2, 0);
      const auto frames = testing::encode_frames(m);
      std::size_t longest = 0;
      for (const CanFrame& f : frames) longest = std::max<std::size_t>(longest, f.len);
      EXPECT_EQ(declared.at(frames[0].id), longest)
          << message_class_name(static_cast<MessageClass>(c));
    }
  }
}

// The DBC files shipped in docs/ are what the generator writes today.
TEST(DbcTest, ShippedFilesAreCurrent) {
  const char* src = std::getenv("SKINBUS_SOURCE_DIR");
  ASSERT_NE(src, nullptr) << "run through ctest (sets SKINBUS_SOURCE_DIR)";
  for (FrameKind kind : {FrameKind::kFd, FrameKind::kClassic}) {
    const std::string path =
        std::string(src) +
        (kind == FrameKind::kFd ? "/docs/dbc/skinbus_fd.dbc" : "/docs/dbc/skinbus_classic.dbc");
    std::ifstream in(path);
    ASSERT_TRUE(in) << "missing " << path << "; regenerate with skinbus-dbc (see docs/protocol.md)";
    std::stringstream ss;
    ss << in.rdbuf();
    EXPECT_EQ(ss.str(), generate_dbc(kind, 1, 16))
        << path << " is stale; regenerate with skinbus-dbc";
  }
}

}  // namespace
}  // namespace skinbus::bus
