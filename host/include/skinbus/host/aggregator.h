// skinbus/host/aggregator.h: many patches in, body-frame contacts out.
//
// The host aggregator's pipeline, without its inputs and outputs (host_loop.h drives it from
// SocketCAN, candump logs or a live pipe at the host's cadence; skinbus-host's sinks publish on
// DDS and as JSON lines):
//
//   frames --on_frame()--> reassembly (one bus::Reassembler per bus)
//          --> registry (patch_registry.h: discovery, states, reboots, duplicate IDs, clocks)
//          --> samples flagged `contact` are queued, newest per patch; all others end here
//   process() --> the lag bound (samples too old to publish in time are superseded)
//          --> common-mode (ambient) rejection (ambient.h) --> the per-patch models, one
//          batched run per model file over every patch with a queued sample (network_runtime.h)
//          --> patch (u, v, depth) -> surface point and normal on the patch's geometry -> the
//          patch's link (skin map) -> the base frame (forward kinematics at the pose of the
//          sample's time, from the joint-state history)
//          --> merge across patches and track (contact_tracker.h) --> ContactArray
//
// Skip what a scene does not need: an idle patch costs its heartbeat once a second (event
// mode), or in stream mode the reassembly of its samples and a flag test; it never reaches a
// model. process() costs O(patches with a queued sample + contacts), not O(patches).
//
// Time: `rx_us` / `now_us` are host times (CLOCK_REALTIME microseconds, as SocketCAN stamps
// frames; replayed logs use their own stamps). A contact's time is its sample's patch timestamp
// mapped to host time by the patch's clock aligner (clock_alignment.h; offset-only until its
// window spans 2 s), or the receive time where the aligner gives no mapping.
//
// Kinematics: set_joint_state() gives joint positions by name, stamped with the time they were
// measured (any subset of the robot's movable joints; joints a state leaves out keep their
// previous value; unknown names are counted and ignored). The states are kept in a joint-state
// history (joint_history.h; `joint_history`: 512 entries by default, 5 s of a 100 Hz stream), and
// every contact is placed with the pose at its own sample's time: interpolated between the two
// states around it, or extrapolated from the newest two when the sample is at most
// `joint_history.extrapolation_us` (50 ms) newer than the newest state (or older than the
// oldest). A sample the history does not cover (the joint states stopped, or began after it) is
// placed with the nearest state and flagged kContactStaleKinematics, never silently with the pose
// of another time. A joint state stamped before the newest one is ignored (counted). Before the
// first joint state contacts use the zero pose, flagged kContactNoKinematics. When the newest
// state is older than `kinematics_stale_us` a kKinematicsStale event is queued once (tick()), and
// kKinematicsFresh when states resume. Without a robot model, link frames are taken as the base
// frame. A publication is one instant: its stamp is the newest sample time among its contacts,
// and every contact in it is placed with the pose at that stamp (a contact held from an older
// sample, the press still on its patch, goes with its limb). Forward kinematics runs per
// published contact, along its link's chain only.
//
// Lag: falling behind may cost latency, never correctness. A queued sample whose time is more
// than `max_lag_us` (100 ms) before process()'s `now_us` is superseded: not estimated, counted
// (late_superseded). Given `clock_us` (the host clock of now_us), process() also bounds the time
// its own model runs take: it measures each model's cost per sample and, before a run, supersedes
// the samples that could not be published within max_lag_us of their time (it takes them in turn
// across calls, so every patch is served when not all fit). When a single estimate takes longer
// than the bound, the bound cannot be met: each run then takes the first sample still in time,
// in turn, and publishes it late by about one estimate. The first late sample of an episode
// queues a kHostLagging event (status topic and log); tick() queues kHostCaughtUp with the count
// once none has been late for `lag_quiet_us`. Every contact that is published is still placed
// with the robot's pose at its publication's stamp, a sample time, never at the time the host
// got to it.
//
// Nothing here throws; no NaN or Inf leaves: non-finite estimates are rejections, counted.
// Not thread-safe: one thread feeds, processes and reads.
#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "skinbus/body_map/robot_model.h"
#include "skinbus/body_map/skin_map.h"
#include "skinbus/bus/can_frame.h"
#include "skinbus/bus/reassembler.h"
#include "skinbus/common/result.h"
#include "skinbus/estimators/network_runtime.h"
#include "skinbus/estimators/refiner.h"
#include "skinbus/host/ambient.h"
#include "skinbus/host/contact_tracker.h"
#include "skinbus/host/contacts.h"
#include "skinbus/host/joint_history.h"
#include "skinbus/host/patch_registry.h"

