// skinbus/host/contacts.h: what the host aggregator publishes, as plain C++ values.
//
// The aggregator (aggregator.h) fills these; the outputs turn them into their own encodings:
// JSON lines (contacts_json.h) and the DDS topics `rt/skin/contacts` and `rt/skin/patch_status`
// (dds.h, types in dds/msg/). Lengths here are millimetres and times microseconds as in the
// rest of skinbus; the DDS layer converts to the SI units of ROS 2 messages (metres, seconds).
// Every number is finite: the aggregator never emits a NaN or an Inf.
#pragma once

#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

#include "skinbus/common/uid.h"

namespace skinbus::host {

// Bits of BodyContact::flags.
enum BodyContactFlag : uint32_t {
  kContactOk = 0,
  // The joint states do not cover the sample's time (they stopped, or began after it, more than
  // the extrapolation allowance before or after it): the nearest known pose was used.
  kContactStaleKinematics = 1u << 0,
  kContactNoKinematics = 1u << 1,    // no joint state yet: the robot's zero pose was used
  kContactMerged = 1u << 2,          // several patches saw this press (merged into one)
  kContactOutsidePatch = 1u << 3,    // the estimate lies beyond the patch edge (kept, flagged)
  kContactDepthRange = 1u << 4,      // depth beyond what the model knows (kept, flagged)
  kContactMaskedChannels = 1u << 5,  // some sensors were left out (dead or saturated)
  kContactAmbientLarge = 1u << 6,    // the common-mode field removed was large (> limit)
  kContactUnmapped = 1u << 7,        // the patch has no skin-map entry: position is patch-frame
  // The patch has a physics refinement but this contact is the network's answer: the period's
  // refinement budget was spent, or the fit was poor (docs/aggregator.md).
  kContactUnrefined = 1u << 8,
  // The contact's shear force was estimated (a refinement with the skin map's refine_shear):
  // shear_n and shear_uncertainty_n hold it. Without it both are 0.
  kContactShear = 1u << 9,
  // The refined contact lies outside the area its unit was pressed on for calibration (the unit
  // file's pressed_area_mm): its place and uncertainty come from a model extrapolated there.
  kContactExtrapolated = 1u << 10,
};

// One contact in the robot's base frame.
struct BodyContact {
  double position_mm[3] = {0, 0, 0};  // on the skin surface, base frame
  double normal[3] = {0, 0, 1};       // unit, outward, base frame
  double depth_mm = 0;                // indentation into the skin
  double force_n = 0;                 // normal force
  double u_mm = 0, v_mm = 0;          // patch-local coordinates (of the strongest patch)
  double uncertainty_mm = 0;          // 1-sigma position uncertainty (model error at this depth)
  uint8_t node = 0;                   // CAN node of the strongest patch
  uint64_t hardware_uid = 0;          // its hardware UID
  std::string link;                   // the link the patch sits on
  uint32_t track_id = 0;              // stable while the press lasts; never 0 for a contact
  uint32_t patch_count = 1;           // patches that saw it
  uint32_t flags = kContactOk;        // BodyContactFlag
  uint64_t first_seen_us = 0;         // host time the track started
  double shear_n[3] = {0, 0, 0};      // tangential force on the skin, base frame (kContactShear)
  double shear_uncertainty_n = 0;     // its 1-sigma: sqrt(var of both components), N
};

// The force the contact applies to the skin, N, base frame: its normal force into the skin
// (-force_n along the outward normal) plus its shear; and the torque of that force about the
// base frame's origin, N m (position in metres x force): the contact as a wrench on the body.
void contact_wrench(const BodyContact& c, double force_n[3], double torque_nm[3]);

// One publication: every contact of one period.
struct ContactArray {
  uint64_t stamp_us = 0;  // host time (CLOCK_REALTIME, us) the samples were taken, aligned
  std::string base_frame = "base_link";
  std::vector<BodyContact> contacts;
};

// Registry states of a patch (see patch_registry.h).
enum class PatchLinkState : uint8_t {
  kDiscovering = 0,  // seen, but not yet a heartbeat (or not yet identified)
  kOnline = 1,       // heartbeats and samples as expected
  kDegraded = 2,     // online with a problem: sensor faults, node-reported degraded state, no
                     // model or no skin-map entry, a clashing node ID
  kStale = 3,        // nothing heard for longer than the stale limit
  kOffline = 4,      // nothing heard for longer than the offline limit
};
std::string_view patch_link_state_name(PatchLinkState s);

// Events the registry reports once each (also counted in PatchStatus).
enum class PatchEventKind : uint8_t {
  kDiscovered,       // a new node ID (with its UID) was heard
  kOnline,           // state became online
  kDegraded,         // state became degraded (detail says why)
  kStale,            // went quiet
  kOffline,          // gone
  kReturned,         // heard again after stale or offline
  kRebooted,         // its uptime went backwards
  kDuplicateId,      // two hardware UIDs send with the same node ID
  kUnknownPatch,     // no skin-map entry for this UID (or this node)
  kNoModel,          // the skin map names no usable model
  kSequenceGap,      // samples lost (detail: how many)
  kBadFrames,        // frames rejected (detail: how many since the last report)
  kInterfaceDown,    // a CAN interface reported an error or went down
  kInterfaceUp,      // it came back
  kKinematicsStale,  // joint states stopped
  kKinematicsFresh,  // joint states resumed
  kHostLagging,      // the host fell behind: late samples are superseded (detail: the bound)
  kHostCaughtUp,     // it caught up (detail: how many were superseded, the oldest)
  kLogTime,          // a replayed log's time went backwards or jumped (detail: where, how far)
};
std::string_view patch_event_name(PatchEventKind k);

// A hardware UID as 16 lower-case hex digits (skinbus/common/uid.h).
using skinbus::format_uid;

struct PatchEvent {
  uint64_t time_us = 0;
  PatchEventKind kind = PatchEventKind::kDiscovered;
  uint8_t node = 0;  // 0 for events of the host (interfaces, kinematics)
  uint64_t hardware_uid = 0;
  std::string detail;  // human-readable
};

// The state of one patch, as published on rt/skin/patch_status.
struct PatchStatus {
  uint8_t node = 0;
  uint64_t hardware_uid = 0;
  std::string interface;  // the CAN interface (or log) it was heard on
  std::string link;       // from the skin map ("" when unmapped)
  PatchLinkState state = PatchLinkState::kDiscovering;
  uint8_t node_state = 0;  // bus::PatchState the node reports
  uint8_t node_mode = 0;   // bus::PatchMode
  uint16_t fault_mask = 0;
  uint32_t uptime_s = 0;
  uint32_t reboots = 0;
  uint64_t samples = 0;        // samples received
  uint64_t samples_lost = 0;   // sequence gaps
  uint64_t contacts = 0;       // samples that gave a contact
  double clock_offset_us = 0;  // host time - patch time at the last sample
  double clock_drift_ppm = 0;  // patch clock rate error (positive: patch runs slow)
  uint64_t last_heard_us = 0;  // host time
  bool duplicate_id = false;   // another UID uses this node ID
  std::string detail;          // why degraded, if it is
};

// Everything published on rt/skin/patch_status at once.
struct PatchStatusArray {
  uint64_t stamp_us = 0;
  std::vector<PatchStatus> patches;
  std::vector<PatchEvent> events;  // events since the previous publication
};

}  // namespace skinbus::host
