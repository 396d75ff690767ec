// Small helpers shared by the command-line tools (tools/ only).
#pragma once

#include <signal.h>
#include <algorithm>
#include <atomic>
#include <cerrno>
#include <cmath>
#include <csignal>
#include <cstdarg>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <ctime>
#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>

#include "skinbus/common/atomic_file.h"
#include "skinbus/common/result.h"
#include "skinbus/common/stats.h"
#include "skinbus/common/text_file.h"

namespace skinbus::tools {

// The exit status for a failure described by `e`: 2 when the input is at fault (arguments or
// files: invalid_argument, parse, not_found, out_of_range), 1 otherwise.
inline int exit_status(const Error& e) {
  switch (e.code) {
    case ErrorCode::kInvalidArgument:
    case ErrorCode::kParse:
    case ErrorCode::kNotFound:
    case ErrorCode::kOutOfRange:
      return 2;
    default:
      return 1;
  }
}

// The one way a tool reports the failure it ends on: "tool: message" on standard error; returns
// `status` for main to return (each tool documents its exit statuses in its --help).
[[nodiscard]] inline int fail(const char* tool, const std::string& message, int status) {
  std::fprintf(stderr, "%s: %s\n", tool, message.c_str());
  return status;
}

// `x` as printf's %g writes it (for messages).
inline std::string format_g(double x) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%g", x);
  return buf;
}

// fail() for an Error value: "tool: code: message", and exit_status(e).
[[nodiscard]] inline int report_error(const char* tool, const Error& e) {
  return fail(tool, e.to_string(), exit_status(e));
}

// Parses "1-4,7,9-10" into node IDs, each within [lo, hi]. Throws std::invalid_argument with
// a message naming the bad part (tools report it and exit non-zero).
inline std::vector<int> parse_id_list(const std::string& text, int lo, int hi) {
  std::vector<int> out;
  std::size_t pos = 0;
  while (pos <= text.size()) {
    const std::size_t comma = text.find(',', pos);
    const std::string part =
        text.substr(pos, comma == std::string::npos ? std::string::npos : comma - pos);
    if (part.empty()) throw std::invalid_argument("empty entry in ID list '" + text + "'");
    const std::size_t dash = part.find('-');
    int a = 0, b = 0;
    try {
      std::size_t used = 0;
      a = std::stoi(part.substr(0, dash), &used);
      if (used != (dash == std::string::npos ? part.size() : dash)) throw std::invalid_argument("");
      b = a;
      if (dash != std::string::npos) {
        const std::string rest = part.substr(dash + 1);
        b = std::stoi(rest, &used);
        if (used != rest.size()) throw std::invalid_argument("");
      }
    } catch (const std::exception&) {
      throw std::invalid_argument("bad ID list entry '" + part + "' (expected N or N-M)");
    }
    if (a < lo || b > hi || a > b) {
      throw std::invalid_argument("ID range '" + part + "' outside " + std::to_string(lo) + "-" +
                                  std::to_string(hi));
    }
    for (int i = a; i <= b; ++i) out.push_back(i);
    if (comma == std::string::npos) break;
    pos = comma + 1;
  }
  return out;
}

using skinbus::mean;
using skinbus::quantile;

// Set by SIGINT / SIGTERM once install_stop_handler() ran; long-running tools poll it.
inline std::atomic<bool>& stop_requested() {
  static std::atomic<bool> flag{false};
  return flag;
}

// SIGINT and SIGTERM set stop_requested() and interrupt a blocking read or sleep (no SA_RESTART):
// every wait of a tool is bounded or interruptible, so it ends within a fraction of a second.
// SIGPIPE keeps (or gets back) its default action: a tool whose reader went away (`| head -1`)
// ends at once and quietly, as `yes | head -1` does.
inline void install_stop_handler() {
  struct sigaction sa {};
  sa.sa_handler = [](int) { stop_requested().store(true); };
  sigemptyset(&sa.sa_mask);
  sa.sa_flags = 0;
  sigaction(SIGINT, &sa, nullptr);
  sigaction(SIGTERM, &sa, nullptr);
  std::signal(SIGPIPE, SIG_DFL);
  sigset_t pipe_set;
  sigemptyset(&pipe_set);
  sigaddset(&pipe_set, SIGPIPE);
  sigprocmask(SIG_UNBLOCK, &pipe_set, nullptr);
}

// Every tool starts with SIGPIPE at its default action (unblocked), whatever its parent set: a
// tool whose reader went away ends at once, as the shell expects (`skinbus-x | head -1`).
inline const bool kSigpipeDefaultAtStart = [] {
  std::signal(SIGPIPE, SIG_DFL);
  sigset_t pipe_set;
  sigemptyset(&pipe_set);
  sigaddset(&pipe_set, SIGPIPE);
  sigprocmask(SIG_UNBLOCK, &pipe_set, nullptr);
  return true;
}();

// Sleeps `us` microseconds in slices of at most 50 ms; false (at once) when a stop was
// requested. A replay never sleeps through a stop, whatever the log's timestamps say.
inline bool sleep_unless_stopped(uint64_t us) {
  while (us > 0 && !stop_requested()) {
    const uint64_t slice = std::min<uint64_t>(us, 50000);
    timespec ts{static_cast<time_t>(slice / 1000000), static_cast<long>(slice % 1000000) * 1000};
    nanosleep(&ts, nullptr);  // a signal cuts it short; the loop looks at the flag
    us -= slice;
  }
  return !stop_requested();
}