namespace skinbus::host {

// What the aggregator takes in, for a recorder (record/recorder.h writes it to an MCAP file).
// Every call is on the thread that feeds the aggregator, inside on_frame() or
// set_joint_state(); the arguments are valid for the call only. A tap must not call back into
// the aggregator.
class InputTap {
 public:
  virtual ~InputTap() = default;
  // Every frame fed, received on bus `bus` at host time `rx_us`.
  virtual void frame(int bus, const bus::CanFrame& frame, uint64_t rx_us) = 0;
  // Every complete sample the registry attributed to a patch (pressed or idle, tared or not):
  // received at `rx_us`, taken at host time `time_us` (the patch clock mapped by its aligner;
  // rx_us where the aligner gives no mapping yet).
  virtual void sample(const PatchEntry& patch, const bus::Sample& sample, uint64_t rx_us,
                      uint64_t time_us) = 0;
  // The robot's pose after each joint state the history took: every joint of the robot model
  // (RobotModel order and units: rad, prismatic joints in mm) at `stamp_us`.
  virtual void joint_state(std::span<const double> q, uint64_t stamp_us) = 0;
};

// What a skin-map entry asks of its refiner (AggregatorOptions::refiner_factory).
struct RefinerRequest {
  std::string unit_path;    // the unit file, resolved against the map's folder
  std::string design_path;  // the design file, resolved; "" when the entry names none
  // PatchPlacement::refine_shear: also fit the shear force (the refiner fills
  // RefinedEstimate::sigma_shear_n and its contact's shear, published with kContactShear).
  bool fit_shear = false;
  // PatchPlacement::max_contacts: 2 or 3 to find that many presses on the patch
  // (ContactRefiner::refine_contacts; each published with its own track).
  int max_contacts = 1;
  // PatchPlacement::proposer, resolved: the proposer network the count starts from; "" none.
  std::string proposer_path;
  // PatchPlacement::correction, resolved: the unit's learned correction file; "" none.
  std::string correction_path;
};

struct AggregatorOptions {
  RegistryOptions registry;
  TrackerOptions tracker;
  CommonModeOptions common_mode;       // method kNone turns the rejection off
  estimators::RuntimeOptions runtime;  // backend, precision, threads of every model's runtime
  bus::Reassembler::Config reassembly;
  // The joint-state history: its capacity (entries) and how far past its ends a pose is
  // extrapolated before a contact is flagged kContactStaleKinematics.
  JointHistoryOptions joint_history;
  uint64_t kinematics_stale_us = 250'000;  // newest joint state older than this: an event
  // A patch's contact is kept this long after its last contact sample (a lost frame does not
  // end a press); a sample without the contact flag ends it at once.
  uint64_t contact_hold_us = 75'000;
  double ambient_flag_ut = 120;  // a common-mode change larger than this flags the contact
  std::string base_frame = "base_link";
  // The lag bound (above): samples older than this when process() would estimate them are
  // superseded. 0: no bound (every queued sample is estimated, however late).
  uint64_t max_lag_us = 100'000;
  // The host clock now_us comes from (e.g. bus::realtime_now_us), read around model runs so that
  // the bound also covers the runs' own time. Empty: only now_us is used (a log replayed as fast
  // as possible, whose time does not move with the host's work).
  std::function<uint64_t()> clock_us;
  // A lag episode ends (kHostCaughtUp) after this long without a late sample.
  uint64_t lag_quiet_us = 1'000'000;
  // Test aid, 0 in use: every model run busy-waits this long per sample after computing, as a
  // CPU this much slower per estimate would (tests of the lag bound). At most 1 s.
  uint64_t model_delay_us = 0;
  // Sees every input (above); borrowed, must outlive the aggregator. Null: none (no cost).
  InputTap* tap = nullptr;
  // Physics refinement: for each skin-map entry that names a unit (PatchPlacement::unit), the
  // refiner this makes of it (RefinerRequest). skinbus-host passes
  // estimators::make_physics_refiner. Empty: no refinement. A unit that cannot be made into a
  // refiner leaves its patch on the network's answers (an event says why).
  std::function<Result<std::unique_ptr<estimators::ContactRefiner>>(const RefinerRequest&)>
      refiner_factory;
  // Host time (steady clock) process() may spend refining, per call. A sample beyond it is
  // published with the network's answer, flagged kContactUnrefined (never late).
  uint64_t refine_budget_us = 8000;
  // A refinement starts from the same patch's previous refined contact while the press lasts
  // (it moves little in one sample period), whatever the network's answer; from the network's
  // answer on a press's first sample and after an unrefined one. When the host's rule below
  // rejects a single warm fit and the network's answer is at least this far from its start, the
  // sample is refined again from the network's answer if the budget is not spent
  // (AggregatorStats::refine_restarts): the distance at which a restart can find another place.
  // 0: no warm starts (always from the network's answer).
  double refine_warm_start_mm = 3.0;
  // A press refined warm from its own previous contact can stay for its whole hold in another
  // minimum of the fit, which its shallow first samples could not tell from the press (a 9 x 9
  // one-polarity design: 10-20 mm off at 1-1.5 mm deep). So the first time a single refined
  // press is at least this deep, and again each time it is twice as deep as at its last check,
  // the sample is also searched from the refiner's own starts (ContactRefiner::search) if the
  // budget is not spent, and the search's contact published instead when the host's rule accepts
  // it and it explains the sample better (AggregatorStats::refine_basin_checks, _moves). A press
  // less than half as deep as at its last check is checked anew. Cost: a search (several
  // refinements) on about one sample in fifteen (docs/benchmarks/refinement.md). 0: no checks.
  double refine_basin_check_mm = 1.0;
  // A refined contact is published when its fit converged, found a contact, explains the sample
  // to at most this reduced chi-square (noise units; its uncertainty is widened by the square root
  // above 1) and lies within `refine_max_shift_mm` of the network's answer, or explains the
  // sample to the noise (reduced chi-square at most `refine_trusted_chi2`) wherever it lies;
  // else the network's answer is, flagged kContactUnrefined. A real unit has physics its
  // identified model lacks: a fit several times the noise can still place the press far better
  // than the network (a simulated patch through the emulated chips: reduced chi-square 4-10 and
  // 0.05 mm), while a fit that wandered to another minimum moves far from the network's answer
  // and does not reach the noise. A press the network was not trained for (a strong shear
  // force) can put the network's answer 5 mm or more off while the fit reaches the noise.
  double refine_max_reduced_chi2 = 25;
  double refine_max_shift_mm = 5;
  double refine_trusted_chi2 = 2;
};

// Whether the host publishes a refined contact instead of the network's answer `network`
// (AggregatorOptions::refine_max_reduced_chi2, refine_trusted_chi2, refine_max_shift_mm): the
// fit converged, found a contact, explains the sample well enough and lies near the network's
// answer or fits to the noise. `network` null: no distance to it is asked (a contact of a pair,
// which the network's single answer does not describe). The distance is to the network's answer
// even for a warm start: a warm fit near its start could stay in a wrong basin for a whole press
// (a 9 x 9 one-polarity design refined from a network trained on another: 20 mm off at 1-3 mm
// deep, reduced chi-square 2-3).
bool refinement_accepted(const estimators::RefinedEstimate& refined,
                         const estimators::ContactEstimate* network, const AggregatorOptions& o);

// Whether the network's rejection `reason` is of channels left out (a dead or stuck sensor the
// patch node flags, a saturated one, a value that is not finite), which a refiner fits without:
// the physics model leaves a channel out of the fit where a network cannot.
bool channels_left_out(estimators::RejectReason reason);

// The contact of a sample the network could not read because channels were left out
// (channels_left_out), fitted by `refiner` on the channels left (`channel_ok`: 0 for those left
// out, empty: the non-finite ones): from `start` when given (the press's previous refined
// contact), and when that fit is not accepted, from the refiner's own starts
// (ContactRefiner::search). Accepted by refinement_accepted with no network answer to stay near.
// Its contact is flagged kEstimateMasked. Empty when no fit is accepted. Cost: one refine(),
// or that and a search (several).
std::optional<estimators::RefinedEstimate> refine_without_network(
    const estimators::ContactRefiner& refiner, std::span<const double> field_ut,
    std::span<const uint8_t> channel_ok, const estimators::ContactEstimate* start,
    const AggregatorOptions& o);

struct AggregatorStats {
  uint64_t frames = 0;
  uint64_t samples = 0;          // complete samples received
  uint64_t idle_samples = 0;     // without the contact flag: no model run
  uint64_t untared_samples = 0;  // contact flag but no baseline (kTared clear): skipped
  uint64_t unattributed = 0;     // dropped by the registry (duplicate ID, unknown node)
  uint64_t superseded = 0;       // a newer sample of the same patch arrived before process()
  uint64_t late_superseded = 0;  // too old to estimate within max_lag_us (the host fell behind)
  uint64_t estimated = 0;        // samples run through a model
  uint64_t rejected = 0;         // estimates the model rejected (dead, saturated, ...)
  uint64_t no_contact = 0;       // estimates placed outside the patch or without depth
  uint64_t model_runs = 0;       // batched runs
  uint64_t unknown_joints = 0;   // joint names neither a joint nor a mimic joint of the robot
  uint64_t joint_states_out_of_order = 0;  // stamped before the newest joint state: ignored
  // Contacts published with a pose the joint-state history did not cover (flagged), counted per
  // publication.
  uint64_t kinematics_uncovered = 0;
  uint64_t publications = 0;  // ContactArrays produced by process()
  // Physics refinement: estimates refined; published unrefined because the period's budget was
  // spent, or because the fit was poor (or failed); the time spent refining (us).
  uint64_t refined = 0, unrefined_budget = 0, unrefined_poor_fit = 0;
  // Of the refined, samples the network could not read for channels left out (a dead, stuck or
  // saturated sensor), fitted on the channels left (refine_without_network); the samples with
  // such channels that no fit explained go to `rejected`, as without a refiner.
  uint64_t refined_without_network = 0;
  uint64_t refine_warm_starts = 0;  // refinements started from the previous refined contact
  uint64_t refine_restarts = 0;     // of those, rejected and refined again from the network's
  // Searches of a deepening press for another minimum (refine_basin_check_mm), and of those the
  // ones whose contact replaced the fit 1 mm or more away from it, or replaced a fit the host's
  // rule rejected.
  uint64_t refine_basin_checks = 0, refine_basin_moves = 0;
  uint64_t refined_pairs = 0;    // refined samples that held two or more presses (max_contacts 2-3)
  uint64_t refined_triples = 0;  // of those, the ones that held three (max_contacts 3)
  uint64_t proposed = 0;  // counts started from a proposer's presses (PatchPlacement::proposer)
  // Samples of a patch holding several presses that went unrefined (budget, poor fit): not
  // published, since the network's single answer would be one contact between the presses; they
  // stay as last refined, at their own time, until a sample is refined or contact_hold_us runs
  // out.
  uint64_t held_pairs = 0;
  double refine_us = 0;
};

class Aggregator {
 public:
  // `map` (required) and `robot` (may be null) must outlive the aggregator. Model files named by
  // the map are read relative to `map_dir`; a model that cannot be read leaves its patches
  // without one (degraded, an event says why), it is not an error. `bus_names`: one per bus
  // (1..kMaxBuses); frames are fed with the bus index. Errors: kInvalidArgument for bad options
  // or a bus count out of range.
  static Result<std::unique_ptr<Aggregator>> create(const body_map::SkinMap* map,
                                                    const std::string& map_dir,
                                                    const body_map::RobotModel* robot,
                                                    std::vector<std::string> bus_names,
                                                    const AggregatorOptions& options = {});
  ~Aggregator();

