// The host aggregator's pipeline (aggregator.h).
#include "skinbus/host/aggregator.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <limits>
#include <map>
#include <optional>

#include "skinbus/body_map/joint_map.h"
#include "skinbus/bus/protocol.h"
#include "skinbus/estimators/evaluation.h"
#include "skinbus/estimators/model_file.h"

namespace skinbus::host {

// Estimator names used here.
using estimators::ContactEstimate;
using estimators::depth_bin;
using estimators::depth_bin_name;
using estimators::kDepthBins;
using estimators::kEstimateDepthRange;
using estimators::kEstimateMasked;
using estimators::kEstimateNoContact;
using estimators::kEstimateOutsidePatch;
using estimators::kMaxContacts;
using estimators::model_stem;
using estimators::ModelMeta;
using estimators::NetworkRuntime;
using estimators::read_model;
using estimators::reject_reason_name;

namespace {

constexpr int kChannels = bus::kChannelCount;

// The model's mean XY error at a depth, from its metadata (measured at training time), used as
// the contact's uncertainty. Falls back to the deep-press validation error, then to 1 mm.
struct ErrorTable {
  std::array<double, kDepthBins> xy_mm{};
  double fallback_mm = 1.0;
  double at(double depth_mm) const {
    const int b = depth_bin(depth_mm);
    const double v = b >= 0 ? xy_mm[static_cast<std::size_t>(std::min(b, kDepthBins - 1))] : 0;
    return v > 0 && std::isfinite(v) ? v : fallback_mm;
  }
};

ErrorTable error_table(const ModelMeta& m) {
  ErrorTable t;
  auto it = m.metrics.find("val_xy_deep_mean_mm");
  if (it != m.metrics.end() && std::isfinite(it->second) && it->second > 0) {
    t.fallback_mm = it->second;
  }
  for (int b = 0; b < kDepthBins; ++b) {
    auto jt = m.metrics.find("test_xy_mean_mm_depth_" + depth_bin_name(b));
    if (jt != m.metrics.end()) t.xy_mm[static_cast<std::size_t>(b)] = jt->second;
  }
  return t;
}

// A file the skin map names: relative paths are relative to the map's folder `map_dir`.
std::string beside_map(const std::string& map_dir, const std::string& name) {
  std::filesystem::path p(name);
  if (p.is_relative() && !map_dir.empty()) p = std::filesystem::path(map_dir) / p;
  return p.lexically_normal().string();
}

}  // namespace

struct Aggregator::Impl {
  const body_map::SkinMap* map = nullptr;
  const body_map::RobotModel* robot = nullptr;
  AggregatorOptions options;
  std::vector<bus::Reassembler> reassemblers;
  PatchRegistry registry;
  ContactTracker tracker;
  AggregatorStats stats;

  struct Model {
    std::string path;
    std::unique_ptr<NetworkRuntime> runtime;
    ErrorTable errors;
    // The batch being built for a process() call.
    std::vector<double> fields;
    std::vector<uint8_t> ok;
    std::vector<std::size_t> slots;  // pending_ index of each row
    std::vector<ContactEstimate> out;
    std::vector<uint32_t> ambient_flags;
    double us_per_sample = 0;          // measured cost of a run per sample (0: not yet measured)
    std::vector<std::size_t> refused;  // admit(): the samples a run cannot take in time
  };
  std::vector<Model> models;
  // The physics refiner of each skin-map entry (index of map->patches), null: none.
  std::vector<std::unique_ptr<estimators::ContactRefiner>> refiners;
  // What each refiner carries between its patch's samples (ContactRefiner::Memory), null: none.
  std::vector<std::unique_ptr<estimators::ContactRefiner::Memory>> refiner_memories;

  // Queued samples, newest per patch: slot per registry index, and the list of used slots.
  struct Pending {
    bool used = false;
    PatchEntry* entry = nullptr;
    uint64_t time_us = 0;  // aligned sample time
    uint64_t rx_us = 0;    // host time its last frame arrived
    // The patch's placement and model when the sample was queued: a heartbeat that arrives
    // before process() may re-identify the node (another UID, a clash); the sample is then
    // dropped rather than placed on a patch it did not come from.
    const body_map::PatchPlacement* placement = nullptr;
    int model_index = -1;
    std::array<double, kChannels> field{};
    std::array<uint8_t, kChannels> ok{};
  };
  std::vector<Pending> pending;           // kMaxBuses * 128
  std::vector<std::size_t> pending_list;  // indices into pending

  // What the refinement of a press keeps from sample to sample (patch frame): the last refined
  // presses when several, the searches for another press, the single contact's shear. A new
  // press starts anew.
  struct RefineMemory {
    int held = 0;  // 2 or 3: the last refined sample held that many presses, in `previous`
    ContactEstimate previous[kMaxContacts];
    bool searched = false;
    double searched_chi2 = 0;
    int since_search = 0;
    double shear_u_n = 0, shear_v_n = 0;
    double checked_depth_mm = 0;  // the press's depth at its last basin check; 0: none yet
    // The last refined single contact's fitted depth (the plate's bend, which a creeping unit's
    // published depth is not: ContactRefiner::press_depth_mm); NaN: none.
    double bend_mm = std::numeric_limits<double>::quiet_NaN();
  };
  // The current contacts of each patch that has one, in its link's frame (position and normal;
  // flags without the kinematics ones): every publication places all of them with the pose at
  // its own stamp, so one array is one instant of the robot.
  struct Current {
    bool used = false;
    RefineMemory refine;
    PatchContact contacts[kMaxContacts];  // the first `count`: more than one with max_contacts 2-3
    int count = 0;
    int link = -1;         // robot link index; -1: the base frame (no robot, or unmapped)
    uint64_t time_us = 0;  // aligned sample time
    uint64_t last_us = 0;  // host time of its last contact sample
  };
  std::vector<Current> current;
  std::vector<std::size_t> current_list;
  bool released = false;  // a contact ended since the last publication

  // Kinematics: the joint-state history (null without a robot) and the pose of the last
  // placement (reused while the sample time is the same).
  std::optional<JointHistory> history;
  std::vector<double> q_new;   // the state set_joint_state() builds
  std::vector<double> q_at;    // the positions at q_at_us
  std::vector<double> q_zero;  // the zero pose (before the first joint state)
  uint64_t q_at_us = 0;
  bool q_at_valid = false;  // q_at holds the pose at q_at_us for the current history
  JointHistory::Coverage q_at_coverage = JointHistory::Coverage::kEmpty;
  bool joints_stale_reported = false;
  body_map::JointMap joint_map;  // the last joint state's names onto q

