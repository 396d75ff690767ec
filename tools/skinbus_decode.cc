// skinbus-decode: print skinbus traffic one readable line per message.
//
//   candump -L can0 | skinbus-decode
//   skinbus-decode recording.log
//   skinbus-decode -i can0 -i can1 --patch 3-5 --stats
#include <CLI/CLI.hpp>

#include <cerrno>
#include <cinttypes>
#include <cstdio>
#include <cstring>
#include <map>
#include <memory>
#include <set>
#include <string>
#include <vector>

#include "skinbus/bus/candump.h"
#include "skinbus/bus/format.h"
#include "skinbus/bus/reassembler.h"
#include "skinbus/bus/socketcan.h"
#include "skinbus/common/rate_limiter.h"
#include "tool_util.h"

namespace {

using namespace skinbus;
using namespace skinbus::bus;

struct PatchCounts {
  uint64_t samples = 0, heartbeats = 0, acks = 0, infos = 0, missing = 0;
};

class Decoder {
 public:
  struct Options {
    std::set<int> patches;  // empty: all
    std::set<MessageClass> classes;
    bool frames = false;
    bool timestamps = false;
    bool quiet = false;
    uint64_t max_messages = 0;
  };
  Decoder(Options o, Reassembler::Config rc) : opt_(std::move(o)), reasm_config_(rc) {}

  bool done() const { return opt_.max_messages && printed_ >= opt_.max_messages; }

  void on_frame(const CanFrame& f, uint64_t rx_us, std::string_view iface, const char* where) {
    Reassembler* reasm = reassembler(iface);
    if (reasm == nullptr) {  // more interface names than any machine has: not a real log
      ++bad_lines_;
      ++too_many_ifaces_;
      if (limiter_.allow(rx_us)) {
        print_suppressed();
        std::fprintf(stderr,
                     "skinbus-decode: %s: interface '%.*s' is one more than the %zu this log may "
                     "name; its frames are skipped\n",
                     where, static_cast<int>(std::min<std::size_t>(iface.size(), 64)), iface.data(),
                     kMaxInterfaces);
      }
      return;
    }
    if (f.error) {
      const std::string what = describe_bus_error(decode_error_frame(f));
      if (!opt_.quiet) print_prefixed(rx_us, iface, ("bus-error " + what).c_str());
      ++bus_errors_;
      return;
    }
    if (opt_.frames && selected_frame(f) && !opt_.quiet)
      print_prefixed(rx_us, iface, ("frame " + describe_frame(f)).c_str());
    const FeedResult r = reasm->feed(f, rx_us);
    switch (r.status) {
      case FeedStatus::kMessage:
        on_message(*r.message, r.missing_before, rx_us, iface);
        break;
      case FeedStatus::kRejected:
        if (r.error != DecodeError::kForeign) report(rx_us, where, f, decode_error_name(r.error));
        break;
      case FeedStatus::kIntegrityFailure:
        report(rx_us, where, f, "integrity failure (CRC) on reassembly");
        break;
      default:
        break;
    }
  }

  void report_line_error(uint64_t line, CandumpError e, std::string_view text, uint64_t now_us) {
    ++bad_lines_;
    if (!limiter_.allow(now_us)) return;
    print_suppressed();
    if (e == CandumpError::kLineTooLong) {
      std::fprintf(stderr, "skinbus-decode: %s:%" PRIu64 ": %s: longer than %zu bytes, skipped\n",
                   source_.c_str(), line, std::string(candump_error_name(e)).c_str(),
                   kCandumpMaxLineBytes);
      return;
    }
    while (!text.empty() && (text.back() == '\n' || text.back() == '\r')) text.remove_suffix(1);
    std::fprintf(stderr, "skinbus-decode: %s:%" PRIu64 ": %s: '%.*s'\n", source_.c_str(), line,
                 std::string(candump_error_name(e)).c_str(),
                 static_cast<int>(std::min<std::size_t>(text.size(), 200)), text.data());
  }

  void set_source(std::string s) { source_ = std::move(s); }

  void finish(uint64_t now_us) {
    for (auto& [name, r] : reasm_) r->expire(now_us + 1000000000ull);
    // Gaps the end of the stream confirmed: to their patches.
    for (auto& [key, c] : per_patch_) {
      auto it = reasm_.find(key.first);
      if (it == reasm_.end()) continue;
      for (int cls = 0; cls < kMessageClassCount; ++cls) {
        c.missing += it->second->take_unreported_losses(static_cast<MessageClass>(cls),
                                                        static_cast<uint8_t>(key.second));
      }
    }
  }

