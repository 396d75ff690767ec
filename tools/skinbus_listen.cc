// skinbus-listen: subscribes to the host's DDS topics and prints what arrives.
//
//   skinbus-listen                               # contacts, one JSON object per line
//   skinbus-listen --status --table              # contacts and patch status, as a table
//   skinbus-listen --count 3 --timeout 20        # three contact arrays, or exit 1
#include <CLI/CLI.hpp>
#include <chrono>
#include <cinttypes>
#include <cstdint>
#include <cstdio>
#include <ctime>
#include <memory>
#include <string>

#include "skinbus/dds/dds.h"
#include "skinbus/host/contacts.h"
#include "skinbus/host/contacts_json.h"
#include "tool_util.h"

using namespace skinbus;
using namespace skinbus::dds;
using namespace skinbus::host;

namespace {

constexpr int kSliceMs = 200;  // how often the loops look at Ctrl-C and the timeout

void print_line(const std::string& line) {
  std::fputs(line.c_str(), stdout);
  std::fputc('\n', stdout);
  tools::check_stdout("skinbus-listen", /*flush=*/true);
}

// "HH:MM:SS.mmm" local time of a CLOCK_REALTIME stamp.
std::string clock_text(uint64_t us) {
  const std::time_t t = static_cast<std::time_t>(us / 1000000u);
  std::tm tm{};
  localtime_r(&t, &tm);
  char buf[32];
  std::snprintf(buf, sizeof buf, "%02d:%02d:%02d.%03u", tm.tm_hour, tm.tm_min, tm.tm_sec,
                static_cast<unsigned>((us % 1000000u) / 1000u));
  return buf;
}

void print_table(const ContactArray& a, bool* header_done) {
  if (!*header_done) {
    std::printf("%-12s %6s %4s %-16s %8s %8s %8s %8s %8s %s\n", "time", "track", "node", "link",
                "x_mm", "y_mm", "z_mm", "depth_mm", "force_n", "flags");
    *header_done = true;
  }
  const std::string t = clock_text(a.stamp_us);
  if (a.contacts.empty()) std::printf("%-12s (no contacts)\n", t.c_str());
  for (const BodyContact& c : a.contacts) {
    std::string flags;
    for (const std::string& f : contact_flag_names(c.flags))
      flags += (flags.empty() ? "" : ",") + f;
    std::printf("%-12s %6" PRIu32 " %4u %-16s %8.2f %8.2f %8.2f %8.3f %8.3f %s\n", t.c_str(),
                c.track_id, static_cast<unsigned>(c.node), c.link.c_str(), c.position_mm[0],
                c.position_mm[1], c.position_mm[2], c.depth_mm, c.force_n,
                flags.empty() ? "-" : flags.c_str());
  }
  tools::check_stdout("skinbus-listen", /*flush=*/true);
}

void print_table(const DiagnosticArray& d) {
  std::printf("%-12s diagnostics: %zu patches\n", clock_text(d.stamp_us).c_str(), d.status.size());
  for (const PatchDiagnostic& p : d.status) {
    std::printf("  %-5s %-32s %s\n", std::string(diagnostic_level_name(p.level)).c_str(),
                p.name.c_str(), p.message.c_str());
  }
  tools::check_stdout("skinbus-listen", /*flush=*/true);
}

void print_table(const PatchStatusArray& s) {
  const std::string t = clock_text(s.stamp_us);
  std::printf("%-12s status: %zu patches, %zu events\n", t.c_str(), s.patches.size(),
              s.events.size());
  for (const PatchStatus& p : s.patches) {
    std::printf("  node %3u uid %016" PRIx64 " %-8s %-10s %-16s samples %" PRIu64 " lost %" PRIu64
                " faults %04x%s%s\n",
                static_cast<unsigned>(p.node), p.hardware_uid, p.interface.c_str(),
                std::string(patch_link_state_name(p.state)).c_str(), p.link.c_str(), p.samples,
                p.samples_lost, static_cast<unsigned>(p.fault_mask), p.detail.empty() ? "" : "  ",
                p.detail.c_str());
  }
  for (const PatchEvent& e : s.events) {
    std::printf("  event %s %-16s node %3u uid %016" PRIx64 " %s\n", clock_text(e.time_us).c_str(),
                std::string(patch_event_name(e.kind)).c_str(), static_cast<unsigned>(e.node),
                e.hardware_uid, e.detail.c_str());
  }
  tools::check_stdout("skinbus-listen", /*flush=*/true);
}

// A malformed sample (dropped, reported) or a DDS failure (fatal)?
bool sample_error(const Error& e) {
  return e.code == ErrorCode::kParse || e.code == ErrorCode::kOutOfRange;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{
      "skinbus-listen: subscribes to the skinbus host's DDS topics and prints what arrives:\n"
      "the body-frame contacts (rt/skin/contacts) and, with --status, the patch status and\n"
      "events (rt/skin/patch_status), one JSON object per line as skinbus-host --json prints\n"
      "them (millimetres, microseconds of CLOCK_REALTIME; keys in docs/aggregator.md), or with\n"
      "--table as a compact table.\n"
      "The network is Cyclone DDS's: set CYCLONEDDS_URI to choose interfaces and peers (see\n"
      "docs/dds.md). ROS_DOMAIN_ID is not read: use --domain.\n\n"
      "Exit status: 0 when --count arrays arrived (or, without --count, when anything arrived\n"
      "before Ctrl-C or --timeout), 1 when nothing (or too little) arrived in time or DDS\n"
      "failed, 2 on bad arguments.\n\n"
      "Examples:\n"
      "  skinbus-listen --status --table\n"
      "  skinbus-listen --domain 5 --count 3 --timeout 20 --wait-match\n"
      "  skinbus-listen | jq -c '.contacts[] | {track_id, force_n}'"};
  int domain = -1, count = 0;
  double timeout_s = 0;
  bool status = false, diagnostics = false, table = false, wait_match = false;
  DdsOptions options;
  app.add_option("--domain", domain, "DDS domain id 0..232 (default: CYCLONEDDS_URI's, else 0)")
      ->check(CLI::Range(0, 232));
  app.add_flag("--status", status, "also print rt/skin/patch_status (patches and events)");
  app.add_flag("--diagnostics", diagnostics,
               "also print rt/diagnostics (each patch's health as diagnostic_msgs/DiagnosticArray: "
               "OK, WARN, ERROR or STALE with the reasons)");
  app.add_flag("--table", table, "print a compact table instead of JSON lines");
  app.add_option("--count", count, "exit after N contact arrays (0: run until Ctrl-C)")
      ->check(CLI::NonNegativeNumber)
      ->capture_default_str();
  app.add_option("--timeout", timeout_s,
                 "give up after SECONDS without a message (0: never); exit 1 if --count was not "
                 "reached or nothing arrived")
      ->check(CLI::NonNegativeNumber)
      ->capture_default_str();
  app.add_flag("--wait-match", wait_match,
               "first wait (within --timeout) until a contacts publisher is matched, and say so "
               "on stderr");
  std::string ns;
  app.add_option(
      "--namespace", ns,
      "the publishing host's --namespace: topics rt/NS/skin/... (docs/guides/scaling.md)");
  app.add_option("--contacts-topic", options.contacts_topic, "DDS topic of the contacts")
      ->capture_default_str();
  app.add_option("--diagnostics-topic", options.diagnostics_topic, "DDS topic of the diagnostics")
      ->capture_default_str();
  app.add_option("--status-topic", options.patch_status_topic, "DDS topic of the patch status")
      ->capture_default_str();
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e) == 0 ? 0 : 2;  // --help: 0
  }
  if (domain >= 0) options.domain_id = static_cast<uint32_t>(domain);
  if (Status st = apply_namespace(&options, ns); !st.ok()) {
    return skinbus::tools::fail("skinbus-listen", st.error().to_string(), 2);
  }

  tools::install_stop_handler();
  auto sub = SkinSubscriber::create(options);
  if (!sub.ok()) {
    return skinbus::tools::fail("skinbus-listen", sub.error().to_string(), 1);
  }
  using Clock = std::chrono::steady_clock;
  const auto timeout =
      std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(timeout_s));
  auto last_activity = Clock::now();
  auto timed_out = [&] { return timeout_s > 0 && Clock::now() - last_activity >= timeout; };

  if (wait_match) {
    while (true) {
      auto r = (*sub)->wait_for_publisher(SkinTopic::kContacts, kSliceMs);
      if (!r.ok()) {
        return skinbus::tools::fail("skinbus-listen", r.error().to_string(), 1);
      }
      if (*r) break;
      if (tools::stop_requested()) return 1;
      if (timed_out()) {
        return skinbus::tools::fail("skinbus-listen",
                                    "no publisher of " + options.contacts_topic +
                                        " matched within " + skinbus::tools::format_g(timeout_s) +
                                        " s",
                                    1);
      }
    }
    std::fprintf(stderr, "skinbus-listen: matched a publisher of %s\n",
                 options.contacts_topic.c_str());
  }

  int contact_arrays = 0;
  bool anything = false, header_done = false;
  ContactArray contacts;
  PatchStatusArray patch_status;
  DiagnosticArray health;
  // Diagnostics are written with every patch status: waiting for either wakes for both.
  const bool more = status || diagnostics;
  while (!tools::stop_requested()) {
    // Without --status only the contacts are waited for (status samples stay unread in the
    // reader's bounded history); with it, whichever comes first.
    if (more) {
      auto w = (*sub)->wait_any(kSliceMs);
      if (!w.ok()) {
        return skinbus::tools::fail("skinbus-listen", w.error().to_string(), 1);
      }
    }
    for (int wait_ms = more ? 0 : kSliceMs;; wait_ms = 0) {
      auto r = (*sub)->wait_contacts(&contacts, wait_ms);
      if (!r.ok()) {
        std::fprintf(stderr, "skinbus-listen: %s\n", r.error().to_string().c_str());
        if (sample_error(r.error())) continue;
        return 1;
      }
      if (!*r) break;
      anything = true;
      last_activity = Clock::now();
      if (table) {
        print_table(contacts, &header_done);
      } else {
        print_line(contacts_to_json(contacts));
      }
      if (count > 0 && ++contact_arrays >= count) return 0;
    }
    // Every patch status, then every diagnostic array the readers hold now.
    auto drain = [&](auto take, auto& sample, auto to_json) {
      for (;;) {
        auto r = take(&sample);
        if (!r.ok()) {
          std::fprintf(stderr, "skinbus-listen: %s\n", r.error().to_string().c_str());
          if (sample_error(r.error())) continue;
          return false;  // the subscriber failed, not one sample
        }
        if (!*r) return true;
        anything = true;
        last_activity = Clock::now();
        if (table) {
          print_table(sample);
        } else {
          print_line(to_json(sample));
        }
      }
    };
    if (status && !drain([&](PatchStatusArray* out) { return (*sub)->wait_patch_status(out, 0); },
                         patch_status, patch_status_to_json)) {
      return 1;
    }
    if (diagnostics &&
        !drain([&](DiagnosticArray* out) { return (*sub)->wait_diagnostics(out, 0); }, health,
               diagnostics_to_json)) {
      return 1;
    }
    if (timed_out()) {
      if (!anything) {
        std::fprintf(stderr, "skinbus-listen: nothing arrived on %s within %g s\n",
                     options.contacts_topic.c_str(), timeout_s);
      } else if (count > 0) {
        std::fprintf(stderr, "skinbus-listen: %d of %d contact arrays, then nothing for %g s\n",
                     contact_arrays, count, timeout_s);
      }
      return anything && count == 0 ? 0 : 1;
    }
  }
  return anything && count == 0 ? 0 : 1;  // Ctrl-C
}
