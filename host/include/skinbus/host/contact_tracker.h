// skinbus/host/contact_tracker.h: one contact per press, with an ID that lasts while it does.
//
// Each period the aggregator has the contacts of its patches, already placed in the robot's base
// frame (one per patch at most). A press near a patch edge is seen by its neighbours too; the
// tracker merges those into one contact and gives each press a track ID that stays the same from
// period to period.
//
// Merge: contacts of different patches whose positions lie within `merge_radius_mm` of each other
// are one press (single linkage: A-B and B-C close makes A, B, C one press). Two contacts of the
// same patch (same node and hardware UID) are never merged, directly or through a chain: pairs
// are joined closest first and a join that would put one patch twice into a press is skipped. A
// merged contact has
//   position, normal, depth   the mean weighted by 1/uncertainty^2 (normal re-normalised);
//   force                     the largest of the members' (each patch sees the whole press);
//   u, v, node, uid, link     those of the deepest member (the patch closest to the press);
//   shear                     the deepest member's with kContactShear, else the first such one's;
//   uncertainty               1 / sqrt(sum of 1/uncertainty^2);
//   patch_count, flags        the number of members; their flags OR-ed, plus kContactMerged.
// A single contact passes unchanged but for its normal (normalised) and uncertainty (clamped).
//
// Track: this period's contacts are matched to existing tracks by distance, one to one, closest
// pairs first, within `gate_mm` of the track's last position. A matched track takes the
// measurement as it is (no smoothing, no prediction: a press moving faster than gate_mm per
// period loses its ID); an unmatched contact starts a track with a new ID. IDs count up from 1,
// skip 0 and any ID still in use when they wrap after 2^32 tracks. A track not matched for longer
// than `hold_us` ends, so a press that lifts for a moment (a lost frame, a patch's gate
// flickering) keeps its ID, and one that lifts and lands elsewhere later gets a new one. Only
// contacts of this period are output; tracks being held produce nothing.
//
// Input checks: a contact with a NaN or Inf field, or with a position, depth, u, v or force
// beyond 1e6 (mm or N), is dropped and counted (dropped()); nothing non-finite is ever output.
// An uncertainty that is not positive or tiny is taken as kMinUncertaintyMm (1e-2 mm) for the
// weights, one beyond 1e6 mm as 1e6 mm. A zero normal is allowed (the merged normal falls back
// to the deepest member's, then to +z).
//
// Time: `stamp_us` is the host time of the period. If it goes back (the host clock stepped), held
// tracks' last sightings are moved back to it, so they still end hold_us later.
//
// Costs: O(n^2 log n + n t log(n t)) for n contacts and t live tracks per update, independent of
// the number of patches; scratch vectors are members and only allocate when they grow beyond their
// past size. `out` is resized and its elements assigned in place, so a caller that keeps the
// vector across updates allocates only when the count or a link name grows. Not thread-safe.
#pragma once

#include <cstddef>
#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include "skinbus/common/result.h"
#include "skinbus/host/contacts.h"

namespace skinbus::host {

// One patch's contact, in the base frame.
struct PatchContact {
  double position_mm[3] = {0, 0, 0};  // on the skin surface, base frame
  double normal[3] = {0, 0, 1};       // outward, base frame (normalised by the tracker)
  double depth_mm = 0;
  double force_n = 0;
  double u_mm = 0, v_mm = 0;  // patch-local coordinates
  double uncertainty_mm = 1;  // 1-sigma position uncertainty
  uint8_t node = 0;           // CAN node of the patch
  uint64_t hardware_uid = 0;
  std::string link;
  uint32_t flags = kContactOk;     // BodyContactFlag bits
  double shear_n[3] = {0, 0, 0};   // base frame, with kContactShear
  double shear_uncertainty_n = 0;  // N, 1-sigma
};

struct TrackerOptions {
  double merge_radius_mm = 15;  // contacts of different patches this close: one press
  double gate_mm = 20;          // a track follows a contact at most this far from its last one
  uint64_t hold_us = 100'000;   // a track unseen for longer ends
};

inline constexpr double kMinUncertaintyMm = 1e-2;
// A contact value beyond this (mm or N) is not a contact on a robot: the tracker drops it
// (counted); the aggregator never hands it one (its patch is degraded instead).
inline constexpr double kMaxContactMagnitude = 1e6;

// kInvalidArgument naming the field when merge_radius_mm or gate_mm is negative or not finite.
// The constructor takes such a value as 0 instead (no merging / no association).
Status check_options(const TrackerOptions& options);

class ContactTracker {
 public:
  explicit ContactTracker(const TrackerOptions& options = {});

  // Merges and tracks one period's contacts; `out` receives one BodyContact per press, in the
  // order of each press's first member in `in`, with track_id (never 0) and first_seen_us (the
  // stamp of the track's first period) set. `out` (not null) is overwritten.
  void update(uint64_t stamp_us, std::span<const PatchContact> in, std::vector<BodyContact>* out);

  // Tracks alive after the last update (matched or held).
  std::size_t active_tracks() const { return tracks_.size(); }
  // Input contacts dropped for non-finite or absurd values since construction or reset().
  uint64_t dropped() const { return dropped_; }
  // Tracks started since construction or reset().
  uint64_t tracks_started() const { return started_; }
  const TrackerOptions& options() const { return options_; }

  // Ends every track and restarts IDs at 1.
  void reset();

 private:
  struct Track {
    uint32_t id;
    double position_mm[3];
    uint64_t first_seen_us, last_seen_us;
  };
  struct Valid {        // a checked input contact
    std::size_t index;  // into `in`
    double normal[3];   // unit or zero
    double weight;      // 1 / uncertainty^2
  };
  struct Edge {
    double distance;
    std::size_t a, b;  // into valid_ (or tracks_, merged_)
  };
  struct Merged {
    double position_mm[3], normal[3];
    double depth_mm, force_n, uncertainty_mm;
    std::size_t deepest;  // into `in`
    std::size_t shear;    // into `in`: the member whose shear is output (kNone: none has one)
    uint32_t count, flags;
  };

  std::size_t find(std::size_t i);
  bool same_patch_across(std::size_t a, std::size_t b, std::span<const PatchContact> in) const;
  void merge(std::span<const PatchContact> in);
  uint32_t next_id();

  TrackerOptions options_;
  std::vector<Track> tracks_;
  uint32_t next_id_ = 1;
  uint64_t dropped_ = 0, started_ = 0;

  // Scratch, reused across updates.
  std::vector<Valid> valid_;
  std::vector<Edge> edges_;
  std::vector<std::size_t> parent_, next_member_, last_member_, cluster_of_;
  std::vector<Merged> merged_;
  std::vector<uint32_t> track_of_merged_;  // track index + 1, 0: none
  std::vector<uint8_t> track_matched_;
};

}  // namespace skinbus::host
