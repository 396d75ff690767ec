// skinbus-host: the host aggregator daemon. Reads patches' frames from SocketCAN interfaces or
// candump logs, estimates contacts with each patch's model, places them on the robot and
// publishes them on DDS (rt/skin/contacts, rt/skin/patch_status) and/or as JSON lines.
//
//   skinbus-host --map skin.yaml -i can0 -i can1
//   skinbus-host --map skin.yaml --replay bus.log --fast --json --no-dds
//   candump -L can0 | skinbus-host --map skin.yaml --replay - --json
#include <fcntl.h>
#include <poll.h>
#include <unistd.h>
#include <CLI/CLI.hpp>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cinttypes>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <map>
#include <memory>
#include <span>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include "skinbus/body_map/joint_trajectory.h"
#include "skinbus/body_map/robot_model.h"
#include "skinbus/body_map/skin_map.h"
#include "skinbus/bus/candump.h"
#include "skinbus/bus/socketcan.h"
#include "skinbus/host/aggregator.h"
#include "skinbus/host/contacts_json.h"
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
  std::string base_frame = "base_link";
  double max_lag_ms = 100;
  int model_delay_us = 0;
  bool allow_no_models = false;
  double max_gap_s = 10;
};

// Publication sinks: JSON lines on stdout, DDS.
class Outputs {
 public:
  explicit Outputs(const HostArgs& a) : json_(a.json), json_status_(a.json_status) {
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
  void contacts(const host::ContactArray& c) {
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
  }
  void status(const host::PatchStatusArray& s) {
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

 private:
  bool json_, json_status_;
#ifdef SKINBUS_HAVE_DDS
  std::unique_ptr<dds::SkinPublisher> pub_;
#endif
};

// Joint states: a trajectory file (time from the start of the run), DDS, or none.
class Joints {
 public:
  Joints(const HostArgs& a, const body_map::RobotModel* robot) {
    std::string mode = a.joints;
    if (mode == "auto") mode = robot == nullptr ? "none" : (a.dds ? "dds" : "none");
    if (mode == "none") return;
    if (robot == nullptr) throw std::runtime_error("--joints needs a robot (the map's or --robot)");
    if (mode == "dds") {
#ifdef SKINBUS_HAVE_DDS
      dds::DdsOptions o;
      if (a.domain >= 0) o.domain_id = static_cast<uint32_t>(a.domain);
      auto s = dds::JointStateSubscriber::create(o);
      if (!s) throw std::runtime_error(s.error().to_string());
      sub_ = std::move(*s);
      return;
#else
      throw std::runtime_error("--joints dds: this build has no DDS");
#endif
    }
    auto t = body_map::load_joint_trajectory(mode);
    if (!t) throw std::runtime_error(t.error().to_string());
    if (Status st = robot->check_joint_names(t->names); !st.ok()) {
      throw std::invalid_argument("--joints " + mode + ": " + st.error().message);
    }
    traj_ = std::move(*t);
    have_traj_ = true;
    q_.resize(traj_.names.size());
  }
  // Feeds the aggregator the joint states up to host time `now_us`; `run_start_us` is time zero
  // of a trajectory file. The aggregator keeps them as a history and places each sample at the
  // pose of its own time, so every state counts, stamped with when it was measured.
  void update(host::Aggregator& agg, uint64_t now_us, uint64_t run_start_us) {
    if (have_traj_) {
      // The file's rows since the last call, at their own times (the history then interpolates
      // exactly as the file does), then the pose now, at most every 10 ms (between rows the file
      // is a straight line, which the history extends exactly; the loop may pass far more often).
      const double t_s = static_cast<double>(now_us - run_start_us) * 1e-6;
      for (; next_row_ < traj_.rows() && traj_.t_s[next_row_] < t_s; ++next_row_) {
        const double row_s = traj_.t_s[next_row_];
        if (row_s <= 0) continue;  // before time zero: the first state (below) holds it
        const std::span<const double> row(&traj_.q[next_row_ * traj_.names.size()],
                                          traj_.names.size());
        agg.set_joint_state(traj_.names, row,
                            run_start_us + static_cast<uint64_t>(std::llround(row_s * 1e6)));
      }
      if (last_now_us_ == 0 || now_us >= last_now_us_ + 10'000) {
        traj_.sample(t_s, q_);
        agg.set_joint_state(traj_.names, q_, now_us);
        last_now_us_ = now_us;
      }
    }
#ifdef SKINBUS_HAVE_DDS
    if (sub_ && sub_->take_all(&states_) > 0) {
      for (const dds::JointStateSample& js : states_) {
        agg.set_joint_state(js.names, js.positions, stamp_of(js), /*prismatic_in_metres=*/true);
      }
    }
#endif
  }

 private:
#ifdef SKINBUS_HAVE_DDS
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
#endif
  bool have_traj_ = false;
  body_map::JointTrajectory traj_;
  std::size_t next_row_ = 0;
  uint64_t last_now_us_ = 0;  // when the pose "now" was last fed
  std::vector<double> q_;
#ifdef SKINBUS_HAVE_DDS
  std::unique_ptr<dds::JointStateSubscriber> sub_;
  std::vector<dds::JointStateSample> states_;
  bool warned_ = false;
#endif
};

constexpr uint64_t kFlushUs = 500'000;  // past every hold time: all contacts end

struct Runner {
  Runner(const HostArgs& a, host::Aggregator& g, Outputs& o, Joints& j)
      : args(a), agg(g), out(o), joints(j) {}
  const HostArgs& args;
  host::Aggregator& agg;
  Outputs& out;
  Joints& joints;
  uint64_t run_start_us = 0;
  uint64_t next_status_us = 0, next_tick_us = 0;
  host::ContactArray contacts;
  host::PatchStatusArray status;
  tools::LatencyHistogram latency_us;  // fixed memory, however long the run

  void after_frames(uint64_t now_us, bool measure_latency) {
    joints.update(agg, now_us, run_start_us);
    if (agg.process(now_us, &contacts)) {
      out.contacts(contacts);
      if (measure_latency && args.stats) {
        const uint64_t done = bus::realtime_now_us();
        for (uint64_t rx : agg.processed_rx_us()) {
          latency_us.add(static_cast<double>(done > rx ? done - rx : 0));
        }
      }
    }
    if (now_us >= next_tick_us) {
      agg.tick(now_us);
      next_tick_us = now_us + 100'000;
    }
    if (now_us >= next_status_us) {
      agg.status(now_us, &status);
      print_events();
      out.status(status);
      next_status_us = now_us + static_cast<uint64_t>(args.status_period_s * 1e6);
    }
  }
  // The end of the run at host time `end_us`: held contacts run out (an empty publication) and
  // the final status goes out, without advancing the registry or kinematics timers past the end.
  void finish(uint64_t end_us) {
    joints.update(agg, end_us, run_start_us);
    if (agg.process(end_us, &contacts)) out.contacts(contacts);  // what is still queued
    if (agg.process(end_us + kFlushUs, &contacts)) out.contacts(contacts);
    agg.status(end_us, &status);
    print_events();
    out.status(status);
  }
  void print_events() {
    if (args.quiet) return;
    for (const host::PatchEvent& e : status.events) {
      const bool loud = e.kind == host::PatchEventKind::kDuplicateId;
      std::fprintf(stderr, "skinbus-host: %s%s: %s\n", loud ? "WARNING " : "",
                   std::string(host::patch_event_name(e.kind)).c_str(), e.detail.c_str());
    }
  }
};

// The time of a replayed log, made usable: monotonic in file order (the order frames were
// received in), and without waits nobody would sit through. Every change is reported: a
// kLogTime event on the status topic and a line on stderr (first occurrences), and a summary at
// the end.
//   - A line stamped before an earlier one by up to kRebaseUs (daemons sharing a pipe, a
//     shuffled log) is taken at the time reached so far (its frames are not dropped).
//   - A step back of more than kRebaseUs (the recording host's clock was set back) continues the
//     log's time from where it was: later lines keep their spacing.
//   - With a gap cap (replays at recorded speed), a forward jump of more than max_gap_us (a
//     recording paused, or a damaged stamp years ahead) is replayed as max_gap_us of silence:
//     long enough for every patch to go offline, short enough to be waited for.
class LogClock {
 public:
  static constexpr uint64_t kRebaseUs = 1'000'000;
  LogClock(std::string source, uint64_t max_gap_us)
      : source_(std::move(source)), max_gap_us_(max_gap_us) {}

  // The adjusted time of a line stamped `ts_us` (line number `line`); events go to `agg` at
  // host time `event_us`.
  uint64_t adjust(uint64_t ts_us, uint64_t line, host::Aggregator& agg, uint64_t event_us) {
    ++lines_;
    if (!started_) {
      started_ = true;
      max_ts_ = ts_us;
      last_ = ts_us;
      return ts_us;
    }
    char buf[256];
    if (ts_us < max_ts_) {
      const uint64_t back = max_ts_ - ts_us;
      ++back_lines_;
      max_back_us_ = std::max(max_back_us_, back);
      if (back > kRebaseUs) {
        offset_ = static_cast<int64_t>(last_) - static_cast<int64_t>(ts_us);  // on from last_
        max_ts_ = ts_us;
        ++rebases_;
        std::snprintf(buf, sizeof buf,
                      "%s:%" PRIu64
                      ": the log's time goes back %.3f s (its clock was set back?): "
                      "continued from the time reached",
                      source_.c_str(), line, static_cast<double>(back) * 1e-6);
        report(agg, event_us, buf);
      } else if (back_lines_ == 1) {
        std::snprintf(buf, sizeof buf,
                      "%s:%" PRIu64
                      ": stamped %.3f s before an earlier line: lines out of time "
                      "order are taken in file order (counted; summary at the end)",
                      source_.c_str(), line, static_cast<double>(back) * 1e-6);
        report(agg, event_us, buf);
      }
    } else {
      const uint64_t ahead = ts_us - max_ts_;
      if (max_gap_us_ > 0 && ahead > max_gap_us_) {
        offset_ -= static_cast<int64_t>(ahead - max_gap_us_);
        ++gaps_;
        std::snprintf(buf, sizeof buf,
                      "%s:%" PRIu64
                      ": the log's time jumps %.1f s ahead: replayed as %.0f s of "
                      "silence",
                      source_.c_str(), line, static_cast<double>(ahead) * 1e-6,
                      static_cast<double>(max_gap_us_) * 1e-6);
        report(agg, event_us, buf);
      }
      max_ts_ = ts_us;
    }
    const int64_t t = static_cast<int64_t>(ts_us) + offset_;
    last_ = std::max(last_, t > 0 ? static_cast<uint64_t>(t) : 0);
    return last_;
  }
  // The end of the replay: a summary of what was adjusted (stderr and an event), if anything.
  void summarise(host::Aggregator& agg, uint64_t event_us) {
    char buf[256];
    if (back_lines_ > 0) {
      std::snprintf(buf, sizeof buf,
                    "%s: %" PRIu64 " of %" PRIu64
                    " line(s) stamped before an earlier one (at most "
                    "%.3f s back; %" PRIu64
                    " step(s) of more than %.0f s continued from the time "
                    "reached)",
                    source_.c_str(), back_lines_, lines_, static_cast<double>(max_back_us_) * 1e-6,
                    rebases_, static_cast<double>(kRebaseUs) * 1e-6);
      report(agg, event_us, buf);
    }
    if (gaps_ > 0) {
      std::snprintf(buf, sizeof buf,
                    "%s: %" PRIu64 " silence(s) longer than %.0f s replayed as %.0f s",
                    source_.c_str(), gaps_, static_cast<double>(max_gap_us_) * 1e-6,
                    static_cast<double>(max_gap_us_) * 1e-6);
      report(agg, event_us, buf);
    }
  }
  // Throws when most of the log runs backwards: not a recording in time order (a reversed or
  // shuffled file), whose contacts would come out of order and mostly superseded.
  void check_end() const {
    if (lines_ >= 10 && 2 * back_lines_ > lines_) {
      throw std::runtime_error(source_ + ": " + std::to_string(back_lines_) + " of its " +
                               std::to_string(lines_) +
                               " lines are stamped before an earlier line: the log is not in time "
                               "order (sort it first: sort -s -k1,1 LOG)");
    }
  }

 private:
  void report(host::Aggregator& agg, uint64_t event_us, const std::string& text) {
    agg.add_event(host::PatchEventKind::kLogTime, event_us, text);
  }
  std::string source_;
  uint64_t max_gap_us_;
  bool started_ = false;
  uint64_t max_ts_ = 0;  // the latest stamp of the current timeline
  uint64_t last_ = 0;    // the latest adjusted time given
  int64_t offset_ = 0;
  uint64_t lines_ = 0, back_lines_ = 0, max_back_us_ = 0, rebases_ = 0, gaps_ = 0;
};

// The bus of each interface name of a log: the -i names in order, or (none named) bus 0 for
// every name. Frames of names not given are counted, reported once per name (stderr and a
// kBadFrames event), and at the end a log none of whose frames was on a named interface is an
// error: nothing was read.
class LogInterfaces {
 public:
  static constexpr std::size_t kMaxNamesReported = 16;
  explicit LogInterfaces(const std::vector<std::string>& names) : names_(names) {
    for (std::size_t i = 0; i < names.size(); ++i) bus_of_[names[i]] = static_cast<int>(i);
  }
  // The bus of a frame on `iface`, or -1 (skipped, counted).
  int bus(std::string_view iface, host::Aggregator& agg, uint64_t event_us) {
    ++frames_;
    if (names_.empty()) {
      ++used_;
      return 0;
    }
    if (auto it = bus_of_.find(iface); it != bus_of_.end()) {
      ++used_;
      return it->second;
    }
    ++skipped_;
    if (skipped_names_.size() < kMaxNamesReported &&
        std::find(skipped_names_.begin(), skipped_names_.end(), iface) == skipped_names_.end()) {
      skipped_names_.emplace_back(iface);
      agg.add_event(host::PatchEventKind::kBadFrames, event_us,
                    "frames on interface '" + skipped_names_.back() +
                        "' are skipped: it is not one of the -i names (" + joined() + ")");
    }
    return -1;
  }
  // Throws when frames were read and none was on a named interface.
  void check_end(const std::string& source) const {
    if (frames_ > 0 && used_ == 0) {
      std::string seen;
      for (const std::string& n : skipped_names_) seen += (seen.empty() ? "" : ", ") + n;
      throw std::runtime_error(source + ": none of its " + std::to_string(frames_) +
                               " frames is on an interface named with -i (" + joined() +
                               "); the log has " + seen);
    }
  }
  uint64_t skipped() const { return skipped_; }
  std::string joined() const {
    std::string out;
    for (const std::string& n : names_) out += (out.empty() ? "" : ", ") + n;
    return out;
  }

 private:
  std::vector<std::string> names_;
  std::map<std::string, int, std::less<>> bus_of_;
  std::vector<std::string> skipped_names_;
  uint64_t frames_ = 0, used_ = 0, skipped_ = 0;
};

// A replay at recorded speed replays a silence of the log for at most this long.
uint64_t max_gap_us(const HostArgs& a) {
  return static_cast<uint64_t>(std::llround(a.max_gap_s * 1e6));
}

// Opens the --replay input ('-': stdin); a directory or a missing file throws with its name.
std::FILE* open_replay(const std::string& path) {
  return path == "-" ? stdin : tools::open_input_stream(path, "candump log");
}

// Throws when the read of a log failed (not its end).
void check_read(const bus::CandumpReader& reader, const std::string& source) {
  if (reader.read_error() != 0) {
    throw std::runtime_error(source + ": read failed after line " +
                             std::to_string(reader.line_number()) + ": " +
                             std::strerror(reader.read_error()));
  }
}

int run_replay(const HostArgs& a, Runner& r) {
  std::FILE* f = open_replay(a.replay);
  const std::string source = a.replay == "-" ? "stdin" : a.replay;
  // Waits of at most 100 ms on a quiet pipe: a stop request ends the replay at once.
  bus::CandumpReader reader(f, /*wait_ms=*/100);
  bus::CandumpRecord rec;
  LogInterfaces ifaces(a.interfaces);
  LogClock clock(source, a.fast ? 0 : max_gap_us(a));
  uint64_t log_start_us = 0, wall_start_us = 0, last_process_us = 0, log_us = 0;
  int frames_since_process = 0;
  bool first = true;
  const uint64_t end_log_us = a.duration_s > 0 ? static_cast<uint64_t>(a.duration_s * 1e6) : 0;
  for (;;) {
    if (tools::stop_requested()) break;
    const auto st = reader.next(&rec);
    if (st == bus::CandumpReader::Status::kWait) continue;
    if (st == bus::CandumpReader::Status::kEof) break;
    if (st == bus::CandumpReader::Status::kBadLine) continue;  // counted by the reader
    const uint64_t event_us = a.fast ? log_us : bus::realtime_now_us();
    if (first) {
      log_start_us = clock.adjust(rec.timestamp_us, reader.line_number(), r.agg, event_us);
      log_us = log_start_us;
      wall_start_us = bus::realtime_now_us();
      r.run_start_us = a.fast ? log_start_us : wall_start_us;
      r.next_status_us = r.run_start_us;
      first = false;
    } else {
      log_us = clock.adjust(rec.timestamp_us, reader.line_number(), r.agg, event_us);
    }
    if (end_log_us > 0 && log_us - log_start_us > end_log_us) break;
    const int b = ifaces.bus(rec.iface, r.agg, event_us);
    if (b < 0) continue;
    uint64_t rx_us;
    if (a.fast) {
      rx_us = log_us;
      // Batch what arrived within 1 ms of log time, as a poll loop would (or 64 frames, where the
      // log's time stands still).
      if (rx_us > last_process_us + 1000 || ++frames_since_process >= 64) {
        r.after_frames(rx_us, false);
        last_process_us = rx_us;
        frames_since_process = 0;
      }
    } else {
      const uint64_t due = wall_start_us + (log_us - log_start_us);
      uint64_t now = bus::realtime_now_us();
      if (due > now) {
        r.after_frames(now, true);  // the bus is quiet until the next frame: publish now
        now = bus::realtime_now_us();
        if (due > now && !tools::sleep_unless_stopped(due - now)) break;
        now = bus::realtime_now_us();
      }
      // Behind (a slow pipeline): the frames that were due are read before the next process()
      // (the newest sample of a patch supersedes its older ones) and keep the time they were
      // due, so a late loop shows as latency and its samples keep their own times.
      rx_us = std::min(due, now);
    }
    r.agg.on_frame(b, rec.frame, rx_us);
  }
  const uint64_t end_us = a.fast ? log_us + 1 : bus::realtime_now_us();
  clock.summarise(r.agg, end_us);
  r.after_frames(end_us, !a.fast);
  r.finish(end_us);
  if (f != stdin) std::fclose(f);
  if (reader.bad_lines() > 0) {
    std::fprintf(stderr, "skinbus-host: %" PRIu64 " log line(s) could not be parsed\n",
                 reader.bad_lines());
  }
  if (ifaces.skipped() > 0) {
    std::fprintf(stderr,
                 "skinbus-host: %" PRIu64 " frame(s) on interfaces not named with -i skipped\n",
                 ifaces.skipped());
  }
  check_read(reader, source);
  ifaces.check_end(source);
  clock.check_end();
  return 0;
}

}  // namespace

namespace {

// True when the interface is administratively up (IFF_UP in /sys/class/net/<name>/flags).
bool interface_up(const std::string& name) {
  std::FILE* f = std::fopen(("/sys/class/net/" + name + "/flags").c_str(), "r");
  if (f == nullptr) return false;
  unsigned flags = 0;
  const bool ok = std::fscanf(f, "%x", &flags) == 1;
  std::fclose(f);
  return ok && (flags & 0x1u) != 0;
}

// A candump log replayed at recorded speed next to live interfaces: its frames go to one more
// bus (after the live ones), whatever interface names the log holds.
class PacedLog {
 public:
  PacedLog(std::FILE* f, std::string source, int bus, uint64_t gap_us, host::Aggregator& agg)
      : f_(f),
        source_(std::move(source)),
        reader_(f),
        bus_(bus),
        agg_(agg),
        clock_(source_, gap_us) {
    advance();
  }
  ~PacedLog() {
    if (f_ != stdin) std::fclose(f_);
  }
  // Milliseconds until the next record is due (0: now), or -1 at the end of the log.
  int wait_ms(uint64_t now_us) {
    if (!have_) return -1;
    const uint64_t due = due_us();
    return due <= now_us ? 0 : static_cast<int>(std::min<uint64_t>((due - now_us) / 1000, 1000));
  }
  // Feeds every record due by `now_us`, stamped with when it was due (its arrival on the
  // replayed bus, as the kernel stamps a live frame), not with when this loop got to it.
  void feed_due(host::Aggregator& agg, uint64_t now_us) {
    while (have_ && due_us() <= now_us) {
      agg.on_frame(bus_, rec_.frame, due_us());
      advance();
    }
  }
  uint64_t bad_lines() const { return reader_.bad_lines(); }
  // At the end: the log's time adjustments summarised; throws when its read failed.
  void finish(uint64_t now_us) {
    clock_.summarise(agg_, now_us);
    check_read(reader_, source_);
    clock_.check_end();
  }

