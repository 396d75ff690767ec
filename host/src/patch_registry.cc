// The host's patch registry (patch_registry.h).
#include "skinbus/host/patch_registry.h"

#include <algorithm>
#include <cinttypes>
#include <cstdio>

namespace skinbus::host {

namespace {

// Time from `then` to `now`, 0 if the clock went back (a host clock step never looks like a
// long silence, nor a negative one).
uint64_t elapsed_us(uint64_t now, uint64_t then) {
  return now > then ? now - then : 0;
}

}  // namespace

PatchRegistry::PatchRegistry(const body_map::SkinMap* map, std::vector<std::string> bus_names,
                             RegistryOptions options)
    : map_(map), bus_names_(std::move(bus_names)), options_(options) {
  if (bus_names_.empty()) bus_names_.push_back("can0");
  if (bus_names_.size() > static_cast<std::size_t>(kMaxBuses)) bus_names_.resize(kMaxBuses);
  table_.resize(bus_names_.size() * 128);
  for (std::size_t i = 0; i < table_.size(); ++i) {
    table_[i].bus = static_cast<int>(i / 128);
    table_[i].node = static_cast<uint8_t>(i % 128);
  }
  if (map_ != nullptr) {
    for (std::size_t i = 0; i < map_->patches.size(); ++i)
      by_uid_[map_->patches[i].hardware_uid] = i;
    model_of_placement_.assign(map_->patches.size(), -1);
  }
  events_.reserve(256);
}

void PatchRegistry::set_models(const std::vector<int>& model_of_placement) {
  model_of_placement_ = model_of_placement;
  if (map_ != nullptr) model_of_placement_.resize(map_->patches.size(), -1);
}

void PatchRegistry::emit(PatchEventKind kind, const PatchEntry& e, uint64_t now_us,
                         std::string detail) {
  add_event(kind, now_us, std::move(detail), e.bus, e.node);
}

void PatchRegistry::add_event(PatchEventKind kind, uint64_t now_us, std::string detail, int bus,
                              uint8_t node) {
  if (events_.size() >= options_.max_events) {
    ++events_dropped_;
    return;
  }
  std::string text = bus >= 0 && bus < bus_count()
                         ? bus_names_[static_cast<std::size_t>(bus)] + ": " + detail
                         : std::move(detail);
  uint64_t uid = 0;
  if (bus >= 0 && bus < bus_count()) uid = entry(bus, node).hardware_uid;
  events_.push_back({now_us, kind, node, uid, std::move(text)});
}

void PatchRegistry::take_events(std::vector<PatchEvent>* out) {
  out->insert(out->end(), std::make_move_iterator(events_.begin()),
              std::make_move_iterator(events_.end()));
  events_.clear();
}

PatchEntry& PatchRegistry::touch(int bus, uint8_t node, uint64_t now_us) {
  PatchEntry& e = table_[index(bus, node)];
  if (!e.heard) {
    e.heard = true;
    e.state = PatchLinkState::kDiscovering;
    heard_.push_back(index(bus, node));
    // Provisional placement by node ID until a heartbeat names the UID.
    if (map_ != nullptr) {
      const body_map::PatchPlacement* p = map_->find_node(node);
      if (p != nullptr) {
        e.placement = p;
        e.model_index = model_of_placement_[static_cast<std::size_t>(p - map_->patches.data())];
      }
    }
    char buf[96];
    std::snprintf(buf, sizeof buf, "node %u heard%s", node,
                  e.placement != nullptr ? " (placed by its node ID until its first heartbeat)"
                                         : " (no skin-map entry for its node ID yet)");
    emit(PatchEventKind::kDiscovered, e, now_us, buf);
  } else if (e.state == PatchLinkState::kStale || e.state == PatchLinkState::kOffline) {
    char buf[96];
    std::snprintf(buf, sizeof buf, "node %u heard again after %.1f s", node,
                  static_cast<double>(elapsed_us(now_us, e.last_heard_us)) * 1e-6);
    emit(PatchEventKind::kReturned, e, now_us, buf);
    e.state = e.have_heartbeat ? PatchLinkState::kOnline : PatchLinkState::kDiscovering;
    update_state(e, now_us);
  }
  e.last_heard_us = std::max(e.last_heard_us, now_us);
  return e;
}

void PatchRegistry::assign_uid(PatchEntry& e, uint64_t uid, uint64_t now_us) {
  e.hardware_uid = uid;
  e.placement = nullptr;
  e.model_index = -1;
  auto it = by_uid_.find(uid);
  if (it == by_uid_.end()) {
    char buf[128];
    std::snprintf(buf, sizeof buf, "node %u: hardware UID %s is not in the skin map", e.node,
                  format_uid(uid).c_str());
    emit(PatchEventKind::kUnknownPatch, e, now_us, buf);
    return;
  }
  e.placement = &map_->patches[it->second];
  e.model_index = model_of_placement_[it->second];
  if (e.placement->node_id != e.node) {
    char buf[160];
    std::snprintf(buf, sizeof buf,
                  "node %u: UID %s is mapped as node %d in the skin map; placed by its UID", e.node,
                  format_uid(uid).c_str(), e.placement->node_id);
    emit(PatchEventKind::kUnknownPatch, e, now_us, buf);
  }
  if (e.model_index < 0) {
    char buf[128];
    std::snprintf(buf, sizeof buf, "node %u: no usable model for UID %s", e.node,
                  format_uid(uid).c_str());
    emit(PatchEventKind::kNoModel, e, now_us, buf);
  }
}

void PatchRegistry::update_state(PatchEntry& e, uint64_t now_us) {
  if (!e.have_heartbeat) return;  // still discovering
  std::string why;
  if (e.duplicate) {
    why =
        "node ID claimed by UIDs " + format_uid(e.hardware_uid) + " and " + format_uid(e.other_uid);
  } else if (e.uid_clash >= 0) {
    const PatchEntry& o = table_[static_cast<std::size_t>(e.uid_clash)];
    char buf[160];
    std::snprintf(buf, sizeof buf, "hardware UID %s also heard on %s node %u%s",
                  format_uid(e.hardware_uid).c_str(),
                  bus_names_[static_cast<std::size_t>(o.bus)].c_str(), o.node,
                  attributable(e) ? "" : "; samples dropped");
    why = buf;
  } else if (e.placement == nullptr) {
    why = "UID not in the skin map";
  } else if (e.model_index < 0) {
    why = "no usable model";
  } else if (e.last_heartbeat.fault_mask != 0) {
    char buf[64];
    std::snprintf(buf, sizeof buf, "faulty sensors 0x%04x", e.last_heartbeat.fault_mask);
    why = buf;
  } else if (e.last_heartbeat.state == bus::PatchState::kDegraded ||
             e.last_heartbeat.state == bus::PatchState::kFault) {
    why = "node reports " + std::string(bus::patch_state_name(e.last_heartbeat.state));
  } else if (!e.estimator_problem.empty()) {
    why = e.estimator_problem;
  }
  const PatchLinkState next = why.empty() ? PatchLinkState::kOnline : PatchLinkState::kDegraded;
  if (next != e.state || (next == PatchLinkState::kDegraded && why != e.detail)) {
    e.state = next;
    e.detail = why;
    char buf[64];
    std::snprintf(buf, sizeof buf, "node %u ", e.node);
    emit(next == PatchLinkState::kOnline ? PatchEventKind::kOnline : PatchEventKind::kDegraded, e,
         now_us, std::string(buf) + (why.empty() ? "online" : why));
  }
}

bool PatchRegistry::attributable(const PatchEntry& e) const {
  if (e.duplicate || e.placement == nullptr) return false;
  if (e.uid_clash < 0) return true;
  const PatchEntry& o = table_[static_cast<std::size_t>(e.uid_clash)];
  return e.placement->node_id == e.node && o.node != e.node;
}

void PatchRegistry::set_estimator_problem(PatchEntry& e, const std::string& problem,
                                          uint64_t now_us) {
  if (problem == e.estimator_problem) return;
  e.estimator_problem = problem;
  update_state(e, now_us);
}

void PatchRegistry::check_uid_clash(PatchEntry& e, uint64_t now_us) {
  const std::size_t self = index_of(e);
  if (e.uid_clash >= 0) {
    PatchEntry& o = table_[static_cast<std::size_t>(e.uid_clash)];
    const bool over = o.hardware_uid != e.hardware_uid ||
                      elapsed_us(now_us, o.last_heartbeat_us) >= options_.duplicate_window_us;
    if (!over) return;
    char buf[160];
    std::snprintf(buf, sizeof buf,
                  "node %u: hardware UID %s no longer heard on %s node %u; the UID is unique again",
                  e.node, format_uid(e.hardware_uid).c_str(),
                  bus_names_[static_cast<std::size_t>(o.bus)].c_str(), o.node);
    emit(PatchEventKind::kOnline, e, now_us, buf);
    if (o.uid_clash == static_cast<int>(self)) {
      o.uid_clash = -1;
      update_state(o, now_us);
    }
    e.uid_clash = -1;
    update_state(e, now_us);
    return;
  }
  for (std::size_t i : heard_) {
    if (i == self) continue;
    PatchEntry& o = table_[i];
    if (!o.have_heartbeat || o.hardware_uid != e.hardware_uid ||
        elapsed_us(now_us, o.last_heartbeat_us) >= options_.duplicate_window_us) {
      continue;
    }
    e.uid_clash = static_cast<int>(i);
    o.uid_clash = static_cast<int>(self);
    for (PatchEntry* p : {&o, &e}) {
      const PatchEntry& other = p == &e ? o : e;
      char buf[224];
      std::snprintf(buf, sizeof buf,
                    "DUPLICATE hardware UID %s: node %u and %s node %u both send it; node %u's "
                    "samples are %s",
                    format_uid(e.hardware_uid).c_str(), p->node,
                    bus_names_[static_cast<std::size_t>(other.bus)].c_str(), other.node, p->node,
                    attributable(*p) ? "placed (the skin map's node for this UID)"
                                     : "dropped until one stops");
      emit(PatchEventKind::kDuplicateId, *p, now_us, buf);
      update_state(*p, now_us);
    }
    return;
  }
}

void PatchRegistry::on_heartbeat(int bus, uint8_t node, const bus::Heartbeat& hb, uint64_t now_us) {
  if (bus < 0 || bus >= bus_count() || !bus::is_patch_node(node)) return;
  PatchEntry& e = touch(bus, node, now_us);
  if (!e.have_heartbeat) {
    assign_uid(e, hb.hardware_uid, now_us);
  } else if (hb.hardware_uid != e.hardware_uid) {
    // Two boards on one ID, or a board swapped. Within the window it is a clash.
    const bool clash = elapsed_us(now_us, e.last_heartbeat_us) < options_.duplicate_window_us;
    if (clash) {
      if (!e.duplicate || e.other_uid != hb.hardware_uid) {
        e.duplicate = true;
        e.other_uid = hb.hardware_uid;
        char buf[160];
        std::snprintf(buf, sizeof buf,
                      "DUPLICATE node ID %u: hardware UIDs %s and %s both send with it; its "
                      "samples are dropped until one stops",
                      node, format_uid(e.hardware_uid).c_str(),
                      format_uid(hb.hardware_uid).c_str());
        emit(PatchEventKind::kDuplicateId, e, now_us, buf);
      }
      e.other_uid_last_us = now_us;
      update_state(e, now_us);
      return;  // the ID keeps its first UID; the other is tracked as the intruder
    }
    // The first UID went quiet for the window: the new board owns the ID.
    char buf[160];
    std::snprintf(buf, sizeof buf, "node %u now belongs to UID %s (was %s)", node,
                  format_uid(hb.hardware_uid).c_str(), format_uid(e.hardware_uid).c_str());
    emit(PatchEventKind::kDiscovered, e, now_us, buf);
    e.duplicate = false;
    e.clock.reset();
    assign_uid(e, hb.hardware_uid, now_us);
    e.have_heartbeat = false;  // another board: its uptime is not compared with the old one's
  } else if (e.duplicate &&
             elapsed_us(now_us, e.other_uid_last_us) >= options_.duplicate_window_us) {
    e.duplicate = false;  // the intruder stopped
    char buf[128];
    std::snprintf(buf, sizeof buf, "node %u: UID %s no longer heard; the ID is unique again", node,
                  format_uid(e.other_uid).c_str());
    emit(PatchEventKind::kOnline, e, now_us, buf);
  }
  if (e.have_heartbeat && hb.uptime_s < e.last_heartbeat.uptime_s) {
    ++e.reboots;
    e.clock.reset();
    char buf[128];
    std::snprintf(buf, sizeof buf, "node %u rebooted (uptime %" PRIu32 " s after %" PRIu32 " s)",
                  node, hb.uptime_s, e.last_heartbeat.uptime_s);
    emit(PatchEventKind::kRebooted, e, now_us, buf);
  }
  e.last_heartbeat = hb;
  e.have_heartbeat = true;
  e.last_heartbeat_us = now_us;
  if (e.state == PatchLinkState::kDiscovering) e.state = PatchLinkState::kDegraded;  // forces
  update_state(e, now_us);                                                           // an event
  check_uid_clash(e, now_us);
}

PatchEntry* PatchRegistry::on_sample(int bus, uint8_t node, const bus::Sample& s,
                                     uint32_t missing_before, uint64_t now_us) {
  if (bus < 0 || bus >= bus_count() || !bus::is_patch_node(node)) return nullptr;
  PatchEntry& e = touch(bus, node, now_us);
  ++e.samples;
  if (missing_before > 0) {
    e.samples_lost += missing_before;
    char buf[96];
    std::snprintf(buf, sizeof buf, "node %u: %" PRIu32 " sample(s) lost", node, missing_before);
    emit(PatchEventKind::kSequenceGap, e, now_us, buf);
  }
  if (!attributable(e)) {
    ++e.samples_dropped;
    return nullptr;
  }
  e.clock.update(s.timestamp_us, now_us);  // a jump resets the aligner's history itself
  return &e;
}

void PatchRegistry::on_traffic(int bus, uint8_t node, uint64_t now_us) {
  if (bus < 0 || bus >= bus_count() || !bus::is_patch_node(node)) return;
  touch(bus, node, now_us);
}

void PatchRegistry::tick(uint64_t now_us) {
  for (std::size_t i : heard_) {
    PatchEntry& e = table_[i];
    if (now_us <= e.last_heard_us) continue;
    const uint64_t quiet = now_us - e.last_heard_us;
    if (quiet >= options_.offline_us && e.state != PatchLinkState::kOffline) {
      e.state = PatchLinkState::kOffline;
      char buf[96];
      std::snprintf(buf, sizeof buf, "node %u offline: nothing heard for %.1f s", e.node,
                    static_cast<double>(quiet) * 1e-6);
      emit(PatchEventKind::kOffline, e, now_us, buf);
    } else if (quiet >= options_.stale_us && quiet < options_.offline_us &&
               e.state != PatchLinkState::kStale && e.state != PatchLinkState::kOffline) {
      e.state = PatchLinkState::kStale;
      char buf[96];
      std::snprintf(buf, sizeof buf, "node %u stale: nothing heard for %.1f s", e.node,
                    static_cast<double>(quiet) * 1e-6);
      emit(PatchEventKind::kStale, e, now_us, buf);
    }
  }
}

void PatchRegistry::status(std::vector<PatchStatus>* out) const {
  std::vector<std::size_t> order = heard_;
  std::sort(order.begin(), order.end());
  for (std::size_t i : order) {
    const PatchEntry& e = table_[i];
    PatchStatus s;
    s.node = e.node;
    s.hardware_uid = e.hardware_uid;
    s.interface = bus_names_[static_cast<std::size_t>(e.bus)];
    s.link = e.placement != nullptr ? e.placement->link : "";
    s.state = e.state;
    s.node_state = static_cast<uint8_t>(e.last_heartbeat.state);
    s.node_mode = static_cast<uint8_t>(e.last_heartbeat.mode);
    s.fault_mask = e.last_heartbeat.fault_mask;
    s.uptime_s = e.last_heartbeat.uptime_s;
    s.reboots = e.reboots;
    s.samples = e.samples;
    s.samples_lost = e.samples_lost;
    s.contacts = e.contacts;
    s.clock_offset_us = e.clock.offset_us();
    s.clock_drift_ppm = e.clock.drift_ppm();
    s.last_heard_us = e.last_heard_us;
    s.duplicate_id = e.duplicate || e.uid_clash >= 0;
    s.detail = e.detail;
    out->push_back(std::move(s));
  }
}

}  // namespace skinbus::host
