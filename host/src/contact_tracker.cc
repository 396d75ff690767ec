// Merging of one press seen by several patches, and track IDs across periods
// (contact_tracker.h).
#include "skinbus/host/contact_tracker.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>

namespace skinbus::host {
namespace {

constexpr double kMaxMagnitude = kMaxContactMagnitude;
constexpr double kMaxUncertaintyMm = 1e6;
constexpr std::size_t kNone = std::numeric_limits<std::size_t>::max();

double sanitised_length(double v) {
  return (std::isfinite(v) && v > 0) ? v : 0.0;
}

bool within(double v, double limit) {
  return std::isfinite(v) && std::abs(v) <= limit;
}

double distance(const double* a, const double* b) {
  return std::hypot(a[0] - b[0], a[1] - b[1], a[2] - b[2]);
}

bool same_patch(const PatchContact& a, const PatchContact& b) {
  return a.node == b.node && a.hardware_uid == b.hardware_uid;
}

}  // namespace

Status check_options(const TrackerOptions& o) {
  if (!std::isfinite(o.merge_radius_mm) || o.merge_radius_mm < 0) {
    return make_error(ErrorCode::kInvalidArgument,
                      "contact tracker: merge_radius_mm must be finite and >= 0");
  }
  if (!std::isfinite(o.gate_mm) || o.gate_mm < 0) {
    return make_error(ErrorCode::kInvalidArgument,
                      "contact tracker: gate_mm must be finite and >= 0");
  }
  return Status::Ok();
}

ContactTracker::ContactTracker(const TrackerOptions& options) : options_(options) {
  options_.merge_radius_mm = sanitised_length(options_.merge_radius_mm);
  options_.gate_mm = sanitised_length(options_.gate_mm);
}

void ContactTracker::reset() {
  tracks_.clear();
  next_id_ = 1;
  dropped_ = 0;
  started_ = 0;
}

uint32_t ContactTracker::next_id() {
  for (;;) {
    const uint32_t id = next_id_;
    next_id_ = next_id_ == std::numeric_limits<uint32_t>::max() ? 1 : next_id_ + 1;
    if (id == 0) continue;
    const bool in_use =
        std::any_of(tracks_.begin(), tracks_.end(), [id](const Track& t) { return t.id == id; });
    if (!in_use) return id;
  }
}

std::size_t ContactTracker::find(std::size_t i) {
  while (parent_[i] != i) {
    parent_[i] = parent_[parent_[i]];  // path halving
    i = parent_[i];
  }
  return i;
}

bool ContactTracker::same_patch_across(std::size_t a, std::size_t b,
                                       std::span<const PatchContact> in) const {
  for (std::size_t i = a; i != kNone; i = next_member_[i]) {
    for (std::size_t j = b; j != kNone; j = next_member_[j]) {
      if (same_patch(in[valid_[i].index], in[valid_[j].index])) return true;
    }
  }
  return false;
}

void ContactTracker::merge(std::span<const PatchContact> in) {
  const std::size_t n = valid_.size();
  parent_.resize(n);
  std::iota(parent_.begin(), parent_.end(), std::size_t{0});
  next_member_.assign(n, kNone);
  last_member_.resize(n);
  std::iota(last_member_.begin(), last_member_.end(), std::size_t{0});

  // Single linkage, closest pairs first, never two contacts of one patch in a press.
  edges_.clear();
  for (std::size_t i = 0; i < n; ++i) {
    const PatchContact& a = in[valid_[i].index];
    for (std::size_t j = i + 1; j < n; ++j) {
      const PatchContact& b = in[valid_[j].index];
      if (same_patch(a, b)) continue;
      const double d = distance(a.position_mm, b.position_mm);
      if (d <= options_.merge_radius_mm) edges_.push_back({d, i, j});
    }
  }
  std::sort(edges_.begin(), edges_.end(), [](const Edge& x, const Edge& y) {
    if (x.distance != y.distance) return x.distance < y.distance;
    return x.a != y.a ? x.a < y.a : x.b < y.b;
  });
  for (const Edge& e : edges_) {
    std::size_t ra = find(e.a), rb = find(e.b);
    if (ra == rb || same_patch_across(ra, rb, in)) continue;
    if (rb < ra) std::swap(ra, rb);  // the root is the cluster's first contact
    parent_[rb] = ra;
    next_member_[last_member_[ra]] = rb;
    last_member_[ra] = last_member_[rb];
  }

  merged_.clear();
  for (std::size_t r = 0; r < n; ++r) {
    if (find(r) != r) continue;
    Merged m{};
    const PatchContact& first = in[valid_[r].index];
    if (next_member_[r] == kNone) {
      // One patch: passed through (normal normalised, uncertainty clamped).
      for (int k = 0; k < 3; ++k) {
        m.position_mm[k] = first.position_mm[k];
        m.normal[k] = valid_[r].normal[k];
      }
      if (m.normal[0] == 0 && m.normal[1] == 0 && m.normal[2] == 0) m.normal[2] = 1;
      m.depth_mm = first.depth_mm;
      m.force_n = first.force_n;
      m.uncertainty_mm = 1.0 / std::sqrt(valid_[r].weight);
      m.deepest = valid_[r].index;
      m.shear = (first.flags & kContactShear) ? valid_[r].index : kNone;
      m.count = 1;
      m.flags = first.flags;
      merged_.push_back(m);
      continue;
    }
    double w_sum = 0, depth = 0, pos[3] = {0, 0, 0}, nrm[3] = {0, 0, 0};
    double force = -std::numeric_limits<double>::infinity();
    std::size_t deepest = kNone, shear = kNone;
    uint32_t count = 0, flags = kContactMerged;
    for (std::size_t i = r; i != kNone; i = next_member_[i]) {
      const Valid& v = valid_[i];
      const PatchContact& c = in[v.index];
      w_sum += v.weight;
      depth += v.weight * c.depth_mm;
      for (int k = 0; k < 3; ++k) {
        pos[k] += v.weight * c.position_mm[k];
        nrm[k] += v.weight * v.normal[k];
      }
      force = std::max(force, c.force_n);
      if (deepest == kNone || c.depth_mm > in[deepest].depth_mm ||
          (c.depth_mm == in[deepest].depth_mm && v.index < deepest)) {
        deepest = v.index;
      }
      if ((c.flags & kContactShear) && shear == kNone) shear = v.index;
      ++count;
      flags |= c.flags;
    }
    if (in[deepest].flags & kContactShear) shear = deepest;
    for (int k = 0; k < 3; ++k) m.position_mm[k] = pos[k] / w_sum;
    m.depth_mm = depth / w_sum;
    m.force_n = force;
    m.uncertainty_mm = 1.0 / std::sqrt(w_sum);
    m.deepest = deepest;
    m.shear = shear;
    m.count = count;
    m.flags = flags;
    // The weighted normal; if the members' normals cancel, the deepest member's, then +z.
    double len = std::hypot(nrm[0], nrm[1], nrm[2]);
    if (!(len > 1e-9 * w_sum) || !std::isfinite(len)) {
      const Valid* dv = nullptr;
      for (std::size_t i = r; i != kNone; i = next_member_[i]) {
        if (valid_[i].index == deepest) dv = &valid_[i];
      }
      for (int k = 0; k < 3; ++k) nrm[k] = dv != nullptr ? dv->normal[k] : 0.0;
      len = std::hypot(nrm[0], nrm[1], nrm[2]);
      if (!(len > 0)) {
        nrm[0] = nrm[1] = 0;
        nrm[2] = len = 1;
      }
    }
    for (int k = 0; k < 3; ++k) m.normal[k] = nrm[k] / len;
    merged_.push_back(m);
  }
}

void ContactTracker::update(uint64_t stamp_us, std::span<const PatchContact> in,
                            std::vector<BodyContact>* out) {
  // End the tracks not seen for longer than hold_us (a stamp that went back ages from now).
  for (Track& t : tracks_) t.last_seen_us = std::min(t.last_seen_us, stamp_us);
  std::erase_if(tracks_,
                [&](const Track& t) { return stamp_us - t.last_seen_us > options_.hold_us; });

  // Check the input.
  valid_.clear();
  for (std::size_t i = 0; i < in.size(); ++i) {
    const PatchContact& c = in[i];
    bool ok = within(c.depth_mm, kMaxMagnitude) && within(c.force_n, kMaxMagnitude) &&
              within(c.u_mm, kMaxMagnitude) && within(c.v_mm, kMaxMagnitude) &&
              !std::isnan(c.uncertainty_mm) && within(c.shear_uncertainty_n, kMaxMagnitude);
    for (int k = 0; k < 3; ++k) {
      ok = ok && within(c.position_mm[k], kMaxMagnitude) && std::isfinite(c.normal[k]) &&
           within(c.shear_n[k], kMaxMagnitude);
    }
    if (!ok) {
      ++dropped_;
      continue;
    }
    Valid v{};
    v.index = i;
    const double len = std::hypot(c.normal[0], c.normal[1], c.normal[2]);
    for (int k = 0; k < 3; ++k)
      v.normal[k] = (len > 0 && std::isfinite(len)) ? c.normal[k] / len : 0;
    const double s = std::clamp(std::isfinite(c.uncertainty_mm) ? c.uncertainty_mm : 0.0,
                                kMinUncertaintyMm, kMaxUncertaintyMm);
    v.weight = 1.0 / (s * s);
    valid_.push_back(v);
  }

  merge(in);

  // Associate: closest (track, contact) pairs first, one to one, within the gate.
  edges_.clear();
  for (std::size_t t = 0; t < tracks_.size(); ++t) {
    for (std::size_t m = 0; m < merged_.size(); ++m) {
      const double d = distance(tracks_[t].position_mm, merged_[m].position_mm);
      if (d <= options_.gate_mm) edges_.push_back({d, t, m});
    }
  }
  std::sort(edges_.begin(), edges_.end(), [](const Edge& x, const Edge& y) {
    if (x.distance != y.distance) return x.distance < y.distance;
    return x.a != y.a ? x.a < y.a : x.b < y.b;
  });
  track_matched_.assign(tracks_.size(), 0);
  track_of_merged_.assign(merged_.size(), 0);
  for (const Edge& e : edges_) {
    if (track_matched_[e.a] != 0 || track_of_merged_[e.b] != 0) continue;
    track_matched_[e.a] = 1;
    track_of_merged_[e.b] = static_cast<uint32_t>(e.a + 1);
  }

  out->resize(merged_.size());
  for (std::size_t m = 0; m < merged_.size(); ++m) {
    const Merged& g = merged_[m];
    std::size_t t = 0;
    if (track_of_merged_[m] != 0) {
      t = track_of_merged_[m] - 1;
    } else {
      const uint32_t id = next_id();
      tracks_.push_back(Track{id, {0, 0, 0}, stamp_us, stamp_us});
      ++started_;
      t = tracks_.size() - 1;
    }
    Track& track = tracks_[t];
    for (int k = 0; k < 3; ++k) track.position_mm[k] = g.position_mm[k];
    track.last_seen_us = stamp_us;

    const PatchContact& rep = in[g.deepest];
    BodyContact& b = (*out)[m];
    for (int k = 0; k < 3; ++k) {
      b.position_mm[k] = g.position_mm[k];
      b.normal[k] = g.normal[k];
    }
    b.depth_mm = g.depth_mm;
    b.force_n = g.force_n;
    b.u_mm = rep.u_mm;
    b.v_mm = rep.v_mm;
    b.uncertainty_mm = g.uncertainty_mm;
    b.node = rep.node;
    b.hardware_uid = rep.hardware_uid;
    b.link = rep.link;
    b.track_id = track.id;
    b.patch_count = g.count;
    b.flags = g.flags;
    b.first_seen_us = track.first_seen_us;
    for (int k = 0; k < 3; ++k) b.shear_n[k] = g.shear != kNone ? in[g.shear].shear_n[k] : 0.0;
    b.shear_uncertainty_n = g.shear != kNone ? in[g.shear].shear_uncertainty_n : 0.0;
  }
}

}  // namespace skinbus::host
