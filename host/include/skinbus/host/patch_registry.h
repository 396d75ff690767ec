// skinbus/host/patch_registry.h: the host's view of every patch it hears.
//
// Patches are discovered from their traffic and identified by the hardware UID in their
// heartbeats. One registry serves every bus of the host: a patch is keyed by (bus index, node
// ID), since each bus has its own node IDs.
//
// States (contacts.h PatchLinkState):
//   discovering  heard, no heartbeat yet. Its samples are used if the skin map has an entry for
//                its node ID (a provisional placement, confirmed or corrected by the first
//                heartbeat's UID), dropped otherwise.
//   online       heartbeats arrive, the UID has a skin-map entry with a model, no faults.
//   degraded     online with a problem, named in `detail`: the node reports faulty sensors or a
//                degraded/fault state, the UID is not in the skin map, its model is missing, or
//                two UIDs claim the node ID.
//   stale        nothing heard for `stale_us`; offline after `offline_us`. A patch heard again
//                returns to online/degraded with a kReturned event.
// Events (PatchEvent) are queued once each, for the status topic and the log: discovery, state
// changes, reboots (heartbeat uptime went backwards), duplicate IDs, unknown UIDs, missing models,
// lost samples, rejected frames, interface and kinematics events (reported by the aggregator).
//
// Duplicate IDs: a heartbeat whose UID differs from the one the node ID belongs to, within
// `duplicate_window_us` of the other UID's last heartbeat, marks the ID as shared. While it is,
// the ID's samples cannot be attributed and are dropped (counted), and the patch is degraded
// with both UIDs named. When one UID stops for the window, the other keeps the ID.
//
// Duplicate UIDs: one hardware UID in the heartbeats of two (bus, node) pairs within the window
// (a cloned or misprogrammed board) marks both duplicate_id and degraded, with a kDuplicateId
// event each. A patch is placed by its UID, so the samples of the one whose node ID is not the
// skin map's for that UID are dropped (counted), never placed at the other's place; when both
// or neither have the map's node ID, both are dropped. When one stops for the window, the other
// is unique again.
//
// Estimates: the aggregator reports a patch whose model gives no estimates (every one rejected,
// e.g. non-finite outputs) with set_estimator_problem(); the patch is degraded with that reason
// until an estimate succeeds.
//
// Costs: a fixed table of kMaxBuses x 128 entries allocated at construction; on_sample and
// on_heartbeat are O(1) (the UID look-up is a hash map built once from the skin map); tick() is
// O(patches heard), and cheap: it only compares times.
#pragma once

#include <cstdint>
#include <string>
#include <unordered_map>
#include <vector>

#include "skinbus/body_map/skin_map.h"
#include "skinbus/bus/protocol.h"
#include "skinbus/host/clock_alignment.h"
#include "skinbus/host/contacts.h"

namespace skinbus::host {

inline constexpr int kMaxBuses = 8;

struct RegistryOptions {
  uint64_t stale_us = 3'000'000;     // no traffic for this long: stale (3 missed heartbeats)
  uint64_t offline_us = 10'000'000;  // and for this long: offline
  uint64_t duplicate_window_us = 5'000'000;  // two UIDs on one ID within this: a clash
  std::size_t max_events = 4096;             // queued events beyond this are counted, not kept
};

// One patch as the host knows it.
struct PatchEntry {
  bool heard = false;
  int bus = 0;
  uint8_t node = 0;
  uint64_t hardware_uid = 0;                            // from heartbeats (0 until the first)
  const body_map::PatchPlacement* placement = nullptr;  // skin-map entry, or nullptr
  int model_index = -1;  // index into the aggregator's model list, -1: none
  PatchLinkState state = PatchLinkState::kDiscovering;
  bus::Heartbeat last_heartbeat;
  bool have_heartbeat = false;
  uint64_t last_heartbeat_us = 0;
  uint64_t last_heard_us = 0;
  uint64_t samples = 0, samples_lost = 0, samples_dropped = 0, contacts = 0;
  uint32_t reboots = 0;
  // Duplicate IDs: the other UID heard on this ID, and when.
  uint64_t other_uid = 0;
  uint64_t other_uid_last_us = 0;
  bool duplicate = false;
  // Another (bus, node) whose heartbeats carry this entry's UID (registry table index), -1: none.
  int uid_clash = -1;
  // Why the model gives this patch no estimates ("" while it does).
  std::string estimator_problem;
  ClockAligner clock;
  std::string detail;  // why degraded
};

class PatchRegistry {
 public:
  // `map` (may be null: every patch is unknown) must outlive the registry. `model_for` maps a
  // placement to a model index (-1: no usable model); it is called once per placement.
  PatchRegistry(const body_map::SkinMap* map, std::vector<std::string> bus_names,
                RegistryOptions options = {});

