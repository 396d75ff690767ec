// skinbus-host: the host aggregator daemon. Reads patches' frames from SocketCAN interfaces or
// candump logs, estimates contacts with each patch's model, places them on the robot and
// publishes them on DDS (rt/skin/contacts, rt/skin/patch_status) and/or as JSON lines.
//
//   skinbus-host --map skin.yaml -i can0 -i can1
//   skinbus-host --map skin.yaml --replay bus.log --fast --json --no-dds
//   candump -L can0 | skinbus-host --map skin.yaml --replay - --json
//
// This file parses the options and builds the aggregator, its sinks (JSON lines, DDS, the log)
// and joint input; the loop itself (inputs, pacing, cadence) is host::HostLoop (host_loop.h).
#include <CLI/CLI.hpp>

#include <cinttypes>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <span>
#include <stdexcept>
#include <string>
#include <vector>

#include "skinbus/body_map/joint_trajectory.h"
#include "skinbus/body_map/robot_model.h"
#include "skinbus/body_map/skin_map.h"
#include "skinbus/bus/socketcan.h"
#include "skinbus/estimators/physics_refiner.h"
#include "skinbus/host/aggregator.h"
#include "skinbus/host/contacts_json.h"
#include "skinbus/host/host_loop.h"
#include "skinbus/record/recorder.h"
#ifdef SKINBUS_HAVE_DDS
#include "skinbus/dds/dds.h"
#endif
#include "tool_util.h"

using namespace skinbus;

namespace {

struct HostArgs {
  std::string map_path, robot_path;
  std::vector<std::string> interfaces;
  std::string replay;
  bool fast = false;
  bool live = false;  // --replay is a live pipe
  bool live_and_replay = false;
  std::string joints = "auto";  // auto | dds | none | FILE
  bool json = false, json_status = false, dds = true;
  int domain = -1;
  std::string ns;
  double duration_s = 0;
  double status_period_s = 1.0;
  std::string backend = "auto", precision = "float32", convolution = "auto", isa = "avx512";
  std::string ambient = "quiet-mean";
  int threads = 1;
  int spin_us = estimators::RuntimeOptions{}.spin_us;
  bool stats = false, quiet = false;
  std::string base_frame;  // empty: the robot's root link (base_link without a robot)
  double max_lag_ms = 100;
  int model_delay_us = 0;
  bool allow_no_models = false;
  double max_gap_s = 10;
  std::string record;  // an MCAP file to record the session into
  bool record_samples = true, record_frames = true;
  bool refine = true;
  int refine_budget_us = 8000;
  double refine_basin_check_mm = host::AggregatorOptions{}.refine_basin_check_mm;
};

// The loop's sink: JSON lines on stdout, DDS, events and the log on stderr, latency statistics.
class Outputs : public host::HostSink {
 public:
  explicit Outputs(const HostArgs& a)
      : json_(a.json), json_status_(a.json_status), quiet_(a.quiet), stats_(a.stats) {
#ifdef SKINBUS_HAVE_DDS
    if (a.dds) {
      dds::DdsOptions o;
      if (a.domain >= 0) o.domain_id = static_cast<uint32_t>(a.domain);
      if (Status st = dds::apply_namespace(&o, a.ns); !st.ok()) {
        throw std::invalid_argument(st.error().message);
      }
      auto p = dds::SkinPublisher::create(o);
      if (!p) throw std::runtime_error(p.error().to_string());
      pub_ = std::move(*p);
    }
#else
    if (a.dds)
      throw std::runtime_error("this build has no DDS (Cyclone DDS not found): use --no-dds");
#endif
  }
  // JSON lines are flushed one by one and checked: a reader gone (`| head`) ends the host at
  // once and quietly, a failed write (a full disk) with a message and status 1.
  void contacts(const host::ContactArray& c, std::span<const uint64_t> estimated_rx_us) override {
    if (recorder != nullptr) recorder->contacts(c);
    if (json_) {
      std::fputs(host::contacts_to_json(c).c_str(), stdout);
      std::fputc('\n', stdout);
      tools::check_stdout("skinbus-host", /*flush=*/true);
    }
#ifdef SKINBUS_HAVE_DDS
    if (pub_) {
      Status st = pub_->publish(c);
      if (!st.ok())
        std::fprintf(stderr, "skinbus-host: publish: %s\n", st.error().to_string().c_str());
    }
#endif
    if (stats_ && !estimated_rx_us.empty()) {
      const uint64_t done = bus::realtime_now_us();
      for (uint64_t rx : estimated_rx_us) {
        latency_us.add(static_cast<double>(done > rx ? done - rx : 0));
      }
    }
  }
  void status(const host::PatchStatusArray& s) override {
    if (recorder != nullptr) recorder->status(s);
    if (!quiet_) {
      for (const host::PatchEvent& e : s.events) {
        const bool loud = e.kind == host::PatchEventKind::kDuplicateId;
        std::fprintf(stderr, "skinbus-host: %s%s: %s\n", loud ? "WARNING " : "",
                     std::string(host::patch_event_name(e.kind)).c_str(), e.detail.c_str());
      }
    }
    if (json_status_) {
      std::fputs(host::patch_status_to_json(s).c_str(), stdout);
      std::fputc('\n', stdout);
      tools::check_stdout("skinbus-host", /*flush=*/true);
    }
#ifdef SKINBUS_HAVE_DDS
    if (pub_) {
      Status st = pub_->publish(s);
      if (!st.ok())
        std::fprintf(stderr, "skinbus-host: publish: %s\n", st.error().to_string().c_str());
    }
#endif
  }
  void log(const std::string& line) override {
    std::fprintf(stderr, "skinbus-host: %s\n", line.c_str());
  }

