// skinbus/host/contacts_json.h: the aggregator's outputs as JSON lines (one object a line), the
// quick second output of skinbus-host (`--json`) and the format skinbus-listen prints.
//
//   {"type":"contacts","stamp_us":...,"base_frame":"base_link","contacts":[{"track_id":1,
//    "position_mm":[x,y,z],"normal":[x,y,z],"depth_mm":..,"force_n":..,"node":3,
//    "hardware_uid":"5eed000000000003","link":"r_forearm","u_mm":..,"v_mm":..,
//    "uncertainty_mm":..,"patch_count":1,"flags":["stale_kinematics",...]}]}
//   {"type":"patch_status","stamp_us":...,"patches":[...],"events":[...]}
//   {"type":"diagnostics","stamp_us":...,"status":[{"level":"WARN","name":"skinbus patch 3",
//    "message":"...","hardware_id":"5eed000000000003","values":{"state":"degraded",...}}]}
//
// Units as in contacts.h (millimetres, microseconds); UIDs as 16 hex digits. docs/aggregator.md
// lists every key.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "skinbus/host/contacts.h"
#include "skinbus/host/diagnostics.h"

namespace skinbus::host {

// The names of the set bits of BodyContact::flags ("stale_kinematics", "merged", ...).
std::vector<std::string> contact_flag_names(uint32_t flags);

std::string contacts_to_json(const ContactArray& a);          // one line, no newline
std::string patch_status_to_json(const PatchStatusArray& s);  // one line, no newline
std::string diagnostics_to_json(const DiagnosticArray& d);    // one line, no newline

}  // namespace skinbus::host
