// The host's run loop (host_loop.h): the inputs of skinbus-host (SocketCAN, candump logs at
// recorded speed or as fast as possible, live pipes), the cadence and the sinks.
#include "skinbus/host/host_loop.h"

#include <fcntl.h>
#include <poll.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cinttypes>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <ctime>
#include <map>
#include <memory>
#include <string_view>
#include <utility>

#include "skinbus/bus/candump.h"
#include "skinbus/bus/socketcan.h"
#include "skinbus/common/text_file.h"

namespace skinbus::host {

namespace {

constexpr uint64_t kFlushUs = 500'000;  // past every hold time: all contacts end

// A log replayed at recorded speed beside live interfaces, on a bus of its own.
bool replay_beside_interfaces(const HostLoopOptions& o) {
  return !o.replay.empty() && !o.interfaces.empty() && o.interfaces_and_replay;
}

// The time of a replayed log, made usable: monotonic in file order (the order frames were
// received in), and without waits nobody would sit through. Every change is reported as a
// kLogTime event (on the status topic and in the log; first occurrences), and summarised at the
// end.
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
  uint64_t adjust(uint64_t ts_us, uint64_t line, Aggregator& agg, uint64_t event_us) {
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
  // The end of the replay: a summary of what was adjusted (an event), if anything.
  void summarise(Aggregator& agg, uint64_t event_us) {
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
  // An error when most of the log runs backwards: not a recording in time order (a reversed or
  // shuffled file), whose contacts would come out of order and mostly superseded.
  Status check_end() const {
    if (lines_ >= 10 && 2 * back_lines_ > lines_) {
      return make_error(ErrorCode::kInvalidArgument,
                        source_ + ": " + std::to_string(back_lines_) + " of its " +
                            std::to_string(lines_) +
                            " lines are stamped before an earlier line: the log is not in time "
                            "order (sort it first: sort -s -k1,1 LOG)");
    }
    return Status();
  }

 private:
  static void report(Aggregator& agg, uint64_t event_us, const std::string& text) {
    agg.add_event(PatchEventKind::kLogTime, event_us, text);
  }
  std::string source_;
  uint64_t max_gap_us_;
  bool started_ = false;
  uint64_t max_ts_ = 0;  // the latest stamp of the current timeline
  uint64_t last_ = 0;    // the latest adjusted time given
  int64_t offset_ = 0;
  uint64_t lines_ = 0, back_lines_ = 0, max_back_us_ = 0, rebases_ = 0, gaps_ = 0;
};

// The bus of each interface name of a log: the interface names in order, or (none named) bus 0
// for every name. Frames of names not given are counted, reported once per name (a kBadFrames
// event), and at the end a log none of whose frames was on a named interface is an error:
// nothing was read.
class LogInterfaces {
 public:
  static constexpr std::size_t kMaxNamesReported = 16;
  explicit LogInterfaces(const std::vector<std::string>& names) : names_(names) {
    for (std::size_t i = 0; i < names.size(); ++i) bus_of_[names[i]] = static_cast<int>(i);
  }
  // The bus of a frame on `iface`, or -1 (skipped, counted).
  int bus(std::string_view iface, Aggregator& agg, uint64_t event_us) {
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
      agg.add_event(PatchEventKind::kBadFrames, event_us,
                    "frames on interface '" + skipped_names_.back() +
                        "' are skipped: it is not one of the -i names (" + joined() + ")");
    }
    return -1;
  }
  // An error when frames were read and none was on a named interface.
  Status check_end(const std::string& source) const {
    if (frames_ > 0 && used_ == 0) {
      std::string seen;
      for (const std::string& n : skipped_names_) seen += (seen.empty() ? "" : ", ") + n;
      return make_error(ErrorCode::kInvalidArgument,
                        source + ": none of its " + std::to_string(frames_) +
                            " frames is on an interface named with -i (" + joined() +
                            "); the log has " + seen);
    }
    return Status();
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

std::string source_name(const std::string& replay) {
  return replay == "-" ? "stdin" : replay;
}

// Opens a log ('-': stdin) as a stream; the error names the file (a directory, a missing file).
Result<std::FILE*> open_log(const std::string& path) {
  if (path == "-") return stdin;
  Result<UniqueFd> fd = open_input_file(path, "candump log");
  if (!fd.ok()) return fd.error();
  std::FILE* f = fdopen(fd->get(), "r");
  if (f == nullptr) {
    return make_error(ErrorCode::kIo, "candump log " + path + ": " + std::strerror(errno));
  }
  fd->release();
  return f;
}

// Closes a log stream at the end of its scope (not stdin).
struct LogFile {
  std::FILE* f;
  ~LogFile() {
    if (f != nullptr && f != stdin) std::fclose(f);
  }
};

// An error when the read of a log failed (not its end).
Status check_read(const bus::CandumpReader& reader, const std::string& source) {
  if (reader.read_error() != 0) {
    return make_error(ErrorCode::kIo, source + ": read failed after line " +
                                          std::to_string(reader.line_number()) + ": " +
                                          std::strerror(reader.read_error()));
  }
  return Status();
}

// The first error of several checks at the end of a run.
Status first_error(std::initializer_list<Status> all) {
  for (const Status& s : all) {
    if (!s.ok()) return s;
  }
  return Status();
}

std::string bad_lines_line(uint64_t n) {
  return std::to_string(n) + " log line(s) could not be parsed";
}

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
  PacedLog(std::FILE* f, std::string source, int bus, uint64_t gap_us, Aggregator& agg,
           std::function<uint64_t()> now_us)
      : file_{f},
        source_(std::move(source)),
        reader_(f),
        bus_(bus),
        agg_(agg),
        now_us_(std::move(now_us)),
        clock_(source_, gap_us) {
    advance();
  }
  // Milliseconds until the next record is due (0: now), or -1 at the end of the log.
  int wait_ms(uint64_t now_us) const {
    if (!have_) return -1;
    const uint64_t due = due_us();
    return due <= now_us ? 0 : static_cast<int>(std::min<uint64_t>((due - now_us) / 1000, 1000));
  }
  // Feeds every record due by `now_us`, stamped with when it was due (its arrival on the
  // replayed bus, as the kernel stamps a live frame), not with when this loop got to it.
  void feed_due(uint64_t now_us) {
    while (have_ && due_us() <= now_us) {
      agg_.on_frame(bus_, rec_.frame, due_us());
      advance();
    }
  }
  uint64_t bad_lines() const { return reader_.bad_lines(); }
  // At the end: the log's time adjustments summarised; an error when its read failed or it is
  // mostly out of time order.
  Status finish(uint64_t now_us) {
    clock_.summarise(agg_, now_us);
    return first_error({check_read(reader_, source_), clock_.check_end()});
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
    rec_.timestamp_us = clock_.adjust(rec_.timestamp_us, reader_.line_number(), agg_, now_us_());
    if (!started_) {
      started_ = true;
      log_start_us_ = rec_.timestamp_us;
      wall_start_us_ = now_us_();
    }
    have_ = true;
  }
  LogFile file_;
  std::string source_;
  bus::CandumpReader reader_;
  bus::CandumpRecord rec_;
  int bus_;
  Aggregator& agg_;
  std::function<uint64_t()> now_us_;
  LogClock clock_;
  bool have_ = false, started_ = false;
  uint64_t log_start_us_ = 0, wall_start_us_ = 0;
};

}  // namespace

TrajectoryJointInput::TrajectoryJointInput(body_map::JointTrajectory trajectory)
    : traj_(std::move(trajectory)), q_(traj_.names.size()) {}

void TrajectoryJointInput::update(Aggregator& agg, uint64_t now_us, uint64_t run_start_us) {
  if (traj_.rows() == 0) return;
  // The file's rows since the last call, at their own times (the history then interpolates
  // exactly as the file does), then the pose now, at most every 10 ms (between rows the file
  // is a straight line, which the history extends exactly; the loop may pass far more often).
  const double t_s = static_cast<double>(now_us - run_start_us) * 1e-6;
  for (; next_row_ < traj_.rows() && traj_.t_s[next_row_] < t_s; ++next_row_) {
    const double row_s = traj_.t_s[next_row_];
    if (row_s <= 0) continue;  // before time zero: the first state (below) holds it
    const std::span<const double> row(&traj_.q[next_row_ * traj_.names.size()], traj_.names.size());
    agg.set_joint_state(traj_.names, row,
                        run_start_us + static_cast<uint64_t>(std::llround(row_s * 1e6)));
  }
  if (last_now_us_ == 0 || now_us >= last_now_us_ + 10'000) {
    traj_.sample(t_s, q_);
    agg.set_joint_state(traj_.names, q_, now_us);
    last_now_us_ = now_us;
  }
}

std::vector<std::string> HostLoop::bus_names(const HostLoopOptions& o) {
  std::vector<std::string> buses = o.interfaces;
  if (replay_beside_interfaces(o)) buses.push_back("replay");
  if (buses.empty()) buses.push_back("can0");
  return buses;
}

bool HostLoop::on_host_clock(const HostLoopOptions& o) {
  return !(o.pace == ReplayPace::kFast && !o.replay.empty() && !replay_beside_interfaces(o));
}

HostLoop::HostLoop(Aggregator& aggregator, HostSink& sink, HostLoopOptions options,
                   JointInput* joints)
    : agg_(aggregator), sink_(sink), options_(std::move(options)), joints_(joints) {}

uint64_t HostLoop::now_us() const {
  return options_.clock.now_us ? options_.clock.now_us() : bus::realtime_now_us();
}

bool HostLoop::stop_requested() const {
  return options_.clock.stop_requested && options_.clock.stop_requested();
}

// Sleeps in slices of at most 50 ms; false (at once) when a stop was requested. A replay never
// sleeps through a stop, whatever the log's timestamps say.
bool HostLoop::sleep_unless_stopped(uint64_t us) const {
  while (us > 0 && !stop_requested()) {
    const uint64_t slice = std::min<uint64_t>(us, 50'000);
    if (options_.clock.sleep_us) {
      options_.clock.sleep_us(slice);
    } else {
      timespec ts{static_cast<time_t>(slice / 1'000'000),
                  static_cast<long>(slice % 1'000'000) * 1000};
      nanosleep(&ts, nullptr);  // a signal cuts it short; the loop looks at the stop request
    }
    us -= slice;
  }
  return !stop_requested();
}

void HostLoop::start(uint64_t now_us) {
  run_start_us_ = now_us;
  next_status_us_ = options_.status_period_us > 0 ? now_us : UINT64_MAX;
  next_tick_us_ = 0;
}

void HostLoop::publish(uint64_t now_us, bool measured) {
  if (joints_ != nullptr) joints_->update(agg_, now_us, run_start_us_);
  if (agg_.process(now_us, &contacts_)) {
    sink_.contacts(contacts_, measured ? agg_.processed_rx_us() : std::span<const uint64_t>());
  }
}

void HostLoop::publish_status(uint64_t now_us) {
  agg_.status(now_us, &status_);
  sink_.status(status_);
}

void HostLoop::step(uint64_t now_us) {
  publish(now_us, on_host_clock(options_));
  if (now_us >= next_tick_us_) {
    agg_.tick(now_us);
    next_tick_us_ = now_us + options_.tick_period_us;
  }
  if (now_us >= next_status_us_) {
    publish_status(now_us);
    next_status_us_ = now_us + options_.status_period_us;
  }
}

void HostLoop::finish(uint64_t end_us) {
  publish(end_us, false);  // what is still queued
  if (agg_.process(end_us + kFlushUs, &contacts_)) sink_.contacts(contacts_, {});
  publish_status(end_us);
}

Status HostLoop::run() {
  const HostLoopOptions& o = options_;
  if (o.replay.empty() && o.interfaces.empty()) {
    return make_error(ErrorCode::kInvalidArgument, "give -i INTERFACE (live) or --replay LOG");
  }
  const bool both = replay_beside_interfaces(o);
  if (o.pace == ReplayPace::kLive) {
    if (o.replay.empty() || both) {
      return make_error(ErrorCode::kInvalidArgument,
                        "a live pipe needs a log (--replay) and no interfaces beside it");
    }
    return run_live_pipe();
  }
  return o.replay.empty() || both ? run_live() : run_replay();
}

Status HostLoop::run_replay() {
  const HostLoopOptions& o = options_;
  const bool fast = o.pace == ReplayPace::kFast;
  Result<std::FILE*> opened = open_log(o.replay);
  if (!opened.ok()) return opened.error();
  LogFile file{*opened};
  const std::string source = source_name(o.replay);
  // Waits of at most 100 ms on a quiet pipe: a stop request ends the replay at once.
  bus::CandumpReader reader(file.f, /*wait_ms=*/100);
  bus::CandumpRecord rec;
  LogInterfaces ifaces(o.interfaces);
  LogClock clock(source, fast ? 0 : o.max_gap_us);
  uint64_t log_start_us = 0, wall_start_us = 0, last_process_us = 0, log_us = 0;
  int frames_since_process = 0;
  bool first = true;
  for (;;) {
    if (stop_requested()) break;
    const auto st = reader.next(&rec);
    if (st == bus::CandumpReader::Status::kWait) continue;
    if (st == bus::CandumpReader::Status::kEof) break;
    if (st == bus::CandumpReader::Status::kBadLine) continue;  // counted by the reader
    const uint64_t event_us = fast ? log_us : now_us();
    if (first) {
      log_start_us = clock.adjust(rec.timestamp_us, reader.line_number(), agg_, event_us);
      log_us = log_start_us;
      wall_start_us = now_us();
      start(fast ? log_start_us : wall_start_us);
      first = false;
    } else {
      log_us = clock.adjust(rec.timestamp_us, reader.line_number(), agg_, event_us);
    }
    if (o.duration_us > 0 && log_us - log_start_us > o.duration_us) break;
    const int b = ifaces.bus(rec.iface, agg_, event_us);
    if (b < 0) continue;
    uint64_t rx_us;
    if (fast) {
      rx_us = log_us;
      // Batch what arrived within 1 ms of log time, as a poll loop would (or 64 frames, where the
      // log's time stands still).
      if (rx_us > last_process_us + 1000 || ++frames_since_process >= 64) {
        step(rx_us);
        last_process_us = rx_us;
        frames_since_process = 0;
      }
    } else {
      const uint64_t due = wall_start_us + (log_us - log_start_us);
      uint64_t now = now_us();
      if (due > now) {
        step(now);  // the bus is quiet until the next frame: publish now
        now = now_us();
        if (due > now && !sleep_unless_stopped(due - now)) break;
        now = now_us();
      }
      // Behind (a slow pipeline): the frames that were due are read before the next process()
      // (the newest sample of a patch supersedes its older ones) and keep the time they were
      // due, so a late loop shows as latency and its samples keep their own times.
      rx_us = std::min(due, now);
    }
    agg_.on_frame(b, rec.frame, rx_us);
  }
  const uint64_t end_us = fast ? log_us + 1 : now_us();
  clock.summarise(agg_, end_us);
  step(end_us);
  finish(end_us);
  if (reader.bad_lines() > 0) sink_.log(bad_lines_line(reader.bad_lines()));
  if (ifaces.skipped() > 0) {
    sink_.log(std::to_string(ifaces.skipped()) +
              " frame(s) on interfaces not named with -i skipped");
  }
  return first_error({check_read(reader, source), ifaces.check_end(source), clock.check_end()});
}

Status HostLoop::run_live() {
  const HostLoopOptions& o = options_;
  std::unique_ptr<PacedLog> log;
  if (!o.replay.empty()) {
    Result<std::FILE*> opened = open_log(o.replay);
    if (!opened.ok()) return opened.error();
    log = std::make_unique<PacedLog>(*opened, source_name(o.replay),
                                     static_cast<int>(o.interfaces.size()), o.max_gap_us, agg_,
                                     [this] { return now_us(); });
  }
  bus::SocketCanOptions so;
  so.fd = true;
  so.rcvbuf_bytes = 1 << 20;
  std::vector<std::unique_ptr<bus::SocketCanPort>> ports(o.interfaces.size());
  std::vector<uint64_t> retry_us(o.interfaces.size(), 0);
  std::vector<bool> down(o.interfaces.size(), false);
  std::unique_ptr<bus::CanPoller> poller;
  auto rebuild_poller = [&]() {
    poller = std::make_unique<bus::CanPoller>();
    for (auto& p : ports) {
      if (p) (void)poller->add(p.get());
    }
  };
  for (std::size_t i = 0; i < ports.size(); ++i) {
    auto p = bus::SocketCanPort::open(o.interfaces[i], so);
    if (!p) return make_error(p.error().code, p.error().to_string());
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
  start(now_us());
  const uint64_t end_us = o.duration_us > 0 ? run_start_us_ + o.duration_us : UINT64_MAX;
  bool changed = false;
  while (!stop_requested()) {
    const uint64_t now = now_us();
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
          agg_.on_frame(bus_of_fd[port.fd()], frame, meta.timestamp_us);
        },
        [&](bus::SocketCanPort& port, const Error& e) {
          const std::size_t bi = static_cast<std::size_t>(bus_of_fd[port.fd()]);
          if (!down[bi]) {
            down[bi] = true;
            agg_.add_event(PatchEventKind::kInterfaceDown, now_us(),
                           port.name() + ": " + e.to_string() + " (reopening every second)", -1);
          }
          retry_us[bi] = now_us() + 1'000'000;
          changed = true;
        });
    if (!n.ok()) return make_error(n.error().code, n.error().to_string());
    if (changed) {  // close the failed ports; reopen below
      changed = false;
      for (std::size_t i = 0; i < ports.size(); ++i) {
        if (down[i] && ports[i]) ports[i].reset();
      }
      rebuild_poller();
      index_fds();
    }
    const uint64_t t = now_us();
    if (log) log->feed_due(t);
    for (std::size_t i = 0; i < ports.size(); ++i) {
      if (!down[i] || t < retry_us[i]) continue;
      if (!interface_up(o.interfaces[i])) {  // a socket binds to a down interface too
        retry_us[i] = t + 1'000'000;
        continue;
      }
      auto p = bus::SocketCanPort::open(o.interfaces[i], so);
      if (p) {
        ports[i] = std::move(*p);
        down[i] = false;
        agg_.add_event(PatchEventKind::kInterfaceUp, t, o.interfaces[i] + ": reopened", -1);
        rebuild_poller();
        index_fds();
      } else {
        retry_us[i] = t + 1'000'000;
      }
    }
    step(t);
  }
  Status log_status;
  if (log) log_status = log->finish(now_us());
  finish(now_us());
  if (log && log->bad_lines() > 0) sink_.log(bad_lines_line(log->bad_lines()));
  return log_status;
}

// A candump -L stream written as it is read (`candump -L can0 | skinbus-host --replay - --live`,
// or patch daemons writing into a pipe): the pipe is read without blocking, like a socket, and
// the pipeline runs after every read, on the host's clock. Each frame keeps the time in its line
// (when it was on the bus) if that is plausible for this host (not in the future, at most 10 s
// old), else the time it was read; a host that falls behind thus sees how old the frames are.
Status HostLoop::run_live_pipe() {
  const HostLoopOptions& o = options_;
  UniqueFd owned;
  int fd = STDIN_FILENO;
  if (o.replay != "-") {
    Result<UniqueFd> opened = open_input_file(o.replay, "candump log");
    if (!opened.ok()) return opened.error();
    owned = std::move(*opened);
    fd = owned.get();
  }
  const int flags = ::fcntl(fd, F_GETFL);
  if (flags < 0 || ::fcntl(fd, F_SETFL, flags | O_NONBLOCK) < 0) {
    return make_error(ErrorCode::kIo, "'" + o.replay + "': " + std::strerror(errno));
  }
  LogInterfaces ifaces(o.interfaces);
  const std::string source = source_name(o.replay);
  bool skipping = false;  // inside a line longer than bus::kCandumpMaxLineBytes
  constexpr uint64_t kMaxAgeUs = 10'000'000;
  constexpr std::size_t kReadMax = 1 << 20;  // per pass, so the pipeline runs under a flood too
  std::string pending;                       // the start of a line not yet complete
  std::vector<char> chunk(64 * 1024);
  uint64_t bad_lines = 0;
  start(now_us());
  const uint64_t end_us = o.duration_us > 0 ? run_start_us_ + o.duration_us : UINT64_MAX;
  bool eof = false;
  Status result;
  while (!eof && !stop_requested()) {
    if (now_us() >= end_us) break;
    pollfd p{fd, POLLIN, 0};
    const int n = ::poll(&p, 1, 20);
    if (n < 0 && errno != EINTR) {
      result = make_error(ErrorCode::kIo, std::string("poll: ") + std::strerror(errno));
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
          result = make_error(ErrorCode::kIo, std::string("read: ") + std::strerror(errno));
          eof = true;
        }
        break;
      }
      read_total += static_cast<std::size_t>(got);
      const uint64_t read_us = now_us();
      pending.append(chunk.data(), static_cast<std::size_t>(got));
      std::size_t start_at = 0;
      for (std::size_t nl; (nl = pending.find('\n', start_at)) != std::string::npos;
           start_at = nl + 1) {
        bus::CandumpRecord rec;
        const std::string_view line(pending.data() + start_at, nl - start_at);
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
        const int b = ifaces.bus(rec.iface, agg_, read_us);
        if (b < 0) continue;
        const bool plausible =
            rec.timestamp_us <= read_us && read_us - rec.timestamp_us <= kMaxAgeUs;
        agg_.on_frame(b, rec.frame, plausible ? rec.timestamp_us : read_us);
      }
      pending.erase(0, start_at);
      if (pending.size() > bus::kCandumpMaxLineBytes) {  // no end in sight: memory stays bounded
        pending.clear();
        skipping = true;
      }
    }
    step(now_us());
  }
  finish(now_us());
  if (bad_lines > 0) sink_.log(std::to_string(bad_lines) + " line(s) could not be parsed");
  ::fcntl(fd, F_SETFL, flags);  // the descriptor may be shared (a terminal, a parent's pipe)
  if (!result.ok()) return result;
  return ifaces.check_end(source);
}

}  // namespace skinbus::host