  // The lag bound: the current episode of late samples.
  bool lag_episode = false;
  uint64_t lag_episode_start_us = 0, lag_last_late_us = 0, lag_count = 0, lag_worst_us = 0;
  std::size_t next_first_slot = 0;  // where the next cost-limited admission starts (fairness)

  std::vector<uint64_t> bad_reported;  // per bus: bad frames already reported
  std::vector<uint64_t> processed_rx;  // rx times of the samples of the last process()
  // Per patch slot: contact samples in a row the model gave no estimate for. From
  // kNoEstimateRun on, the patch is degraded with the reason until an estimate succeeds.
  static constexpr uint32_t kNoEstimateRun = 10;
  std::vector<uint32_t> no_estimate_run;
  // Counts a sample of `p` the model gave no usable estimate for (`why`), or (empty) one it did.
  void estimate_outcome(Pending& p, const char* why, uint64_t now_us) {
    uint32_t& run = no_estimate_run[slot(p.entry->bus, p.entry->node)];
    if (why == nullptr) {
      run = 0;
      if (!p.entry->estimator_problem.empty()) registry.set_estimator_problem(*p.entry, "", now_us);
      return;
    }
    if (++run < kNoEstimateRun || !p.entry->estimator_problem.empty()) return;
    registry.set_estimator_problem(*p.entry,
                                   "no estimate from its model for " + std::to_string(run) +
                                       " contact samples in a row (" + why + ")",
                                   now_us);
  }
  std::vector<int> link_of_placement;  // robot link index of each skin-map entry, -1: none
  PatchContact placed[kMaxContacts];   // the contacts being placed
  std::vector<PatchContact> scratch_contacts;
  std::vector<BodyContact> scratch_out;

  Impl(const body_map::SkinMap* m, std::vector<std::string> names, const AggregatorOptions& o)
      : map(m), options(o), registry(m, std::move(names), o.registry), tracker(o.tracker) {}

  static std::size_t slot(int bus, uint8_t node) {
    return static_cast<std::size_t>(bus) * 128 + (node & 0x7F);
  }

