#include "skinbus/bus/codec.h"

#include <gtest/gtest.h>

#include <limits>
#include <map>
#include <random>

#include "byte_order.h"
#include "skinbus/bus/candump.h"
#include "testing.h"

namespace skinbus::bus {
namespace {

using testing::encode_frames;
using testing::frames_text;

// Golden frames. Each expected string was computed by an independent encoder written from
// docs/protocol.md (Python struct + binascii.crc_hqx), not by this codec.

Message golden_sample(FrameKind kind) {
  Sample s;
  s.timestamp_us = 0x01020304;
  s.flags = sample_flags::kContact | sample_flags::kTared;
  for (int ch = 0; ch < kChannelCount; ++ch)
    s.field_lsb[ch] = static_cast<int16_t>(ch * 100 - 2400);
  return Message{5, 42, kind, s};
}

Heartbeat golden_heartbeat() {
  Heartbeat h;
  h.state = PatchState::kRunning;
  h.mode = PatchMode::kEvent;
  h.rate_chz = 4170;
  h.uptime_s = 3600;
  h.hardware_uid = 0x0123456789ABCDEF;
  h.fw_major = 1;
  h.fw_minor = 2;
  h.fw_patch = 3;
  h.status = heartbeat_status::kSyncMode | heartbeat_status::kTared;
  h.fault_mask = 0x0002;
  h.i2c_errors = 7;
  h.can_errors = 1;
  h.saturation_count = 9;
  h.temperature_cdeg = 3150;
  return h;
}

Info golden_info() {
  Info i;
  i.hardware_uid = 0x0123456789ABCDEF;
  i.fw_major = 1;
  i.fw_minor = 2;
  i.fw_patch = 3;
  i.gain_sel = 7;
  i.resolution = 0;
  i.oversampling = 3;
  i.digital_filter = 2;
  i.rate_chz = 4170;
  i.max_rate_chz = 10000;
  i.conversion_time_us = 2000;
  return i;
}

TEST(CodecTest, FieldToWireUnitsRoundsClampsAndFlagsClipping) {
  bool clipped = true;
  EXPECT_EQ(field_ut_to_lsb(12.34, &clipped), 123);
  EXPECT_FALSE(clipped);
  EXPECT_EQ(field_ut_to_lsb(-12.36, &clipped), -124);
  EXPECT_FALSE(clipped);
  EXPECT_EQ(field_ut_to_lsb(3276.6, &clipped), 32766);
  EXPECT_FALSE(clipped);
  // Reaching the limit is clipping too: the wire cannot tell 3276.7 uT from more.
  EXPECT_EQ(field_ut_to_lsb(3276.7, &clipped), kFieldMaxLsb);
  EXPECT_TRUE(clipped);
  EXPECT_EQ(field_ut_to_lsb(-5000.0, &clipped), -kFieldMaxLsb);
  EXPECT_TRUE(clipped);
  for (double bad :
       {std::numeric_limits<double>::quiet_NaN(), std::numeric_limits<double>::infinity()}) {
    clipped = false;
    EXPECT_EQ(field_ut_to_lsb(bad, &clipped), 0);
    EXPECT_TRUE(clipped);
  }
  EXPECT_EQ(field_ut_to_lsb(0.04), 0);  // the flag is optional
  // Halfway between two LSBs rounds away from zero; the last half LSB below the limit clips.
  EXPECT_EQ(field_ut_to_lsb(0.25), 3);
  EXPECT_EQ(field_ut_to_lsb(-0.25), -3);
  EXPECT_EQ(field_ut_to_lsb(1.25), 13);
  EXPECT_EQ(field_ut_to_lsb(3276.65, &clipped), kFieldMaxLsb);
  EXPECT_TRUE(clipped);
  EXPECT_EQ(field_ut_to_lsb(-3276.64, &clipped), -32766);
  EXPECT_FALSE(clipped);
}

TEST(CodecTest, CrcCheckValue) {
  const uint8_t check[] = {'1', '2', '3', '4', '5', '6', '7', '8', '9'};
  EXPECT_EQ(crc16_ccitt(check), 0x29B1);  // CRC-16/CCITT-FALSE catalogue check value
}

TEST(CodecTest, GoldenSampleFd) {
  EXPECT_EQ(
      frames_text(encode_frames(golden_sample(FrameKind::kFd))),
      "185##1202A04030201090000000000A0F604F768F7CCF730F894F8F8F85CF9C0F924FA88FAECFA50FBB4FB18"
      "FC7CFCE0FC44FDA8FD0CFE70FED4FE38FF9CFF00006400 "
      "185##1212AC8002C019001F4015802BC0220038403E8034C04B00414057805DC054006A40608076C07D00734"
      "089808FC084232");
}

TEST(CodecTest, GoldenSampleClassic) {
  const auto frames = encode_frames(golden_sample(FrameKind::kClassic));
  ASSERT_EQ(frames.size(), 18u);
  EXPECT_EQ(frames_text({frames[0], frames[1], frames[17]}),
            "185#202A040302010900 185#212A00000000A0F6 185#312A9808FC084232");
}

TEST(CodecTest, GoldenHeartbeat) {
  EXPECT_EQ(frames_text(encode_frames(Message{5, 9, FrameKind::kFd, golden_heartbeat()})),
            "285##1200901024A10100E0000EFCDAB89674523010102030502000700010009004E0CA5CB0000000000"
            "000000000000000000");
  EXPECT_EQ(frames_text(encode_frames(Message{5, 9, FrameKind::kClassic, golden_heartbeat()})),
            "285#200901024A10100E 285#21090000EFCDAB89 285#2209674523010102 285#2309030502000700 "
            "285#2409010009004E0C 285#2509A5CB");
}

TEST(CodecTest, GoldenInfo) {
  EXPECT_EQ(frames_text(encode_frames(Message{5, 3, FrameKind::kFd, golden_info()})),
            "205##12003EFCDAB8967452301010203011003070003024A101027D0076400AD020000");
  EXPECT_EQ(frames_text(encode_frames(Message{5, 3, FrameKind::kClassic, golden_info()})),
            "205#2003EFCDAB896745 205#2103230101020301 205#2203100307000302 205#23034A101027D007 "
            "205#24036400AD02");
}

TEST(CodecTest, GoldenCommandsAcksSync) {
  Command rate{Opcode::kSetRate, {0x4A, 0x10, 0, 0, 0}};
  EXPECT_EQ(frames_text(encode_frames(Message{12, 7, FrameKind::kClassic, rate})),
            "08C#2007034A10000000");
  EXPECT_EQ(frames_text(encode_frames(
                Message{kNodeBroadcast, 8, FrameKind::kFd, Command{Opcode::kTare, {}}})),
            "0FF##12008010000000000");
  EXPECT_EQ(frames_text(encode_frames(
                Message{12, 0, FrameKind::kClassic, Ack{3, AckStatus::kOk, 7, false, 4170}})),
            "10C#2000030007004A10");
  EXPECT_EQ(frames_text(encode_frames(Message{12, 1, FrameKind::kClassic,
                                              Ack{0x42, AckStatus::kUnknownOpcode, 9, false, 0}})),
            "10C#2001420109000000");
  EXPECT_EQ(frames_text(
                encode_frames(Message{12, 2, FrameKind::kFd, Ack{1, AckStatus::kOk, 8, true, 0}})),
            "10C##12002010008010000");
  EXPECT_EQ(frames_text(encode_frames(
                Message{kNodeBroadcast, 1, FrameKind::kClassic, Sync{0x12345678, 0x0102}})),
            "07F#2001785634120201");
}

TEST(CodecTest, PartCountsMatchTheBudget) {
  EXPECT_EQ(part_count(MessageClass::kSample, FrameKind::kFd), 2u);
  EXPECT_EQ(part_count(MessageClass::kSample, FrameKind::kClassic), 18u);
  EXPECT_EQ(part_count(MessageClass::kHeartbeat, FrameKind::kFd), 1u);
  EXPECT_EQ(part_count(MessageClass::kHeartbeat, FrameKind::kClassic), 6u);
  EXPECT_EQ(part_count(MessageClass::kInfo, FrameKind::kClassic), 5u);
  for (int c = 0; c < kMessageClassCount; ++c) {
    for (FrameKind k : {FrameKind::kFd, FrameKind::kClassic}) {
      EXPECT_LE(part_count(static_cast<MessageClass>(c), k), kMaxParts);
    }
  }
}

// The field tables (used for the DBC file and for describing single frames) must describe the
// same bytes the codec writes: every payload covered exactly, and each field read back through
// its table entry equals the struct member it names.
TEST(CodecTest, FieldTablesMatchTheCodec) {
  for (int ci = 0; ci < kMessageClassCount; ++ci) {
    const auto c = static_cast<MessageClass>(ci);
    std::size_t next = 0;
    for (const FieldDesc* f = fields_begin(c); f != fields_end(c); ++f) {
      EXPECT_EQ(f->offset, next) << message_class_name(c) << "." << f->name;
      next = f->offset + field_size(f->type);
    }
    EXPECT_EQ(next, payload_len(c)) << message_class_name(c);
  }

  auto read = [](const uint8_t* p, const FieldDesc& f) -> int64_t {
    switch (f.type) {
      case FieldType::kU8:
        return p[f.offset];
      case FieldType::kU16:
        return internal::get_u16(p + f.offset);
      case FieldType::kI16:
        return internal::get_i16(p + f.offset);
      case FieldType::kU32:
        return internal::get_u32(p + f.offset);
      case FieldType::kU64:
        return static_cast<int64_t>(internal::get_u64(p + f.offset));
    }
    return 0;
  };
  const Heartbeat h = golden_heartbeat();
  std::map<std::string, int64_t> expect = {{"state", 1},
                                           {"mode", 2},
                                           {"rate", 4170},
                                           {"uptime", 3600},
                                           {"hardware_uid", 0x0123456789ABCDEF},
                                           {"fw_major", 1},
                                           {"fw_minor", 2},
                                           {"fw_patch", 3},
                                           {"status", h.status},
                                           {"fault_mask", 2},
                                           {"i2c_errors", 7},
                                           {"can_errors", 1},
                                           {"saturation_count", 9},
                                           {"temperature", 3150}};
  uint8_t buf[kMaxPayloadLen];
  ASSERT_EQ(serialize_payload(h, buf), kHeartbeatPayloadLen);
  for (const FieldDesc* f = fields_begin(MessageClass::kHeartbeat);
       f != fields_end(MessageClass::kHeartbeat); ++f) {
    if (expect.count(f->name)) {
      EXPECT_EQ(read(buf, *f), expect[f->name]) << f->name;
    }
  }
  const Message s = golden_sample(FrameKind::kFd);
  ASSERT_EQ(serialize_payload(s.body, buf), kSamplePayloadLen);
  int ch = 0;
  for (const FieldDesc* f = fields_begin(MessageClass::kSample);
       f != fields_end(MessageClass::kSample); ++f) {
    if (f->name[0] == 's' && f->name[3] == '_') {
      EXPECT_EQ(read(buf, *f), ch * 100 - 2400) << f->name;
      ++ch;
    }
  }
  EXPECT_EQ(ch, kChannelCount);
}

// No 16-bit field straddles a part boundary, so each part's fields decode on their own (the
// DBC file relies on it). 64-bit and 32-bit fields in classic frames are the documented exception.
TEST(CodecTest, SixteenBitFieldsNeverStraddleParts) {
  for (int ci = 0; ci < kMessageClassCount; ++ci) {
    const auto c = static_cast<MessageClass>(ci);
    if (!is_multi_part(c)) continue;
    for (FrameKind k : {FrameKind::kFd, FrameKind::kClassic}) {
      for (const FieldDesc* f = fields_begin(c); f != fields_end(c); ++f) {
        if (field_size(f->type) != 2) continue;
        EXPECT_EQ(f->offset / part_len(k), (f->offset + 1u) / part_len(k)) << f->name;
      }
    }
  }
}

TEST(CodecTest, RandomRoundTrip) {
  std::mt19937_64 rng(testing::test_seed("CodecTest.RandomRoundTrip"));
  for (int i = 0; i < 5000; ++i) {
    const auto c = static_cast<MessageClass>(rng() % kMessageClassCount);
    const FrameKind kind = rng() % 2 ? FrameKind::kFd : FrameKind::kClassic;
    const Message m = testing::random_message(
        rng, c, kind, static_cast<uint8_t>(rng() % kNodeMax + 1), static_cast<uint8_t>(rng()));
    const auto frames = encode_frames(m);
    ASSERT_EQ(frames.size(), part_count(c, kind));
    uint8_t payload[kMaxPayloadLen] = {};
    for (std::size_t p = 0; p < frames.size(); ++p) {
      const CanFrame& f = frames[p];
      EXPECT_EQ(f.fd, kind == FrameKind::kFd);
      EXPECT_TRUE(f.fd ? is_valid_fd_len(f.len) : f.len <= 8);
      FrameView v;
      ASSERT_EQ(parse_frame(f, &v), DecodeError::kNone);
      EXPECT_EQ(v.header.part, p);
      EXPECT_EQ(v.header.seq, m.seq);
      EXPECT_EQ(v.node, m.node);
      std::copy(v.part_data, v.part_data + v.part_len, payload + v.payload_offset);
    }
    Message back{m.node, m.seq, kind, {}};
    ASSERT_EQ(deserialize_payload(c, {payload, payload_len(c)}, &back.body), DecodeError::kNone);
    EXPECT_EQ(back, m);
  }
}

CanFrame frame_of(const char* text) {
  CanFrame f;
  EXPECT_EQ(parse_frame_text(text, &f), CandumpError::kNone) << text;
  return f;
}

TEST(CodecTest, RejectsWithAReason) {
  FrameView v;
  EXPECT_EQ(parse_frame(frame_of("1F334455#2001"), &v), DecodeError::kForeign);  // extended
  EXPECT_EQ(parse_frame(frame_of("10C#R"), &v), DecodeError::kForeign);          // remote
  EXPECT_EQ(parse_frame(frame_of("30C#2007034A10000000"), &v), DecodeError::kUnknownClass);
  EXPECT_EQ(parse_frame(frame_of("08C#4007034A10000000"), &v), DecodeError::kBadVersion);
  EXPECT_EQ(parse_frame(frame_of("08C#0007034A10000000"), &v), DecodeError::kBadVersion);
  EXPECT_EQ(parse_frame(frame_of("080#2007034A10000000"), &v), DecodeError::kBadNode);  // host ID
  EXPECT_EQ(parse_frame(frame_of("00C#2001785634120201"), &v),
            DecodeError::kBadNode);  // SYNC unicast
  EXPECT_EQ(parse_frame(frame_of("08C#2007034A"), &v), DecodeError::kBadLength);
  EXPECT_EQ(parse_frame(frame_of("08C#20"), &v), DecodeError::kBadLength);
  EXPECT_EQ(parse_frame(frame_of("185##1322A00"), &v), DecodeError::kBadPart);  // part 18 of 2
  EXPECT_EQ(parse_frame(frame_of("185#312A9808"), &v),
            DecodeError::kBadLength);  // part 17 carries 6
  EXPECT_EQ(parse_frame(frame_of("185#322A040302010900"), &v),
            DecodeError::kBadPart);  // part 18 of 0..17
  EXPECT_EQ(parse_frame(frame_of("185##1202A0403"), &v),
            DecodeError::kBadLength);  // FD part 0 short

  Message m;
  EXPECT_EQ(decode_single(frame_of("10C#2007030F4A100000"), &m),
            DecodeError::kBadValue);  // ack status 15
  EXPECT_EQ(decode_single(frame_of("10C#2000030007024A10"), &m),
            DecodeError::kBadValue);  // ack flags: only bit 0 is defined
  EXPECT_EQ(decode_single(frame_of("185#202A040302010900"), &m), DecodeError::kBadPart);
  EXPECT_EQ(decode_single(frame_of("08C#2007034A10000000"), &m), DecodeError::kNone);
  EXPECT_EQ(std::get<Command>(m.body).opcode, Opcode::kSetRate);
  EXPECT_EQ(decode_single(frame_of("08C#2007424A10000000"), &m),
            DecodeError::kNone);                                        // unknown opcode
  EXPECT_EQ(static_cast<int>(std::get<Command>(m.body).opcode), 0x42);  // passes to the NACK

  uint8_t bad_hb[kHeartbeatPayloadLen] = {};
  bad_hb[0] = 9;  // no such state
  internal::put_u16(bad_hb + 30, crc16_ccitt({bad_hb, 30}));
  MessageBody body;
  EXPECT_EQ(deserialize_payload(MessageClass::kHeartbeat, bad_hb, &body), DecodeError::kBadValue);
  bad_hb[5] ^= 1;
  EXPECT_EQ(deserialize_payload(MessageClass::kHeartbeat, bad_hb, &body), DecodeError::kBadCrc);
}

TEST(CodecTest, EncodeChecksNodeAndBuffer) {
  CanFrame one[1];
  EXPECT_EQ(encode(golden_sample(FrameKind::kFd), one).error, EncodeError::kBufferTooSmall);
  Message m = golden_sample(FrameKind::kFd);
  m.node = kNodeBroadcast;
  CanFrame two[2];
  EXPECT_EQ(encode(m, two).error, EncodeError::kBadNode);
  EXPECT_EQ(encode(Message{12, 0, FrameKind::kFd, Sync{}}, two).error, EncodeError::kBadNode);
}

}  // namespace
}  // namespace skinbus::bus