// The exit status of a tool whose output's reader went away: what the shell reports for a
// process ended by SIGPIPE.
inline constexpr int kExitBrokenPipe = 128 + SIGPIPE;

// Ends the tool when writing `stream` (standard output, an output file) failed. The reader of a
// pipe going away (EPIPE, when SIGPIPE is ignored or blocked) ends it quietly with
// kExitBrokenPipe; any other error (a full disk) is named on stderr and ends it with status 1.
// Call with the errno of the failed write.
[[noreturn]] inline void exit_on_write_error(const char* tool, const char* what, int error) {
  if (error == EPIPE) std::_Exit(kExitBrokenPipe);
  if (error == EINTR && stop_requested()) std::_Exit(128 + SIGINT);  // stopped while blocked
  std::fprintf(stderr, "%s: writing %s failed: %s\n", tool, what, std::strerror(error));
  std::_Exit(1);
}

// Checks standard output after writing to it: a failed write ends the tool
// (exit_on_write_error). `flush` pushes buffered output first (at the end, or per line for a
// live stream).
inline void check_stdout(const char* tool, bool flush = false) {
  errno = 0;
  if ((flush && std::fflush(stdout) != 0) || std::ferror(stdout)) {
    exit_on_write_error(tool, "standard output", errno != 0 ? errno : EIO);
  }
}

// printf to standard output, checked: a write that fails ends the tool (exit_on_write_error).
[[gnu::format(printf, 2, 3)]] inline void out_printf(const char* tool, const char* fmt, ...) {
  va_list ap;
  va_start(ap, fmt);
  errno = 0;
  const int n = std::vprintf(fmt, ap);
  va_end(ap);
  if (n < 0) exit_on_write_error(tool, "standard output", errno != 0 ? errno : EIO);
}

// Opens an input file as a stream; `what` names it in the error ("candump log"). Throws
// std::runtime_error naming the file when it cannot be opened or is a directory (which would
// read as empty).
inline std::FILE* open_input_stream(const std::string& path, const std::string& what) {
  Result<UniqueFd> fd = open_input_file(path, what);
  if (!fd.ok()) throw std::runtime_error(fd.error().message);
  std::FILE* f = fdopen(fd->get(), "r");
  if (f == nullptr) throw std::runtime_error(what + " " + path + ": " + std::strerror(errno));
  fd->release();
  return f;
}

// Latencies (or any positive durations) in fixed memory, for a run of any length: counts in
// buckets 1 % wide from 1 us to 1000 s, the exact maximum. quantile() answers within 1 %.
class LatencyHistogram {
 public:
  static constexpr double kRatio = 1.01;
  static constexpr std::size_t kBuckets = 2084;  // 1.01^2083 > 1e9 us
  void add(double us) {
    const double v = std::max(us, 1.0);
    const auto b = static_cast<std::size_t>(std::log(v) / std::log(kRatio));
    ++counts_[std::min(b, kBuckets - 1)];
    ++n_;
    max_ = std::max(max_, us);
  }
  uint64_t count() const { return n_; }
  double max() const { return max_; }
  // The q-quantile (0..1): the upper edge of the bucket it falls in, at most the maximum.
  double quantile(double q) const {
    if (n_ == 0) return 0;
    const auto want = static_cast<uint64_t>(std::ceil(q * static_cast<double>(n_)));
    uint64_t seen = 0;
    for (std::size_t b = 0; b < kBuckets; ++b) {
      seen += counts_[b];
      if (seen >= std::max<uint64_t>(want, 1)) {
        return std::min(std::pow(kRatio, static_cast<double>(b + 1)), max_);
      }
    }
    return max_;
  }

 private:
  std::vector<uint64_t> counts_ = std::vector<uint64_t>(kBuckets, 0);
  uint64_t n_ = 0;
  double max_ = 0;
};

// printf appended to `out` (an output built in memory, then written with write_output).
[[gnu::format(printf, 2, 3)]] inline void appendf(std::string& out, const char* fmt, ...) {
  char buf[512];
  va_list ap;
  va_start(ap, fmt);
  const int n = std::vsnprintf(buf, sizeof buf, fmt, ap);
  va_end(ap);
  if (n < 0) return;
  if (static_cast<std::size_t>(n) < sizeof buf) {
    out.append(buf, static_cast<std::size_t>(n));
    return;
  }
  std::string big(static_cast<std::size_t>(n) + 1, '\0');
  va_start(ap, fmt);
  std::vsnprintf(big.data(), big.size(), fmt, ap);
  va_end(ap);
  out.append(big.data(), static_cast<std::size_t>(n));
}

// Writes an output file whole: to a temporary name beside it, checked, synced and renamed
// (skinbus/common/atomic_file.h), so that a reader never finds it torn or empty. '-' is standard
// output (checked). Throws std::runtime_error naming the file when the write fails.
inline void write_output(const std::string& path, std::string_view text, const std::string& what) {
  if (path == "-") {
    errno = 0;
    if (std::fwrite(text.data(), 1, text.size(), stdout) != text.size() ||
        std::fflush(stdout) != 0) {
      const int e = errno != 0 ? errno : EIO;
      if (e == EPIPE) std::_Exit(kExitBrokenPipe);
      throw std::runtime_error("writing " + what +
                               " to standard output failed: " + std::strerror(e));
    }
    return;
  }
  if (Status s = write_file_atomic(path, text, what); !s.ok()) {
    throw std::runtime_error(s.error().message);
  }
}

}  // namespace skinbus::tools
