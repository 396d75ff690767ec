// skinbus-budget: bus load of a skin, and how many patches fit on one bus.
//
//   skinbus-budget --patches 64 --rate 41.7 --active 0.1
//   skinbus-budget --classic --nominal-bitrate 500000
//   skinbus-budget --table    # the table of docs/protocol.md
//   skinbus-budget --log bus.log --interval-ms 100 --csv load.csv   # measured, over time
#include <CLI/CLI.hpp>

#include <algorithm>
#include <cinttypes>
#include <cstdio>
#include <map>
#include <string>
#include <vector>

#include "skinbus/bus/budget.h"
#include "skinbus/bus/candump.h"
#include "tool_util.h"

namespace {

using namespace skinbus::bus;

void print_table() {
  std::printf(
      "| bus | bit rates | mode | frames/sample | sample time (us) | frames/s per patch | load per "
      "patch | max patches (<=70%%) |\n");
  std::printf("|---|---|---|---|---|---|---|---|\n");
  struct Row {
    const char* bus;
    BusTiming t;
    const char* rates;
  };
  const Row rows[] = {
      {"CAN FD", {true, 1e6, 5e6}, "1 M / 5 M"},   {"CAN FD", {true, 500e3, 2e6}, "500 k / 2 M"},
      {"CAN FD", {true, 1e6, 8e6}, "1 M / 8 M"},   {"classic", {false, 1e6, 1e6}, "1 M"},
      {"classic", {false, 500e3, 500e3}, "500 k"},
  };
  struct Mode {
    const char* name;
    double active;
  };
  const Mode modes[] = {{"stream", 1.0}, {"event, 10% touched", 0.1}, {"event, idle", 0.0}};
  for (const Row& r : rows) {
    for (const Mode& m : modes) {
      const BudgetResult b = compute_budget(r.t, PatchTraffic{41.7, m.active, 1.0}, 1, 0.7);
      std::printf("| %s | %s | %s | %.0f | %.1f | %.1f | %.3f%% | %d |\n", r.bus, r.rates, m.name,
                  b.sample_frames, b.sample_time_us, b.frames_per_s_per_patch,
                  100 * b.load_per_patch, b.max_patches);
    }
  }
}

// The load a candump log put on each of its interfaces, per interval: wire time of its frames
// (worst-case stuffing, as the budget; each frame timed as the classic or FD frame it is, at the
// bit rates given) over the interval. Prints a summary; writes one CSV row
// per interval and interface (t_s,interface,frames,load) when `csv_path` is given.
constexpr double kMaxIntervals = 1e7;  // a log longer than this many intervals is refused

int log_load(const std::string& log_path, const BusTiming& t, double interval_ms,
             const std::string& csv_path) {
  std::FILE* f = nullptr;
  try {
    f = log_path == "-" ? stdin : skinbus::tools::open_input_stream(log_path, "candump log");
  } catch (const std::exception& e) {
    return skinbus::tools::fail("skinbus-budget", e.what(), 1);
  }
  CandumpReader reader(f);
  CandumpRecord rec;
  struct Bin {
    uint64_t frames = 0;
    double wire_us = 0;
  };
  std::map<std::string, std::map<uint64_t, Bin>, std::less<>> bins;  // interface -> interval
  constexpr std::size_t kMaxInterfaces = 64;
  bool warned_ifaces = false;
  uint64_t t0 = 0;
  bool first = true;
  const double interval_us = interval_ms * 1000;
  while (true) {
    const auto st = reader.next(&rec);
    if (st == CandumpReader::Status::kEof) break;
    if (st != CandumpReader::Status::kRecord || rec.frame.error) continue;
    if (first) {
      t0 = rec.timestamp_us;
      first = false;
    }
    if (rec.timestamp_us < t0) continue;
    const double k_real = static_cast<double>(rec.timestamp_us - t0) / interval_us;
    if (k_real > kMaxIntervals) {
      std::fprintf(stderr,
                   "skinbus-budget: line %" PRIu64
                   " lies %.0f s after the first: not one "
                   "recording (or a bad timestamp); stopped there\n",
                   reader.line_number(), k_real * interval_ms / 1000);
      break;
    }
    auto per = bins.find(rec.iface);
    if (per == bins.end()) {
      if (bins.size() >= kMaxInterfaces) {  // more names than any machine has: skipped, said once
        if (!warned_ifaces) {
          warned_ifaces = true;
          std::fprintf(stderr,
                       "skinbus-budget: line %" PRIu64
                       ": more than %zu interface names; "
                       "frames of the others are skipped\n",
                       reader.line_number(), kMaxInterfaces);
        }
        continue;
      }
      per = bins.emplace(std::string(rec.iface), std::map<uint64_t, Bin>{}).first;
    }
    Bin& b = per->second[static_cast<uint64_t>(k_real)];
    ++b.frames;
    // Each frame at its own kind: classic frames at the nominal rate, FD data at the data rate
    // only with bit-rate switching.
    BusTiming ft = t;
    ft.fd = rec.frame.fd;
    if (!rec.frame.fd || !rec.frame.brs) ft.data_bps = t.nominal_bps;
    b.wire_us += frame_time_us(ft, rec.frame.len);
  }
  if (f != stdin) std::fclose(f);
  if (reader.read_error() != 0) {
    return skinbus::tools::fail("skinbus-budget",
                                log_path + ": read failed after line " +
                                    std::to_string(reader.line_number()) + ": " +
                                    std::strerror(reader.read_error()),
                                1);
  }
  const bool csv = !csv_path.empty();
  std::string csv_text;  // written whole at the end (a temporary file, renamed)
  if (csv) csv_text = "t_s,interface,frames,load\n";
  for (const auto& [iface, per] : bins) {
    double peak = 0, sum = 0;
    uint64_t frames = 0;
    const uint64_t last = per.rbegin()->first;
    for (uint64_t k = 0; k <= last; ++k) {
      auto it = per.find(k);
      const Bin b = it == per.end() ? Bin{} : it->second;
      const double load = b.wire_us / interval_us;
      peak = std::max(peak, load);
      sum += load;
      frames += b.frames;
      if (csv) {
        skinbus::tools::appendf(csv_text, "%.3f,%s,%" PRIu64 ",%.5f\n",
                                static_cast<double>(k) * interval_ms / 1000, iface.c_str(),
                                b.frames, load);
      }
    }
    std::printf("%s: %" PRIu64
                " frames over %.1f s: mean load %.1f%%, peak %.1f%% (%g ms intervals)\n",
                iface.c_str(), frames, static_cast<double>(last + 1) * interval_ms / 1000,
                100 * sum / static_cast<double>(last + 1), 100 * peak, interval_ms);
  }
  if (csv) {
    try {
      skinbus::tools::write_output(csv_path, csv_text, "bus load CSV");
    } catch (const std::exception& e) {
      return skinbus::tools::fail("skinbus-budget", e.what(), 1);
    }
  }
  if (reader.bad_lines() > 0) {
    std::fprintf(stderr, "skinbus-budget: %" PRIu64 " log line(s) could not be parsed\n",
                 reader.bad_lines());
  }
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{
      "skinbus-budget: CAN bus load of skin patches and the largest patch count a bus carries.\n\n"
      "Frame times assume worst-case bit stuffing, so loads are upper bounds. Each patch sends\n"
      "samples (in event mode only while touched: --active is the touched share of time) and a\n"
      "heartbeat.\n\n"
      "Examples:\n"
      "  skinbus-budget --patches 64 --active 0.1\n"
      "  skinbus-budget --classic --nominal-bitrate 500000 --patches 8\n"
      "  skinbus-budget --table\n"
      "  skinbus-budget --log bus.log --interval-ms 100 --csv load.csv   # a recording's load\n"};
  int patches = 16;
  double rate_hz = 41.7, active = 1.0, nominal = 1e6, data = 5e6, limit = 0.7, hb = 1.0;
  bool classic = false, table = false;
  app.add_option("-n,--patches", patches, "patches on the bus")
      ->capture_default_str()
      ->check(CLI::Range(0, 125));
  app.add_option("-r,--rate", rate_hz, "sample rate per patch, Hz")
      ->capture_default_str()
      ->check(CLI::Range(0.0, 10000.0));
  app.add_option("-a,--active", active, "share of time a patch streams (1 = stream mode)")
      ->capture_default_str()
      ->check(CLI::Range(0.0, 1.0));
  app.add_option("--heartbeat-hz", hb, "heartbeat rate per patch, Hz")
      ->capture_default_str()
      ->check(CLI::Range(0.0, 1000.0));
  app.add_flag("--classic", classic, "classic CAN (8-byte frames) instead of CAN FD");
  app.add_option("--nominal-bitrate", nominal, "arbitration bit rate, bit/s")
      ->capture_default_str()
      ->check(CLI::Range(10e3, 1e6));
  app.add_option("--data-bitrate", data, "CAN FD data bit rate, bit/s")
      ->capture_default_str()
      ->check(CLI::Range(10e3, 12e6));
  app.add_option("--load-limit", limit, "largest acceptable bus load for the patch count (0..1)")
      ->capture_default_str()
      ->check(CLI::Range(0.01, 1.0));
  app.add_flag("--table", table, "print the standard budget table (Markdown) and exit");
  std::string log_path, csv_path;
  double interval_ms = 100;
  app.add_option("--log", log_path,
                 "measure instead: the load a candump -L log put on each interface ('-': stdin)");
  app.add_option("--interval-ms", interval_ms, "--log: interval of the load figures, ms")
      ->capture_default_str()
      ->check(CLI::Range(1.0, 60000.0));
  app.add_option("--csv", csv_path, "--log: write t_s,interface,frames,load rows here");
  CLI11_PARSE(app, argc, argv);

  if (!classic && data < nominal) {
    std::fprintf(
        stderr,
        "skinbus-budget: --data-bitrate (%.0f) must not be below --nominal-bitrate (%.0f)\n", data,
        nominal);
    return 1;
  }
  if (table) {
    print_table();
    return 0;
  }
  const BusTiming t{!classic, nominal, classic ? nominal : data};
  if (!log_path.empty()) return log_load(log_path, t, interval_ms, csv_path);
  const BudgetResult b = compute_budget(t, PatchTraffic{rate_hz, active, hb}, patches, limit);
  std::printf(
      "bus              %s, %.0f bit/s%s\n", classic ? "classic CAN" : "CAN FD", nominal,
      classic ? "" : (" / " + std::to_string(static_cast<long>(data)) + " bit/s data").c_str());
  std::printf("sample message   %.0f frames, %.1f us on the wire\n", b.sample_frames,
              b.sample_time_us);
  std::printf("heartbeat        %.1f us on the wire\n", b.heartbeat_time_us);
  std::printf("per patch        %.1f frames/s, %.3f%% of the bus\n", b.frames_per_s_per_patch,
              100 * b.load_per_patch);
  std::printf("%3d patches      %.1f%% of the bus%s\n", patches, 100 * b.load_total,
              b.load_total > limit ? "  (OVER the limit)" : "");
  std::printf("max patches      %d under %.0f%% load\n", b.max_patches, 100 * limit);
  std::printf("full bus         %.0f frames/s of %s frames\n", b.full_bus_frames_per_s,
              classic ? "8-byte" : "64-byte");
  return b.load_total > 1.0 ? 2 : 0;
}
