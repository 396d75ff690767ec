#include "skinbus/bus/format.h"

#include <gtest/gtest.h>

#include "skinbus/bus/candump.h"

namespace skinbus::bus {
namespace {

CanFrame frame_of(const char* text) {
  CanFrame f;
  EXPECT_EQ(parse_frame_text(text, &f), CandumpError::kNone) << text;
  return f;
}

TEST(FormatTest, MessagesOnOneLine) {
  Message m{12, 0, FrameKind::kClassic, Ack{3, AckStatus::kOk, 7, false, 4170}};
  EXPECT_EQ(format_message(m), "ack node=12 seq=0 op=set_rate status=ok cmd_seq=7 value=4170");
  m.body = Ack{1, AckStatus::kBusy, 8, true, 2};
  EXPECT_EQ(format_message(m), "ack node=12 seq=0 op=tare status=busy cmd_seq=8 broadcast value=2");
  m.seq = 7;
  m.body = Command{Opcode::kSetRate, {0x4A, 0x10, 0, 0, 0}};
  EXPECT_EQ(format_message(m), "command node=12 seq=7 op=set_rate rate_hz=41.70 arg=4A10000000");
  m.body = Command{static_cast<Opcode>(0x42), {}};
  EXPECT_EQ(format_message(m), "command node=12 seq=7 op=unknown(0x42) arg=0000000000");
  Heartbeat h;
  h.state = PatchState::kDegraded;
  h.mode = PatchMode::kEvent;
  h.rate_chz = 4170;
  h.hardware_uid = 0xABCDEF;
  h.status = heartbeat_status::kTared;
  h.temperature_cdeg = -550;
  m.body = h;
  EXPECT_EQ(format_message(m),
            "heartbeat node=12 seq=7 state=degraded mode=event rate_hz=41.70 uptime_s=0 "
            "uid=0000000000abcdef fw=0.0.0 "
            "status=tared fault=0000 i2c_err=0 can_err=0 sat=0 temp_c=-5.50");
  Sample s;
  s.flags = sample_flags::kContact | sample_flags::kSaturated;
  s.field_lsb[0] = -12345;
  m.body = s;
  const std::string line = format_message(m);
  EXPECT_EQ(line.rfind("sample node=12 seq=7 t_us=0 flags=contact,saturated fault=0000 sat=0000 "
                       "field_ut=-1234.5,0.0,",
                       0),
            0u)
      << line;
}

TEST(FormatTest, DescribesALoneFrame) {
  // Part 2 of 2 of the golden FD sample (codec_test.cc): channels 26..47 and the CRC.
  const std::string d =
      describe_frame(frame_of("185##"
                              "1212AC8002C019001F4015802BC0220038403E8034C04B00414057805DC054006A40"
                              "608076C07D00734089808FC084232"));
  EXPECT_EQ(d.rfind("sample node=5 seq=42 part=2/2 bytes=62..107 s08_z=20 s09_x=30", 0), 0u) << d;
  EXPECT_NE(d.find("s15_z=230"), std::string::npos) << d;
  EXPECT_NE(d.find("crc=12866"), std::string::npos) << d;  // 0x3242
  EXPECT_EQ(describe_frame(frame_of("08C#2007034A10000000")),
            "command node=12 seq=7 op=set_rate rate_hz=41.70 arg=4A10000000");
  EXPECT_EQ(describe_frame(frame_of("08C#4007034A10000000")), "invalid id=08C len=8: bad_version");
}

}  // namespace
}  // namespace skinbus::bus