 private:
  uint64_t due_us() const { return wall_start_us_ + (rec_.timestamp_us - log_start_us_); }
  void advance() {
    for (;;) {
      const auto st = reader_.next(&rec_);
      if (st == bus::CandumpReader::Status::kEof) {
        have_ = false;
        return;
      }
      if (st == bus::CandumpReader::Status::kRecord) break;
    }
    rec_.timestamp_us =
        clock_.adjust(rec_.timestamp_us, reader_.line_number(), agg_, bus::realtime_now_us());
    if (!started_) {
      started_ = true;
      log_start_us_ = rec_.timestamp_us;
      wall_start_us_ = bus::realtime_now_us();
    }
    have_ = true;
  }
  std::FILE* f_;
  std::string source_;
  bus::CandumpReader reader_;
  bus::CandumpRecord rec_;
  int bus_;
  host::Aggregator& agg_;
  LogClock clock_;
  bool have_ = false, started_ = false;
  uint64_t log_start_us_ = 0, wall_start_us_ = 0;
};

int run_live(const HostArgs& a, Runner& r) {
  std::unique_ptr<PacedLog> log;
  if (!a.replay.empty()) {
    log = std::make_unique<PacedLog>(open_replay(a.replay), a.replay == "-" ? "stdin" : a.replay,
                                     static_cast<int>(a.interfaces.size()), max_gap_us(a), r.agg);
  }
  bus::SocketCanOptions so;
  so.fd = true;
  so.rcvbuf_bytes = 1 << 20;
  std::vector<std::unique_ptr<bus::SocketCanPort>> ports(a.interfaces.size());
  std::vector<uint64_t> retry_us(a.interfaces.size(), 0);
  std::vector<bool> down(a.interfaces.size(), false);
  std::unique_ptr<bus::CanPoller> poller;
  auto rebuild_poller = [&]() {
    poller = std::make_unique<bus::CanPoller>();
    for (auto& p : ports) {
      if (p) (void)poller->add(p.get());
    }
  };
  for (std::size_t i = 0; i < ports.size(); ++i) {
    auto p = bus::SocketCanPort::open(a.interfaces[i], so);
    if (!p) {
      std::fprintf(stderr, "skinbus-host: %s\n", p.error().to_string().c_str());
      return 1;
    }
    ports[i] = std::move(*p);
  }
  rebuild_poller();
  std::map<int, int> bus_of_fd;
  auto index_fds = [&]() {
    bus_of_fd.clear();
    for (std::size_t i = 0; i < ports.size(); ++i) {
      if (ports[i]) bus_of_fd[ports[i]->fd()] = static_cast<int>(i);
    }
  };
  index_fds();
  r.run_start_us = bus::realtime_now_us();
  r.next_status_us = r.run_start_us;
  const uint64_t end_us =
      a.duration_s > 0 ? r.run_start_us + static_cast<uint64_t>(a.duration_s * 1e6) : UINT64_MAX;
  bool changed = false;
  while (!tools::stop_requested()) {
    const uint64_t now = bus::realtime_now_us();
    if (now >= end_us) break;
    int timeout_ms = 20;
    if (log) {
      const int w = log->wait_ms(now);
      if (w >= 0) timeout_ms = std::min(timeout_ms, w);
    }
    auto n = poller->poll(
        timeout_ms,
        [&](bus::SocketCanPort& port, const bus::CanFrame& frame, const bus::RxMeta& meta) {
          if (frame.error) return;  // controller events: counted by the port
          r.agg.on_frame(bus_of_fd[port.fd()], frame, meta.timestamp_us);
        },
        [&](bus::SocketCanPort& port, const Error& e) {
          const int b = bus_of_fd[port.fd()];
          const std::size_t bi = static_cast<std::size_t>(b);
          if (!down[bi]) {
            down[bi] = true;
            r.agg.add_event(host::PatchEventKind::kInterfaceDown, bus::realtime_now_us(),
                            port.name() + ": " + e.to_string() + " (reopening every second)", -1);
          }
          retry_us[bi] = bus::realtime_now_us() + 1'000'000;
          changed = true;
        });
    if (!n.ok()) {
      std::fprintf(stderr, "skinbus-host: %s\n", n.error().to_string().c_str());
      return 1;
    }
    if (changed) {  // close the failed ports; reopen below
      changed = false;
      for (std::size_t i = 0; i < ports.size(); ++i) {
        if (down[i] && ports[i]) ports[i].reset();
      }
      rebuild_poller();
      index_fds();
    }
    const uint64_t t = bus::realtime_now_us();
    if (log) log->feed_due(r.agg, t);
    for (std::size_t i = 0; i < ports.size(); ++i) {
      if (!down[i] || t < retry_us[i]) continue;
      if (!interface_up(a.interfaces[i])) {  // a socket binds to a down interface too
        retry_us[i] = t + 1'000'000;
        continue;
      }
      auto p = bus::SocketCanPort::open(a.interfaces[i], so);
      if (p) {
        ports[i] = std::move(*p);
        down[i] = false;
        r.agg.add_event(host::PatchEventKind::kInterfaceUp, t, a.interfaces[i] + ": reopened", -1);
        rebuild_poller();
        index_fds();
      } else {
        retry_us[i] = t + 1'000'000;
      }
    }
    r.after_frames(t, true);
  }
  if (log) log->finish(bus::realtime_now_us());
  r.finish(bus::realtime_now_us());
  if (log && log->bad_lines() > 0) {
    std::fprintf(stderr, "skinbus-host: %" PRIu64 " log line(s) could not be parsed\n",
                 log->bad_lines());
  }
  return 0;
}

// A candump -L stream written as it is read (`candump -L can0 | skinbus-host --replay - --live`,
// or patch daemons writing into a pipe): the pipe is read without blocking, like a socket, and
// the pipeline runs after every read, on the host's clock. Each frame keeps the time in its line
// (when it was on the bus) if that is plausible for this host (not in the future, at most 10 s
// old), else the time it was read; a host that falls behind thus sees how old the frames are.
int run_live_pipe(const HostArgs& a, Runner& r) {
  int fd = STDIN_FILENO;
  if (a.replay != "-") {
    Result<UniqueFd> opened = open_input_file(a.replay, "candump log");
    if (!opened.ok()) throw std::runtime_error(opened.error().message);
    fd = opened->release();
  }
  const int flags = ::fcntl(fd, F_GETFL);
  if (flags < 0 || ::fcntl(fd, F_SETFL, flags | O_NONBLOCK) < 0) {
    std::fprintf(stderr, "skinbus-host: '%s': %s\n", a.replay.c_str(), std::strerror(errno));
    if (fd != STDIN_FILENO) ::close(fd);
    return 1;
  }
  LogInterfaces ifaces(a.interfaces);
  const std::string source = a.replay == "-" ? "stdin" : a.replay;
  bool skipping = false;  // inside a line longer than bus::kCandumpMaxLineBytes
  constexpr uint64_t kMaxAgeUs = 10'000'000;
  constexpr std::size_t kReadMax = 1 << 20;  // per pass, so the pipeline runs under a flood too
  std::string pending;                       // the start of a line not yet complete
  std::vector<char> chunk(64 * 1024);
  uint64_t bad_lines = 0;
  r.run_start_us = bus::realtime_now_us();
  r.next_status_us = r.run_start_us;
  const uint64_t end_us =
      a.duration_s > 0 ? r.run_start_us + static_cast<uint64_t>(a.duration_s * 1e6) : UINT64_MAX;
  bool eof = false;
  int rc = 0;
  while (!eof && !tools::stop_requested()) {
    if (bus::realtime_now_us() >= end_us) break;
    pollfd p{fd, POLLIN, 0};
    const int n = ::poll(&p, 1, 20);
    if (n < 0 && errno != EINTR) {
      std::fprintf(stderr, "skinbus-host: poll: %s\n", std::strerror(errno));
      rc = 1;
      break;
    }
    std::size_t read_total = 0;
    while (n > 0 && read_total < kReadMax) {
      const ssize_t got = ::read(fd, chunk.data(), chunk.size());
      if (got == 0) {
        eof = true;
        break;
      }
      if (got < 0) {
        if (errno == EINTR) continue;
        if (errno != EAGAIN && errno != EWOULDBLOCK) {
          std::fprintf(stderr, "skinbus-host: read: %s\n", std::strerror(errno));
          rc = 1;
          eof = true;
        }
        break;
      }
      read_total += static_cast<std::size_t>(got);
      const uint64_t read_us = bus::realtime_now_us();
      pending.append(chunk.data(), static_cast<std::size_t>(got));
      std::size_t start = 0;
      for (std::size_t nl; (nl = pending.find('\n', start)) != std::string::npos; start = nl + 1) {
        bus::CandumpRecord rec;
        const std::string_view line(pending.data() + start, nl - start);
        if (skipping || line.size() > bus::kCandumpMaxLineBytes) {  // the end of a long line
          skipping = false;
          ++bad_lines;
          continue;
        }
        const bus::CandumpError e = bus::parse_candump_line(line, &rec);
        if (e == bus::CandumpError::kEmpty) continue;
        if (e != bus::CandumpError::kNone) {
          ++bad_lines;
          continue;
        }
        const int b = ifaces.bus(rec.iface, r.agg, read_us);
        if (b < 0) continue;
        const bool plausible =
            rec.timestamp_us <= read_us && read_us - rec.timestamp_us <= kMaxAgeUs;
        r.agg.on_frame(b, rec.frame, plausible ? rec.timestamp_us : read_us);
      }
      pending.erase(0, start);
      if (pending.size() > bus::kCandumpMaxLineBytes) {  // no end in sight: memory stays bounded
        pending.clear();
        skipping = true;
      }
    }
    r.after_frames(bus::realtime_now_us(), true);
  }
  r.finish(bus::realtime_now_us());
  if (bad_lines > 0) {
    std::fprintf(stderr, "skinbus-host: %" PRIu64 " line(s) could not be parsed\n", bad_lines);
  }
  ::fcntl(fd, F_SETFL, flags);  // the descriptor may be shared (a terminal, a parent's pipe)
  if (fd != STDIN_FILENO) ::close(fd);
  if (rc == 0) ifaces.check_end(source);
  return rc;
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
  if (estimators::parse_runtime_isa(s, &isa)) return isa;
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
  app.add_option("--joints", a.joints, "auto | dds | none | FILE (joint trajectory CSV)")
      ->capture_default_str();
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
  app.add_option("--base-frame", a.base_frame, "frame_id of the published contacts")
      ->capture_default_str();
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
    // On the host's clock the bound covers the model runs' own time too; a log replayed as fast
    // as possible has only its own time.
    if (!(a.fast && !a.replay.empty() && !a.live_and_replay)) o.clock_us = bus::realtime_now_us;
    auto map = body_map::load_skin_map_file(a.map_path);
    if (!map) {
      std::fprintf(stderr, "skinbus-host: %s\n", map.error().to_string().c_str());
      return 1;
    }
    const std::string map_dir = std::filesystem::path(a.map_path).parent_path().string();
    const std::string robot_path =
        a.robot_path.empty() ? body_map::path_beside(a.map_path, map->robot) : a.robot_path;
    std::unique_ptr<body_map::RobotModel> robot;
    if (!robot_path.empty()) {
      auto rm = body_map::RobotModel::from_urdf_file(robot_path);
      if (!rm) {
        std::fprintf(stderr, "skinbus-host: %s\n", rm.error().to_string().c_str());
        return 1;
      }
      robot = std::make_unique<body_map::RobotModel>(std::move(*rm));
      if (Status st = body_map::validate_skin_map(*map, robot.get()); !st.ok()) {
        std::fprintf(stderr, "skinbus-host: %s\n", st.error().to_string().c_str());
        return 1;
      }
    }
    std::vector<std::string> buses = a.interfaces;
    const bool both = !a.replay.empty() && !a.interfaces.empty() && a.live_and_replay;
    if (both) buses.push_back("replay");
    if (buses.empty()) buses.push_back("can0");
    auto agg = host::Aggregator::create(&*map, map_dir, robot.get(), buses, o);
    if (!agg) {
      std::fprintf(stderr, "skinbus-host: %s\n", agg.error().to_string().c_str());
      return 2;
    }
    if (!a.quiet) {
      std::fprintf(stderr, "skinbus-host: %zu patches in the map, robot %s, models:\n",
                   map->patches.size(), robot ? robot->name().c_str() : "(none)");
      for (const std::string& m : (*agg)->model_descriptions()) {
        std::fprintf(stderr, "  %s\n", m.c_str());
      }
    }
    Outputs out(a);
    Joints joints(a, robot.get());
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
    Runner r(a, **agg, out, joints);
    const int rc = a.live                     ? run_live_pipe(a, r)
                   : a.replay.empty() || both ? run_live(a, r)
                                              : run_replay(a, r);
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
      if (r.latency_us.count() > 0) {
        std::fprintf(stderr,
                     "skinbus-host: latency frame arrival -> publication over %zu samples: "
                     "p50 %.0f us, p99 %.0f us, max %.0f us\n",
                     static_cast<std::size_t>(r.latency_us.count()), r.latency_us.quantile(0.5),
                     r.latency_us.quantile(0.99), r.latency_us.max());
      }
    }
    return rc;
  } catch (const std::invalid_argument& e) {
    std::fprintf(stderr, "skinbus-host: %s\n", e.what());
    return 2;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "skinbus-host: %s\n", e.what());
    return 1;
  }
}
