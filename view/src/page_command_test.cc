#include "skinbus/view/page_command.h"

#include <gtest/gtest.h>

#include <nlohmann/json.hpp>

namespace skinbus::view {
namespace {

TEST(PageCommand, ParsesTareAndTheModes) {
  auto tare = parse_page_command(R"({"type":"command","node":3,"command":"tare"})");
  ASSERT_TRUE(tare.ok()) << tare.error().to_string();
  EXPECT_EQ(tare->node, 3);
  EXPECT_EQ(tare->command.opcode, bus::Opcode::kTare);
  EXPECT_EQ(tare->name, "tare");
  auto mode = parse_page_command(R"({"type":"command","node":125,"command":"mode","mode":"off"})");
  ASSERT_TRUE(mode.ok());
  EXPECT_EQ(mode->command.opcode, bus::Opcode::kSetMode);
  EXPECT_EQ(mode->command.arg[0], static_cast<uint8_t>(bus::PatchMode::kOff));
  EXPECT_EQ(mode->name, "mode off");
  const auto j = nlohmann::json::parse(command_result_to_json(&*mode, true, "sent on can0"));
  EXPECT_EQ(j["type"], "command_result");
  EXPECT_EQ(j["ok"], true);
  EXPECT_EQ(j["node"], 125);
  EXPECT_EQ(j["command"], "mode off");
  EXPECT_EQ(nlohmann::json::parse(command_result_to_json(nullptr, false, "x")).count("node"), 0u);
}

TEST(PageCommand, RefusesAnythingElseWithAReason) {
  for (const char* bad :
       {"", "not json", "[]", R"({"type":"hello"})", R"({"type":"command","command":"tare"})",
        R"({"type":"command","node":0,"command":"tare"})",
        R"({"type":"command","node":126,"command":"tare"})",
        R"({"type":"command","node":"3","command":"tare"})",
        R"({"type":"command","node":3,"command":"reboot"})",
        R"({"type":"command","node":3,"command":"mode","mode":"fast"})",
        R"({"type":"command","node":3.5,"command":"tare"})",
        // Found by fuzzing: a key of another type threw instead of failing.
        R"({"type":3,"node":3,"command":"tare"})", R"({"type":"command","node":3,"command":7})",
        R"({"type":"command","node":3,"command":"mode","mode":[]})"}) {
    auto r = parse_page_command(bad);
    ASSERT_FALSE(r.ok()) << bad;
    EXPECT_FALSE(r.error().message.empty());
  }
}

}  // namespace
}  // namespace skinbus::view
