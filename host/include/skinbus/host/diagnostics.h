// skinbus/host/diagnostics.h: each patch's health as ROS diagnostics show it
// (diagnostic_msgs/DiagnosticStatus: a level, a name, a message, a hardware id and key-value
// details), derived from the registry's PatchStatus. The DDS layer publishes it on
// rt/diagnostics beside rt/skin/patch_status (docs/dds.md lists the levels and keys). Pure
// functions: no state, no allocation beyond the strings returned.
#pragma once

#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

#include "skinbus/host/contacts.h"

namespace skinbus::host {

// diagnostic_msgs/DiagnosticStatus's levels, with their values on the wire.
enum class DiagnosticLevel : uint8_t { kOk = 0, kWarn = 1, kError = 2, kStale = 3 };
std::string_view diagnostic_level_name(DiagnosticLevel level);  // "OK", "WARN", "ERROR", "STALE"

// A patch clock running off by more than this is reported (WARN): a crystal is within
// +-100 ppm; beyond it the node's clock or the host's alignment is suspect.
inline constexpr double kClockDriftWarnPpm = 200;
// This many dead sensors (of 16) or more is an ERROR: the patch no longer covers its area.
inline constexpr int kDeadSensorsError = 8;

struct DiagnosticValue {
  std::string key, value;
};

struct PatchDiagnostic {
  DiagnosticLevel level = DiagnosticLevel::kOk;
  std::string name;         // "skinbus patch 3 (left_forearm)"
  std::string message;      // "ok", or every reason, "; "-separated
  std::string hardware_id;  // the UID, 16 hex digits
  // state, node, link, interface, dead_sensors ("none" or "0,5"), samples, samples_lost,
  // contacts, reboots, uptime_s, clock_offset_ms, clock_drift_ppm, duplicate_id, detail.
  std::vector<DiagnosticValue> values;
};

struct DiagnosticArray {
  uint64_t stamp_us = 0;  // as the PatchStatusArray's
  std::vector<PatchDiagnostic> status;
};

// The health of one patch. Level: STALE when stale; ERROR when offline, when its node ID is
// used by another patch, or with kDeadSensorsError dead sensors or more; WARN when discovering,
// degraded, with any dead sensor, or with its clock off by more than kClockDriftWarnPpm (also
// when the drift is not a finite number); OK otherwise. The most severe reason sets the level
// (ERROR > STALE > WARN > OK); the message names every reason.
PatchDiagnostic diagnose(const PatchStatus& status);

// Every patch of `status`, in its order (its events are not diagnostics: they stay on
// rt/skin/patch_status).
DiagnosticArray diagnose(const PatchStatusArray& status);

}  // namespace skinbus::host
