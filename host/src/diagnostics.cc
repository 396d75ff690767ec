// Patch health as ROS diagnostics (diagnostics.h).
#include "skinbus/host/diagnostics.h"

#include <bit>
#include <cmath>
#include <cstdio>

namespace skinbus::host {
namespace {

int severity(DiagnosticLevel l) {
  switch (l) {
    case DiagnosticLevel::kOk:
      return 0;
    case DiagnosticLevel::kWarn:
      return 1;
    case DiagnosticLevel::kStale:
      return 2;
    case DiagnosticLevel::kError:
      return 3;
  }
  return 3;
}

std::string number(double x, const char* format) {
  char buf[64];
  std::snprintf(buf, sizeof buf, format, x);
  return buf;
}

}  // namespace

std::string_view diagnostic_level_name(DiagnosticLevel level) {
  switch (level) {
    case DiagnosticLevel::kOk:
      return "OK";
    case DiagnosticLevel::kWarn:
      return "WARN";
    case DiagnosticLevel::kError:
      return "ERROR";
    case DiagnosticLevel::kStale:
      return "STALE";
  }
  return "ERROR";
}

PatchDiagnostic diagnose(const PatchStatus& s) {
  PatchDiagnostic d;
  d.name = "skinbus patch " + std::to_string(s.node);
  if (!s.link.empty()) d.name += " (" + s.link + ")";
  d.hardware_id = format_uid(s.hardware_uid);
  auto raise = [&d](DiagnosticLevel l, const std::string& reason) {
    if (severity(l) > severity(d.level)) d.level = l;
    d.message += (d.message.empty() ? "" : "; ") + reason;
  };
  switch (s.state) {
    case PatchLinkState::kDiscovering:
      raise(DiagnosticLevel::kWarn, "discovering");
      break;
    case PatchLinkState::kOnline:
      break;
    case PatchLinkState::kDegraded:
      raise(DiagnosticLevel::kWarn,
            "degraded" + (s.detail.empty() ? std::string() : ": " + s.detail));
      break;
    case PatchLinkState::kStale:
      raise(DiagnosticLevel::kStale, "stale: nothing heard recently");
      break;
    case PatchLinkState::kOffline:
      raise(DiagnosticLevel::kError, "offline: nothing heard for longer than the offline limit");
      break;
  }
  if (s.duplicate_id) raise(DiagnosticLevel::kError, "node ID also used by another patch");
  const int dead = std::popcount(static_cast<unsigned>(s.fault_mask));
  std::string dead_list;
  for (int i = 0; i < 16; ++i) {
    if (s.fault_mask & (1u << i)) dead_list += (dead_list.empty() ? "" : ",") + std::to_string(i);
  }
  if (dead > 0) {
    raise(dead >= kDeadSensorsError ? DiagnosticLevel::kError : DiagnosticLevel::kWarn,
          std::to_string(dead) + " of 16 sensors dead (" + dead_list + ")");
  }
  if (!std::isfinite(s.clock_drift_ppm) || std::fabs(s.clock_drift_ppm) > kClockDriftWarnPpm) {
    raise(DiagnosticLevel::kWarn, "clock drift " + number(s.clock_drift_ppm, "%.0f") + " ppm");
  }
  if (d.message.empty()) d.message = "ok";
  d.values = {
      {"state", std::string(patch_link_state_name(s.state))},
      {"node", std::to_string(s.node)},
      {"link", s.link},
      {"interface", s.interface},
      {"dead_sensors", dead_list.empty() ? "none" : dead_list},
      {"samples", std::to_string(s.samples)},
      {"samples_lost", std::to_string(s.samples_lost)},
      {"contacts", std::to_string(s.contacts)},
      {"reboots", std::to_string(s.reboots)},
      {"uptime_s", std::to_string(s.uptime_s)},
      {"clock_offset_ms", number(s.clock_offset_us / 1000, "%.3f")},
      {"clock_drift_ppm", number(s.clock_drift_ppm, "%.1f")},
      {"duplicate_id", s.duplicate_id ? "true" : "false"},
      {"detail", s.detail},
  };
  return d;
}

DiagnosticArray diagnose(const PatchStatusArray& status) {
  DiagnosticArray out;
  out.stamp_us = status.stamp_us;
  out.status.reserve(status.patches.size());
  for (const PatchStatus& p : status.patches) out.status.push_back(diagnose(p));
  return out;
}

}  // namespace skinbus::host