  // Sets the model index of every skin-map entry (by its position in map->patches); entries
  // not listed have none.
  void set_models(const std::vector<int>& model_of_placement);

  // A heartbeat from (bus, node) received at host time `now_us`.
  void on_heartbeat(int bus, uint8_t node, const bus::Heartbeat& hb, uint64_t now_us);

  // A sample from (bus, node); `missing_before` is the reassembler's count of samples lost just
  // before it. Returns the patch to estimate it for, or nullptr when the sample cannot be
  // attributed (duplicate ID, unknown node before its first heartbeat): counted, not used.
  PatchEntry* on_sample(int bus, uint8_t node, const bus::Sample& s, uint32_t missing_before,
                        uint64_t now_us);

  // The model's verdict on this patch: `problem` non-empty when it gives no estimates (the patch
  // is degraded with it, one event), empty when an estimate succeeded (back to online).
  void set_estimator_problem(PatchEntry& e, const std::string& problem, uint64_t now_us);

  // True when the samples of `e` can be placed: a UID with a skin-map entry, no duplicate ID,
  // and in a duplicate UID the one with the map's node ID.
  bool attributable(const PatchEntry& e) const;

  // Any other message from (bus, node) (acks, info): keeps it alive.
  void on_traffic(int bus, uint8_t node, uint64_t now_us);

  // Advances the stale/offline timers to `now_us`. O(patches heard).
  void tick(uint64_t now_us);

  // Host events (interfaces, kinematics, bad frames): queued like the patches' own.
  void add_event(PatchEventKind kind, uint64_t now_us, std::string detail, int bus = -1,
                 uint8_t node = 0);

  // Moves the queued events into `out` (appended).
  void take_events(std::vector<PatchEvent>* out);
  uint64_t events_dropped() const { return events_dropped_; }

  // The status of every patch heard, in (bus, node) order.
  void status(std::vector<PatchStatus>* out) const;

  const PatchEntry& entry(int bus, uint8_t node) const { return table_[index(bus, node)]; }
  PatchEntry& entry(int bus, uint8_t node) { return table_[index(bus, node)]; }
  std::size_t patches_heard() const { return heard_.size(); }
  const std::string& bus_name(int bus) const { return bus_names_[bus]; }
  int bus_count() const { return static_cast<int>(bus_names_.size()); }

 private:
  static std::size_t index(int bus, uint8_t node) {
    return static_cast<std::size_t>(bus) * 128 + (node & 0x7F);
  }
  PatchEntry& touch(int bus, uint8_t node, uint64_t now_us);
  void emit(PatchEventKind kind, const PatchEntry& e, uint64_t now_us, std::string detail);
  void assign_uid(PatchEntry& e, uint64_t uid, uint64_t now_us);
  void update_state(PatchEntry& e, uint64_t now_us);
  // Looks for another entry with the UID of `e` (a duplicate UID) and ends a clash that is over.
  void check_uid_clash(PatchEntry& e, uint64_t now_us);
  static std::size_t index_of(const PatchEntry& e) { return index(e.bus, e.node); }

  const body_map::SkinMap* map_;
  std::vector<std::string> bus_names_;
  RegistryOptions options_;
  std::vector<PatchEntry> table_;
  std::vector<std::size_t> heard_;  // indices into table_, in the order first heard
  std::unordered_map<uint64_t, std::size_t> by_uid_;  // UID -> index into map_->patches
  std::vector<int> model_of_placement_;
  std::vector<PatchEvent> events_;
  uint64_t events_dropped_ = 0;
};

}  // namespace skinbus::host
