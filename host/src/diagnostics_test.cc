#include "skinbus/host/diagnostics.h"

#include <gtest/gtest.h>

#include <cmath>
#include <string>

namespace skinbus::host {
namespace {

PatchStatus online() {
  PatchStatus s;
  s.node = 3;
  s.hardware_uid = 0x5B00000000000003ull;
  s.interface = "can0";
  s.link = "left_forearm";
  s.state = PatchLinkState::kOnline;
  s.samples = 1000;
  s.clock_drift_ppm = 12;
  return s;
}

std::string value(const PatchDiagnostic& d, const std::string& key) {
  for (const DiagnosticValue& v : d.values) {
    if (v.key == key) return v.value;
  }
  return "(missing)";
}

TEST(Diagnostics, AHealthyPatchIsOkWithItsNameAndUid) {
  const PatchDiagnostic d = diagnose(online());
  EXPECT_EQ(d.level, DiagnosticLevel::kOk);
  EXPECT_EQ(d.message, "ok");
  EXPECT_EQ(d.name, "skinbus patch 3 (left_forearm)");
  EXPECT_EQ(d.hardware_id, "5b00000000000003");
  EXPECT_EQ(value(d, "state"), "online");
  EXPECT_EQ(value(d, "dead_sensors"), "none");
  EXPECT_EQ(value(d, "samples"), "1000");
  EXPECT_EQ(value(d, "interface"), "can0");
}

TEST(Diagnostics, EachStateHasItsLevel) {
  const struct {
    PatchLinkState state;
    DiagnosticLevel level;
  } cases[] = {{PatchLinkState::kDiscovering, DiagnosticLevel::kWarn},
               {PatchLinkState::kOnline, DiagnosticLevel::kOk},
               {PatchLinkState::kDegraded, DiagnosticLevel::kWarn},
               {PatchLinkState::kStale, DiagnosticLevel::kStale},
               {PatchLinkState::kOffline, DiagnosticLevel::kError}};
  for (const auto& c : cases) {
    PatchStatus s = online();
    s.state = c.state;
    EXPECT_EQ(diagnose(s).level, c.level) << patch_link_state_name(c.state);
  }
}

TEST(Diagnostics, DeadSensorsAreListedAndManyAreAnError) {
  PatchStatus s = online();
  s.state = PatchLinkState::kDegraded;
  s.detail = "sensor faults";
  s.fault_mask = 0b0010'0000'0000'0001;  // sensors 0 and 13
  PatchDiagnostic d = diagnose(s);
  EXPECT_EQ(d.level, DiagnosticLevel::kWarn);
  EXPECT_EQ(value(d, "dead_sensors"), "0,13");
  EXPECT_NE(d.message.find("2 of 16 sensors dead (0,13)"), std::string::npos) << d.message;
  EXPECT_NE(d.message.find("degraded: sensor faults"), std::string::npos) << d.message;
  s.fault_mask = 0x00FF;  // 8 of 16
  d = diagnose(s);
  EXPECT_EQ(d.level, DiagnosticLevel::kError);
  EXPECT_NE(d.message.find("8 of 16 sensors dead"), std::string::npos) << d.message;
}

TEST(Diagnostics, ClockDriftBeyondTheLimitOrNotANumberWarns) {
  PatchStatus s = online();
  s.clock_drift_ppm = kClockDriftWarnPpm;  // at the limit: fine
  EXPECT_EQ(diagnose(s).level, DiagnosticLevel::kOk);
  s.clock_drift_ppm = -350;
  PatchDiagnostic d = diagnose(s);
  EXPECT_EQ(d.level, DiagnosticLevel::kWarn);
  EXPECT_NE(d.message.find("clock drift -350 ppm"), std::string::npos) << d.message;
  EXPECT_EQ(value(d, "clock_drift_ppm"), "-350.0");
  s.clock_drift_ppm = NAN;
  EXPECT_EQ(diagnose(s).level, DiagnosticLevel::kWarn);
}

TEST(Diagnostics, TheMostSevereReasonSetsTheLevelAndEveryReasonIsNamed) {
  PatchStatus s = online();
  s.state = PatchLinkState::kStale;
  s.duplicate_id = true;
  s.clock_drift_ppm = 900;
  const PatchDiagnostic d = diagnose(s);
  EXPECT_EQ(d.level, DiagnosticLevel::kError);
  EXPECT_NE(d.message.find("stale"), std::string::npos);
  EXPECT_NE(d.message.find("node ID also used by another patch"), std::string::npos);
  EXPECT_NE(d.message.find("clock drift 900 ppm"), std::string::npos);
  EXPECT_EQ(value(d, "duplicate_id"), "true");
}

TEST(Diagnostics, AnArrayKeepsItsStampAndPatchOrder) {
  PatchStatusArray a;
  a.stamp_us = 1'700'000'000'000'000ull;
  a.patches = {online(), online()};
  a.patches[1].node = 7;
  a.patches[1].link.clear();
  a.events.push_back({});
  const DiagnosticArray d = diagnose(a);
  EXPECT_EQ(d.stamp_us, a.stamp_us);
  ASSERT_EQ(d.status.size(), 2u);
  EXPECT_EQ(d.status[1].name, "skinbus patch 7");
  EXPECT_EQ(diagnostic_level_name(DiagnosticLevel::kStale), "STALE");
}

}  // namespace
}  // namespace skinbus::host
