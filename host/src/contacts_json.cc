// JSON lines of the aggregator's outputs (contacts_json.h).
#include "skinbus/host/contacts_json.h"

#include <cinttypes>
#include <cstdio>
#include <nlohmann/json.hpp>

namespace skinbus::host {

namespace {

using Json = nlohmann::ordered_json;

}  // namespace

std::vector<std::string> contact_flag_names(uint32_t flags) {
  static const struct {
    uint32_t bit;
    const char* name;
  } kNames[] = {
      {kContactStaleKinematics, "stale_kinematics"},
      {kContactNoKinematics, "no_kinematics"},
      {kContactMerged, "merged"},
      {kContactOutsidePatch, "outside_patch"},
      {kContactDepthRange, "depth_range"},
      {kContactMaskedChannels, "masked_channels"},
      {kContactAmbientLarge, "ambient_large"},
      {kContactUnmapped, "unmapped"},
      {kContactUnrefined, "unrefined"},
      {kContactShear, "shear"},
      {kContactExtrapolated, "extrapolated"},
  };
  std::vector<std::string> out;
  for (const auto& n : kNames) {
    if (flags & n.bit) out.emplace_back(n.name);
  }
  return out;
}

std::string contacts_to_json(const ContactArray& a) {
  Json j;
  j["type"] = "contacts";
  j["stamp_us"] = a.stamp_us;
  j["base_frame"] = a.base_frame;
  Json list = Json::array();
  for (const BodyContact& c : a.contacts) {
    Json o;
    o["track_id"] = c.track_id;
    o["position_mm"] = {c.position_mm[0], c.position_mm[1], c.position_mm[2]};
    o["normal"] = {c.normal[0], c.normal[1], c.normal[2]};
    o["depth_mm"] = c.depth_mm;
    o["force_n"] = c.force_n;
    o["node"] = c.node;
    o["hardware_uid"] = format_uid(c.hardware_uid);
    o["link"] = c.link;
    o["u_mm"] = c.u_mm;
    o["v_mm"] = c.v_mm;
    o["uncertainty_mm"] = c.uncertainty_mm;
    o["patch_count"] = c.patch_count;
    o["first_seen_us"] = c.first_seen_us;
    o["flags"] = contact_flag_names(c.flags);
    o["shear_n"] = {c.shear_n[0], c.shear_n[1], c.shear_n[2]};
    o["shear_uncertainty_n"] = c.shear_uncertainty_n;
    list.push_back(std::move(o));
  }
  j["contacts"] = std::move(list);
  return j.dump(-1, ' ', false, Json::error_handler_t::replace);
}

std::string patch_status_to_json(const PatchStatusArray& s) {
  Json j;
  j["type"] = "patch_status";
  j["stamp_us"] = s.stamp_us;
  Json patches = Json::array();
  for (const PatchStatus& p : s.patches) {
    Json o;
    o["node"] = p.node;
    o["hardware_uid"] = format_uid(p.hardware_uid);
    o["interface"] = p.interface;
    o["link"] = p.link;
    o["state"] = std::string(patch_link_state_name(p.state));
    o["node_state"] = p.node_state;
    o["node_mode"] = p.node_mode;
    o["fault_mask"] = p.fault_mask;
    o["uptime_s"] = p.uptime_s;
    o["reboots"] = p.reboots;
    o["samples"] = p.samples;
    o["samples_lost"] = p.samples_lost;
    o["contacts"] = p.contacts;
    o["clock_offset_us"] = p.clock_offset_us;
    o["clock_drift_ppm"] = p.clock_drift_ppm;
    o["last_heard_us"] = p.last_heard_us;
    o["duplicate_id"] = p.duplicate_id;
    o["detail"] = p.detail;
    patches.push_back(std::move(o));
  }
  j["patches"] = std::move(patches);
  Json events = Json::array();
  for (const PatchEvent& e : s.events) {
    events.push_back({{"time_us", e.time_us},
                      {"event", std::string(patch_event_name(e.kind))},
                      {"node", e.node},
                      {"hardware_uid", format_uid(e.hardware_uid)},
                      {"detail", e.detail}});
  }
  j["events"] = std::move(events);
  return j.dump(-1, ' ', false, Json::error_handler_t::replace);
}

std::string diagnostics_to_json(const DiagnosticArray& d) {
  Json j;
  j["type"] = "diagnostics";
  j["stamp_us"] = d.stamp_us;
  Json status = Json::array();
  for (const PatchDiagnostic& p : d.status) {
    Json values = Json::object();
    for (const DiagnosticValue& v : p.values) values[v.key] = v.value;
    status.push_back({{"level", std::string(diagnostic_level_name(p.level))},
                      {"name", p.name},
                      {"message", p.message},
                      {"hardware_id", p.hardware_id},
                      {"values", std::move(values)}});
  }
  j["status"] = std::move(status);
  return j.dump();
}

}  // namespace skinbus::host
