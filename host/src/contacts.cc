// Names of the aggregator's states and events, and a contact's wrench (contacts.h).
#include "skinbus/host/contacts.h"

namespace skinbus::host {

void contact_wrench(const BodyContact& c, double force_n[3], double torque_nm[3]) {
  for (int k = 0; k < 3; ++k) force_n[k] = -c.force_n * c.normal[k] + c.shear_n[k];
  const double r[3] = {c.position_mm[0] * 1e-3, c.position_mm[1] * 1e-3, c.position_mm[2] * 1e-3};
  torque_nm[0] = r[1] * force_n[2] - r[2] * force_n[1];
  torque_nm[1] = r[2] * force_n[0] - r[0] * force_n[2];
  torque_nm[2] = r[0] * force_n[1] - r[1] * force_n[0];
}

std::string_view patch_link_state_name(PatchLinkState s) {
  switch (s) {
    case PatchLinkState::kDiscovering:
      return "discovering";
    case PatchLinkState::kOnline:
      return "online";
    case PatchLinkState::kDegraded:
      return "degraded";
    case PatchLinkState::kStale:
      return "stale";
    case PatchLinkState::kOffline:
      return "offline";
  }
  return "unknown";
}

std::string_view patch_event_name(PatchEventKind k) {
  switch (k) {
    case PatchEventKind::kDiscovered:
      return "discovered";
    case PatchEventKind::kOnline:
      return "online";
    case PatchEventKind::kDegraded:
      return "degraded";
    case PatchEventKind::kStale:
      return "stale";
    case PatchEventKind::kOffline:
      return "offline";
    case PatchEventKind::kReturned:
      return "returned";
    case PatchEventKind::kRebooted:
      return "rebooted";
    case PatchEventKind::kDuplicateId:
      return "duplicate_id";
    case PatchEventKind::kUnknownPatch:
      return "unknown_patch";
    case PatchEventKind::kNoModel:
      return "no_model";
    case PatchEventKind::kSequenceGap:
      return "sequence_gap";
    case PatchEventKind::kBadFrames:
      return "bad_frames";
    case PatchEventKind::kInterfaceDown:
      return "interface_down";
    case PatchEventKind::kInterfaceUp:
      return "interface_up";
    case PatchEventKind::kKinematicsStale:
      return "kinematics_stale";
    case PatchEventKind::kKinematicsFresh:
      return "kinematics_fresh";
    case PatchEventKind::kHostLagging:
      return "host_lagging";
    case PatchEventKind::kHostCaughtUp:
      return "host_caught_up";
    case PatchEventKind::kLogTime:
      return "log_time";
  }
  return "unknown";
}

}  // namespace skinbus::host