  void on_sample(int bus, uint8_t node, const bus::Sample& s, uint32_t missing, uint64_t rx_us);
  // Places `est` on its patch's link: the contact in the link's frame; *link the robot link
  // (-1: the link frame is the base frame).
  void place(const PatchEntry& e, const ContactEstimate& est, const Model& m, uint32_t flags,
             PatchContact* out, int* link);
  // `c` (in the frame of `link`) into the base frame with the pose at `time_us`; false when no
  // pose can be had.
  bool to_base(int link, uint64_t time_us, PatchContact* c);
  // The positions at `time_us` (cached per time) into q_at; ORs the kinematics flags into
  // *flags.
  const std::vector<double>& pose_at(uint64_t time_us, uint32_t* flags);
  // A queued sample superseded by the lag bound at host time `now_us`.
  void late(const Pending& p, uint64_t now_us, double us_per_sample);
  // Keeps the samples of m.slots that one run can publish within max_lag_us of their time, when
  // the host clock is known; the others are superseded as late.
  void admit(Model& m, uint64_t now_us);
};

Aggregator::Aggregator(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
Aggregator::~Aggregator() = default;

Result<std::unique_ptr<Aggregator>> Aggregator::create(const body_map::SkinMap* map,
                                                       const std::string& map_dir,
                                                       const body_map::RobotModel* robot,
                                                       std::vector<std::string> bus_names,
                                                       const AggregatorOptions& options) {
  if (map == nullptr) return make_error(ErrorCode::kInvalidArgument, "aggregator: no skin map");
  if (bus_names.empty() || bus_names.size() > static_cast<std::size_t>(kMaxBuses)) {
    return make_error(ErrorCode::kInvalidArgument, "aggregator: 1 to " + std::to_string(kMaxBuses) +
                                                       " buses, not " +
                                                       std::to_string(bus_names.size()));
  }
  if (Status st = check_options(options.tracker); !st.ok()) return st.error();
  if (Status st = check_runtime_options(options.runtime); !st.ok()) {
    return make_error(st.error().code, "aggregator options: runtime: " + st.error().message);
  }
  const CommonModeOptions& cm = options.common_mode;
  if (!(cm.quiet_fraction > 0 && cm.quiet_fraction <= 1) || cm.min_sensors < 1 ||
      options.registry.stale_us == 0 || options.registry.offline_us < options.registry.stale_us ||
      options.contact_hold_us == 0 || !(options.ambient_flag_ut > 0)) {
    return make_error(ErrorCode::kInvalidArgument,
                      "aggregator options: common-mode quiet fraction in (0, 1] and min sensors "
                      ">= 1, 0 < stale <= offline time, a contact hold > 0, an ambient flag level "
                      "> 0");
  }
  if (options.joint_history.capacity < 2 || options.joint_history.capacity > (1u << 20) ||
      options.model_delay_us > 1'000'000 || options.lag_quiet_us == 0) {
    return make_error(ErrorCode::kInvalidArgument,
                      "aggregator options: a joint history of 2 to 2^20 entries, a model delay "
                      "of at most 1 s, a lag quiet time > 0");
  }
  auto impl = std::make_unique<Impl>(map, bus_names, options);
  impl->robot = robot;
  impl->reassemblers.reserve(bus_names.size());
  for (std::size_t b = 0; b < bus_names.size(); ++b)
    impl->reassemblers.emplace_back(options.reassembly);
  impl->pending.resize(bus_names.size() * 128);
  impl->bad_reported.assign(bus_names.size(), 0);
  impl->no_estimate_run.assign(bus_names.size() * 128, 0);
  impl->current.resize(bus_names.size() * 128);
  impl->pending_list.reserve(impl->pending.size());
  impl->current_list.reserve(impl->current.size());
  if (robot != nullptr) {
    const std::size_t joints = static_cast<std::size_t>(robot->joint_count());
    std::vector<bool> wrapping(joints, false);  // continuous joints
    for (const body_map::PatchPlacement& p : map->patches) {
      impl->link_of_placement.push_back(robot->find_link(p.link));
    }
    for (int l = 0; l < robot->link_count(); ++l) {
      const body_map::LinkJoint& lj = robot->link(l).joint;
      const int j =
          lj.type == body_map::JointType::kContinuous ? robot->find_joint(lj.joint_name) : -1;
      if (j >= 0) wrapping[static_cast<std::size_t>(j)] = true;
    }
    impl->history.emplace(joints, std::move(wrapping), options.joint_history);
    impl->q_new.assign(joints, 0.0);
    impl->q_at.assign(joints, 0.0);
    impl->q_zero.assign(joints, 0.0);
  }

  // One runtime per distinct model file; the patches that share a file share its batch.
  std::map<std::string, int> by_path;
  std::vector<int> model_of(map->patches.size(), -1);
  std::vector<std::pair<std::string, std::string>> failures;
  for (std::size_t i = 0; i < map->patches.size(); ++i) {
    const std::string& name = map->patches[i].model;
    if (name.empty()) continue;
    const std::string key = model_stem(beside_map(map_dir, name));
    auto it = by_path.find(key);
    if (it != by_path.end()) {
      model_of[i] = it->second;
      continue;
    }
    int index = -1;
    auto mf = read_model(key);
    if (mf) {
      auto rt = NetworkRuntime::create(*mf, options.runtime);
      if (rt && rt->channels() == kChannels) {
        Impl::Model m;
        m.path = key;
        m.runtime = std::make_unique<NetworkRuntime>(std::move(*rt));
        m.errors = error_table(mf->meta);
        index = static_cast<int>(impl->models.size());
        impl->models.push_back(std::move(m));
      } else {
        failures.emplace_back(key, rt ? "the model takes " + std::to_string(rt->channels()) +
                                            " channels, a patch sends " + std::to_string(kChannels)
                                      : rt.error().to_string());
      }
    } else {
      failures.emplace_back(key, mf.error().to_string());
    }
    by_path[key] = index;
    model_of[i] = index;
  }
  impl->registry.set_models(model_of);
  for (const auto& [path, why] : failures) {
    impl->registry.add_event(PatchEventKind::kNoModel, 0, "model " + path + ": " + why);
  }
  // The physics refiners of the entries that name a unit.
  impl->refiners.resize(map->patches.size());
  impl->refiner_memories.resize(map->patches.size());
  if (options.refiner_factory) {
    for (std::size_t i = 0; i < map->patches.size(); ++i) {
      const body_map::PatchPlacement& pl = map->patches[i];
      if (pl.unit.empty()) continue;
      RefinerRequest request;
      request.unit_path = beside_map(map_dir, pl.unit);
      request.design_path = pl.design.empty() ? std::string() : beside_map(map_dir, pl.design);
      request.fit_shear = pl.refine_shear;
      request.max_contacts = pl.max_contacts;
      request.proposer_path =
          pl.proposer.empty() ? std::string() : beside_map(map_dir, pl.proposer);
      request.correction_path =
          pl.correction.empty() ? std::string() : beside_map(map_dir, pl.correction);
      auto r = options.refiner_factory(request);
      if (r.ok() && (*r)->channel_count() != kChannels) {
        r = make_error(ErrorCode::kInvalidArgument,
                       "its design has " + std::to_string((*r)->channel_count() / 3) +
                           " sensors, a patch on the bus sends " + std::to_string(kChannels / 3) +
                           " (docs/protocol.md)");
      }
      if (r.ok()) {
        impl->refiners[i] = std::move(*r);
        impl->refiner_memories[i] = impl->refiners[i]->make_memory();
      } else {
        // The unit is named once: by the factory's message when it names the file (as
        // make_physics_refiner's do), else here.
        const std::string& why = r.error().message;
        const std::string unit = why.find(request.unit_path) == std::string::npos
                                     ? "unit " + pl.unit + ": "
                                     : std::string();
        impl->registry.add_event(PatchEventKind::kNoModel, 0,
                                 "node " + std::to_string(pl.node_id) + ": " + unit + why +
                                     " (its contacts are the network's, unrefined)");
      }
    }
  }
  return std::unique_ptr<Aggregator>(new Aggregator(std::move(impl)));
}

bool refinement_accepted(const estimators::RefinedEstimate& r,
                         const estimators::ContactEstimate* network, const AggregatorOptions& o) {
  const uint32_t bad = kEstimateNoContact | estimators::kEstimateNotConverged;
  return r.contact.valid() && (r.contact.flags & bad) == 0 &&
         r.reduced_chi2 <= o.refine_max_reduced_chi2 &&
         (network == nullptr || r.reduced_chi2 <= o.refine_trusted_chi2 ||
          std::hypot(r.contact.u_mm - network->u_mm, r.contact.v_mm - network->v_mm) <=
              o.refine_max_shift_mm);
}

bool channels_left_out(estimators::RejectReason reason) {
  using estimators::RejectReason;
  return reason == RejectReason::kDead || reason == RejectReason::kSaturated ||
         reason == RejectReason::kNonFinite;
}

std::optional<estimators::RefinedEstimate> refine_without_network(
    const estimators::ContactRefiner& refiner, std::span<const double> field_ut,
    std::span<const uint8_t> channel_ok, const estimators::ContactEstimate* start,
    const AggregatorOptions& o) {
  estimators::ContactEstimate held;  // what the search may leave out: the failed fit's basin
  held.flags = estimators::kEstimateRejected;
  if (start != nullptr) {
    const estimators::RefinedEstimate r = refiner.refine(field_ut, channel_ok, *start);
    if (refinement_accepted(r, nullptr, o)) return r;
    if (r.contact.valid()) held = r.contact;
    held.flags |= estimators::kEstimateRejected;
  }
  const estimators::RefinedEstimate r = refiner.search(field_ut, channel_ok, held);
  if (refinement_accepted(r, nullptr, o)) return r;
  return std::nullopt;
}

void Aggregator::on_frame(int bus, const bus::CanFrame& frame, uint64_t rx_us) {
  Impl& s = *impl_;
  if (bus < 0 || bus >= static_cast<int>(s.reassemblers.size())) return;
  ++s.stats.frames;
  if (s.options.tap != nullptr) s.options.tap->frame(bus, frame, rx_us);
  const bus::FeedResult r = s.reassemblers[static_cast<std::size_t>(bus)].feed(frame, rx_us);
  if (r.status != bus::FeedStatus::kMessage) return;
  const bus::Message& m = *r.message;
  switch (m.message_class()) {
    case bus::MessageClass::kHeartbeat:
      s.registry.on_heartbeat(bus, m.node, std::get<bus::Heartbeat>(m.body), rx_us);
      break;
    case bus::MessageClass::kSample:
      s.on_sample(bus, m.node, std::get<bus::Sample>(m.body), r.missing_before, rx_us);
      break;
    case bus::MessageClass::kAck:
    case bus::MessageClass::kInfo:
      s.registry.on_traffic(bus, m.node, rx_us);
      break;
    case bus::MessageClass::kSync:
    case bus::MessageClass::kCommand:
      break;  // the host's own (or another host's) frames
  }
}

void Aggregator::Impl::on_sample(int bus, uint8_t node, const bus::Sample& smp, uint32_t missing,
                                 uint64_t rx_us) {
  ++stats.samples;
  PatchEntry* e = registry.on_sample(bus, node, smp, missing, rx_us);
  if (e == nullptr) {
    ++stats.unattributed;
    return;
  }
  if (options.tap != nullptr) {
    auto host = e->clock.to_host_us(smp.timestamp_us);
    options.tap->sample(*e, smp, rx_us, host ? *host : rx_us);
  }
  const std::size_t k = slot(bus, node);
  if ((smp.flags & bus::sample_flags::kContact) == 0) {
    ++stats.idle_samples;
    // The press is over (event-mode tail, or a stream-mode idle sample).
    if (current[k].used) {
      current[k].used = false;
      current[k].refine = {};
      current_list.erase(std::find(current_list.begin(), current_list.end(), k));
      released = true;
    }
    if (pending[k].used) {  // a contact sample queued before this release: drop it
      pending[k].used = false;
      pending_list.erase(std::find(pending_list.begin(), pending_list.end(), k));
    }
    return;
  }
  if ((smp.flags & bus::sample_flags::kTared) == 0 ||
      (smp.flags & bus::sample_flags::kTareActive) != 0) {
    ++stats.untared_samples;
    return;
  }
  if (e->model_index < 0) {
    ++stats.unattributed;
    return;
  }
  Pending& p = pending[k];
  if (p.used) {
    ++stats.superseded;
  } else {
    p.used = true;
    pending_list.push_back(k);
  }
  p.entry = e;
  p.rx_us = rx_us;
  p.placement = e->placement;
  p.model_index = e->model_index;
  auto host = e->clock.to_host_us(smp.timestamp_us);
  p.time_us = host ? *host : rx_us;
  for (int c = 0; c < kChannels; ++c) {
    const int sensor = c / 3;
    const bool bad =
        ((smp.fault_mask >> sensor) & 1u) != 0 || ((smp.saturation_mask >> sensor) & 1u) != 0;
    p.field[static_cast<std::size_t>(c)] =
        smp.field_lsb[static_cast<std::size_t>(c)] * bus::kFieldUtPerLsb;
    p.ok[static_cast<std::size_t>(c)] = bad ? 0 : 1;
  }
}

const std::vector<double>& Aggregator::Impl::pose_at(uint64_t time_us, uint32_t* flags) {
  if (history->empty()) {
    *flags |= kContactNoKinematics;
    return q_zero;
  }
  if (!q_at_valid || q_at_us != time_us) {
    q_at_coverage = history->pose_at(time_us, q_at);
    q_at_us = time_us;
    q_at_valid = true;
  }
  if (q_at_coverage == JointHistory::Coverage::kOutside) {
    *flags |= kContactStaleKinematics;  // the nearest state: not the pose at the sample's time
    ++stats.kinematics_uncovered;
  }
  return q_at;
}

void Aggregator::Impl::place(const PatchEntry& e, const ContactEstimate& est, const Model& m,
                             uint32_t flags, PatchContact* out, int* link) {
  const body_map::PatchPlacement& pl = *e.placement;
  // The contact point on the undeformed skin surface; depth is reported alongside.
  const body_map::SurfacePoint sp = body_map::link_surface_point(pl, est.u_mm, est.v_mm, 0.0);
  *link = -1;
  if (robot != nullptr) {
    *link = link_of_placement[static_cast<std::size_t>(&pl - map->patches.data())];
    // The link is not in the robot: its frame taken as the base.
    if (*link < 0) flags |= kContactUnmapped;
  }
  // The shear (0 unless a refinement fitted it) along the surface's tangents.
  const Eigen::Vector3d shear = sp.tangent_u * est.shear_u_n + sp.tangent_v * est.shear_v_n;
  for (int i = 0; i < 3; ++i) {
    out->position_mm[i] = sp.point_mm[i];
    out->normal[i] = sp.normal[i];
    out->shear_n[i] = shear[i];
  }
  out->shear_uncertainty_n = 0;
  out->depth_mm = est.depth_mm;
  out->force_n = est.force_n;
  out->u_mm = est.u_mm;
  out->v_mm = est.v_mm;
  out->uncertainty_mm = m.errors.at(est.depth_mm);
  out->node = e.node;
  out->hardware_uid = e.hardware_uid != 0 ? e.hardware_uid : pl.hardware_uid;
  out->link = pl.link;
  out->flags = flags;
}

bool Aggregator::Impl::to_base(int link, uint64_t time_us, PatchContact* c) {
  if (link < 0) return true;
  // The link's pose at that time.
  auto pose = robot->link_pose(pose_at(time_us, &c->flags), link);
  if (!pose) return false;  // cannot happen with finite positions: never a guessed place
  const Eigen::Vector3d p =
      pose->apply(Eigen::Vector3d(c->position_mm[0], c->position_mm[1], c->position_mm[2]));
  const Eigen::Vector3d n =
      pose->rotation * Eigen::Vector3d(c->normal[0], c->normal[1], c->normal[2]);
  const Eigen::Vector3d s =
      pose->rotation * Eigen::Vector3d(c->shear_n[0], c->shear_n[1], c->shear_n[2]);
  for (int i = 0; i < 3; ++i) {
    c->position_mm[i] = p[i];
    c->normal[i] = n[i];
    c->shear_n[i] = s[i];
  }
  return true;
}

void Aggregator::Impl::late(const Pending& p, uint64_t now_us, double us_per_sample) {
  ++stats.late_superseded;
  const uint64_t age_us = now_us > p.time_us ? now_us - p.time_us : 0;
  lag_last_late_us = now_us;
  lag_worst_us = std::max(lag_worst_us, age_us);
  ++lag_count;
  if (lag_episode) return;
  lag_episode = true;
  lag_episode_start_us = now_us;
  char buf[320];
  const bool never = us_per_sample > static_cast<double>(options.max_lag_us);
  std::snprintf(buf, sizeof buf,
                "the host fell behind: samples that cannot be published within %.0f ms of their "
                "time are superseded, not estimated (this one %.1f ms old; model runs take %.2f ms "
                "a sample%s)",
                static_cast<double>(options.max_lag_us) * 1e-3, static_cast<double>(age_us) * 1e-3,
                us_per_sample * 1e-3,
                never ? ", more than the bound: one sample a run, published late" : "");
  registry.add_event(PatchEventKind::kHostLagging, now_us, buf);
}

void Aggregator::Impl::admit(Model& m, uint64_t now_us) {
  if (options.max_lag_us == 0 || !options.clock_us || m.slots.empty()) return;
  const uint64_t t = std::max(now_us, options.clock_us());
  // Served in turn: slot order, starting where the last cost-limited admission stopped.
  std::sort(m.slots.begin(), m.slots.end());
  const auto first = std::lower_bound(m.slots.begin(), m.slots.end(), next_first_slot);
  std::rotate(m.slots.begin(), first, m.slots.end());
  std::size_t admitted = 0;
  uint64_t deadline = UINT64_MAX;  // the earliest deadline of the admitted samples
  m.refused.clear();
  for (std::size_t i = 0; i < m.slots.size(); ++i) {
    const std::size_t k = m.slots[i];
    const uint64_t own = pending[k].time_us + options.max_lag_us;
    const double end = static_cast<double>(t) + m.us_per_sample * static_cast<double>(admitted + 1);
    if (end > static_cast<double>(std::min(deadline, own))) {
      m.refused.push_back(k);
      continue;
    }
    deadline = std::min(deadline, own);
    m.slots[admitted++] = k;
  }
  if (admitted == 0) {
    // Not even one estimate fits (the model takes longer than the bound): the first sample
    // still in time, in turn, is estimated anyway. Contacts keep coming, late by about one
    // estimate; the bound cannot be met on this CPU, and the places are still right.
    for (std::size_t i = 0; i < m.refused.size(); ++i) {
      if (t <= pending[m.refused[i]].time_us + options.max_lag_us) {
        m.slots[admitted++] = m.refused[i];
        m.refused.erase(m.refused.begin() + static_cast<std::ptrdiff_t>(i));
        break;
      }
    }
  }
  for (std::size_t k : m.refused) late(pending[k], t, m.us_per_sample);
  if (!m.refused.empty() && admitted > 0) next_first_slot = m.slots[admitted - 1] + 1;
  m.slots.resize(admitted);
}

void Aggregator::set_joint_state(std::span<const std::string> names,
                                 std::span<const double> positions, uint64_t stamp_us,
                                 bool prismatic_in_metres) {
  Impl& s = *impl_;
  if (!s.history) return;  // no robot
  const body_map::PrismaticUnit unit = prismatic_in_metres ? body_map::PrismaticUnit::kMetres
                                                           : body_map::PrismaticUnit::kMillimetres;
  if (!s.joint_map.same_source(names, unit)) {
    s.joint_map = body_map::JointMap(*s.robot, names, unit);
    s.stats.unknown_joints += static_cast<uint64_t>(s.joint_map.unknown_count());
  }
  // The newest state (the zero pose before the first) with this state's joints set.
  const std::span<const double> newest = s.history->newest();
  if (newest.empty()) {
    std::fill(s.q_new.begin(), s.q_new.end(), 0.0);
  } else {
    std::copy(newest.begin(), newest.end(), s.q_new.begin());
  }
  const bool mapped = s.joint_map.apply(positions, s.q_new) > 0;
  if (!mapped) return;  // nothing this robot knows: still no kinematics (or the last known)
  if (s.history->add(stamp_us, s.q_new) == JointHistory::AddResult::kOutOfOrder) {
    ++s.stats.joint_states_out_of_order;
    return;
  }
  s.q_at_valid = false;
  if (s.options.tap != nullptr) s.options.tap->joint_state(s.q_new, stamp_us);
  if (s.joints_stale_reported) {
    s.joints_stale_reported = false;
    s.registry.add_event(PatchEventKind::kKinematicsFresh, stamp_us, "joint states resumed");
  }
}

bool Aggregator::process(uint64_t now_us, ContactArray* out) {
  Impl& s = *impl_;
  // Contacts whose patch went quiet without a release sample (lost frames, a vanished patch).
  for (std::size_t i = 0; i < s.current_list.size();) {
    const std::size_t k = s.current_list[i];
    if (now_us > s.current[k].last_us + s.options.contact_hold_us) {
      s.current[k].used = false;
      s.current[k].refine = {};
      s.current_list[i] = s.current_list.back();
      s.current_list.pop_back();
      s.released = true;
    } else {
      ++i;
    }
  }
  s.processed_rx.clear();
  if (s.pending_list.empty() && !s.released) return false;
  double refine_spent_us = 0;  // this call's refinement time (options.refine_budget_us)
  bool changed = s.released;   // a contact ended, or (below) one was placed

  // Sort the queued samples per model; those already older than the lag bound go.
  for (Impl::Model& m : s.models) m.slots.clear();
  for (std::size_t k : s.pending_list) {
    Impl::Pending& p = s.pending[k];
    const PatchEntry& e = *p.entry;
    if (!s.registry.attributable(e) || e.model_index < 0 || e.placement != p.placement ||
        e.model_index != p.model_index) {
      ++s.stats.unattributed;  // re-identified since it was queued
      continue;
    }
    Impl::Model& m = s.models[static_cast<std::size_t>(e.model_index)];
    if (s.options.max_lag_us > 0 && now_us > p.time_us + s.options.max_lag_us) {
      s.late(p, now_us, m.us_per_sample);
      continue;
    }
    m.slots.push_back(k);
  }
  for (Impl::Model& m : s.models) {
    s.admit(m, now_us);  // with the host clock: what this run can still publish in time
    const int batch = static_cast<int>(m.slots.size());
    if (batch == 0) continue;
    m.fields.clear();
    m.ok.clear();
    for (std::size_t k : m.slots) {
      const Impl::Pending& p = s.pending[k];
      m.fields.insert(m.fields.end(), p.field.begin(), p.field.end());
      m.ok.insert(m.ok.end(), p.ok.begin(), p.ok.end());
    }
    // Common-mode rejection, per sample, before the network.
    std::vector<uint32_t>& amb_flags = m.ambient_flags;
    amb_flags.assign(m.slots.size(), 0);
    for (int b = 0; b < batch; ++b) {
      std::span<double> f(m.fields.data() + static_cast<std::size_t>(b) * kChannels, kChannels);
      std::span<const uint8_t> ok(m.ok.data() + static_cast<std::size_t>(b) * kChannels, kChannels);
      const CommonModeEstimate cm = estimate_common_mode(f, ok, s.options.common_mode);
      remove_common_mode(f, cm);
      if (cm.valid && cm.magnitude_ut() > s.options.ambient_flag_ut) {
        amb_flags[static_cast<std::size_t>(b)] = kContactAmbientLarge;
      }
    }
    m.out.resize(m.slots.size());
    const auto run_start = std::chrono::steady_clock::now();
    const bool ran = m.runtime->run(m.fields, batch, m.out, m.ok).ok();
    if (s.options.model_delay_us > 0) {  // test aid: a slower CPU
      const auto until = std::chrono::steady_clock::now() +
                         std::chrono::microseconds(s.options.model_delay_us * batch);
      while (std::chrono::steady_clock::now() < until) {
      }
    }
    // The cost per sample: up at once, down slowly (a cost under-estimated breaks the bound).
    const double cost =
        std::chrono::duration<double, std::micro>(std::chrono::steady_clock::now() - run_start)
            .count() /
        batch;
    m.us_per_sample = cost > m.us_per_sample ? cost : 0.8 * m.us_per_sample + 0.2 * cost;
    if (!ran) continue;
    ++s.stats.model_runs;
    s.stats.estimated += static_cast<uint64_t>(batch);
    for (int b = 0; b < batch; ++b) {
      const std::size_t k = m.slots[static_cast<std::size_t>(b)];
      ContactEstimate est = m.out[static_cast<std::size_t>(b)];
      Impl::Pending& p = s.pending[k];
      s.processed_rx.push_back(p.rx_us);
      const std::size_t entry = p.placement != nullptr
                                    ? static_cast<std::size_t>(p.placement - s.map->patches.data())
                                    : 0;
      const estimators::ContactRefiner* refiner =
          p.placement != nullptr ? s.refiners[entry].get() : nullptr;
      estimators::ContactRefiner::Memory* refiner_memory =
          p.placement != nullptr ? s.refiner_memories[entry].get() : nullptr;
      Impl::Current& prev = s.current[k];
      Impl::RefineMemory& mem = prev.refine;
      const std::size_t row = static_cast<std::size_t>(b) * kChannels;
      const std::span<const double> field(m.fields.data() + row, kChannels);
      const std::span<const uint8_t> field_ok(m.ok.data() + row, kChannels);
      int count = 1;
      ContactEstimate ests[kMaxContacts] = {est};
      double refined_sigma_mm[kMaxContacts], refined_sigma_shear_n[kMaxContacts];
      std::fill_n(refined_sigma_mm, kMaxContacts, std::numeric_limits<double>::quiet_NaN());
      std::fill_n(refined_sigma_shear_n, kMaxContacts, std::numeric_limits<double>::quiet_NaN());
      // A refined fit published: its contacts, and what the patch's next sample starts from.
      auto take_refined = [&](const estimators::RefinedContacts& rc) {
        const int found = std::clamp(rc.count, 1, kMaxContacts);
        count = found;
        for (int j = 0; j < found; ++j) {
          ests[j] = rc.contacts[j].contact;
          refined_sigma_mm[j] = rc.contacts[j].sigma_uv_mm;
          refined_sigma_shear_n[j] = rc.contacts[j].sigma_shear_n;
        }
        ++s.stats.refined;
        if (found >= 2) ++s.stats.refined_pairs;
        if (found == 3) ++s.stats.refined_triples;
        // What the next sample starts from: the presses when several (kept over unrefined
        // samples until a refined one finds a single press), the single contact's shear.
        mem.held = found >= 2 ? found : 0;
        for (int j = 0; j < found; ++j) mem.previous[j] = ests[j];
        const bool shear = found == 1 && std::isfinite(refined_sigma_shear_n[0]);
        mem.shear_u_n = shear ? ests[0].shear_u_n : 0.0;
        mem.shear_v_n = shear ? ests[0].shear_v_n : 0.0;
        // A single press's depth along its press (a creeping unit's lag undone); the fit's
        // depth stays the next warm start.
        mem.bend_mm = found == 1 ? ests[0].depth_mm : std::numeric_limits<double>::quiet_NaN();
        if (found == 1) {
          ests[0].depth_mm = refiner->press_depth_mm(ests[0], static_cast<double>(p.time_us) * 1e-6,
                                                     prev.used, refiner_memory);
        }
      };
      // Warm start (options.refine_warm_start_mm > 0): the patch's previous refined contact (the
      // same press, moved little in one period: a press ends with a sample without contact), its
      // depth the bend the creep left, its shear. False, `start` untouched, on a press's first
      // sample or after an unrefined one.
      const auto warm_start = [&](ContactEstimate* start) {
        const PatchContact& last = prev.contacts[0];
        if (!(s.options.refine_warm_start_mm > 0) || !prev.used ||
            (last.flags & kContactUnrefined) != 0) {
          return false;
        }
        start->u_mm = last.u_mm;
        start->v_mm = last.v_mm;
        start->depth_mm = std::isfinite(mem.bend_mm) ? mem.bend_mm : last.depth_mm;
        start->shear_u_n = mem.shear_u_n;  // patch frame; 0 without a fitted shear
        start->shear_v_n = mem.shear_v_n;
        return true;
      };
      // A patch whose sensor is dead, stuck or saturated gives samples the network cannot read;
      // with a refiner they are fitted on the channels left (from the press's previous refined
      // contact, else from the refiner's own starts), within the call's budget, and published
      // flagged kContactMaskedChannels. Without one, or with no fit accepted, they are rejected.
      bool without_network = false;
      if (!est.valid() && refiner != nullptr && channels_left_out(est.reason) &&
          refine_spent_us < static_cast<double>(s.options.refine_budget_us)) {
        const auto t0 = std::chrono::steady_clock::now();
        ContactEstimate start;
        const bool warm = prev.count == 1 && warm_start(&start);
        const std::optional<estimators::RefinedEstimate> r =
            refine_without_network(*refiner, field, field_ok, warm ? &start : nullptr, s.options);
        const double us =
            std::chrono::duration<double, std::micro>(std::chrono::steady_clock::now() - t0)
                .count();
        refine_spent_us += us;
        s.stats.refine_us += us;
        if (r) {
          estimators::RefinedContacts rc;
          rc.count = 1;
          rc.contacts[0] = *r;
          take_refined(rc);
          ests[0].flags |= estimators::kEstimateMasked;
          ++s.stats.refined_without_network;
          without_network = true;
        }
      }
      if (!est.valid() && !without_network) {
        ++s.stats.rejected;
        s.estimate_outcome(p, reject_reason_name(est.reason), now_us);
        continue;
      }
      if ((est.flags & kEstimateNoContact) != 0) {
        ++s.stats.no_contact;
        continue;
      }
      uint32_t flags = amb_flags[static_cast<std::size_t>(b)];
      // Physics refinement of the network's answer, within the call's budget: one contact, or
      // with the entry's max_contacts 2 or 3, up to that many.
      if (refiner != nullptr && !without_network) {
        if (refine_spent_us >= static_cast<double>(s.options.refine_budget_us)) {
          flags |= kContactUnrefined;
          ++s.stats.unrefined_budget;
        } else {
          const auto t0 = std::chrono::steady_clock::now();
          // Warm start (warm_start) whatever the network says (a network trained on another
          // design can be centimetres off for a whole press); else the network's answer. A
          // previous pair is tried again first. A single warm fit the host's rule rejects is
          // made again from the network's answer when that is refine_warm_start_mm or more away
          // and the budget is not spent.
          ContactEstimate start = est;
          const bool warm = warm_start(&start);
          if (warm) ++s.stats.refine_warm_starts;
          // A search for a second press from nothing: the first time this press's single fit
          // leaves more than noise, then when that fit gets 1.5x worse than at the last search
          // (a finger added), or every kSearchEverySamples samples; and on every sample whose
          // single fit could not be published anyway (above refine_max_reduced_chi2: the last
          // search missed a pair that is there; the budget bounds the cost).
          constexpr int kSearchEverySamples = 10;
          const bool last_unusable = mem.searched_chi2 > s.options.refine_max_reduced_chi2;
          const double search_above =
              !mem.searched || mem.since_search >= kSearchEverySamples || last_unusable
                  ? 0.0
                  : 1.5 * mem.searched_chi2;
          auto refine_from = [&](const ContactEstimate& from) {
            return refiner->refine_contacts(
                field, field_ok, from,
                std::span<const ContactEstimate>(mem.previous, static_cast<std::size_t>(mem.held)),
                search_above, refiner_memory);
          };
          auto accepted = [&](const estimators::RefinedContacts& r) {
            const int n = std::clamp(r.count, 1, kMaxContacts);
            bool all = true;
            for (int j = 0; j < n; ++j) {
              all = all && refinement_accepted(r.contacts[j], n == 1 ? &est : nullptr, s.options);
            }
            return all;
          };
          auto elapsed_us = [&t0] {
            return std::chrono::duration<double, std::micro>(std::chrono::steady_clock::now() - t0)
                .count();
          };
          // The search and proposer bookkeeping of each call made.
          bool searched = false;
          auto note = [&](const estimators::RefinedContacts& r) {
            if (r.proposed) ++s.stats.proposed;
            if (r.searched) {
              searched = true;
              mem.searched_chi2 = r.single_reduced_chi2;
            }
          };
          estimators::RefinedContacts rc = refine_from(start);
          note(rc);
          bool ok = accepted(rc);
          if (!ok && warm && rc.count <= 1 && mem.held < 2 &&
              std::hypot(start.u_mm - est.u_mm, start.v_mm - est.v_mm) >=
                  s.options.refine_warm_start_mm &&
              refine_spent_us + elapsed_us() < static_cast<double>(s.options.refine_budget_us)) {
            ++s.stats.refine_restarts;
            estimators::RefinedContacts again = refine_from(est);
            note(again);
            if (accepted(again)) {
              rc = again;
              ok = true;
            }
          }
          // The basin check of a deepening single press (refine_basin_check_mm), at each doubling
          // of its depth: a press 4 mm deep is checked at most three times. Checking at each
          // 1.5-fold cost more and, on one 9 x 9 unit, sent presses to the other minimum about as
          // often as it found them (skinbus-bench refine --design).
          // A press less than half as deep as at its last check (lifted, or another press that
          // came down within the hold) is checked anew from check_mm.
          const double check_mm = s.options.refine_basin_check_mm;
          const estimators::RefinedEstimate single = rc.contacts[0];
          if (single.contact.valid() && single.contact.depth_mm < 0.5 * mem.checked_depth_mm) {
            mem.checked_depth_mm = 0;
          }
          if (check_mm > 0 && rc.count <= 1 && single.contact.valid() &&
              single.contact.depth_mm >= check_mm &&
              single.contact.depth_mm >= 2 * mem.checked_depth_mm &&
              refine_spent_us + elapsed_us() < static_cast<double>(s.options.refine_budget_us)) {
            ++s.stats.refine_basin_checks;
            // An accepted warm fit stands for its basin: the search looks elsewhere.
            estimators::ContactEstimate held = single.contact;
            if (!ok) held.flags |= estimators::kEstimateRejected;
            const estimators::RefinedEstimate other = refiner->search(field, field_ok, held);
            if (refinement_accepted(other, &est, s.options) &&
                (!ok || other.reduced_chi2 < single.reduced_chi2)) {
              const double moved_mm = std::hypot(other.contact.u_mm - single.contact.u_mm,
                                                 other.contact.v_mm - single.contact.v_mm);
              if (!ok || moved_mm >= 1.0) ++s.stats.refine_basin_moves;
              rc = estimators::RefinedContacts{};
              rc.contacts[0] = other;
              ok = true;
            }
            // The warm fit's depth, not the search's when it replaced it: measured better on
            // the 9 x 9 units (1.00-1.42x the bound at 1-2 mm against 1.10-1.73x).
            mem.checked_depth_mm = single.contact.depth_mm;
          }
          if (searched) {
            mem.searched = true;
            mem.since_search = 0;
          } else {
            ++mem.since_search;
          }
          const double us = elapsed_us();
          refine_spent_us += us;
          s.stats.refine_us += us;
          if (ok) {
            take_refined(rc);
          } else {
            flags |= kContactUnrefined;
            ++s.stats.unrefined_poor_fit;
          }
        }
      }
      // Several presses held and this sample unrefined: the network's one answer would sit
      // between them. Late, not wrong: they stay as last refined (at their own time) and nothing
      // is published for this sample; the hold (contact_hold_us) bounds how long.
      if ((flags & kContactUnrefined) != 0 && mem.held >= 2 && prev.used && prev.count >= 2) {
        ++s.stats.held_pairs;
        s.estimate_outcome(p, nullptr, now_us);
        continue;
      }
      // Each contact placed aside (a bad estimate never erases a held one); a place that is not
      // finite, or farther than any robot reaches (an absurd estimate or placement), is no
      // contact: counted, and the patch degraded with the reason if it lasts.
      int link = -1;
      bool finite = true;
      for (int j = 0; j < count; ++j) {
        const ContactEstimate& e = ests[j];
        uint32_t f = flags;
        if (e.flags & kEstimateOutsidePatch) f |= kContactOutsidePatch;
        if (e.flags & kEstimateDepthRange) f |= kContactDepthRange;
        if (e.flags & kEstimateMasked) f |= kContactMaskedChannels;
        if (e.flags & estimators::kEstimateExtrapolated) f |= kContactExtrapolated;
        PatchContact& placed = s.placed[j];
        s.place(*p.entry, e, m, f, &placed, &link);
        if (std::isfinite(refined_sigma_mm[j])) placed.uncertainty_mm = refined_sigma_mm[j];
        if (std::isfinite(refined_sigma_shear_n[j])) {  // the fit had the shear
          placed.flags |= kContactShear;
          placed.shear_uncertainty_n = refined_sigma_shear_n[j];
        }
        for (int i = 0; i < 3; ++i) {
          finite = finite && std::isfinite(placed.normal[i]) &&
                   std::fabs(placed.position_mm[i]) <= kMaxContactMagnitude;
        }
        for (double v : {e.u_mm, e.v_mm, e.depth_mm, placed.shear_n[0], placed.shear_n[1],
                         placed.shear_n[2], placed.shear_uncertainty_n}) {
          finite = finite && std::fabs(v) <= kMaxContactMagnitude;
        }
      }
      if (!finite) {
        ++s.stats.rejected;
        s.estimate_outcome(p, "estimates placed beyond any robot (non-finite or over 1 km)",
                           now_us);
        continue;
      }
      s.estimate_outcome(p, nullptr, now_us);
      Impl::Current& c = s.current[k];
      std::copy(s.placed, s.placed + count, c.contacts);
      c.count = count;
      c.link = link;
      ++p.entry->contacts;
      changed = true;
      c.time_us = p.time_us;
      c.last_us = now_us;
      if (!c.used) {
        c.used = true;
        s.current_list.push_back(k);
      }
    }
  }
  for (std::size_t k : s.pending_list) s.pending[k].used = false;
  s.pending_list.clear();
  s.released = false;
  if (!changed) return false;  // only rejected, late or dropped samples: nothing to publish

  // Every patch's current contact in the base frame at one instant, the newest sample time (a
  // held contact, the press still on its patch, goes with its limb to where it is then); then
  // merge and track.
  s.scratch_contacts.clear();
  uint64_t stamp = 0;
  std::sort(s.current_list.begin(), s.current_list.end());
  for (std::size_t k : s.current_list) stamp = std::max(stamp, s.current[k].time_us);
  if (stamp == 0) stamp = now_us;
  for (std::size_t k : s.current_list) {
    const Impl::Current& cur = s.current[k];
    for (int j = 0; j < cur.count; ++j) {
      PatchContact& c = s.scratch_contacts.emplace_back(cur.contacts[j]);
      if (!s.to_base(cur.link, stamp, &c)) s.scratch_contacts.pop_back();
    }
  }
  out->stamp_us = stamp;
  out->base_frame = s.options.base_frame;
  out->contacts.clear();
  s.tracker.update(stamp, s.scratch_contacts, &out->contacts);
  ++s.stats.publications;
  return true;
}

void Aggregator::tick(uint64_t now_us) {
  Impl& s = *impl_;
  s.registry.tick(now_us);
  for (std::size_t b = 0; b < s.reassemblers.size(); ++b) {
    bus::Reassembler& r = s.reassemblers[b];
    r.expire(now_us);
    // Frames the bus layer refused since the last tick, as one event per bus.
    const bus::ReassemblyStats& st = r.stats();
    const uint64_t bad = st.rejected + st.integrity_failures + st.conflicts + st.stale_parts;
    if (bad > s.bad_reported[b]) {
      char buf[200];
      std::snprintf(buf, sizeof buf,
                    "%llu bad frame(s) since the last report (totals: rejected %llu, failed CRC "
                    "or values %llu, conflicting parts %llu, stale parts %llu)",
                    static_cast<unsigned long long>(bad - s.bad_reported[b]),
                    static_cast<unsigned long long>(st.rejected),
                    static_cast<unsigned long long>(st.integrity_failures),
                    static_cast<unsigned long long>(st.conflicts),
                    static_cast<unsigned long long>(st.stale_parts));
      s.registry.add_event(PatchEventKind::kBadFrames, now_us, buf, static_cast<int>(b));
      s.bad_reported[b] = bad;
    }
  }
  if (s.history && !s.history->empty() && !s.joints_stale_reported &&
      now_us > s.history->newest_us() + s.options.kinematics_stale_us) {
    s.joints_stale_reported = true;
    char buf[160];
    std::snprintf(buf, sizeof buf,
                  "joint states stopped %.2f s ago: contacts after them use the last known pose "
                  "(flagged)",
                  static_cast<double>(now_us - s.history->newest_us()) * 1e-6);
    s.registry.add_event(PatchEventKind::kKinematicsStale, now_us, buf);
  }
  if (s.lag_episode && now_us > s.lag_last_late_us + s.options.lag_quiet_us) {
    char buf[200];
    std::snprintf(buf, sizeof buf,
                  "the host caught up: %llu sample(s) superseded over %.2f s, the oldest %.1f ms "
                  "old",
                  static_cast<unsigned long long>(s.lag_count),
                  static_cast<double>(s.lag_last_late_us - s.lag_episode_start_us) * 1e-6,
                  static_cast<double>(s.lag_worst_us) * 1e-3);
    s.registry.add_event(PatchEventKind::kHostCaughtUp, now_us, buf);
    s.lag_episode = false;
    s.lag_count = 0;
    s.lag_worst_us = 0;
  }
}

void Aggregator::status(uint64_t now_us, PatchStatusArray* out) {
  Impl& s = *impl_;
  out->stamp_us = now_us;
  out->patches.clear();
  out->events.clear();
  s.registry.status(&out->patches);
  s.registry.take_events(&out->events);
}

void Aggregator::add_event(PatchEventKind kind, uint64_t now_us, std::string detail, int bus) {
  impl_->registry.add_event(kind, now_us, std::move(detail), bus);
}

const AggregatorStats& Aggregator::stats() const {
  return impl_->stats;
}

bus::ReassemblyStats Aggregator::reassembly_stats() const {
  bus::ReassemblyStats sum;
  for (const bus::Reassembler& r : impl_->reassemblers) sum += r.stats();
  return sum;
}

const PatchRegistry& Aggregator::registry() const {
  return impl_->registry;
}

std::span<const uint64_t> Aggregator::processed_rx_us() const {
  return impl_->processed_rx;
}

std::vector<std::string> Aggregator::model_descriptions() const {
  std::vector<std::string> out;
  for (const Impl::Model& m : impl_->models) {
    out.push_back(m.path + " (" + m.runtime->kernel_name() + ")");
  }
  return out;
}

}  // namespace skinbus::host