  void print_stats(std::FILE* out) const {
    ReassemblyStats s;  // summed over interfaces
    for (const auto& [name, r] : reasm_) s += r->stats();
    std::fprintf(out, "# skinbus-decode statistics\n");
    std::fprintf(
        out,
        "frames %" PRIu64 " messages %" PRIu64 " samples %" PRIu64 " integrity_failures %" PRIu64
        " gaps %" PRIu64 " duplicates %" PRIu64 " reorders %" PRIu64 " resyncs %" PRIu64
        " restarts %" PRIu64 " stale_parts %" PRIu64 " evictions %" PRIu64 " conflicts %" PRIu64
        " rejected %" PRIu64 " foreign %" PRIu64 " bad_lines %" PRIu64 " bus_errors %" PRIu64 "\n",
        s.frames, s.messages, s.samples, s.integrity_failures, s.gaps, s.duplicates, s.reorders,
        s.resyncs, s.restarts, s.stale_parts, s.evictions, s.conflicts, s.rejected, s.foreign,
        bad_lines_, bus_errors_);
    for (int e = 1; e < kDecodeErrorCount; ++e) {
      if (s.by_error[e]) {
        std::fprintf(out, "rejected %s %" PRIu64 "\n",
                     std::string(decode_error_name(static_cast<DecodeError>(e))).c_str(),
                     s.by_error[e]);
      }
    }
    std::fprintf(out, "%-12s %-6s %10s %10s %8s %6s %8s\n", "interface", "node", "samples",
                 "heartbeats", "acks", "infos", "missing");
    for (const auto& [key, c] : per_patch_) {
      std::fprintf(
          out, "%-12s %-6d %10" PRIu64 " %10" PRIu64 " %8" PRIu64 " %6" PRIu64 " %8" PRIu64 "\n",
          key.first.c_str(), key.second, c.samples, c.heartbeats, c.acks, c.infos, c.missing);
    }
    if (too_many_ifaces_) {
      std::fprintf(out, "(%" PRIu64 " frames on interfaces beyond the first %zu skipped)\n",
                   too_many_ifaces_, kMaxInterfaces);
    }
    if (limiter_.total_suppressed()) {
      std::fprintf(out, "(%" PRIu64 " error reports suppressed by rate limiting)\n",
                   limiter_.total_suppressed());
    }
  }

 private:
  bool selected_node(int node) const { return opt_.patches.empty() || opt_.patches.count(node); }
  bool selected_frame(const CanFrame& f) const {
    return selected_node(can_id_node(f.id)) &&
           (opt_.classes.empty() ||
            opt_.classes.count(static_cast<MessageClass>(can_id_class(f.id))));
  }

  void on_message(const Message& m, uint32_t missing, uint64_t rx_us, std::string_view iface) {
    PatchCounts& c = per_patch_[{std::string(iface), m.node}];
    c.missing += missing;
    switch (m.message_class()) {
      case MessageClass::kSample:
        ++c.samples;
        break;
      case MessageClass::kHeartbeat:
        ++c.heartbeats;
        break;
      case MessageClass::kAck:
        ++c.acks;
        break;
      case MessageClass::kInfo:
        ++c.infos;
        break;
      default:
        break;
    }
    if (!selected_node(m.node) || (!opt_.classes.empty() && !opt_.classes.count(m.message_class())))
      return;
    if (done()) return;
    ++printed_;
    if (!opt_.quiet) print_prefixed(rx_us, iface, format_message(m).c_str());
  }

  // Every line out is checked: a reader gone (`| head`) ends the tool at once and quietly, a
  // failed write (a full disk) with a message.
  void print_prefixed(uint64_t rx_us, std::string_view iface, const char* text) {
    if (opt_.timestamps) {
      tools::out_printf("skinbus-decode", "(%010" PRIu64 ".%06" PRIu64 ") %.*s %s\n",
                        rx_us / 1000000, rx_us % 1000000, static_cast<int>(iface.size()),
                        iface.data(), text);
    } else {
      tools::out_printf("skinbus-decode", "%s\n", text);
    }
  }

  void print_suppressed() {
    if (limiter_.suppressed()) {
      std::fprintf(stderr, "skinbus-decode: (%" PRIu64 " similar errors suppressed)\n",
                   limiter_.suppressed());
    }
  }

  void report(uint64_t now_us, const char* where, const CanFrame& f, std::string_view why) {
    if (!limiter_.allow(now_us)) return;
    print_suppressed();
    char text[kCandumpLineMax];
    format_frame_text(f, text);
    std::fprintf(stderr, "skinbus-decode: %s: frame %s: %.*s\n", where, text,
                 static_cast<int>(why.size()), why.data());
  }