  // One frame of bus `bus` received at host time `rx_us`. O(1) unless it completes a message.
  void on_frame(int bus, const bus::CanFrame& frame, uint64_t rx_us);

  // Joint positions by name, measured at host time `stamp_us` (the state's own stamp, not when it
  // arrived): radians for revolute joints; prismatic joints in millimetres (as RobotModel) or,
  // with `prismatic_in_metres` (ROS 2 JointState), metres; names as body_map::JointMap maps them
  // (mimic joints follow their leader, unknown names are counted). Feed states in stamp order; one
  // older than the newest is ignored (counted), one with the same stamp merges into it. O(names +
  // joints); allocates only when the list of names changes.
  void set_joint_state(std::span<const std::string> names, std::span<const double> positions,
                       uint64_t stamp_us, bool prismatic_in_metres = false);

  // Estimates every queued sample (but those the lag bound supersedes), places each at its own
  // sample time, merges and tracks. Returns true and fills `out` when the contact set changed
  // (new estimates, or contacts that ended); false otherwise. Costs one batched model run per
  // model file with queued samples, plus O(joints + chain length) per placed contact.
  bool process(uint64_t now_us, ContactArray* out);

  // Registry timers (stale, offline), kinematics staleness and the end of a lag episode; call
  // about every 100 ms.
  void tick(uint64_t now_us);

  // The status of every patch and the events since the last call.
  void status(uint64_t now_us, PatchStatusArray* out);

  // Host events (an interface went down, ...), reported with the patches' own.
  void add_event(PatchEventKind kind, uint64_t now_us, std::string detail, int bus = -1);

  const AggregatorStats& stats() const;
  bus::ReassemblyStats reassembly_stats() const;  // summed over buses
  const PatchRegistry& registry() const;
  // The receive times of the samples the last process() estimated (for latency statistics).
  std::span<const uint64_t> processed_rx_us() const;
  // Models loaded (file, runtime kernel) for logs.
  std::vector<std::string> model_descriptions() const;

  struct Impl;

 private:
  explicit Aggregator(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

}  // namespace skinbus::host
