#include "skinbus/bus/command.h"

#include <gtest/gtest.h>

#include "skinbus/bus/candump.h"
#include "skinbus/bus/format.h"

namespace skinbus::bus {
namespace {

Command cmd(Opcode op, std::array<uint8_t, 5> arg = {}) {
  return Command{op, arg};
}

TEST(CommandTest, AcceptsWellFormedCommands) {
  const CommandLimits lim;
  EXPECT_EQ(check_command(cmd(Opcode::kTare), lim).status, AckStatus::kOk);
  EXPECT_EQ(check_command(cmd(Opcode::kGetInfo), lim).status, AckStatus::kOk);
  const CommandCheck m = check_command(cmd(Opcode::kSetMode, {2}), lim);
  EXPECT_EQ(m.status, AckStatus::kOk);
  EXPECT_EQ(m.value, 2);
  const CommandCheck r = check_command(cmd(Opcode::kSetRate, {0x4A, 0x10}), lim);
  EXPECT_EQ(r.status, AckStatus::kOk);
  EXPECT_EQ(r.value, 4170);
  EXPECT_EQ(check_command(cmd(Opcode::kSyncMode, {1}), lim).status, AckStatus::kOk);
  EXPECT_EQ(check_command(cmd(Opcode::kIdentify, {5}), lim).value, 5);
  EXPECT_EQ(check_command(cmd(Opcode::kReboot, {0x52, 0x42, 0x4F, 0x54}), lim).status,
            AckStatus::kOk);
}

TEST(CommandTest, RefusesWithAReason) {
  const CommandLimits lim;
  EXPECT_EQ(check_command(cmd(static_cast<Opcode>(0x42)), lim).status, AckStatus::kUnknownOpcode);
  EXPECT_EQ(check_command(cmd(static_cast<Opcode>(0)), lim).status, AckStatus::kUnknownOpcode);
  EXPECT_EQ(check_command(cmd(Opcode::kSetMode, {3}), lim).status, AckStatus::kBadArgument);
  EXPECT_EQ(check_command(cmd(Opcode::kSetRate, {0, 0}), lim).status, AckStatus::kBadArgument);
  EXPECT_EQ(check_command(cmd(Opcode::kSetRate, {0x11, 0x27}), lim).status,
            AckStatus::kBadArgument);  // 100.01 Hz
  EXPECT_EQ(check_command(cmd(Opcode::kSyncMode, {2}), lim).status, AckStatus::kBadArgument);
  EXPECT_EQ(check_command(cmd(Opcode::kIdentify, {200}), lim).status, AckStatus::kBadArgument);
  EXPECT_EQ(check_command(cmd(Opcode::kReboot, {1, 2, 3, 4}), lim).status,
            AckStatus::kNotPermitted);
  // Unused argument bytes must be zero: the detail names the first offending byte.
  const CommandCheck junk = check_command(cmd(Opcode::kTare, {0, 0, 7}), lim);
  EXPECT_EQ(junk.status, AckStatus::kBadArgument);
  EXPECT_EQ(junk.value, 3);
  EXPECT_EQ(check_command(cmd(Opcode::kSetMode, {1, 9}), lim).value, 2);
}

Message answer(const char* text, uint8_t node = 12) {
  CanFrame f;
  EXPECT_EQ(parse_frame_text(text, &f), CandumpError::kNone);
  Message ack;
  Command accepted;
  EXPECT_TRUE(answer_command_frame(f, node, 4, CommandLimits{}, &ack, &accepted)) << text;
  return ack;
}

TEST(CommandTest, EveryCommandFrameGetsOneAnswer) {
  EXPECT_EQ(format_message(answer("08C#2007034A10000000")),
            "ack node=12 seq=4 op=set_rate status=ok cmd_seq=7 value=4170");
  EXPECT_EQ(format_message(answer("0FF##12008010000000000")),
            "ack node=12 seq=4 op=tare status=ok cmd_seq=8 broadcast value=0");
  EXPECT_EQ(format_message(answer("08C#2009420000000000")),
            "ack node=12 seq=4 op=unknown(0x42) status=unknown_opcode cmd_seq=9 value=0");
  EXPECT_EQ(format_message(answer("08C#20090302")),
            "ack node=12 seq=4 op=set_rate status=bad_length cmd_seq=9 value=4");
  EXPECT_EQ(format_message(answer("08C#4009034A10000000")),
            "ack node=12 seq=4 op=set_rate status=version_mismatch cmd_seq=9 value=1");
  EXPECT_EQ(format_message(answer("08C#")),
            "ack node=12 seq=4 op=unknown(0x00) status=bad_length cmd_seq=0 value=0");
  // Not for this node, or not a command: no answer.
  CanFrame f;
  Message ack;
  ASSERT_EQ(parse_frame_text("08D#2007034A10000000", &f), CandumpError::kNone);
  EXPECT_FALSE(answer_command_frame(f, 12, 0, CommandLimits{}, &ack, nullptr));
  ASSERT_EQ(parse_frame_text("10C#2000030007004A10", &f), CandumpError::kNone);
  EXPECT_FALSE(answer_command_frame(f, 12, 0, CommandLimits{}, &ack, nullptr));
}

}  // namespace
}  // namespace skinbus::bus