  tools::LatencyHistogram latency_us;    // fixed memory, however long the run
  record::Recorder* recorder = nullptr;  // --record: the session into an MCAP file

 private:
  bool json_, json_status_, quiet_, stats_;
#ifdef SKINBUS_HAVE_DDS
  std::unique_ptr<dds::SkinPublisher> pub_;
#endif
};

#ifdef SKINBUS_HAVE_DDS
// Joint states from DDS (rt/joint_states), each at its header stamp.
class DdsJoints : public host::JointInput {
 public:
  explicit DdsJoints(std::unique_ptr<dds::JointStateSubscriber> sub) : sub_(std::move(sub)) {}
  void update(host::Aggregator& agg, uint64_t /*now_us*/, uint64_t /*run_start_us*/) override {
    if (sub_->take_all(&states_) > 0) {
      for (const dds::JointStateSample& js : states_) {
        agg.set_joint_state(js.names, js.positions, stamp_of(js), /*prismatic_in_metres=*/true);
      }
    }
  }

 private:
  // When the state was measured: its header stamp (the publisher's CLOCK_REALTIME), unless that
  // is implausible for this host's clock (more than kAheadUs after its arrival or kBehindUs
  // before it: clocks not synchronised), then its arrival time, said once on stderr.
  static constexpr uint64_t kAheadUs = 200'000, kBehindUs = 2'000'000;
  uint64_t stamp_of(const dds::JointStateSample& js) {
    const bool plausible = js.stamp_us != 0 && js.stamp_us <= js.received_us + kAheadUs &&
                           js.received_us <= js.stamp_us + kBehindUs;
    if (plausible) return js.stamp_us;
    if (!warned_) {
      warned_ = true;
      std::fprintf(stderr,
                   "skinbus-host: WARNING joint-state stamps are %.3f s from this host's clock: "
                   "using their arrival times instead (synchronise the clocks; contacts of a "
                   "moving robot are then placed with the delivery delay)\n",
                   (static_cast<double>(js.stamp_us) - static_cast<double>(js.received_us)) * 1e-6);
    }
    return js.received_us;
  }
  std::unique_ptr<dds::JointStateSubscriber> sub_;
  std::vector<dds::JointStateSample> states_;
  bool warned_ = false;
};
#endif

// Joint states: a trajectory file (time from the start of the run), DDS, or none (null).
std::unique_ptr<host::JointInput> make_joints(const HostArgs& a,
                                              const body_map::RobotModel* robot) {
  std::string mode = a.joints;
  if (mode == "auto") mode = robot == nullptr ? "none" : (a.dds ? "dds" : "none");
  if (mode == "none") return nullptr;
  if (robot == nullptr) throw std::runtime_error("--joints needs a robot (the map's or --robot)");
  if (mode == "dds") {
#ifdef SKINBUS_HAVE_DDS
    dds::DdsOptions o;
    if (a.domain >= 0) o.domain_id = static_cast<uint32_t>(a.domain);
    auto s = dds::JointStateSubscriber::create(o);
    if (!s) throw std::runtime_error(s.error().to_string());
    return std::make_unique<DdsJoints>(std::move(*s));
#else
    throw std::runtime_error("--joints dds: this build has no DDS");
#endif
  }
  if (mode.ends_with(".mcap")) {  // a recording's joint states, for a replay of its frames
    auto m = record::McapJointInput::load(mode);
    if (!m) throw std::runtime_error("--joints " + mode + ": " + m.error().message);
    return std::move(*m);
  }
  auto t = body_map::load_joint_trajectory(mode);
  if (!t) throw std::runtime_error(t.error().to_string());
  if (Status st = robot->check_joint_names(t->names); !st.ok()) {
    throw std::invalid_argument("--joints " + mode + ": " + st.error().message);
  }
  return std::make_unique<host::TrajectoryJointInput>(std::move(*t));
}

estimators::RuntimeBackend parse_backend(const std::string& s) {
  if (s == "auto") return estimators::RuntimeBackend::kAuto;
  if (s == "kernels") return estimators::RuntimeBackend::kKernels;
  if (s == "portable") return estimators::RuntimeBackend::kPortable;
  if (s == "onednn") return estimators::RuntimeBackend::kOneDnn;
  throw std::invalid_argument("--backend: auto, kernels, portable or onednn");
}

estimators::RuntimeIsa parse_isa(const std::string& s) {
  estimators::RuntimeIsa isa = estimators::RuntimeIsa::kAvx512;
  if (parse_isa(s, &isa)) return isa;
  throw std::invalid_argument("--isa: avx512, avx2, neon or portable");
}

estimators::RuntimePrecision parse_precision(const std::string& s) {
  if (s == "float32") return estimators::RuntimePrecision::kFloat32;
  if (s == "bfloat16") return estimators::RuntimePrecision::kBfloat16;
  if (s == "int8") return estimators::RuntimePrecision::kInt8;
  throw std::invalid_argument("--precision: float32, bfloat16 or int8");
}

estimators::RuntimeConvolution parse_convolution(const std::string& s) {
  if (s == "auto") return estimators::RuntimeConvolution::kAuto;
  if (s == "direct") return estimators::RuntimeConvolution::kDirect;
  if (s == "winograd") return estimators::RuntimeConvolution::kWinograd;
  throw std::invalid_argument("--convolution: auto, direct or winograd");
}

host::CommonModeMethod parse_ambient(const std::string& s) {
  if (s == "none") return host::CommonModeMethod::kNone;
  if (s == "median") return host::CommonModeMethod::kMedian;
  if (s == "quiet-mean") return host::CommonModeMethod::kQuietMean;
  throw std::invalid_argument("--ambient: none, median or quiet-mean");
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{
      "skinbus-host: the host aggregator. Reads the patches' frames from SocketCAN interfaces\n"
      "(-i, several allowed) or from a candump log (--replay, '-' for stdin), keeps a registry of\n"
      "the patches it hears (state, reboots, duplicate node IDs, clock offset and drift), runs\n"
      "each touched patch's model (batched per model file), rejects the common-mode field a\n"
      "moving limb sees, places contacts on the robot through the skin map and forward\n"
      "kinematics, merges presses seen by neighbouring patches and tracks them with stable IDs.\n\n"
      "Outputs: DDS topics rt/skin/contacts and rt/skin/patch_status (ROS 2 compatible,\n"
      "docs/dds.md), and/or JSON lines on stdout (--json, --json-status). Events (patches\n"
      "appearing, going stale, rebooting, duplicate IDs, ...) are logged on stderr.\n\n"
      "Joint states (--joints): 'dds' (rt/joint_states), a trajectory file (CSV: time_s,<joint>,\n"
      "...; docs/aggregator.md), or 'none' (the robot's zero pose). 'auto': dds when DDS output\n"
      "is on and the map names a robot, else none. Every contact is placed with the robot's pose\n"
      "at its own sample's time (from the joint states' stamps), however late it is estimated.\n\n"
      "Falling behind: a sample the host cannot publish within --max-lag-ms of its time is\n"
      "superseded (not estimated); a host_lagging event says so on the status topic and here,\n"
      "host_caught_up when it caught up.\n\n"
      "Examples:\n"
      "  skinbus-host --map skin.yaml -i can0 -i can1\n"
      "  skinbus-host --map skin.yaml --replay bus.log --fast --json --no-dds --stats\n"
      "  candump -L can0 | skinbus-host --map skin.yaml --replay - --live --json --no-dds\n"
      "  skinbus-host --map skin.yaml -i can0 --replay other_limb.log --live-and-replay\n\n"
      "A log's time that goes backwards or jumps ahead is taken in file order and reported\n"
      "(log_time events); frames on interfaces not named with -i are skipped and reported.\n\n"
      "Exit status: 0 done, 1 a device or file failed (or no usable model, or no frame on the\n"
      "named interfaces), 2 bad arguments; ended by SIGPIPE when the reader of its output\n"
      "went away."};
  HostArgs a;
  app.add_option("--map", a.map_path, "skin map (YAML, docs/body_map.md)")->required();
  app.add_option("--robot", a.robot_path, "robot description (URDF); default: the map's");
  app.add_option("-i,--interface", a.interfaces,
                 "SocketCAN interface (repeat for several buses); with --replay: the log's "
                 "interface names, in bus order");
  app.add_option("--replay", a.replay, "candump -L log to replay ('-': stdin)");
  app.add_flag("--fast", a.fast, "--replay: as fast as possible (log time is host time)");
  app.add_flag("--live", a.live,
               "--replay: the log is written as it is read (a pipe from candump -L or from patch "
               "daemons): read it as it comes, on the host's clock, as a CAN interface");
  app.add_flag("--live-and-replay", a.live_and_replay,
               "read the -i interfaces live AND replay --replay at recorded speed on one more "
               "bus (named 'replay')");
  app.add_option("--joints", a.joints,
                 "auto | dds | none | FILE (joint trajectory CSV, or a recording's .mcap: its "
                 "joint states, with its frames replayed)")
      ->capture_default_str();
  app.add_option("--record", a.record,
                 "record the session into this MCAP file (as rosbag2 would: contacts, patch "
                 "status, diagnostics, each patch's tared samples, the CAN frames, joint states; "
                 "the skin map, URDF, design and unit files attached; docs/recording.md)");
  app.add_flag("!--record-no-samples", a.record_samples, "--record: leave out /skin/samples");
  app.add_flag("!--record-no-frames", a.record_frames,
               "--record: leave out /skin/can (the recording can then not be replayed)");
  app.add_flag("--json", a.json, "print contacts as JSON lines on stdout");
  app.add_flag("--json-status", a.json_status, "print patch status as JSON lines on stdout");
  app.add_flag("!--no-dds", a.dds, "do not publish on DDS");
  app.add_option("--domain", a.domain, "DDS domain ID (default: Cyclone DDS's, usually 0)");
  app.add_option("--namespace", a.ns,
                 "publish on rt/NS/skin/contacts and rt/NS/skin/patch_status, for several hosts "
                 "in one domain (docs/guides/scaling.md)");
  app.add_option("--duration", a.duration_s, "stop after this many seconds (0: run to the end)")
      ->capture_default_str();
  app.add_option("--status-period", a.status_period_s, "seconds between patch status messages")
      ->capture_default_str()
      ->check(CLI::Range(0.01, 3600.0));
  app.add_option("--backend", a.backend, "network runtime: auto, kernels, portable, onednn")
      ->capture_default_str();
  app.add_option("--precision", a.precision, "network precision: float32, bfloat16, int8")
      ->capture_default_str();
  app.add_option("--isa", a.isa,
                 "the widest instruction set the kernels may use: avx512 (every one this CPU "
                 "has), avx2, neon, portable; the log names the kernels in use")
      ->capture_default_str();
  app.add_option("--convolution", a.convolution,
                 "CNN convolutions: auto (Winograd for float32 where it computes less), direct, "
                 "winograd")
      ->capture_default_str();
  app.add_option("--threads", a.threads, "threads per model runtime")->capture_default_str();
  app.add_option("--spin-us", a.spin_us,
                 "with --threads > 1: how long the runtime's threads spin for the next batch "
                 "before they sleep, us (a wake-up costs about as much as a few samples; 0 "
                 "saves the CPU time)")
      ->capture_default_str();
  app.add_option("--ambient", a.ambient, "common-mode rejection: quiet-mean, median, none")
      ->capture_default_str();
  app.add_option("--base-frame", a.base_frame,
                 "frame_id of the published contacts (default: the robot's root link, as in its "
                 "URDF and so in ROS 2's TF tree; base_link when the map names no robot)");
  app.add_option("--max-lag-ms", a.max_lag_ms,
                 "the lag bound: a sample that cannot be published within this many ms of its "
                 "time is superseded, not estimated (0: no bound; --fast replays bound by log time "
                 "only)")
      ->capture_default_str();
  app.add_option("--model-delay-us", a.model_delay_us,
                 "test aid: every estimate busy-waits this many us more, as on a slower CPU "
                 "(tests of the lag bound)")
      ->capture_default_str()
      ->group("Testing");
  app.add_option("--max-gap-s", a.max_gap_s,
                 "--replay at recorded speed: a silence in the log longer than this is replayed "
                 "as this long (reported as a log_time event), s")
      ->capture_default_str();
  app.add_flag("!--no-refine", a.refine,
               "do not refine: publish the networks' answers even for patches whose skin-map "
               "entry names an identified unit (physics refinement: docs/aggregator.md)");
  app.add_option("--refine-budget-us", a.refine_budget_us,
                 "host time the physics refinement may take per pipeline run (about one sample "
                 "period); samples beyond it publish the network's answer, flagged unrefined")
      ->capture_default_str()
      ->check(CLI::Range(0, 1'000'000));
  app.add_option("--refine-basin-check-mm", a.refine_basin_check_mm,
                 "search a refined press again from the unit's start table once it is this deep "
                 "and at each doubling of its depth, publishing the search's contact when it "
                 "explains the sample better (a warm start can keep a press in another minimum "
                 "of the fit); 0: never")
      ->capture_default_str()
      ->check(CLI::Range(0.0, 100.0));
  app.add_flag("--allow-no-models", a.allow_no_models,
               "run even when no patch of the map has a usable model (patch status only); "
               "without it that is an error (exit 1)");
  app.add_flag("--stats", a.stats, "print pipeline statistics and latency at the end (stderr)");
  app.add_flag("-q,--quiet", a.quiet, "do not log events");
  CLI11_PARSE(app, argc, argv);
  try {
    if (a.replay.empty() && a.interfaces.empty()) {
      throw std::invalid_argument("give -i INTERFACE (live) or --replay LOG");
    }
    if (!(a.max_lag_ms >= 0 && a.max_lag_ms <= 60'000)) {
      throw std::invalid_argument("--max-lag-ms: 0 (no bound) to 60000");
    }
    if (!(a.max_gap_s >= 0.1 && a.max_gap_s <= 86400)) {
      throw std::invalid_argument("--max-gap-s: 0.1 to 86400");
    }
    if (a.model_delay_us < 0 || a.model_delay_us > 1'000'000) {
      throw std::invalid_argument("--model-delay-us: 0 to 1000000");
    }
    if (a.live && (a.replay.empty() || a.fast || a.live_and_replay)) {
      throw std::invalid_argument("--live: with --replay, without --fast or --live-and-replay");
    }
    host::AggregatorOptions o;
    o.runtime.backend = parse_backend(a.backend);
    o.runtime.precision = parse_precision(a.precision);
    o.runtime.max_isa = parse_isa(a.isa);
    o.runtime.convolution = parse_convolution(a.convolution);
    o.runtime.threads = a.threads;
    o.runtime.spin_us = a.spin_us;
    o.common_mode.method = parse_ambient(a.ambient);
    o.base_frame = a.base_frame;
    o.max_lag_us = static_cast<uint64_t>(std::llround(a.max_lag_ms * 1000));
    o.model_delay_us = static_cast<uint64_t>(a.model_delay_us);
    if (a.refine)
      o.refiner_factory = [](const host::RefinerRequest& r) {
        estimators::RefinerOptions ro;
        ro.physics.fit_shear = r.fit_shear;
        ro.max_contacts = r.max_contacts;
        ro.proposer = r.proposer_path;
        ro.correction = r.correction_path;
        return estimators::make_physics_refiner(r.unit_path, r.design_path, ro);
      };
    o.refine_budget_us = static_cast<uint64_t>(a.refine_budget_us);
    o.refine_basin_check_mm = a.refine_basin_check_mm;
    host::HostLoopOptions lo;
    lo.interfaces = a.interfaces;
    lo.replay = a.replay;
    lo.pace = a.live   ? host::ReplayPace::kLive
              : a.fast ? host::ReplayPace::kFast
                       : host::ReplayPace::kRecorded;
    lo.interfaces_and_replay = a.live_and_replay;
    lo.duration_us = a.duration_s > 0 ? static_cast<uint64_t>(a.duration_s * 1e6) : 0;
    lo.status_period_us = static_cast<uint64_t>(a.status_period_s * 1e6);
    lo.max_gap_us = static_cast<uint64_t>(std::llround(a.max_gap_s * 1e6));
    lo.clock.stop_requested = [] { return tools::stop_requested().load(); };
    // On the host's clock the bound covers the model runs' own time too; a log replayed as fast
    // as possible has only its own time.
    if (host::HostLoop::on_host_clock(lo)) o.clock_us = bus::realtime_now_us;
    auto map = body_map::load_skin_map_file(a.map_path);
    if (!map) {
      return skinbus::tools::fail("skinbus-host", map.error().to_string(), 1);
    }
    const std::string map_dir = std::filesystem::path(a.map_path).parent_path().string();
    const std::string robot_path =
        a.robot_path.empty() ? body_map::path_beside(a.map_path, map->robot) : a.robot_path;
    std::unique_ptr<body_map::RobotModel> robot;
    if (!robot_path.empty()) {
      auto rm = body_map::RobotModel::from_urdf_file(robot_path);
      if (!rm) {
        return skinbus::tools::fail("skinbus-host", rm.error().to_string(), 1);
      }
      robot = std::make_unique<body_map::RobotModel>(std::move(*rm));
      if (Status st = body_map::validate_skin_map(*map, robot.get()); !st.ok()) {
        return skinbus::tools::fail("skinbus-host", st.error().to_string(), 1);
      }
    }
    if (a.base_frame.empty()) o.base_frame = robot ? robot->link(0).name : "base_link";
    std::unique_ptr<record::Recorder> recorder;
    if (!a.record.empty()) {
      record::RecorderOptions ro;
      ro.samples = a.record_samples;
      ro.frames = a.record_frames;
      ro.attachments[std::filesystem::path(a.map_path).filename().string()] = a.map_path;
      if (!robot_path.empty()) {
        ro.attachments[std::filesystem::path(robot_path).filename().string()] = robot_path;
      }
      // The design and unit files the map's entries name (as the refinement reads them), each
      // once, by its file name (the node's number before it when two differ in folder only).
      for (const body_map::PatchPlacement& p : map->patches) {
        for (const std::string& f : {p.design, p.unit}) {
          if (f.empty()) continue;
          const std::string path = body_map::path_beside(a.map_path, f);
          std::string name = std::filesystem::path(path).filename().string();
          auto it = ro.attachments.find(name);
          if (it != ro.attachments.end() && it->second != path) {
            name = "node" + std::to_string(p.node_id) + "_" + name;
          }
          ro.attachments[name] = path;
        }
      }
      std::string models;
      for (const body_map::PatchPlacement& p : map->patches) {
        if (models.find(p.model) == std::string::npos)
          models += (models.empty() ? "" : ", ") + p.model;
      }
      ro.metadata = {{"skin_map", a.map_path},
                     {"robot", robot_path},
                     {"models", models},
                     {"base_frame", o.base_frame},
                     {"runtime", a.backend + " " + a.precision + " " + a.isa},
                     {"input", a.replay.empty() ? "interfaces" : "replay " + a.replay}};
      auto r = record::Recorder::create(a.record, host::HostLoop::bus_names(lo), robot.get(), ro);
      if (!r) return skinbus::tools::fail("skinbus-host", "--record: " + r.error().message, 1);
      recorder = std::move(*r);
      o.tap = recorder.get();
    }
    auto agg =
        host::Aggregator::create(&*map, map_dir, robot.get(), host::HostLoop::bus_names(lo), o);
    if (!agg) {
      return skinbus::tools::fail("skinbus-host", agg.error().to_string(), 2);
    }
    if (!a.quiet) {
      std::fprintf(stderr, "skinbus-host: %zu patches in the map, robot %s, models:\n",
                   map->patches.size(), robot ? robot->name().c_str() : "(none)");
      for (const std::string& m : (*agg)->model_descriptions()) {
        std::fprintf(stderr, "  %s\n", m.c_str());
      }
    }
    Outputs out(a);
    out.recorder = recorder.get();
    const std::unique_ptr<host::JointInput> joints = make_joints(a, robot.get());
    if ((*agg)->model_descriptions().empty() && !a.allow_no_models) {
      host::PatchStatusArray why;
      (*agg)->status(0, &why);
      for (const host::PatchEvent& e : why.events) {
        std::fprintf(stderr, "skinbus-host: %s: %s\n",
                     std::string(host::patch_event_name(e.kind)).c_str(), e.detail.c_str());
      }
      std::fprintf(stderr,
                   "skinbus-host: no patch of %s has a usable model: nothing to estimate "
                   "(--allow-no-models runs anyway, for the patch status only)\n",
                   a.map_path.c_str());
      return 1;
    }
    tools::install_stop_handler();
    host::HostLoop loop(**agg, out, lo, joints.get());
    Status run = loop.run();
    if (recorder) {
      const Status closed = recorder->close();
      const record::RecorderStats rs = recorder->stats();
      if (!a.quiet || !closed.ok()) {
        std::fprintf(
            stderr, "skinbus-host: recorded %" PRIu64 " messages (%.1f MB) into %s%s%s\n",
            rs.messages, static_cast<double>(rs.bytes) / 1e6, a.record.c_str(),
            closed.ok() ? "" : "; stopped: ", closed.ok() ? "" : closed.error().message.c_str());
      }
      if (run.ok() && !closed.ok()) run = closed;
    }
    if (!run.ok()) {
      return skinbus::tools::fail("skinbus-host", run.error().message, 1);
    }
    if (a.stats) {
      const host::AggregatorStats& s = (*agg)->stats();
      const bus::ReassemblyStats rs = (*agg)->reassembly_stats();
      std::fprintf(stderr,
                   "skinbus-host: frames %" PRIu64 " (rejected %" PRIu64 ", integrity %" PRIu64
                   "), samples %" PRIu64 " (idle %" PRIu64 ", untared %" PRIu64
                   ", unattributed %" PRIu64 ", superseded %" PRIu64 ", late %" PRIu64
                   "), estimated %" PRIu64 " in %" PRIu64 " runs (rejected %" PRIu64
                   "), publications %" PRIu64 ", unknown joint names %" PRIu64
                   ", joint states out of order %" PRIu64
                   ", contacts outside the joint states %" PRIu64 "\n",
                   s.frames, rs.rejected, rs.integrity_failures, s.samples, s.idle_samples,
                   s.untared_samples, s.unattributed, s.superseded, s.late_superseded, s.estimated,
                   s.model_runs, s.rejected, s.publications, s.unknown_joints,
                   s.joint_states_out_of_order, s.kinematics_uncovered);
      if (s.refined + s.unrefined_budget + s.unrefined_poor_fit > 0) {
        std::fprintf(
            stderr,
            "skinbus-host: refined %" PRIu64 " (%.0f us each, %" PRIu64
            " from the previous contact, %" PRIu64
            " of those made again from the "
            "network's answer, %" PRIu64 " searched again as the press deepened, %" PRIu64
            " of those moved, %" PRIu64 " with two or more presses, %" PRIu64
            " with three, %" PRIu64 " counted from a proposer, %" PRIu64
            " fitted without the network for a dead or saturated sensor), unrefined %" PRIu64
            " over the budget and %" PRIu64 " poor fits (%" PRIu64
            " of them held several presses unpublished)\n",
            s.refined, s.refined > 0 ? s.refine_us / static_cast<double>(s.refined) : 0.0,
            s.refine_warm_starts, s.refine_restarts, s.refine_basin_checks, s.refine_basin_moves,
            s.refined_pairs, s.refined_triples, s.proposed, s.refined_without_network,
            s.unrefined_budget, s.unrefined_poor_fit, s.held_pairs);
      }
      if (out.latency_us.count() > 0) {
        std::fprintf(stderr,
                     "skinbus-host: latency frame arrival -> publication over %zu samples: "
                     "p50 %.0f us, p99 %.0f us, max %.0f us\n",
                     static_cast<std::size_t>(out.latency_us.count()), out.latency_us.quantile(0.5),
                     out.latency_us.quantile(0.99), out.latency_us.max());
      }
    }
    return 0;
  } catch (const std::invalid_argument& e) {
    return skinbus::tools::fail("skinbus-host", e.what(), 2);
  } catch (const std::exception& e) {
    return skinbus::tools::fail("skinbus-host", e.what(), 1);
  }
}