  Options opt_;
  // Node IDs are per bus: one reassembler per interface, created on first sight (a log may
  // interleave several, as `candump -L any` writes it), at most kMaxInterfaces of them (nullptr
  // beyond: memory stays bounded whatever names a log holds).
  static constexpr std::size_t kMaxInterfaces = 64;
  Reassembler* reassembler(std::string_view iface) {
    auto it = reasm_.find(iface);
    if (it == reasm_.end()) {
      if (reasm_.size() >= kMaxInterfaces) return nullptr;
      it = reasm_.emplace(std::string(iface), std::make_unique<Reassembler>(reasm_config_)).first;
    }
    return it->second.get();
  }

  Reassembler::Config reasm_config_;
  std::map<std::string, std::unique_ptr<Reassembler>, std::less<>> reasm_;
  RateLimiter limiter_{10, 1000000};
  std::map<std::pair<std::string, int>, PatchCounts> per_patch_;
  std::string source_ = "stdin";
  uint64_t bad_lines_ = 0;
  uint64_t bus_errors_ = 0;
  uint64_t printed_ = 0;
  uint64_t too_many_ifaces_ = 0;
};

int run_log(Decoder& dec, std::FILE* in, const std::string& name) {
  dec.set_source(name);
  // Waits of at most 100 ms on a quiet pipe, so that Ctrl-C ends a decoder reading stdin at once.
  CandumpReader reader(in, /*wait_ms=*/100);
  CandumpRecord rec;
  char where[64];
  uint64_t last_us = 0;
  for (;;) {
    if (tools::stop_requested() || dec.done()) break;
    const auto st = reader.next(&rec);
    if (st == CandumpReader::Status::kWait) continue;
    if (st == CandumpReader::Status::kEof) {
      if (reader.read_error() != 0) {
        dec.finish(last_us);
        throw std::runtime_error(name + ": read failed after line " +
                                 std::to_string(reader.line_number()) + ": " +
                                 std::strerror(reader.read_error()));
      }
      break;
    }
    if (st == CandumpReader::Status::kBadLine) {
      dec.report_line_error(reader.line_number(), reader.error(), reader.line(), last_us);
      continue;
    }
    last_us = rec.timestamp_us;
    std::snprintf(where, sizeof where, "%s:%" PRIu64, name.c_str(), reader.line_number());
    dec.on_frame(rec.frame, rec.timestamp_us, rec.iface, where);
  }
  dec.finish(last_us);
  return 0;
}

int run_live(Decoder& dec, const std::vector<std::string>& ifaces, bool fd, double duration_s,
             const std::vector<CanIdFilter>& filters) {
  SocketCanOptions opts;
  opts.fd = fd;
  opts.filters = filters;  // the kernel drops what was not asked for
  std::vector<std::unique_ptr<SocketCanPort>> ports;
  CanPoller poller;
  for (const std::string& name : ifaces) {
    auto port = SocketCanPort::open(name, opts);
    if (!port.ok()) throw std::runtime_error(port.error().message);
    Status s = poller.add(port->get());
    if (!s.ok()) throw std::runtime_error(s.error().message);
    ports.push_back(std::move(port).value());
  }
  const uint64_t start = monotonic_now_us();
  const uint64_t end =
      duration_s > 0 ? start + static_cast<uint64_t>(duration_s * 1e6) : UINT64_MAX;
  while (!tools::stop_requested() && !dec.done() && monotonic_now_us() < end) {
    auto r = poller.poll(
        50,
        [&](SocketCanPort& port, const CanFrame& f, const RxMeta& meta) {
          dec.on_frame(f, meta.timestamp_us, port.name(), port.name().c_str());
        },
        [&](SocketCanPort& port, const Error& e) {
          std::fprintf(stderr, "skinbus-decode: %s: %s\n", port.name().c_str(), e.message.c_str());
        });
    if (!r.ok()) throw std::runtime_error(r.error().message);
  }
  dec.finish(realtime_now_us());
  for (const auto& p : ports) {
    const PortStats& s = p->stats();
    std::fprintf(stderr,
                 "# %s: rx_frames %" PRIu64 " kernel_drops %" PRIu64 " error_frames %" PRIu64
                 " bus_off %" PRIu64 " error_passive %" PRIu64 " restarted %" PRIu64 "\n",
                 p->name().c_str(), s.rx_frames, s.rx_kernel_drops, s.error_frames, s.bus_off,
                 s.error_passive, s.restarted);
  }
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{
      "skinbus-decode: print skinbus CAN traffic, one readable line per message.\n\n"
      "Reads `candump -L` / `candump -l` lines from standard input or from log files, or listens "
      "on\n"
      "live SocketCAN interfaces (-i). Multi-part messages are reassembled and checked (CRC);\n"
      "bad lines and bad frames are reported on stderr with their line number (at most 10 a "
      "second)\n"
      "and counted, and decoding goes on.\n\n"
      "Examples:\n"
      "  candump -L can0 | skinbus-decode\n"
      "  skinbus-decode --patch 3 --class sample recording.log\n"
      "  skinbus-decode -i can0 --frames --stats\n"};
  std::vector<std::string> files;
  std::vector<std::string> ifaces;
  std::string patches, classes;
  bool frames = false, timestamps = false, stats = false, quiet = false, classic = false;
  double duration_s = 0;
  uint64_t count = 0;
  uint32_t timeout_us = 50000;
  app.add_option("files", files,
                 "candump log files to read ('-' = standard input; default: standard input)");
  app.add_option("-i,--interface", ifaces, "listen on this SocketCAN interface (repeatable)");
  app.add_option("-p,--patch", patches, "only these patch node IDs, e.g. 3 or 1-4,9");
  app.add_option("-c,--class", classes,
                 "only these classes: sync,command,ack,sample,info,heartbeat (comma-separated)");
  app.add_flag("-f,--frames", frames,
               "also print every frame as decoded on its own, before reassembly");
  app.add_flag("-t,--timestamps", timestamps, "prefix lines with the receive time and interface");
  app.add_flag("-s,--stats", stats, "print a statistics summary on stderr at the end");
  app.add_flag("-q,--quiet", quiet, "print no message lines (use with --stats)");
  app.add_flag("--classic-only", classic, "live interfaces: do not enable CAN FD frames");
  app.add_option("--duration", duration_s,
                 "live interfaces: stop after this many seconds (default: until Ctrl-C)");
  app.add_option("-n,--count", count, "stop after printing this many messages");
  app.add_option("--timeout-us", timeout_us,
                 "reassembly timeout for incomplete messages, microseconds")
      ->capture_default_str();
  CLI11_PARSE(app, argc, argv);

  try {
    tools::install_stop_handler();
    Decoder::Options o;
    o.frames = frames;
    o.timestamps = timestamps;
    o.quiet = quiet;
    o.max_messages = count;
    if (!patches.empty()) {
      for (int n : tools::parse_id_list(patches, 0, kNodeBroadcast)) o.patches.insert(n);
    }
    if (!classes.empty()) {
      std::string rest = classes + ",";
      for (std::size_t p; (p = rest.find(',')) != std::string::npos; rest.erase(0, p + 1)) {
        const std::string name = rest.substr(0, p);
        bool found = false;
        for (int c = 0; c < kMessageClassCount; ++c) {
          if (message_class_name(static_cast<MessageClass>(c)) == name) {
            o.classes.insert(static_cast<MessageClass>(c));
            found = true;
          }
        }
        if (!found) throw std::invalid_argument("unknown class '" + name + "'");
      }
    }
    Decoder dec(o, Reassembler::Config{64, timeout_us});
    if (!ifaces.empty()) {
      // Kernel filters for --patch / --class, as `candump can0,<id>:<mask>` would set them.
      std::vector<CanIdFilter> filters;
      if (!o.patches.empty() && !o.classes.empty()) {
        for (int n : o.patches) {
          for (MessageClass c : o.classes)
            filters.push_back({make_can_id(c, static_cast<uint8_t>(n)), 0x7FF});
        }
      } else if (!o.patches.empty()) {
        for (int n : o.patches) filters.push_back(filter_for_node(static_cast<uint8_t>(n)));
      } else {
        for (MessageClass c : o.classes) filters.push_back(filter_for_class(c));
      }
      run_live(dec, ifaces, !classic, duration_s, filters);
    } else if (files.empty()) {
      run_log(dec, stdin, "stdin");
    } else {
      for (const std::string& f : files) {
        if (f == "-") {
          run_log(dec, stdin, "stdin");
          continue;
        }
        std::FILE* in = tools::open_input_stream(f, "candump log");
        run_log(dec, in, f);
        std::fclose(in);
      }
    }
    tools::check_stdout("skinbus-decode", /*flush=*/true);
    if (stats) dec.print_stats(stderr);
  } catch (const std::exception& e) {
    return skinbus::tools::fail("skinbus-decode", e.what(), 1);
  }
  return 0;
}
